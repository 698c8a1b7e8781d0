"""Where a camera should look to show a cloud: the shape of the data (an object or a terrain
tile), the automatic viewing directions, and the framing that makes the points fill the image.

:meth:`pointviz.camera.Camera.fit` is the entry point; the functions here take the camera class
they build, so this module does not depend on the camera's own."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .arrays import bounds as _bounds
from .errors import InputError
from .values import check_fov, check_image_size, check_real, check_vec3

#: The camera values this module makes and reads: :class:`pointviz.camera.Camera`, whose class
#: ``fit_camera`` receives as an argument, so that framing never imports the camera module (the
#: camera module depends on framing, not the other way round).
CameraValue = Any

#: Default up vector (+Y), used when neither the caller nor the cloud says.
DEFAULT_UP = (0.0, 1.0, 0.0)
#: Default viewing direction of :meth:`Camera.fit` (from the eye toward the cloud): from the +Z
#: side and slightly above for a +Y-up scene.
DEFAULT_FIT_DIRECTION = (0.0, -0.3, -1.0)
#: Bisection steps of the tight framing of an automatic view (relative precision 2^-steps).
FIT_BISECTION_STEPS = 30
#: Default padding of :meth:`Camera.fit`: the bounding sphere's image radius is the half size of
#: the smaller image side divided by this.
DEFAULT_MARGIN = 1.05
#: Automatic views of :meth:`Camera.fit` (``direction=None``). An object is seen from a
#: three-quarter view: OBJECT_AZIMUTH_DEG off the normal of its longest horizontal axis (its
#: broad side), OBJECT_ELEVATION_DEG above the horizon. A terrain tile is seen from above at an
#: oblique angle (one of TERRAIN_ELEVATIONS_DEG below the horizon), across its short or along its
#: long horizontal axis: whichever fills the frame most.
OBJECT_AZIMUTH_DEG = 30.0
OBJECT_ELEVATION_DEG = 20.0
TERRAIN_ELEVATIONS_DEG = (50.0, 62.0)
#: A cloud taken from one viewpoint (a depth camera's frame) is seen from there, raised by this
#: much: the view its points were taken for, which hides the gaps behind them, with enough
#: height to show their relief and the ground. Only when the data lies in front of the
#: viewpoint: (1 - VIEWPOINT_QUANTILE) of the points within VIEWPOINT_CONE_DEG of the line of
#: sight to their centre (a scanner in the middle of its scene has no such view).
VIEWPOINT_ELEVATION_DEG = 10.0
VIEWPOINT_CONE_DEG = 70.0
VIEWPOINT_QUANTILE = 0.05
#: Cells (columns, rows) of the occupancy grid that compares the terrain views.
COVERAGE_GRID = (64, 48)
#: Points used to compare the candidate terrain views.
FIT_CANDIDATE_SAMPLE = 8000
#: A cloud is a terrain tile when its height (along up, between the TERRAIN_QUANTILE and
#: 1 - TERRAIN_QUANTILE quantiles) is below this fraction of its smaller horizontal extent.
TERRAIN_FLATNESS = 0.25
TERRAIN_QUANTILE = 0.01
#: Points used to decide the shape and framing of a large cloud (an even subsample).
FIT_SAMPLE = 50000
#: Fraction of points Camera.fit may leave out of the frame (stray points of raw scans).
FIT_OUTLIER_FRACTION = 0.002
#: Below this many points every point is framed (too few to call any of them stray).
FIT_ROBUST_MIN_POINTS = 2000
#: Points per block of :func:`bounding_sphere`: bounds its temporaries.
SPHERE_BLOCK = 1 << 18
#: Radius used by :meth:`Camera.fit` for a cloud whose points all coincide (scene units).
DEGENERATE_RADIUS = 1.0


def bounding_sphere(points: Any, name: str = "points") -> tuple[np.ndarray, float]:
    """Bounding sphere of a point set: centre of the bounding box, radius to the farthest point.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Finite points, n >= 1.
    name : str
        Argument name used in error messages.

    Returns
    -------
    centre : ndarray, shape (3,), float64
    radius : float
        ``max |p - centre|``; 0 if all points coincide.
    """
    return _sphere(*_check_points(points, name))


def _check_points(points: Any, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``points`` as an (n, 3) numeric array (n >= 1) of finite values, and its bounds (lo, hi,
    float64); InputError naming ``name`` otherwise."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.dtype.kind not in "iuf":
        raise InputError(f"{name} must be an (n, 3) numeric array, got shape {pts.shape}")
    if pts.shape[0] == 0:
        raise InputError(f"{name} is empty")
    lo, hi = _bounds(pts)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise InputError(f"{name} contains NaN or inf")
    return pts, lo, hi


def _sphere(pts: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, float]:
    """:func:`bounding_sphere` of checked points with bounds (lo, hi)."""
    centre = 0.5 * (lo + hi)
    # block by block: the whole cloud's offsets at once would be 56 bytes per point (float64
    # offsets whatever the points' type: the same numbers as converting the points first)
    r2 = max(float(np.max(np.einsum("ij,ij->i", d, d)))
             for d in (pts[b:b + SPHERE_BLOCK] - centre for b in range(0, len(pts), SPHERE_BLOCK)))
    return centre, float(np.sqrt(r2))


def fit_distance(
    radius: float, fov_deg: float, width: int, height: int, margin: float = DEFAULT_MARGIN
) -> float:
    """Eye distance at which a sphere fills the smaller field of view with a margin.

    The sphere's silhouette (a circle on the image, centred when the camera looks at the
    sphere's centre) gets the radius ``min(width, height) / (2 * margin)`` pixels: its tangent
    cone has half angle ``theta = atan(tan_half_min / margin)`` where ``tan_half_min`` is the
    tangent of the smaller half field of view, so the distance is ``radius / sin(theta)``.

    Parameters
    ----------
    radius : float
        Sphere radius (> 0).
    fov_deg : float
        Vertical field of view, degrees.
    width, height : int
        Image size, pixels.
    margin : float
        Padding factor (> 0); 1 makes the sphere touch the image border.

    Returns
    -------
    float
        Distance from the eye to the sphere centre.
    """
    margin = check_real(margin, "margin")
    if margin <= 0.0:
        raise InputError(f"margin must be > 0, got {margin}")
    tan_half = math.tan(math.radians(check_fov(fov_deg)) / 2.0)
    aspect = check_image_size(width, "width") / check_image_size(height, "height")
    tan_half_min = tan_half * min(1.0, aspect)
    theta = math.atan(tan_half_min / margin)
    return float(radius) / math.sin(theta)


def _rotate_y_to(v: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``v`` rotated by the smallest rotation that takes +Y to ``up``."""
    y = np.array([0.0, 1.0, 0.0])
    u = np.asarray(up, dtype=np.float64)
    n = np.linalg.norm(u)
    if not n > 0:
        return v
    u = u / n
    axis = np.cross(y, u)
    s, c = np.linalg.norm(axis), float(y @ u)
    if s < 1e-12:
        return v if c > 0 else -v
    k = axis / s
    return v * c + np.cross(k, v) * s + k * (k @ v) * (1.0 - c)


