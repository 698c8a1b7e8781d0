"""Pinhole camera shared by the Python side and the C++ renderer.

The renderer generates primary rays with exactly the model implemented by :meth:`Camera.rays`:

* ``forward = normalize(target - eye)``, ``right = normalize(cross(forward, up))``,
  ``true_up = cross(right, forward)`` (an orthonormal, right-handed basis);
* ``fov_deg`` is the **vertical** field of view, ``tan_half = tan(radians(fov_deg) / 2)`` and
  ``aspect = width / height`` (square pixels);
* pixel ``(row i, col j)`` with in-pixel offset ``(u, v)`` in ``[0, 1)`` (``0.5, 0.5`` is the
  pixel centre) looks along ``normalize(forward + sx * right + sy * true_up)`` with
  ``sx = (2 * (j + u) / width - 1) * tan_half * aspect`` and
  ``sy = (1 - 2 * (i + v) / height) * tan_half``; all rays start at ``eye``.

Rows go top to bottom, columns left to right; continuous pixel coordinates put the centre of
pixel ``(i, j)`` at ``(col, row) = (j + 0.5, i + 0.5)``, so the image spans ``[0, width] x
[0, height]``. :meth:`Camera.project` is the exact inverse of the ray model.

Open3D (:meth:`Camera.to_open3d`) uses a world->camera extrinsic with the camera looking down
+Z, +X right and +Y down, and an intrinsic matrix whose pixel centres sit at *integer*
coordinates; hence ``cx = width / 2 - 0.5`` and ``cy = height / 2 - 0.5`` there.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import FileFormatError, InputError, require
from .files import atomic_write_text, json_text, read_json_file
from .framing import (  # noqa: F401  (re-exported: Camera.fit's framing, which lived here)
    DEFAULT_FIT_DIRECTION,
    DEFAULT_MARGIN,
    DEFAULT_UP,
    DEGENERATE_RADIUS,
    FIT_OUTLIER_FRACTION,
    OBJECT_AZIMUTH_DEG,
    OBJECT_ELEVATION_DEG,
    TERRAIN_ELEVATIONS_DEG,
    VIEWPOINT_ELEVATION_DEG,
    _horizontal_axes,
    bounding_sphere,
    fit_camera,
    fit_distance,
    frame_coverage,
    shape_kind,
)
from .frozen import ArrayValue, set_fields
from .values import MAX_IMAGE_SIZE  # noqa: F401  (re-exported)
from .values import check_fov as _fov
from .values import check_image_size as _size
from .values import check_real as _real
from .values import check_vec3 as _vec3

#: Default vertical field of view, degrees.
DEFAULT_FOV_DEG = 40.0
#: Default image size, pixels.
DEFAULT_WIDTH = 640
DEFAULT_HEIGHT = 480
#: ``up`` is rejected when the sine of its angle to the view direction is below this.
PARALLEL_SIN_TOL = 1e-6
#: Default relative tolerance when checking that Open3D intrinsics fit the pinhole model.
OPEN3D_RTOL = 1e-6
#: Identifier written into camera JSON files.
CAMERA_FORMAT = "pointviz.camera"
CAMERA_FORMAT_VERSION = 1
#: Rows of rays generated per block in :meth:`Camera.rays` (bounds float64 temporaries).
RAY_BLOCK_ROWS = 256

_FIELDS = ("eye", "target", "up", "fov_deg", "width", "height")


# --------------------------------------------------------------------------- validation helpers


def view_basis(
    eye: np.ndarray, target: np.ndarray, up: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthonormal camera basis of the ray model.

    Parameters
    ----------
    eye, target, up : ndarray, shape (3,), float64
        Validated (finite) vectors.

    Returns
    -------
    forward, right, true_up : ndarray, shape (3,), float64
        ``forward = normalize(target - eye)``, ``right = normalize(cross(forward, up))``,
        ``true_up = cross(right, forward)``.

    Raises
    ------
    InputError
        If eye and target coincide, or ``up`` is zero or parallel to the view direction.
    """
    view = target - eye
    dist = float(np.linalg.norm(view))
    if dist == 0.0 or not math.isfinite(dist):
        raise InputError("eye and target coincide")
    forward = view / dist
    up_norm = float(np.linalg.norm(up))
    if up_norm == 0.0:
        raise InputError("up must be a non-zero vector")
    side = np.cross(forward, up / up_norm)
    side_norm = float(np.linalg.norm(side))
    if side_norm < PARALLEL_SIN_TOL:
        raise InputError(f"up {tuple(float(x) for x in up)} is parallel to the view direction")
    right = side / side_norm
    true_up = np.cross(right, forward)
    return forward, right, true_up


