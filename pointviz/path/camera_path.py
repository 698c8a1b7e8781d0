"""A keyframed camera animation: keyframes at times, the camera of every frame, JSON files."""

from __future__ import annotations

import math
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import DEFAULT_FOV_DEG, DEFAULT_HEIGHT, DEFAULT_WIDTH, Camera
from ..files import atomic_write_text, json_text, read_json_file
from ..framing import DEFAULT_MARGIN, DEFAULT_UP
from ..values import check_image_size as _size
from ..values import check_real as _real
from ..errors import FileFormatError, InputError, require
from .keyframes import (
    DEFAULT_EASING,
    DEFAULT_FPS,
    FRAME_COUNT_EPS,
    Keyframe,
    KeyframeInterpolator,
    check_easing,
    check_fps,
)
from .presets import (
    DEFAULT_FLY_SECONDS,
    DEFAULT_ORBIT_ELEVATION_DEG,
    DEFAULT_ORBIT_SECONDS,
    fly_through_keyframes,
    orbit_keyframes,
)

#: Time step used by :meth:`CameraPath.add` when no time is given, seconds.
DEFAULT_KEYFRAME_STEP = 1.0
#: Keyframes closer in time than this are rejected as duplicates, seconds.
MIN_KEYFRAME_GAP = 1e-9
#: Identifier and version of camera path JSON files.
PATH_FORMAT = "pointviz.camera_path"
PATH_FORMAT_VERSION = 1