def _cloud_points_and_up(cloud: Any) -> tuple[np.ndarray, Any]:
    """Points (n, 3) and optional ``up`` of a cloud object (or a bare (n, 3) array)."""
    points = getattr(cloud, "points", cloud)
    return np.asarray(points), getattr(cloud, "up", None)


def _single_viewpoint(cloud: Any) -> np.ndarray | None:
    """The one viewpoint (3,) of a cloud taken from a single position, else None."""
    vp = getattr(cloud, "viewpoints", None)
    if vp is None:
        return None
    vp = np.asarray(vp, dtype=np.float64)
    return vp if vp.shape == (3,) and np.isfinite(vp).all() else None


def viewpoint_direction(pts: np.ndarray, centre: np.ndarray, viewpoint: np.ndarray,
                        up: np.ndarray) -> np.ndarray | None:
    """The automatic view of a cloud taken from ``viewpoint``: its line of sight to the data's
    ``centre``, raised by VIEWPOINT_ELEVATION_DEG about the horizontal axis across it; None when
    the data does not lie in front of the viewpoint (see VIEWPOINT_CONE_DEG) or the line of
    sight is along ``up``."""
    sight = centre - viewpoint
    length = float(np.linalg.norm(sight))
    if not length > 0.0:
        return None
    sight = sight / length
    rays = pts - viewpoint
    norms = np.linalg.norm(rays, axis=1)
    ok = norms > 0
    if not ok.any():
        return None
    cos = (rays[ok] @ sight) / norms[ok]
    if np.quantile(cos, VIEWPOINT_QUANTILE) < math.cos(math.radians(VIEWPOINT_CONE_DEG)):
        return None
    u = up / np.linalg.norm(up)
    horizontal = sight - u * (sight @ u)
    h = float(np.linalg.norm(horizontal))
    if h < 1e-6:
        return None
    horizontal /= h
    below = math.asin(float(np.clip(-(sight @ u), -1.0, 1.0)))  # the line of sight's dip
    elev = min(below + math.radians(VIEWPOINT_ELEVATION_DEG), math.radians(89.0))
    return math.cos(elev) * horizontal - math.sin(elev) * u


