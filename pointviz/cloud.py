"""Point clouds as surfels: positions, normals, radii and optional colours.

:class:`PointCloud` validates and owns the arrays the renderer consumes. Normals and radii that
were not given are estimated lazily, on first access, by :mod:`pointviz.estimation` (the C++
core): normals from a neighbourhood chosen per point, oriented toward the scanner when the
viewpoints are known and by minimum-spanning-tree propagation otherwise; radii that cover the
surface. :meth:`PointCloud.fitted` moves raw scans onto a fitted surface.

Only numpy and the core are needed here; Open3D and pyvista are imported inside the converters
that use them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .array_checks import (  # noqa: F401 - the checks of the arrays a cloud is made of
    check_finite as _check_finite,
    colors as _validate_colors,
    normals as _validate_normals,
    numeric as _numeric,
    per_point as _validate_per_point,
    radii as _validate_radii,
    rows3 as _rows3,
    unit_vector as _unit_vector,
    viewpoints as _validate_viewpoints,
)
from .arrays import bounds
from .errors import InputError, require
from .estimation import (  # noqa: F401 - re-exported: the estimation used to live here
    COVER_CAP,
    COVER_DIRECTIONS,
    COVER_GLOBAL_CAP,
    COVER_K,
    COVER_MARGIN,
    NORMAL_K,
    ORIENT_DISTANCE_WEIGHT,
    ORIENT_K,
    OUTWARD_UNDECIDED_MARGIN,
    RADIUS_FACTOR,
    RADIUS_K,
    SurfaceFit,
    coverage_radii,
    estimate_normals,
    estimate_radii,
    fit_surface,
    knn,
    normals_and_radii,
    orient_normals,
)
from .settings import check_int

# Largest extent of a cloud: surfels are stored in float32 relative to the cloud's centre, and
# squared distances (normal and radius estimation) must stay finite in float64.
MAX_EXTENT = 1e30


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, cross=None) -> np.ndarray:
    """Area-weighted vertex normals of a triangle mesh (follows the face winding).

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int
    cross : (f, 3) float, optional
        The faces' edge cross products (v1 - v0) x (v2 - v0), when the caller has them.

    Returns
    -------
    normals : (v, 3) float64
        Unit normals; rows of vertices not used by any (non-degenerate) face are zero.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if cross is None:  # |cross| = 2 * area
        cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    # each face's cross product added to its three corners: one weighted count per axis
    corners = f.reshape(-1)
    acc = np.stack([np.bincount(corners, weights=np.repeat(cross[:, k], 3), minlength=len(v))
                    for k in range(3)], axis=1) if len(f) else np.zeros_like(v)
    length = np.linalg.norm(acc, axis=1)
    return np.divide(acc, length[:, None], out=np.zeros_like(acc), where=length[:, None] > 0)


#: Most boundary edges (in one face only) a mesh may have, as a share of its edges, for its
#: winding's signed volume to say which way is out (a few holes or seams left by zippering).
CLOSED_BOUNDARY_SHARE = 0.02