# ---------------------------------------------------------------------------------------- Camera


@dataclass(frozen=True, eq=False, repr=False)
class Camera(ArrayValue):
    """Immutable pinhole camera (the renderer's ray model; see the module docstring).

    Parameters
    ----------
    eye : array_like, shape (3,)
        Centre of projection, world units.
    target : array_like, shape (3,)
        Point looked at; must differ from ``eye``.
    up : array_like, shape (3,), optional
        Up hint, not parallel to ``target - eye``; stored as given.
    fov_deg : float, optional
        Vertical field of view in degrees, in (0, 180) exclusive.
    width, height : int, optional
        Image size in pixels, 1..MAX_IMAGE_SIZE.

    Raises
    ------
    InputError
        For any invalid argument; the message names it.
    """

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray = DEFAULT_UP
    fov_deg: float = DEFAULT_FOV_DEG
    width: int = DEFAULT_WIDTH
    height: int = DEFAULT_HEIGHT
    #: Unit view direction ``normalize(target - eye)``; shape (3,), float64.
    forward: np.ndarray = field(init=False, repr=False)
    #: Unit ``normalize(cross(forward, up))``; shape (3,), float64.
    right: np.ndarray = field(init=False, repr=False)
    #: Unit ``cross(right, forward)``; shape (3,), float64.
    true_up: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        eye, target, up = _vec3(self.eye, "eye"), _vec3(self.target, "target"), _vec3(self.up, "up")
        fov_deg = _fov(self.fov_deg)
        width, height = _size(self.width, "width"), _size(self.height, "height")
        forward, right, true_up = view_basis(eye, target, up)
        set_fields(self, eye=eye, target=target, up=up, fov_deg=fov_deg, width=width,
                   height=height, forward=forward, right=right, true_up=true_up)

    # ------------------------------------------------------------------ construction
    @classmethod
    def look_at(
        cls,
        eye: Any,
        target: Any,
        up: Any = DEFAULT_UP,
        fov_deg: float = DEFAULT_FOV_DEG,
        width: int = DEFAULT_WIDTH,
        height: int = DEFAULT_HEIGHT,
    ) -> Camera:
        """Camera at ``eye`` looking at ``target`` (same as the constructor)."""
        return cls(eye, target, up, fov_deg, width, height)

    @classmethod
    def fit(
        cls,
        cloud: Any,
        direction: Any = None,
        fov_deg: float = DEFAULT_FOV_DEG,
        width: int = DEFAULT_WIDTH,
        height: int = DEFAULT_HEIGHT,
        up: Any = None,
        margin: float = DEFAULT_MARGIN,
        outliers: float = FIT_OUTLIER_FRACTION,
    ) -> Camera:
        """Camera that frames a whole cloud.

        With ``direction=None`` (the default) the view comes from the data's shape (see
        :func:`shape_kind`): a terrain tile is seen from above at an oblique angle
        (TERRAIN_ELEVATIONS_DEG), across its short or along its long horizontal axis, whichever
        fills the frame most (:func:`frame_coverage`), an object from a
        three-quarter view (OBJECT_AZIMUTH_DEG off its broad side, OBJECT_ELEVATION_DEG above),
        and a cloud taken from a single viewpoint (``cloud.viewpoints`` of shape (3,): a depth
        camera's frame) from that viewpoint, raised by VIEWPOINT_ELEVATION_DEG, when its points
        lie in front of it. The camera then moves as close as it can while the points'
        projections (all but the ``outliers`` fraction on each side) stay inside the image
        shrunk by ``margin``, and the target is set so that they are centred: the data fills
        the frame's width or height.

        With an explicit ``direction`` the bounding sphere of the points (see
        :func:`bounding_sphere`) is looked at along it from the distance given by
        :func:`fit_distance`: its silhouette is a centred circle of radius
        ``min(width, height) / (2 * margin)`` pixels, so every point projects inside the image
        when ``margin >= 1``. The direction :data:`DEFAULT_FIT_DIRECTION` is given for +Y up;
        for a cloud with another ``up`` (LiDAR is +Z up) it is rotated so that the view keeps
        the same elevation.

        Parameters
        ----------
        cloud : object with ``points`` (n, 3) and optional ``up`` (3,), or an (n, 3) array
            The points to frame (n >= 1).
        direction : array_like, shape (3,), optional
            Viewing direction, from the eye toward the cloud (need not be unit length).
        fov_deg, width, height
            As for the constructor.
        up : array_like, shape (3,), optional
            Up hint; None uses ``cloud.up`` when set, else +Y.
        margin : float
            Padding factor (> 0).
        outliers : float
            Fraction of points (in [0, 0.1]) that may fall outside the frame: raw scans carry a
            few stray points far from the object, which would otherwise shrink it to a corner.
            Clouds under FIT_ROBUST_MIN_POINTS points are always framed whole.

        Returns
        -------
        Camera
            A cloud whose points all coincide is framed as a sphere of radius
            DEGENERATE_RADIUS around them.
        """
        return fit_camera(cls, cloud, direction, fov_deg, width, height, up, margin, outliers)

    @classmethod
    def from_dict(cls, data: Any) -> Camera:
        """Camera from a mapping like :meth:`to_dict` (extra keys are ignored).

        Raises
        ------
        InputError
            If ``data`` is not a mapping, a key is missing or a value has the wrong type or is
            invalid; the message names the key.
        """
        if not isinstance(data, dict):
            raise InputError(f"camera must be a JSON object, got {type(data).__name__}")
        missing = [key for key in _FIELDS if key not in data]
        if missing:
            raise InputError(f"missing key {missing[0]!r}")
        return cls(
            _vec3(data["eye"], "eye"),
            _vec3(data["target"], "target"),
            _vec3(data["up"], "up"),
            _fov(data["fov_deg"]),
            _size(data["width"], "width"),
            _size(data["height"], "height"),
        )

    @classmethod
    def from_json(cls, path: str | os.PathLike) -> Camera:
        """Read a camera written by :meth:`to_json`.

        Raises
        ------
        FileFormatError
            Naming the file (and the field) for a missing file, invalid JSON, a wrong
            ``format``, a missing key, a wrong type or an invalid value (NaN, ...).
        """
        data = read_json_file(path)
        where = os.fspath(path)
        if isinstance(data, dict):
            fmt = data.get("format", CAMERA_FORMAT)
            if fmt != CAMERA_FORMAT:
                raise FileFormatError(f"{where}: format is {fmt!r}, expected {CAMERA_FORMAT!r}")
            version = data.get("version", CAMERA_FORMAT_VERSION)
            if version != CAMERA_FORMAT_VERSION:
                raise FileFormatError(f"{where}: unsupported version {version!r}")
        try:
            return cls.from_dict(data)
        except InputError as exc:
            raise FileFormatError(f"{where}: {exc}") from exc

    @classmethod
    def from_open3d(cls, params: Any, target_distance: float = 1.0) -> Camera:
        """Camera from ``open3d.camera.PinholeCameraParameters`` (inverse of :meth:`to_open3d`).

        Parameters
        ----------
        params : open3d.camera.PinholeCameraParameters
            Intrinsic must have ``fx == fy`` and the principal point at the image centre
            (``cx = width / 2 - 0.5``, ``cy = height / 2 - 0.5``), relative tolerance
            OPEN3D_RTOL; the extrinsic's rotation must be proper (orthonormal, det +1).
        target_distance : float
            Open3D does not store a target: it is put this far along the view direction.

        Returns
        -------
        Camera
            ``up`` is the camera's true up (Open3D's -Y axis).
        """
        intr = params.intrinsic
        width, height = int(intr.width), int(intr.height)
        k = np.asarray(intr.intrinsic_matrix, dtype=np.float64)
        ext = np.asarray(params.extrinsic, dtype=np.float64)
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        _size(width, "intrinsic.width")
        _size(height, "intrinsic.height")
        if not (np.all(np.isfinite(k)) and np.all(np.isfinite(ext))):
            raise InputError("open3d params contain NaN or inf")
        scale = max(width, height)
        if not math.isclose(fx, fy, rel_tol=OPEN3D_RTOL) or fy <= 0:
            raise InputError(f"intrinsic must have fx == fy > 0 (square pixels), got {fx}, {fy}")
        if (abs(cx - (width / 2 - 0.5)) > OPEN3D_RTOL * scale
                or abs(cy - (height / 2 - 0.5)) > OPEN3D_RTOL * scale):
            raise InputError(
                f"intrinsic principal point ({cx}, {cy}) is not the image centre "
                f"({width / 2 - 0.5}, {height / 2 - 0.5})"
            )
        rot, trans = ext[:3, :3], ext[:3, 3]
        if (not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6)
                or np.linalg.det(rot) <= 0 or not np.allclose(ext[3], [0, 0, 0, 1])):
            raise InputError("extrinsic is not a rigid transform (rotation must be proper)")
        distance = _real(target_distance, "target_distance")
        if distance <= 0:
            raise InputError(f"target_distance must be > 0, got {distance}")
        eye = -rot.T @ trans
        forward, down = rot[2], rot[1]
        fov_deg = math.degrees(2.0 * math.atan(height / (2.0 * fy)))
        return cls(eye, eye + distance * forward, -down, fov_deg, width, height)

    # ------------------------------------------------------------------ attributes
    @property
    def aspect(self) -> float:
        """``width / height``."""
        return self.width / self.height

    @property
    def tan_half(self) -> float:
        """``tan(radians(fov_deg) / 2)``."""
        return math.tan(math.radians(self.fov_deg) / 2.0)

    @property
    def pixel_angle(self) -> float:
        """Angle in radians subtended by one pixel at the image centre."""
        return 2.0 * math.atan(self.tan_half / self.height)

    @property
    def distance(self) -> float:
        """``|target - eye|``."""
        return float(np.linalg.norm(self.target - self.eye))

    @property
    def focal_px(self) -> float:
        """Focal length in pixels, ``height / (2 * tan_half)`` (same horizontally)."""
        return self.height / (2.0 * self.tan_half)

    # ------------------------------------------------------------------ rays and projection
    def _offsets(self, samples: Any) -> tuple[Any, Any]:
        """In-pixel offsets (u, v) broadcastable to (height, width)."""
        if samples is None:
            return 0.5, 0.5
        s = np.asarray(samples, dtype=np.float64)
        h, w = self.height, self.width
        if s.shape == (2,):
            u, v = s[0], s[1]
        elif s.shape == (h, w, 2):
            u, v = s[..., 0], s[..., 1]
        elif s.shape == (h * w, 2):
            u, v = s[:, 0].reshape(h, w), s[:, 1].reshape(h, w)
        else:
            raise InputError(
                f"samples must have shape (2,), ({h}, {w}, 2) or ({h * w}, 2), got {s.shape}"
            )
        if not (np.all(np.isfinite(s)) and np.all(s >= 0.0) and np.all(s < 1.0)):
            raise InputError("samples must be finite offsets in [0, 1)")
        return u, v

    def rays(self, samples: Any = None, dtype: Any = np.float32) -> np.ndarray:
        """Primary rays, row by row from the top-left pixel.

        Parameters
        ----------
        samples : array_like, optional
            In-pixel offsets ``(u, v)`` in [0, 1): shape (2,) for every pixel, or
            (height, width, 2) / (height * width, 2) per pixel. None means the pixel centres.
        dtype : numpy dtype
            float32 (default, what the renderer consumes) or float64 (keeps precision far from
            the origin). Directions are computed in float64 and normalised before the cast.

        Returns
        -------
        ndarray, shape (height * width, 6), ``dtype``
            Origin xyz (the eye) then unit direction xyz; row ``i * width + j`` is pixel
            ``(i, j)``.
        """
        dtype = np.dtype(dtype)
        if dtype not in (np.float32, np.float64):
            raise InputError(f"dtype must be float32 or float64, got {dtype}")
        h, w = self.height, self.width
        u, v = self._offsets(samples)
        u = np.broadcast_to(u, (h, w))
        v = np.broadcast_to(v, (h, w))
        tan_half = self.tan_half
        cols = np.arange(w, dtype=np.float64)
        out = np.empty((h * w, 6), dtype=dtype)
        out[:, :3] = self.eye
        for r0 in range(0, h, RAY_BLOCK_ROWS):
            r1 = min(h, r0 + RAY_BLOCK_ROWS)
            rows = np.arange(r0, r1, dtype=np.float64)[:, None]
            sx = (2.0 * (cols + u[r0:r1]) / w - 1.0) * tan_half * self.aspect
            sy = (1.0 - 2.0 * (rows + v[r0:r1]) / h) * tan_half
            d = (self.forward + sx[..., None] * self.right + sy[..., None] * self.true_up)
            d /= np.linalg.norm(d, axis=-1, keepdims=True)
            out[r0 * w:r1 * w, 3:] = d.reshape(-1, 3)
        return out

    def project(self, points: Any) -> tuple[np.ndarray, np.ndarray]:
        """Project world points to continuous pixel coordinates (inverse of :meth:`rays`).

        Parameters
        ----------
        points : array_like, shape (n, 3)
            World points.

        Returns
        -------
        pixels : ndarray, shape (n, 2), float64
            ``(col, row)``; the centre of pixel ``(i, j)`` is ``(j + 0.5, i + 0.5)`` and the
            image covers ``[0, width] x [0, height]``. NaN for points with depth <= 0.
        depth : ndarray, shape (n,), float64
            Distance along ``forward`` (not along the ray).
        """
        pts = np.asarray(points)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.dtype.kind not in "iuf":
            raise InputError(f"points must be an (n, 3) numeric array, got shape {pts.shape}")
        rel = pts.astype(np.float64) - self.eye
        depth = rel @ self.forward
        x = rel @ self.right
        y = rel @ self.true_up
        focal = self.focal_px
        with np.errstate(divide="ignore", invalid="ignore"):
            col = self.width / 2.0 + focal * x / depth
            row = self.height / 2.0 - focal * y / depth
        pixels = np.stack([col, row], axis=1)
        pixels[~(depth > 0)] = np.nan
        return pixels, depth

    # ------------------------------------------------------------------ conversions
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready mapping with keys eye, target, up (lists of 3 floats), fov_deg, width,
        height."""
        return {
            "eye": [float(x) for x in self.eye],
            "target": [float(x) for x in self.target],
            "up": [float(x) for x in self.up],
            "fov_deg": self.fov_deg,
            "width": self.width,
            "height": self.height,
        }

    def to_json(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write ``{"format": "pointviz.camera", "version": 1, **to_dict()}`` atomically.

        Raises
        ------
        FileExistsError
            If ``path`` exists and ``overwrite`` is False.
        """
        data = {"format": CAMERA_FORMAT, "version": CAMERA_FORMAT_VERSION, **self.to_dict()}
        return atomic_write_text(path, json_text(data), overwrite=overwrite)

    def intrinsic_matrix(self) -> np.ndarray:
        """Open3D-convention K, shape (3, 3), float64 (pixel centres at integer coordinates)."""
        f = self.focal_px
        return np.array([[f, 0.0, self.width / 2.0 - 0.5],
                         [0.0, f, self.height / 2.0 - 0.5],
                         [0.0, 0.0, 1.0]])

    def extrinsic_matrix(self) -> np.ndarray:
        """World->camera 4x4 (float64) with the camera looking down +Z, +X right, +Y down."""
        rot = np.stack([self.right, -self.true_up, self.forward])
        ext = np.eye(4)
        ext[:3, :3] = rot
        ext[:3, 3] = -rot @ self.eye
        return ext

    def to_open3d(self) -> Any:
        """``open3d.camera.PinholeCameraParameters`` that project points to the same pixels.

        A point at our continuous pixel ``(col, row)`` lands at ``(col - 0.5, row - 0.5)`` in
        Open3D's convention (pixel centres at integers), i.e. on the same pixel.
        """
        o3d = require("open3d", "viewer")
        params = o3d.camera.PinholeCameraParameters()
        k = self.intrinsic_matrix()
        params.intrinsic = o3d.camera.PinholeCameraIntrinsic(
            self.width, self.height, k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        )
        params.extrinsic = self.extrinsic_matrix()
        return params

    # ------------------------------------------------------------------ copies, equality
    def with_size(self, width: int, height: int) -> Camera:
        """Copy with another image size (the vertical field of view is kept)."""
        return self.replace(width=width, height=height)

    def isclose(self, other: Camera, atol: float = 1e-9) -> bool:
        """True if all fields agree within ``atol`` (sizes exactly)."""
        return (
            self.width == other.width and self.height == other.height
            and abs(self.fov_deg - other.fov_deg) <= atol
            and all(np.allclose(a, b, rtol=0.0, atol=atol) for a, b in (
                (self.eye, other.eye), (self.target, other.target), (self.up, other.up)))
        )