class CameraPath:
    """Keyframed camera animation.

    Parameters
    ----------
    keyframes : iterable of Keyframe, optional
        Any order; sorted by time. Times must differ by at least MIN_KEYFRAME_GAP.
    width, height : int
        Image size of every camera the path produces.
    fps : float
        Frames per second (> 0).
    easing : {"ease-in-out", "linear"}
        Time maps, see the module docstring.

    Notes
    -----
    ``len(path)`` is the number of *keyframes*; iterating yields the camera of every *frame*
    (``n_frames`` of them).
    """

    def __init__(self, keyframes: Any = None, width: int = DEFAULT_WIDTH,
                 height: int = DEFAULT_HEIGHT, fps: float = DEFAULT_FPS,
                 easing: str = DEFAULT_EASING) -> None:
        self._width = _size(width, "width")
        self._height = _size(height, "height")
        self._fps = check_fps(fps)
        self._easing = check_easing(easing)
        self._keyframes: list[Keyframe] = []
        self._interp: KeyframeInterpolator | None = None
        for i, kf in enumerate(keyframes or ()):
            if not isinstance(kf, Keyframe):
                raise InputError(f"keyframes[{i}] must be a Keyframe, got {type(kf).__name__}")
            self._insert(kf)

    # ------------------------------------------------------------------ keyframes
    def _insert(self, kf: Keyframe) -> None:
        times = [k.time for k in self._keyframes]
        pos = int(np.searchsorted(times, kf.time))
        for j in (pos - 1, pos):
            if 0 <= j < len(times) and abs(times[j] - kf.time) < MIN_KEYFRAME_GAP:
                raise InputError(f"time {kf.time} is already used by keyframe {j}")
        self._keyframes.insert(pos, kf)
        self._interp = None

    def add(self, camera_or_keyframe: Camera | Keyframe, time: float | None = None) -> Keyframe:
        """Add a keyframe.

        Parameters
        ----------
        camera_or_keyframe : Camera or Keyframe
            A camera contributes its view only (eye, target, up, fov); its image size is
            ignored in favour of the path's.
        time : float, optional
            Seconds. None: a Keyframe keeps its own time; a Camera goes
            DEFAULT_KEYFRAME_STEP after the last keyframe (0 for the first).

        Returns
        -------
        Keyframe
            The keyframe stored.
        """
        item = camera_or_keyframe
        if isinstance(item, Keyframe):
            kf = item if time is None else item.replace(time=time)
        elif isinstance(item, Camera):
            if time is None:
                time = (self._keyframes[-1].time + DEFAULT_KEYFRAME_STEP
                        if self._keyframes else 0.0)
            kf = Keyframe.from_camera(item, _real(time, "time"))
        else:
            raise InputError(
                f"camera_or_keyframe must be a Camera or Keyframe, got {type(item).__name__}")
        self._insert(kf)
        return kf

    @property
    def keyframes(self) -> tuple[Keyframe, ...]:
        """Keyframes sorted by time."""
        return tuple(self._keyframes)

    def __len__(self) -> int:
        return len(self._keyframes)

    # ------------------------------------------------------------------ settings
    @property
    def width(self) -> int:
        return self._width

    @property
    def height(self) -> int:
        return self._height

    @property
    def fps(self) -> float:
        return self._fps

    @property
    def easing(self) -> str:
        return self._easing

    @property
    def start(self) -> float:
        """Time of the first keyframe, seconds (0 for an empty path)."""
        return self._keyframes[0].time if self._keyframes else 0.0

    @property
    def duration(self) -> float:
        """Last keyframe time minus first, seconds (0 for fewer than two keyframes)."""
        return self._keyframes[-1].time - self._keyframes[0].time if self._keyframes else 0.0

    @property
    def n_frames(self) -> int:
        """``floor(duration * fps) + 1``; 0 for an empty path."""
        if not self._keyframes:
            return 0
        return math.floor(self.duration * self._fps + FRAME_COUNT_EPS) + 1

    def times(self) -> np.ndarray:
        """Frame times ``start + k / fps``, shape (n_frames,), float64, seconds."""
        return self.start + np.arange(self.n_frames) / self._fps

    # ------------------------------------------------------------------ evaluation
    def _interpolator(self) -> KeyframeInterpolator:
        if not self._keyframes:
            raise InputError("the camera path has no keyframes")
        if self._interp is None:
            self._interp = KeyframeInterpolator(self._keyframes, self._easing)
        return self._interp

    def _evaluate(self, t: np.ndarray) -> list[Camera]:
        interp = self._interpolator()
        if not np.all(np.isfinite(t)):
            raise InputError("t must be finite")
        t = np.clip(t, self._keyframes[0].time, self._keyframes[-1].time)
        eyes, targets, ups, fovs = interp(t)
        return [Camera(e, g, u, f, self._width, self._height)
                for e, g, u, f in zip(eyes, targets, ups, fovs)]

    def camera_at(self, t: float) -> Camera:
        """Camera at time ``t`` (seconds; clamped to the keyframe time range).

        At a keyframe's time the eye, target, fov and orientation are the keyframe's (up is its
        true up, the component of its up hint orthogonal to the view).
        """
        return self._evaluate(np.array([_real(t, "t")]))[0]

    def cameras_at(self, times: Any) -> list[Camera]:
        """Cameras at many times at once (e.g. sub-frame times for motion blur).

        Parameters
        ----------
        times : array_like, shape (m,), float
            Seconds; clamped to the keyframe time range.
        """
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        return self._evaluate(t)

    def cameras(self) -> list[Camera]:
        """Camera of every frame (at :meth:`times`)."""
        if not self._keyframes:
            return []
        return self._evaluate(self.times())

    def __iter__(self) -> Iterator[Camera]:
        return iter(self.cameras())

    # ------------------------------------------------------------------ generators
    @classmethod
    def orbit(cls, cloud: Any, seconds: float = DEFAULT_ORBIT_SECONDS, fps: float = DEFAULT_FPS,
              elevation_deg: float = DEFAULT_ORBIT_ELEVATION_DEG, distance: float | None = None,
              up: Any = None, width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT,
              fov_deg: float = DEFAULT_FOV_DEG, easing: str = DEFAULT_EASING,
              margin: float = DEFAULT_MARGIN) -> CameraPath:
        """One closed revolution around the cloud: :func:`~pointviz.path.presets.orbit_keyframes`
        (same parameters) as a path."""
        keyframes = orbit_keyframes(cloud, seconds=seconds, fps=fps, elevation_deg=elevation_deg,
                                    distance=distance, up=up, width=width, height=height,
                                    fov_deg=fov_deg, easing=easing, margin=margin)
        return cls(keyframes, width=width, height=height, fps=fps, easing=easing)

    @classmethod
    def turntable(cls, cloud: Any, seconds: float = DEFAULT_ORBIT_SECONDS,
                  fps: float = DEFAULT_FPS, distance: float | None = None, up: Any = None,
                  width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT,
                  fov_deg: float = DEFAULT_FOV_DEG, margin: float = DEFAULT_MARGIN) -> CameraPath:
        """:meth:`orbit` at elevation 0 with linear easing (constant angular speed)."""
        return cls.orbit(cloud, seconds=seconds, fps=fps, elevation_deg=0.0, distance=distance,
                         up=up, width=width, height=height, fov_deg=fov_deg, easing="linear",
                         margin=margin)

    @classmethod
    def fly_through(cls, points: Any, look_ahead: float | None = None,
                    seconds: float = DEFAULT_FLY_SECONDS, fps: float = DEFAULT_FPS,
                    up: Any = DEFAULT_UP, width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT,
                    fov_deg: float = DEFAULT_FOV_DEG,
                    easing: str = DEFAULT_EASING) -> CameraPath:
        """Camera travelling along a polyline, looking ahead along it:
        :func:`~pointviz.path.presets.fly_through_keyframes` as a path of the given image size,
        fps and easing."""
        path = cls(width=width, height=height, fps=fps, easing=easing)
        for kf in fly_through_keyframes(points, look_ahead=look_ahead, seconds=seconds, up=up,
                                        fov_deg=fov_deg):
            path.add(kf)
        return path

    # ------------------------------------------------------------------ I/O
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready mapping of the file format (see :meth:`save`)."""
        return {"format": PATH_FORMAT, "version": PATH_FORMAT_VERSION, "width": self._width,
                "height": self._height, "fps": self._fps, "easing": self._easing,
                "keyframes": [kf.to_dict() for kf in self._keyframes]}

    @classmethod
    def from_dict(cls, data: Any) -> CameraPath:
        """Inverse of :meth:`to_dict`; InputError names the bad field."""
        if not isinstance(data, dict):
            raise InputError(f"camera path must be a JSON object, got {type(data).__name__}")
        fmt = data.get("format")
        if fmt != PATH_FORMAT:
            raise InputError(f"format is {fmt!r}, expected {PATH_FORMAT!r}")
        version = data.get("version")
        if version != PATH_FORMAT_VERSION:
            raise InputError(f"unsupported version {version!r} (expected {PATH_FORMAT_VERSION})")
        for key in ("width", "height", "fps", "easing", "keyframes"):
            if key not in data:
                raise InputError(f"missing key {key!r}")
        if not isinstance(data["keyframes"], list):
            raise InputError("keyframes must be a list")
        if not data["keyframes"]:
            raise InputError("keyframes is empty: a camera path needs at least one keyframe")
        path = cls(width=data["width"], height=data["height"], fps=data["fps"],
                   easing=data["easing"])
        for i, item in enumerate(data["keyframes"]):
            kf = Keyframe.from_dict(item, f"keyframes[{i}]")
            try:
                path._insert(kf)
            except InputError as exc:
                raise InputError(f"keyframes[{i}].time: {exc}") from exc
        return path

    def save(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write the path as JSON atomically::

            {"format": "pointviz.camera_path", "version": 1, "width": ..., "height": ...,
             "fps": ..., "easing": ..., "keyframes": [{"eye": [x, y, z], "target": [...],
             "up": [...], "fov_deg": ..., "time": ...}, ...]}

        Raises
        ------
        FileExistsError
            If ``path`` exists and ``overwrite`` is False (the file is left untouched).
        """
        return atomic_write_text(path, json_text(self.to_dict()), overwrite=overwrite)

    @classmethod
    def load(cls, path: str | os.PathLike) -> CameraPath:
        """Read a file written by :meth:`save`.

        Raises
        ------
        FileFormatError
            Naming the file and the bad field (missing file, invalid JSON, wrong format or
            version, missing key, wrong type, NaN, duplicate times, ...).
        """
        data = read_json_file(path)
        try:
            return cls.from_dict(data)
        except InputError as exc:
            raise FileFormatError(f"{os.fspath(path)}: {exc}") from exc

    @classmethod
    def from_open3d_trajectory(cls, path_or_obj: Any, fps: float = DEFAULT_FPS,
                               target_distance: float | None = None,
                               easing: str = DEFAULT_EASING) -> CameraPath:
        """Path through the poses of an Open3D ``PinholeCameraTrajectory``, 1 / fps apart.

        Parameters
        ----------
        path_or_obj : str, PathLike or open3d.camera.PinholeCameraTrajectory
            A trajectory JSON file (read with ``open3d.io.read_pinhole_camera_trajectory``) or
            the object. Every pose needs the same image size, square pixels and a centred
            principal point (see :meth:`Camera.from_open3d`).
        target_distance : float, optional
            Open3D stores no target; each keyframe looks at the point this far ahead. Default:
            the diagonal of the eye positions' bounding box (1 if they all coincide), so the
            interpolated view direction is insensitive to the eye's motion.

        Raises
        ------
        FileFormatError
            If the file is missing, unreadable, empty or holds a pose we cannot represent.
        """
        o3d = require("open3d", "viewer")
        where = "trajectory"
        if isinstance(path_or_obj, (str, os.PathLike)):
            where = os.fspath(path_or_obj)
            if not os.path.isfile(where):
                raise FileFormatError(f"{where}: file not found")
            traj = o3d.io.read_pinhole_camera_trajectory(where)
        else:
            traj = path_or_obj
        params = list(getattr(traj, "parameters", None) or [])
        error = FileFormatError if where != "trajectory" else InputError
        if not params:
            raise error(f"{where}: no camera poses (missing or invalid trajectory)")
        eyes = []
        for p in params:
            ext = np.asarray(p.extrinsic, dtype=np.float64)
            eyes.append(-ext[:3, :3].T @ ext[:3, 3])
        if target_distance is None:
            eyes_arr = np.array(eyes)
            diag = float(np.linalg.norm(eyes_arr.max(axis=0) - eyes_arr.min(axis=0)))
            target_distance = diag if diag > 0 and math.isfinite(diag) else 1.0
        fps = check_fps(fps)
        cams = []
        for i, p in enumerate(params):
            try:
                cams.append(Camera.from_open3d(p, target_distance=target_distance))
            except InputError as exc:
                raise error(f"{where}: parameters[{i}]: {exc}") from exc
        size = (cams[0].width, cams[0].height)
        for i, cam in enumerate(cams):
            if (cam.width, cam.height) != size:
                raise error(f"{where}: parameters[{i}]: image size {cam.width}x{cam.height} "
                            f"differs from {size[0]}x{size[1]}")
        path = cls(width=size[0], height=size[1], fps=fps, easing=easing)
        for i, cam in enumerate(cams):
            path.add(cam, time=i / fps)
        return path

    @classmethod
    def from_viewer_keyframes(cls, keyframes: Sequence[dict], width: int | None = None,
                              height: int | None = None, fps: float = DEFAULT_FPS,
                              easing: str = DEFAULT_EASING) -> CameraPath:
        """Path from dicts like :meth:`Camera.to_dict` with an optional ``"time"``.

        Missing times follow :meth:`add` (DEFAULT_KEYFRAME_STEP after the previous one, 0 for
        the first); a missing ``up`` is +Y and a missing ``fov_deg`` DEFAULT_FOV_DEG. ``width``/``height`` default to the first dict's (then 640 x 480).
        InputError names the bad entry (``keyframes[i].field``).
        """
        if not isinstance(keyframes, (list, tuple)):
            raise InputError(f"keyframes must be a list of dicts, got {type(keyframes).__name__}")
        if keyframes and isinstance(keyframes[0], dict):
            first = keyframes[0]
            width = first.get("width", DEFAULT_WIDTH) if width is None else width
            height = first.get("height", DEFAULT_HEIGHT) if height is None else height
        path = cls(width=DEFAULT_WIDTH if width is None else width,
                   height=DEFAULT_HEIGHT if height is None else height, fps=fps, easing=easing)
        last = None
        for i, item in enumerate(keyframes):
            where = f"keyframes[{i}]"
            if not isinstance(item, dict):
                raise InputError(f"{where} must be a dict, got {type(item).__name__}")
            data = {"up": list(DEFAULT_UP), "fov_deg": DEFAULT_FOV_DEG, **item}
            if data.get("time") is None:
                data["time"] = 0.0 if last is None else last + DEFAULT_KEYFRAME_STEP
            kf = Keyframe.from_dict(data, where)
            try:
                path._insert(kf)
            except InputError as exc:
                raise InputError(f"{where}.time: {exc}") from exc
            last = kf.time if last is None else max(last, kf.time)
        return path

    # ------------------------------------------------------------------ dunder
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CameraPath):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    __hash__ = None  # mutable

    def __repr__(self) -> str:
        return (f"CameraPath({len(self)} keyframes, {self.duration:.6g} s, {self._width}x"
                f"{self._height} @ {self._fps:g} fps, easing={self._easing!r})")