def outward_faces(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, bool]:
    """The faces wound outward: those of a closed mesh whose winding encloses a negative volume
    (counter-clockwise seen from inside: a mesh saved inside out) with two of each face's
    vertices swapped; any other mesh's as given.

    The signed volume (summed over faces, about the vertices' centroid) decides only when the
    mesh is closed: at most CLOSED_BOUNDARY_SHARE of its edges belong to one face. An open sheet
    has no inside, and its winding is kept.

    Returns
    -------
    faces : (f, 3) int64
    turned : bool
        Whether the winding was turned.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    c = v.mean(axis=0)
    a, b, d = v[f[:, 0]] - c, v[f[:, 1]] - c, v[f[:, 2]] - c
    if not np.einsum("ij,ij->i", a, np.cross(b, d)).sum() < 0:
        return f, False
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    key = edges[:, 0] * np.int64(len(v)) + edges[:, 1]
    _, count = np.unique(key, return_counts=True)
    if np.count_nonzero(count == 1) > CLOSED_BOUNDARY_SHARE * len(count):
        return f, False
    return f[:, [0, 2, 1]], True


#: Largest angle between a vertex's normal and a face's normal for the face's samples to take
#: it: beyond it the vertex sits on a crease (a box's edge) and the face keeps its own normal.
SMOOTHING_ANGLE_DEG = 45.0


def _smooth_sample_normals(v, f, cross, area2, face, wa, wb, wc) -> np.ndarray:
    """Normals of points sampled on faces ``face`` at barycentric weights ``(wa, wb, wc)``: the
    corners' normals blended by those weights (the smooth surface a mesh's shading shows, not
    its flat facets). A corner takes its vertex's area-weighted normal where that vertex is
    smooth (every face around it within SMOOTHING_ANGLE_DEG of the vertex normal), else its
    face's own normal: a crease (a box's edge or corner) stays sharp."""
    face_n = cross / np.where(area2 > 0, area2, 1.0)[:, None]
    vert_n = vertex_normals(v, f, cross)
    corner_dot = np.stack([np.einsum("ij,ij->i", vert_n[f[:, k]], face_n) for k in range(3)], 1)
    worst = np.ones(len(v))
    np.minimum.at(worst, f.reshape(-1), corner_dot.reshape(-1))
    smooth = worst >= np.cos(np.radians(SMOOTHING_ANGLE_DEG))
    fn = face_n[face]
    out = np.zeros_like(fn)
    for corner, weight in zip(f[face].T, (wa, wb, wc)):
        out += weight[:, None] * np.where(smooth[corner][:, None], vert_n[corner], fn)
    length = np.linalg.norm(out, axis=1)
    ok = length > 1e-12
    out[ok] /= length[ok, None]
    out[~ok] = fn[~ok]
    return out


def _check_faces(faces, nverts: int) -> np.ndarray:
    arr = _numeric("faces", faces)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"faces: expected shape (f, 3) of triangle indices, got {arr.shape}")
    if arr.dtype.kind == "f" and not (np.all(np.isfinite(arr)) and np.all(arr == np.round(arr))):
        raise InputError("faces: expected integer vertex indices")
    arr = arr.astype(np.int64)
    if arr.size and (arr.min() < 0 or arr.max() >= nverts):
        raise InputError(f"faces: indices must be in 0..{nverts - 1}, got {arr.min()}..{arr.max()}")
    return arr


def _rng(rng) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(rng)


class _Handed:
    """An array attribute of a :class:`PointCloud` that :meth:`PointCloud.hand_over` can take
    away: reading it afterwards raises InputError instead of returning a freed array."""

    def __set_name__(self, owner, name: str) -> None:
        self.name, self.slot = name, "_held" + name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        state = obj.__dict__
        if state.get("_handed_over"):
            raise InputError("cloud: its arrays were handed over to a SurfelScene "
                             "(consume_cloud=True); load or copy the cloud again to use it")
        return state[self.slot]

    def __set__(self, obj, value) -> None:
        obj.__dict__[self.slot] = value


# ---------------------------------------------------------------------------------------------


class PointCloud:
    """A surfel cloud: positions, normals, radii, optional colours.

    Parameters
    ----------
    points : (n, 3) array_like
        Positions, any real dtype; stored as C-contiguous float64 (georeferenced scans sit at
        1e6..1e7, where float32 keeps only decimetres).
    normals : (n, 3) array_like, optional
        Normals; normalised. Zero rows are an error. If omitted they are estimated on first
        access (:func:`pointviz.estimation.estimate_normals`, consistently oriented) and cached.
    radii : (n,) array_like or scalar, optional
        Disk radii > 0. If omitted they are estimated on first access so that the disks cover
        the surface (:func:`pointviz.estimation.coverage_radii`) and cached.
    colors : (n, 3) array_like, optional
        sRGB colours: floats in [0, 1] or 8-bit integers 0..255 (uint16 is scaled by 65535).
        An RGBA array's alpha is dropped. Stored as float32 in [0, 1].
    up : (3,) array_like, optional
        "Up" hint (normalised), e.g. +Z for airborne LiDAR, +Y for the Stanford models.
    seen_from_above : bool
        The sensor saw every surface from the ``up`` side, never from below (aerial and most
        terrestrial LiDAR; the LAS/LAZ reader sets it): estimated normals face up, or their
        oriented neighbours where they are steep (``estimate_normals(from_above=True)``),
        instead of being oriented along a spanning tree. Needs ``up``.
    name : str, optional
        A label, e.g. the file name.
    viewpoints : (3,) or (n, 3) array_like, optional
        Scanner position(s); estimated normals are oriented toward them.
    intensity : (n,) array_like, optional
        Per-point return intensity (LiDAR), stored as float32.
    scan_index : (n,) array_like of int, optional
        Which scan each point came from (registered range scans), stored as int32.
    scan_grid : (n, 2) array_like of int, optional
        Row and column of each point in its scan's sampling grid (a range scan's grid of rays,
        e.g. a PLY ``range_grid``; negative: none), stored as int32; needs ``scan_index``.
        Normals then take their neighbours within a scan from the grid (faster, see
        :func:`pointviz.estimation.estimate_normals`).
    notes : list of str, optional
        Human-readable remarks from loading (e.g. how many non-finite points were dropped).

    Raises
    ------
    InputError
        If an array has the wrong shape or dtype, contains NaN/inf, a normal has zero length, a
        radius is <= 0, a colour is outside [0, 1], the lengths differ, or the cloud is empty.
    """

    _points = _Handed()
    _normals = _Handed()
    _radii = _Handed()
    _colors = _Handed()

    def __init__(
        self,
        points,
        normals=None,
        radii=None,
        colors=None,
        *,
        up=None,
        seen_from_above: bool = False,
        name=None,
        viewpoints=None,
        intensity=None,
        scan_index=None,
        scan_grid=None,
        notes: Sequence[str] | None = None,
    ):
        pts = _rows3("points", points, None)
        n = pts.shape[0]
        if n == 0:
            raise InputError("points: the cloud is empty (0 points)")
        self._points = np.ascontiguousarray(pts, dtype=np.float64)
        lo, hi = bounds(self._points)
        extent = float(np.max(hi - lo))
        if not extent <= MAX_EXTENT:
            raise InputError(
                f"points: the cloud spans {extent:.3g} units, beyond what float32 surfels can "
                f"resolve (limit {MAX_EXTENT:.0e}); check for corrupt or mis-scaled coordinates")
        self._points.setflags(write=False)
        self._normals = None if normals is None else _validate_normals(normals, n)
        self._normals_given = normals is not None
        self._radii = None if radii is None else _validate_radii(radii, n)
        self._radii_given = radii is not None
        self._colors = None if colors is None else _validate_colors(colors, n)
        self.up = None if up is None else _unit_vector("up", up)
        if not isinstance(seen_from_above, (bool, np.bool_)):
            raise InputError(f"seen_from_above: expected True or False, got {seen_from_above!r}")
        if seen_from_above and self.up is None:
            raise InputError("seen_from_above: needs up (the side the surfaces were seen from)")
        self.seen_from_above = bool(seen_from_above)
        if name is not None and not isinstance(name, str):
            raise InputError(f"name: expected a str, got {type(name).__name__}")
        self.name = name
        self.viewpoints = None if viewpoints is None else _validate_viewpoints(viewpoints, n)
        self.intensity = (
            None
            if intensity is None
            else _validate_per_point("intensity", intensity, n, np.float32)
        )
        if scan_index is not None:
            si = _numeric("scan_index", scan_index)
            if si.dtype.kind not in "iu":
                raise InputError(f"scan_index: expected integers, got dtype {si.dtype}")
            scan_index = _validate_per_point("scan_index", si, n, np.int32)
        self.scan_index = scan_index
        if scan_grid is not None:
            if scan_index is None:
                raise InputError("scan_grid: needs scan_index (the grid of which scan)")
            sg = _numeric("scan_grid", scan_grid)
            if sg.dtype.kind not in "iu":
                raise InputError(f"scan_grid: expected integers, got dtype {sg.dtype}")
            if sg.shape != (n, 2):
                raise InputError(f"scan_grid: expected shape ({n}, 2), got {sg.shape}")
            if sg.size and (sg.min() < -(2**31) or sg.max() >= 2**31):
                raise InputError("scan_grid: rows and columns must fit in 32 bits")
            scan_grid = np.ascontiguousarray(sg, dtype=np.int32)
        self.scan_grid = scan_grid
        self.notes: list[str] = list(notes) if notes is not None else []
        #: What :meth:`fitted` changed (a dict), or None for a cloud that was not fitted.
        self.fit_report: dict | None = None
        for arr in (self._normals, self._radii, self._colors):
            if arr is not None:
                arr.setflags(write=False)

    # -- attributes ---------------------------------------------------------------------------

    @property
    def points(self) -> np.ndarray:
        """(n, 3) float64, C-contiguous, read-only positions."""
        return self._points

    @property
    def normals(self) -> np.ndarray:
        """(n, 3) float32 unit normals; estimated (and cached) on first access if not given."""
        if self._normals is None and self._radii is None and self._lidar_at_once():
            # LiDAR without radii: both from the normals' neighbour search (the radii would
            # build a tree and search again)
            est, radii = normals_and_radii(self._points, up=self.up, from_above=True,
                                           volume=True)
            est.setflags(write=False)
            radii.setflags(write=False)
            self._normals, self._radii = est, radii
        if self._normals is None:
            est = estimate_normals(self._points, viewpoints=self.viewpoints,
                                   scan_index=self.scan_index, scan_grid=self.scan_grid,
                                   up=self.up,
                                   from_above=self.seen_from_above and self.up is not None)
            est.setflags(write=False)
            self._normals = est
        return self._normals

    def _lidar_at_once(self) -> bool:
        """Whether normals and radii are estimated together (:func:`normals_and_radii`): a
        cloud seen from above, without viewpoints or scans, with at least 3 distinct points."""
        pts = self._points
        return (self.seen_from_above and self.up is not None
                and self.viewpoints is None and self.scan_index is None and len(pts) >= 3
                and bool((pts != pts[0]).any()))

    @property
    def radii(self) -> np.ndarray:
        """(n,) float32 disk radii > 0; estimated (and cached) on first access if not given."""
        if self._radii is None:
            pts = self._points
            # all points at one position: one comparison pass (np.ptp over the short axis of
            # an (n, 3) array takes 8x longer, 0.05 s of CPU at 1M points)
            if len(pts) < 2 or not (pts != pts[0]).any():
                est = estimate_radii(self._points)  # raises the specific error
            else:
                normals = self.normals  # (LiDAR: estimates the radii with them)
                if self._radii is not None:
                    return self._radii
                # LiDAR (seen from above) holds returns of vegetation, not only of surfaces
                est = coverage_radii(pts, normals, volume=self.seen_from_above)
            est.setflags(write=False)
            self._radii = est
        return self._radii

    @property
    def is_raw_scan(self) -> bool:
        """Whether this is raw scan data that :meth:`fitted` is meant for: no normals were given
        and the scanner viewpoints are known (registered ``.conf`` scans, clouds with
        viewpoints), and it has not been fitted yet."""
        return (not self._normals_given and self.viewpoints is not None
                and getattr(self, "fit_report", None) is None)

    def fitted(self, *, thin: float | None = None, quadric: bool = True,
               steps: bool = True, edges: bool = True, threads: int = 0) -> PointCloud:
        """A copy moved onto a robust local fit of the surface, without redundant points.

        See :func:`pointviz.estimation.fit_surface`: each point moves onto a quadric fitted to
        its neighbourhood across all scans and takes that fit's normal; where scans overlap,
        points within the spacing of a kept point are dropped, and so are stray clusters (small
        pieces apart from the object). ``notes`` gets one line saying what changed, and
        ``fit_report`` holds it as numbers (``points_in``, ``points_kept``, ``mean_shift``,
        ``mean_shift_spacings``, ``unmoved``, ``stray_points``, ``stray_clusters``) and that line
        (``summary``).

        Parameters
        ----------
        thin : float, optional
            Thinning radius in units of each point's spacing in its own scan (default
            :data:`pointviz.estimation.FIT_THIN`; 0 keeps every point).
        quadric : bool
            Fit quadrics (default) or planes.
        steps : bool
            A depth-camera frame (one scan on a pixel grid, without normals) whose depths come
            in steps (:mod:`pointviz.depth_steps`: Kinect-class disparity quantisation) starts
            the fit from planes fitted over pixel patches as wide as the steps (default); False:
            from its raw points, as any scan.
        edges : bool
            With ``steps``: the patches stop at depth edges and the frame's flying pixels (mixed
            depths between a foreground edge and the background, in mid-air) are dropped, with
            a note saying how many (default); False: square patches across edges, nothing
            dropped.
        threads : int
            Worker threads, 0 for all cores; results do not depend on it.

        Returns
        -------
        PointCloud
            Normals are the fit's (counted as estimated: ``has_normals`` stays as it was);
            radii too unless this cloud's were given (``fit_surface(radii=True)``: the coverage
            radii for the new positions and spacing, their neighbours from the fit's).
        """
        from .estimation import FIT_THIN

        points, normals = self._points, self._normals
        step_note = None
        src = self  # the points the fit starts from: this cloud's, without flying pixels
        if steps and not self._normals_given:
            points, step_normals, step_note, flying = self._depth_step_planes(points, edges)
            if step_normals is not None:
                normals = step_normals
            if flying is not None and flying.any():
                kept = np.flatnonzero(~flying)
                src = self._subset(kept)
                points, normals = points[kept], normals[kept]
        fit = fit_surface(
            points, normals, viewpoints=src.viewpoints, scan_index=src.scan_index,
            scan_grid=src.scan_grid,
            up=self.up, thin=FIT_THIN if thin is None else thin, quadric=quadric,
            radii=not self._radii_given, threads=threads)
        if points is not self._points:  # the shift from the points as read
            fit.shift = np.linalg.norm(fit.points - src._points, axis=1).astype(np.float32)
        keep = np.flatnonzero(fit.keep)
        # every per-point attribute, estimated radii replaced; the points and normals the fit's
        # (this cloud's are not copied only to be replaced)
        out = src._subset(keep, points=fit.points.take(keep, axis=0),
                           normals=fit.normals.take(keep, axis=0))
        if fit.radii is not None:
            radii = fit.radii.take(keep)
            radii.setflags(write=False)
            out._radii = radii
        summary = fit.summary()
        if step_note:
            out.notes.append(step_note)
        out.notes.append(summary)
        shift = float(fit.shift.mean())
        out.fit_report = {
            "points_in": len(fit.keep),
            "points_kept": fit.kept,
            "mean_shift": shift,
            "mean_shift_spacings": shift / fit.spacing if fit.spacing > 0 else 0.0,
            "unmoved": fit.unmoved,
            "stray_points": fit.stray_points,
            "stray_clusters": fit.stray_clusters,
            "summary": summary,
        }
        return out

    def _depth_step_planes(self, points, edges=True):
        """(points, normals, note, flying) moved onto planes over pixel patches sized to a
        depth-camera frame's steps (:func:`pointviz.depth_steps.patch_planes`), or (points,
        None, None, None) when this is not one frame on a pixel grid or its depths are not
        stepped."""
        from .depth_steps import depth_steps, patch_planes

        grid, vp = self.scan_grid, self.viewpoints
        none = points, None, None, None
        if grid is None or vp is None or len(points) < 64 or (grid < 0).any():
            return none
        vp = np.asarray(vp, dtype=np.float64)
        if vp.ndim == 2:
            if not (vp == vp[0]).all():
                return none
            vp = vp[0]
        if self.scan_index is not None and (self.scan_index != self.scan_index[0]).any():
            return none
        if (int(grid[:, 0].max()) + 1) * (int(grid[:, 1].max()) + 1) > 16 * len(points):
            return none  # not a frame's pixels (its moment images would be mostly empty)
        step = depth_steps(points[:, 2])
        if step is None:
            return none
        moved, normals, radius, flying = patch_planes(points, grid, vp, step, edges=edges)
        lo, hi = np.percentile(step, [5, 95])
        r = radius[radius > 0]
        width = (f"{2 * int(np.median(r)) + 1} px wide (median; 5-95 %: "
                 f"{2 * int(np.percentile(r, 5)) + 1}-{2 * int(np.percentile(r, 95)) + 1})"
                 if len(r) else "none")
        note = (f"depths in steps of {lo:.3g}-{hi:.3g} (5-95 %): the fit starts from planes over "
                f"pixel patches {width}" + (" that stop at depth edges" if edges else ""))
        if flying.any():
            note += (f"; dropped {int(flying.sum())} flying pixels (depths in mid-air between a "
                     f"foreground edge and the background)")
        return moved, normals, note, flying

    @property
    def colors(self) -> np.ndarray | None:
        """(n, 3) float32 sRGB colours in [0, 1], or None."""
        return self._colors

    @property
    def has_normals(self) -> bool:
        """Whether normals were given or loaded (False when they are, or would be, estimated)."""
        return self._normals_given

    @property
    def has_radii(self) -> bool:
        """Whether radii were given or loaded (False when they are, or would be, estimated)."""
        return self._radii_given

    @property
    def has_colors(self) -> bool:
        """Whether the cloud has colours."""
        return self._colors is not None

    def __len__(self) -> int:
        return self._points.shape[0]

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi)``: (3,) float64 corners of the axis-aligned bounding box of the points."""
        return bounds(self._points)

    @property
    def center(self) -> np.ndarray:
        """(3,) float64 centre of the bounding box."""
        lo, hi = self.bounds
        return (lo + hi) / 2

    @property
    def diagonal(self) -> float:
        """Length of the bounding box diagonal."""
        lo, hi = self.bounds
        return float(np.linalg.norm(hi - lo))

    @property
    def handed_over(self) -> bool:
        """Whether :meth:`hand_over` took this cloud's arrays (it can no longer be used)."""
        return bool(self.__dict__.get("_handed_over"))

    def hand_over(self) -> dict:
        """Give the positions, normals, radii and colours away, for a consumer that frees each
        as soon as it has copied it (``SurfelScene(consume_cloud=True)``): the cloud keeps no
        reference to them, so that they are freed when the consumer drops its own.

        Normals and radii that were not given are estimated first. Afterwards every use of the
        arrays (``points``, ``len()``, ``bounds``, ...) raises InputError; the other attributes
        (``up``, ``name``, ``viewpoints``, ...) stay.

        Returns
        -------
        dict
            ``points`` (n, 3) float64, ``normals`` (n, 3) float32, ``radii`` (n,) float32 and
            ``colors`` (n, 3) float32 or None.
        """
        arrays = {"points": self.points, "normals": self.normals, "radii": self.radii,
                  "colors": self.colors}
        for name in ("_points", "_normals", "_radii", "_colors"):
            setattr(self, name, None)
        self.__dict__["_handed_over"] = True
        return arrays

    def __repr__(self) -> str:
        if self.handed_over:
            return "PointCloud(arrays handed over)"
        parts = [f"{len(self)} points"]
        parts.append("normals" if self.has_normals else "normals estimated lazily")
        if self.has_colors:
            parts.append("colors")
        if self.name:
            parts.insert(0, repr(self.name))
        return f"PointCloud({', '.join(parts)})"

    # -- derived clouds -----------------------------------------------------------------------

    def _derive(self, points, normals, normals_given, radii, radii_given, colors, **extra):
        out = PointCloud.__new__(PointCloud)
        out._points = np.ascontiguousarray(points, dtype=np.float64)
        out._points.setflags(write=False)
        out._normals, out._normals_given = normals, normals_given
        out._radii, out._radii_given = radii, radii_given
        out._colors = colors
        for arr in (out._normals, out._radii, out._colors):
            if arr is not None:
                arr.setflags(write=False)
        out.up = extra.get("up", self.up)
        out.seen_from_above = self.seen_from_above
        out.name = self.name
        out.viewpoints = extra.get("viewpoints")
        out.intensity = extra.get("intensity")
        out.scan_index = extra.get("scan_index")
        out.scan_grid = extra.get("scan_grid")
        out.notes = list(self.notes)
        out.fit_report = getattr(self, "fit_report", None)
        return out

    def subset(self, index_or_mask) -> PointCloud:
        """A new cloud with the selected points and every per-point attribute that is present.

        Parameters
        ----------
        index_or_mask : (n,) bool array, integer index array or slice
            Which points to keep (order and repeats of an index array are kept).

        Returns
        -------
        PointCloud
            Given normals/radii/colours, intensity, scan_index, scan_grid and per-point
            viewpoints are
            carried over. Normals already estimated are carried over too (orientation is local);
            estimated radii are not, since they depend on the density of the subset.
        """
        return self._subset(self._selection(index_or_mask))

    def _selection(self, index_or_mask):
        """``index_or_mask`` checked; a boolean mask as the indices it selects (each array is
        then gathered by one ``take``: indexing an (n, 3) array with a mask finds the selected
        rows again for every array, ~3x slower)."""
        sel = index_or_mask
        if isinstance(sel, slice):
            return sel
        sel = np.asarray(sel)
        if sel.dtype == bool:
            if sel.shape != (len(self),):
                raise InputError(
                    f"index_or_mask: boolean mask must have shape ({len(self)},), "
                    f"got {sel.shape}"
                )
            return np.flatnonzero(sel)
        if sel.dtype.kind in "iu":
            if sel.ndim != 1:
                raise InputError(f"index_or_mask: expected a 1-d index, got shape {sel.shape}")
            if sel.size and (sel.min() < -len(self) or sel.max() >= len(self)):
                raise InputError(
                    f"index_or_mask: indices must be in -{len(self)}..{len(self) - 1}"
                )
            return sel
        raise InputError(
            f"index_or_mask: expected a boolean mask or integer indices, got {sel.dtype}"
        )

    def _subset(self, sel, points=None, normals=None) -> PointCloud:
        """:meth:`subset` of a checked selection (:meth:`_selection`); ``points`` and ``normals``,
        when given, are the subset's own (already selected) instead of this cloud's."""
        size = len(range(len(self))[sel]) if isinstance(sel, slice) else len(sel)
        if size == 0:
            raise InputError("index_or_mask: selects no points (the cloud would be empty)")

        def take(a):
            if a is None:
                return None
            return np.ascontiguousarray(a[sel] if isinstance(sel, slice) else a.take(sel, axis=0))

        vp = self.viewpoints
        if vp is not None and vp.ndim == 2:
            vp = take(vp)
        return self._derive(
            take(self._points) if points is None else points,
            take(self._normals) if normals is None else normals,
            self._normals_given,
            take(self._radii) if self._radii_given else None,
            self._radii_given,
            take(self._colors),
            viewpoints=vp,
            intensity=take(self.intensity),
            scan_index=take(self.scan_index),
            scan_grid=take(self.scan_grid),
        )

    def transformed(self, matrix) -> PointCloud:
        """A copy moved by an affine 4x4 matrix (column vectors: ``p' = M @ [p, 1]``).

        Normals use the inverse transpose of the linear part (so they stay perpendicular to the
        surface, and outward under reflections too); radii are scaled by ``|det A|^(1/3)``
        (exact for rotations and uniform scales); viewpoints move like points, ``up`` like a
        direction.

        Parameters
        ----------
        matrix : (4, 4) array_like
            Affine transform; the last row must be ``[0, 0, 0, 1]``.

        Returns
        -------
        PointCloud
        """
        m = _numeric("matrix", matrix).astype(np.float64)
        if m.shape != (4, 4):
            raise InputError(f"matrix: expected shape (4, 4), got {m.shape}")
        if not np.all(np.isfinite(m)):
            raise InputError("matrix: contains NaN or inf")
        if not np.allclose(m[3], [0, 0, 0, 1]):
            raise InputError(f"matrix: last row must be [0, 0, 0, 1] (affine), got {m[3]}")
        a, t = m[:3, :3], m[:3, 3]
        det = float(np.linalg.det(a))
        if abs(det) < 1e-300:
            raise InputError("matrix: the linear part is singular")
        pts = self._points @ a.T + t
        normals = None
        if self._normals is not None:
            nt = self._normals.astype(np.float64) @ np.linalg.inv(a)  # (A^-T n) as rows
            nt /= np.linalg.norm(nt, axis=1, keepdims=True)
            normals = nt.astype(np.float32)
        radii = None
        if self._radii is not None:
            radii = np.maximum(
                (self._radii * abs(det) ** (1.0 / 3.0)).astype(np.float32),
                np.finfo(np.float32).tiny,
            )
        up = None
        if self.up is not None:
            u = a @ self.up
            up = u / np.linalg.norm(u)
        vp = None if self.viewpoints is None else self.viewpoints @ a.T + t
        return self._derive(
            pts,
            normals,
            self._normals_given,
            radii,
            self._radii_given,
            None if self._colors is None else self._colors.copy(),
            up=up,
            viewpoints=vp,
            intensity=None if self.intensity is None else self.intensity.copy(),
            scan_index=None if self.scan_index is None else self.scan_index.copy(),
            scan_grid=None if self.scan_grid is None else self.scan_grid.copy(),
        )

    # -- conversions --------------------------------------------------------------------------

    @classmethod
    def from_mesh(cls, vertices, faces, sample=None, rng=None, **kw) -> PointCloud:
        """Surfels from a triangle mesh.

        Parameters
        ----------
        vertices : (v, 3) array_like
        faces : (f, 3) array_like of int
        sample : int, optional
            If given, draw this many points uniformly (by area) on the surface, each with its
            corners' vertex normals blended (the smooth surface; a corner whose vertex sits on
            a crease, a face around it more than SMOOTHING_ANGLE_DEG from its normal, gives
            its face's own normal instead) and their colours blended the same way. Otherwise
            use the vertices, with area-weighted normals from the faces; a vertex no face uses
            takes the normal of the nearest vertex one does (and ``notes`` says how many did).
        rng : numpy.random.Generator or int, optional
            Randomness for ``sample``.
        **kw
            Passed on to :class:`PointCloud` (``colors`` for the vertices, ``up``, ``name``...).

        Returns
        -------
        PointCloud
            Normals follow the face winding (counter-clockwise seen from outside = outward);
            a closed mesh wound inside out is turned first (:func:`outward_faces`; ``notes``
            says so).
        """
        v = _rows3("vertices", vertices, None).astype(np.float64)
        f = _check_faces(faces, len(v))
        if len(f) == 0:
            raise InputError("faces: the mesh has no faces")
        f, turned = outward_faces(v, f)
        if turned:
            kw["notes"] = list(kw.get("notes") or []) + [
                "the mesh is closed and wound inside out (its faces enclose a negative volume): "
                "normals turned outward"]
        if sample is not None:
            check_int(sample, "sample")
            colors = kw.pop("colors", None)
            a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
            cross = np.cross(b - a, c - a)
            area2 = np.linalg.norm(cross, axis=1)
            if not np.any(area2 > 0):
                raise InputError("faces: every face is degenerate (zero area)")
            gen = _rng(rng)
            face = gen.choice(len(f), size=int(sample), p=area2 / area2.sum())
            u, w = gen.random(int(sample)), gen.random(int(sample))
            su = np.sqrt(u)
            pts = (
                (1 - su)[:, None] * a[face]
                + (su * (1 - w))[:, None] * b[face]
                + (su * w)[:, None] * c[face]
            )
            weights = (1 - su, su * (1 - w), su * w)
            nrm = _smooth_sample_normals(v, f, cross, area2, face, *weights)
            if colors is not None:  # the corners' colours, blended as the normals are
                col = np.asarray(colors, dtype=np.float64)
                blend = sum(wk[:, None] * col[f[face, k]] for k, wk in enumerate(weights))
                kw["colors"] = np.clip(blend, 0.0, 1.0)  # a convex blend, up to rounding
            return cls(pts, nrm, **kw)
        nrm = vertex_normals(v, f)
        ok = np.linalg.norm(nrm, axis=1) > 0
        notes = list(kw.pop("notes", None) or [])
        colors = kw.pop("colors", None)
        if not ok.any():
            raise InputError("faces: every face is degenerate (zero area)")
        if not ok.all():
            # loose vertices (e.g. left over from zippering scans) lie on the surface too:
            # they borrow the normal of the nearest vertex that a face uses
            from .estimation import nearest

            used = np.flatnonzero(ok)
            _, near = nearest(v[used], v[~ok])
            nrm[~ok] = nrm[used[near]]
            notes.append(
                f"{int((~ok).sum())} of {len(v)} vertices are in no (non-degenerate) face: "
                "they took the normal of the nearest vertex that is, and at most its radius"
            )
            out = cls(v, nrm, colors=colors, notes=notes, **kw)
            if not out.has_radii:
                # The faces cover the surface; a loose vertex only adds a sample of it. Its own
                # cell, among other loose vertices in a row off the faces' edge with a normal
                # borrowed from across that edge, can reach the global cap (a disk 13x the
                # median radius on drill_shaft_zip.ply): it keeps no more than its face
                # vertex's cover. Cached as estimated, not given.
                radii = np.array(out.radii)
                radii[~ok] = np.minimum(radii[~ok], radii[used[near]])
                radii.setflags(write=False)
                out._radii = radii
            return out
        return cls(v, nrm, colors=colors, notes=notes, **kw)

    @classmethod
    def from_open3d(cls, geometry, **kw) -> PointCloud:
        """From an ``open3d.geometry.PointCloud`` or ``TriangleMesh`` (its vertices).

        Normals and colours are kept when present; a mesh without vertex normals gets them from
        its triangles. ``**kw`` is passed on to :class:`PointCloud`.
        """
        o3d = require("open3d", "io")
        if isinstance(geometry, o3d.geometry.PointCloud):
            pts = np.asarray(geometry.points)
            normals = np.asarray(geometry.normals) if geometry.has_normals() else None
            colors = np.asarray(geometry.colors) if geometry.has_colors() else None
            return cls(pts, normals, colors=colors, **kw)
        if isinstance(geometry, o3d.geometry.TriangleMesh):
            v = np.asarray(geometry.vertices)
            colors = np.asarray(geometry.vertex_colors) if geometry.has_vertex_colors() else None
            if geometry.has_vertex_normals():
                return cls(v, np.asarray(geometry.vertex_normals), colors=colors, **kw)
            if geometry.has_triangles():
                return cls.from_mesh(v, np.asarray(geometry.triangles), colors=colors, **kw)
            return cls(v, colors=colors, **kw)
        raise InputError(
            "geometry: expected an open3d.geometry.PointCloud or TriangleMesh, got "
            f"{type(geometry).__name__}"
        )

    @classmethod
    def from_pyvista(cls, dataset, sample=None, rng=None, **kw) -> PointCloud:
        """From a ``pyvista`` dataset (PolyData or any other point set).

        Point-data normals (``Normals`` / active normals) and colours (``RGB``, ``RGBA``,
        ``Colors``, ``colors``) are used when present; polygonal faces give normals otherwise
        and allow ``sample=N``. ``**kw`` is passed on to :class:`PointCloud`.
        """
        pv = require("pyvista", "io")
        if not isinstance(dataset, pv.DataSet):
            raise InputError(f"dataset: expected a pyvista DataSet, got {type(dataset).__name__}")
        pts = np.asarray(dataset.points, dtype=np.float64)
        pdata = dataset.point_data
        normals = None
        for key in ("Normals", "normals", "Normal"):
            if key in pdata and np.asarray(pdata[key]).shape == pts.shape:
                normals = np.asarray(pdata[key])
                break
        colors = None
        for key in ("RGB", "RGBA", "Colors", "colors", "rgb", "rgba"):
            if key in pdata:
                arr = np.asarray(pdata[key])
                if arr.ndim == 2 and arr.shape[1] in (3, 4):
                    colors = arr
                    break
        faces = None
        if isinstance(dataset, pv.PolyData) and dataset.faces.size > 0:
            tri = dataset.triangulate()
            # the polygons of a triangulated PolyData are stored as [3, a, b, c, 3, ...]
            faces = np.asarray(tri.faces).reshape(-1, 4)[:, 1:]
        if faces is not None and (sample is not None or normals is None):
            return cls.from_mesh(pts, faces, sample=sample, rng=rng, colors=colors, **kw)
        return cls(pts, normals, colors=colors, **kw)

    def to_open3d(self, *, normals: bool = True):
        """An ``open3d.geometry.PointCloud`` with points, normals (estimated if needed unless
        ``normals=False``) and colours."""
        o3d = require("open3d", "io")
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(self._points)))
        if normals:
            pcd.normals = o3d.utility.Vector3dVector(np.array(self.normals, dtype=np.float64))
        if self._colors is not None:
            pcd.colors = o3d.utility.Vector3dVector(np.array(self._colors, dtype=np.float64))
        return pcd