def _horizontal_axes(pts: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit up, and the longest and shortest horizontal principal axes of the points."""
    u = up / np.linalg.norm(up)
    flat = pts - np.outer(pts @ u, u)
    flat = flat - flat.mean(axis=0)
    cov = flat.T @ flat
    w, v = np.linalg.eigh(cov)
    major = v[:, 2] - u * (v[:, 2] @ u)
    if not np.linalg.norm(major) > 1e-12:  # no horizontal spread: any horizontal axis
        major = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 0.0, 1.0])
    major = major / np.linalg.norm(major)
    minor = np.cross(u, major)
    return u, major, minor


def fit_sample(points: np.ndarray) -> np.ndarray:
    """The even subsample (a view: every ``len // FIT_SAMPLE``-th row) that :func:`shape_kind`
    and :func:`fit_camera` look at; the array itself when it has at most FIT_SAMPLE rows.
    Taking it again changes nothing, so a caller may take it before an elementwise transform
    of the rows (a change of frame) to avoid transforming the whole cloud."""
    return points[:: len(points) // FIT_SAMPLE] if len(points) > FIT_SAMPLE else points


def shape_kind(points: Any, up: Any = DEFAULT_UP) -> str:
    """What a cloud looks like from its points: ``"terrain"`` or ``"object"``.

    A terrain tile is flat and wide: its height along ``up`` (between the TERRAIN_QUANTILE and
    1 - TERRAIN_QUANTILE quantiles, so stray points do not count) is below TERRAIN_FLATNESS
    times its smaller horizontal extent (same quantiles, along its principal axes).

    Parameters
    ----------
    points : array_like, shape (n, 3)
    up : array_like, shape (3,)

    Returns
    -------
    str
    """
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 4:
        return "object"
    pts = fit_sample(pts).astype(np.float64, copy=False)  # no whole-cloud float64 copy
    return _shape_kind_of(pts, _horizontal_axes(pts, check_vec3(up, "up")))


def _shape_kind_of(pts: np.ndarray, axes: tuple[np.ndarray, np.ndarray, np.ndarray]) -> str:
    """:func:`shape_kind` of a float64 sample (at least 4 rows) whose :func:`_horizontal_axes`
    are ``axes``."""
    u, major, minor = axes
    q = (TERRAIN_QUANTILE, 1.0 - TERRAIN_QUANTILE)
    height = np.diff(np.quantile(pts @ u, q))[0]
    width = min(np.diff(np.quantile(pts @ major, q))[0], np.diff(np.quantile(pts @ minor, q))[0])
    return "terrain" if width > 0 and height < TERRAIN_FLATNESS * width else "object"


def _auto_directions(pts: np.ndarray, up: np.ndarray) -> list[np.ndarray]:
    """The viewing directions :func:`fit_camera` may pick from the data's shape, best first
    for an object (one three-quarter view); for a terrain tile, views across its short axis and
    along its long axis at each of TERRAIN_ELEVATIONS_DEG (the one that fills the frame most is
    kept)."""
    axes = _horizontal_axes(pts, up)
    u, major, minor = axes
    # a deterministic side: the one facing the default view (+Z for +Y up)
    front = _rotate_y_to(-np.asarray(DEFAULT_FIT_DIRECTION, dtype=np.float64), u)
    if minor @ front < 0:
        minor, major = -minor, -major
    # shape_kind(pts, u): its axes are these unless normalising u again moves it by a rounding
    if len(pts) < 4:
        kind = "object"
    elif np.array_equal(u / np.linalg.norm(u), u):
        kind = _shape_kind_of(pts, axes)
    else:
        kind = shape_kind(pts, u)
    if kind == "terrain":
        # the principal axes, and the data's own horizontal axes (LiDAR tiles are cut along
        # their map grid, which the principal axes of an irregular tile miss)
        sides = [minor, major]
        for axis in np.eye(3):
            h = axis - u * (axis @ u)
            if np.linalg.norm(h) > 0.5:
                h = h / np.linalg.norm(h)
                sides.append(h if h @ front >= 0 else -h)
        out = []
        for elev_deg in TERRAIN_ELEVATIONS_DEG:
            elev = math.radians(elev_deg)
            for side in sides:
                out.append(-math.cos(elev) * side - math.sin(elev) * u)
        return out
    az, elev = math.radians(OBJECT_AZIMUTH_DEG), math.radians(OBJECT_ELEVATION_DEG)
    horizontal = math.cos(az) * minor + math.sin(az) * major
    return [-math.cos(elev) * horizontal - math.sin(elev) * u]


def frame_coverage(camera: CameraValue, points: np.ndarray) -> float:
    """Fraction of the image's COVERAGE_GRID cells that some projected point falls in: how much
    of the frame a dense cloud fills (a lower bound for a sparse one)."""
    px, depth = camera.project(points)
    ok = (depth > 0) & np.all((px >= 0) & (px < [camera.width, camera.height]), axis=1)
    gx, gy = COVERAGE_GRID
    cells = (px[ok] / [camera.width, camera.height] * [gx, gy]).astype(np.int64)
    return len(np.unique(cells[:, 1] * gx + cells[:, 0])) / (gx * gy)


class TailQuantiles:
    """``np.quantile(v, (q, 1 - q))`` (method "linear") of a sequence of finite arrays of one
    length whose values keep nearly the same order from one to the next, as the points'
    projections do while :func:`_fill_frame` bisects the eye distance.

    Each call remembers which entries were the lowest and the highest few (twice as many as the
    quantiles need); the next call takes as its lower threshold the largest of those entries'
    new values, so at least that many values lie at or below it, and each value left out lies
    above all of them: the order statistics the lower quantile interpolates are found by
    partitioning the few values below the threshold (likewise above). The result is numpy's,
    bit for bit: the same order statistics, interpolated with numpy's formula.

    Parameters
    ----------
    n : int
        Length of the arrays.
    q : float in (0, 0.5)
        The lower quantile; the upper one is ``1 - q``.
    """

    def __init__(self, n: int, q: float):
        self.n = int(n)
        self.q = (float(q), 1.0 - float(q))
        virtual = (self.n - 1) * np.asarray(self.q)      # numpy's "linear" virtual indices
        below = np.floor(virtual).astype(np.int64)
        self.i0, self.i1 = int(below[0]), int(below[1])
        self.gamma = (virtual - below).tolist()
        # the sequence's own search needs both pairs of order statistics inside the array
        self.exact = self.n >= 4 and 0 <= self.i0 and self.i1 + 1 <= self.n - 1
        # entries remembered at each end: twice the order statistics each side needs
        self.keep_low = min(self.n, 2 * (self.i0 + 2))
        self.keep_high = min(self.n, 2 * (self.n - self.i1))
        self.low = self.high = None   # indices of the last call's lowest / highest entries
        self.searched = 0             # values partitioned over all calls (for tests)

    @staticmethod
    def _lerp(a: float, b: float, t: float) -> float:
        """numpy's linear interpolation between neighbouring order statistics (``_lerp``)."""
        diff = b - a
        return b - diff * (1.0 - t) if t >= 0.5 else a + diff * t

    def _lowest(self, v: np.ndarray, sel: np.ndarray | None, ranks: tuple[int, int], keep: int,
                negate: bool = False):
        """Values of ranks ``ranks`` among v[sel] (all of v if sel is None), negated first with
        ``negate``, and the indices into v of its ``keep`` lowest."""
        vals = v if sel is None else v[sel]
        if negate:  # (only the selected values: the others are never looked at)
            vals = -vals
        self.searched += len(vals)
        order = np.argpartition(vals, sorted({*ranks, keep - 1}))
        kept = order[:keep] if sel is None else sel[order[:keep]]
        return float(vals[order[ranks[0]]]), float(vals[order[ranks[1]]]), kept

    def __call__(self, v: np.ndarray) -> tuple[float, float]:
        if not self.exact or len(v) != self.n:
            lo, hi = np.quantile(v, self.q)
            return float(lo), float(hi)
        n, i0, i1 = self.n, self.i0, self.i1
        sel_low = sel_high = None
        if self.low is not None:
            # at least keep_low values lie at or below this, and none left out lies below it
            sel_low = np.flatnonzero(v <= v[self.low].max())
            sel_high = np.flatnonzero(v >= v[self.high].min())
        a0, b0, self.low = self._lowest(v, sel_low, (i0, i0 + 1), self.keep_low)
        # the highest values, as the lowest of their negatives: v's rank r is rank n-1-r there
        b1, a1, self.high = self._lowest(v, sel_high, (n - 2 - i1, n - 1 - i1), self.keep_high,
                                         negate=True)
        a1, b1 = -a1, -b1
        return self._lerp(a0, b0, self.gamma[0]), self._lerp(a1, b1, self.gamma[1])


def _fill_frame(camera: CameraValue, pts: np.ndarray, outliers: float,
                margin: float) -> CameraValue:
    """``camera`` moved along its view direction and sideways so that the points (all but
    ``outliers`` on each side) fill the image shrunk by ``margin``, centred.

    For an eye distance ``d`` the target is recentred on the points' projected bounds (a few
    fixed-point steps), and ``d`` is bisected to the closest eye whose frame holds them all,
    in front of the eye.
    """
    f, r, u = camera.forward, camera.right, camera.true_up
    half_x = camera.tan_half * camera.width / camera.height / margin
    half_y = camera.tan_half / margin
    q = (outliers / 2, 1.0 - outliers / 2) if outliers > 0 else None
    centre0 = camera.target

    # the points along the camera's axes once: each eye below only shifts them (155 calls on
    # a FIT_SAMPLE-point sample for a default fit)
    along_f, along_r, along_u = pts @ f, pts @ r, pts @ u
    # every depth along_f - e is > 0 exactly when the nearest point's is (for finite doubles
    # a - b > 0 iff a > b): one comparison instead of one per point
    nearest = along_f.min()
    if q is not None:
        tails_x, tails_y = TailQuantiles(len(pts), q[0]), TailQuantiles(len(pts), q[0])

    def bounds(eye):
        ef = eye @ f
        if not nearest > ef:
            return None
        depth = along_f - ef
        x, y = (along_r - eye @ r) / depth, (along_u - eye @ u) / depth
        if q is None:
            return x.min(), x.max(), y.min(), y.max()
        (x0, x1), (y0, y1) = tails_x(x), tails_y(y)
        return x0, x1, y0, y1

    def place(d):
        """Target for distance d, and whether the framed points fit."""
        target = centre0
        for _ in range(4):
            b = bounds(target - d * f)
            if b is None:
                return target, False
            x0, x1, y0, y1 = b
            target = target + d * (0.5 * (x0 + x1) * r + 0.5 * (y0 + y1) * u)
        b = bounds(target - d * f)
        if b is None:
            return target, False
        x0, x1, y0, y1 = b
        fits = (x1 - x0) / 2 <= half_x * (1 + 1e-9) and (y1 - y0) / 2 <= half_y * (1 + 1e-9)
        return target, fits

    far = camera.distance
    target, ok = place(far)
    while not ok and far < 1e6 * camera.distance:
        far *= 2.0
        target, ok = place(far)
    if not ok:
        return camera
    near = 0.0
    for _ in range(FIT_BISECTION_STEPS):
        mid = 0.5 * (near + far)
        t, fits = place(mid)
        if fits:
            far, target = mid, t
        else:
            near = mid
    return type(camera)(target - far * f, target, camera.up, camera.fov_deg, camera.width,
                        camera.height)


def fit_camera(cls: type, cloud: Any, direction: Any, fov_deg: float, width: int, height: int,
               up: Any, margin: float, outliers: float):
    """The camera (an instance of ``cls``) that frames a whole cloud: the work of
    :meth:`pointviz.camera.Camera.fit`, whose docstring states the rules; the arguments are
    the same."""
    points, cloud_up = _cloud_points_and_up(cloud)
    points, lo, hi = _check_points(points, "cloud.points")
    outliers = check_real(outliers, "outliers")
    if not 0.0 <= outliers <= 0.1:
        raise InputError(f"outliers must be in [0, 0.1], got {outliers}")
    margin = check_real(margin, "margin")
    if margin <= 0.0:
        raise InputError(f"margin must be > 0, got {margin}")
    if len(points) < FIT_ROBUST_MIN_POINTS:
        outliers = 0.0
    if outliers == 0.0:  # (else centre and radius come from the sample's quantiles below)
        centre, radius = _sphere(points, lo, hi)
    # the sample before any conversion: a float32 cloud is not copied whole to float64
    pts = fit_sample(points).astype(np.float64, copy=False)
    if outliers > 0.0:
        lo = np.quantile(pts, outliers / 2, axis=0)
        hi = np.quantile(pts, 1.0 - outliers / 2, axis=0)
        centre = 0.5 * (lo + hi)
        dist = np.sqrt(np.einsum("ij,ij->i", pts - centre, pts - centre))
        radius = float(np.quantile(dist, 1.0 - outliers))
    if up is None:
        up = cloud_up if cloud_up is not None else DEFAULT_UP
        up_name = "cloud.up" if cloud_up is not None else "up"
    else:
        up_name = "up"
    up = check_vec3(up, up_name)
    auto = direction is None
    candidates = []
    if auto:
        viewpoint = _single_viewpoint(cloud)
        seen = None if viewpoint is None else viewpoint_direction(pts, centre, viewpoint, up)
        candidates = [seen] if seen is not None else _auto_directions(pts, up)
        direction = candidates[0]
    direction = check_vec3(direction, "direction")
    norm = float(np.linalg.norm(direction))
    if norm == 0.0:
        raise InputError("direction must be a non-zero vector")
    if np.array_equal(direction, DEFAULT_FIT_DIRECTION):
        direction = _rotate_y_to(np.asarray(DEFAULT_FIT_DIRECTION, dtype=np.float64), up)
        norm = float(np.linalg.norm(direction))
    direction = direction / norm
    if radius == 0.0:
        radius = DEGENERATE_RADIUS
        auto = False
    distance = fit_distance(radius, fov_deg, width, height, margin)
    camera = cls(centre - distance * direction, centre, up, fov_deg, width, height)
    if not auto:
        return camera
    if len(candidates) > 1:
        few = pts[:: max(1, len(pts) // FIT_CANDIDATE_SAMPLE)]
        best = -1.0
        for cand in candidates:
            c = cand / np.linalg.norm(cand)
            trial = _fill_frame(cls(centre - distance * c, centre, up, fov_deg, width, height),
                                few, outliers, margin)
            cover = frame_coverage(trial, few)
            if cover > best + 1e-3:
                best, camera = cover, trial
    return _fill_frame(camera, pts, outliers, margin)
