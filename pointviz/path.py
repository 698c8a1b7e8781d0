"""Camera paths: keyframes, their interpolation, and rendering a path to frames and video.

Rendering (:func:`render_path`) is at the end of this module; its Dask back end is
:mod:`pointviz.distributed` and its video writer :mod:`pointviz.video`.

Interpolation (:meth:`CameraPath.camera_at`)
--------------------------------------------
Each keyframe is hit exactly at its own time. Between keyframes every quantity is a *curve*
(the shape) composed with a *time map* (when the camera is where on that curve):

* **eye and target** each follow a centripetal Catmull-Rom spline (alpha = 0.5) through the
  keyframe positions, with phantom end points obtained by reflection
  (``P[-1] = 2 P[0] - P[1]``). The spline is C1 in its knot parameter ``tau`` (cumulative
  ``|dP| ** 0.5``).
* **orientation** is a chain of quaternion slerps between the keyframe rotations (built from
  forward / true up; each quaternion's sign is chosen so every slerp takes the shortest arc),
  parameterised by the cumulative rotation angle. The camera's up is the slerped up, carried by
  the minimal rotation from the slerped forward to the actual view direction
  ``normalize(target - eye)`` (the two agree at keyframes, so there it *is* the slerped up).
* **fov** is interpolated directly.

The time maps (keyframe time -> knot / cumulative angle / fov) depend on ``easing``:

* ``"linear"``: piecewise linear: constant parameter speed inside each segment; the speed
  changes abruptly at interior keyframes when neighbouring segments differ.
* ``"ease-in-out"`` (default): one monotone C1 piecewise-cubic Hermite map over the whole path
  (Fritsch-Butland / PCHIP slopes at interior keyframes, zero slope at the first and last).
  The camera starts and ends at rest and its velocity is continuous across interior
  keyframes (it does not stop there, unlike per-segment smoothstep). With two keyframes this
  is exactly smoothstep. Keyframes are still reached at their own times, so the easing only
  shapes the first and last segments and the speed transitions in between.

Frames are at ``t0 + k / fps`` for ``k = 0 .. n_frames - 1`` with
``n_frames = floor(duration * fps) + 1`` (a tolerance of FRAME_COUNT_EPS absorbs rounding).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .camera import (
    DEFAULT_FOV_DEG,
    DEFAULT_HEIGHT,
    DEFAULT_MARGIN,
    DEFAULT_UP,
    DEFAULT_WIDTH,
    DEGENERATE_RADIUS,
    Camera,
    _cloud_points_and_up,
    _fov,
    _json_dumps,
    _real,
    _size,
    _vec3,
    atomic_write_text,
    bounding_sphere,
    fit_distance,
    read_json_file,
    view_basis,
)
from .errors import CancelledError, FileFormatError, InputError, require
from .frames import frame_png, is_complete_png  # noqa: F401 - public here too
from .interrupt import stage

#: Catmull-Rom exponent: 0.5 is the centripetal variant (no cusps or self-intersections).
CATMULL_ROM_ALPHA = 0.5
#: Knot increments are floored at this fraction of the largest one (repeated keyframe positions).
KNOT_FLOOR = 1e-9
#: Easing names accepted by :class:`CameraPath`.
EASINGS = ("ease-in-out", "linear")
DEFAULT_EASING = "ease-in-out"
DEFAULT_FPS = 30.0
#: Time step used by :meth:`CameraPath.add` when no time is given, seconds.
DEFAULT_KEYFRAME_STEP = 1.0
#: Keyframes closer in time than this are rejected as duplicates, seconds.
MIN_KEYFRAME_GAP = 1e-9
#: Added to ``duration * fps`` before the floor so that e.g. 0.7 s * 30 fps gives 22 frames.
FRAME_COUNT_EPS = 1e-9
#: Below this quaternion half angle (radians) slerp falls back to normalised lerp.
SLERP_EPS = 1e-9
#: Largest angle between orbit keyframes, degrees.
ORBIT_STEP_DEG = 5.0
#: Default elevation of :meth:`CameraPath.orbit`, degrees.
DEFAULT_ORBIT_ELEVATION_DEG = 20.0
DEFAULT_ORBIT_SECONDS = 8.0
#: Default look-ahead of :meth:`CameraPath.fly_through` as a fraction of the polyline length.
FLY_LOOK_AHEAD_FRACTION = 0.1
#: :meth:`CameraPath.fly_through` places keyframes at most look_ahead / this apart.
FLY_SAMPLES_PER_LOOK_AHEAD = 2
DEFAULT_FLY_SECONDS = 10.0
#: Identifier and version of camera path JSON files.
PATH_FORMAT = "pointviz.camera_path"
PATH_FORMAT_VERSION = 1


# ------------------------------------------------------------------------------ math helpers


def _lerp(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``a + w (b - a)``, exact at ``w == 0`` (gives a) and ``w == 1`` (gives b).

    ``a, b`` shape (m, d) or (d,), ``w`` shape (m,). Written in difference form so that
    coincident ``a == b`` give exactly ``a`` even for large extrapolation weights.
    """
    w = w[:, None]
    diff = b - a
    return np.where(w < 0.5, a + w * diff, b - (1.0 - w) * diff)


def _knots(increments: np.ndarray) -> np.ndarray:
    """Cumulative knots (starting at 0) from non-negative increments, floored to stay increasing.

    Parameters
    ----------
    increments : ndarray, shape (m,), float64

    Returns
    -------
    ndarray, shape (m + 1,), float64, strictly increasing
    """
    largest = float(increments.max()) if increments.size else 0.0
    if largest == 0.0:
        increments = np.ones_like(increments)
    else:
        increments = np.maximum(increments, KNOT_FLOOR * largest)
    return np.concatenate([[0.0], np.cumsum(increments)])


def _segment(knots: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Index k of the segment ``[knots[k], knots[k+1]]`` holding each x (clipped to valid)."""
    return np.clip(np.searchsorted(knots, x, side="right") - 1, 0, len(knots) - 2)


class _CatmullRom:
    """Centripetal Catmull-Rom spline through points, phantom ends by reflection.

    Parameters
    ----------
    points : ndarray, shape (n, d), float64, n >= 1
    """

    def __init__(self, points: np.ndarray) -> None:
        self.n = len(points)
        if self.n == 1:
            self.points = points
            self.knots = np.zeros(1)
            return
        ext = np.concatenate([2 * points[:1] - points[1:2], points, 2 * points[-1:] - points[-2:-1]])
        steps = np.linalg.norm(np.diff(ext, axis=0), axis=1) ** CATMULL_ROM_ALPHA
        self.ext = ext
        self.ext_knots = _knots(steps)  # (n + 2,)
        self.knots = self.ext_knots[1:-1]  # knot of keyframe k
        self.points = points

    def __call__(self, tau: np.ndarray) -> np.ndarray:
        """Evaluate at knot values ``tau`` (m,) -> (m, d) (Barry-Goldman pyramid)."""
        if self.n == 1:
            return np.repeat(self.points, len(tau), axis=0)
        k = _segment(self.knots, tau)
        p, t = self.ext, self.ext_knots
        q0, q1, q2, q3 = p[k], p[k + 1], p[k + 2], p[k + 3]
        t0, t1, t2, t3 = t[k], t[k + 1], t[k + 2], t[k + 3]
        a1 = _lerp(q0, q1, (tau - t0) / (t1 - t0))
        a2 = _lerp(q1, q2, (tau - t1) / (t2 - t1))
        a3 = _lerp(q2, q3, (tau - t2) / (t3 - t2))
        b1 = _lerp(a1, a2, (tau - t0) / (t2 - t0))
        b2 = _lerp(a2, a3, (tau - t1) / (t3 - t1))
        return _lerp(b1, b2, (tau - t1) / (t2 - t1))


class _TimeMap:
    """Map from time to a scalar through (times[k], values[k]) for each easing mode.

    ``linear``: piecewise linear. ``ease-in-out``: C1 monotone cubic Hermite with
    Fritsch-Butland slopes inside and zero slopes at both ends.

    Parameters
    ----------
    times : ndarray, shape (n,), strictly increasing
    values : ndarray, shape (n,) or (n, d)
    easing : str
    """

    def __init__(self, times: np.ndarray, values: np.ndarray, easing: str) -> None:
        self.times = times
        self.values = values.reshape(len(times), -1)
        self.linear = easing == "linear"
        n = len(times)
        self.slopes = np.zeros_like(self.values)
        if n >= 3 and not self.linear:
            h = np.diff(times)[:, None]
            delta = np.diff(self.values, axis=0) / h
            d0, d1 = delta[:-1], delta[1:]
            w1 = 2 * h[1:] + h[:-1]
            w2 = h[1:] + 2 * h[:-1]
            same_sign = d0 * d1 > 0
            with np.errstate(divide="ignore", invalid="ignore"):
                mean = (w1 + w2) / (w1 / d0 + w2 / d1)
            self.slopes[1:-1] = np.where(same_sign, mean, 0.0)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Evaluate at times ``t`` (m,) -> (m, d)."""
        if len(self.times) == 1:
            return np.repeat(self.values, len(t), axis=0)
        k = _segment(self.times, t)
        t0, t1 = self.times[k], self.times[k + 1]
        y0, y1 = self.values[k], self.values[k + 1]
        u = (t - t0) / (t1 - t0)
        if self.linear:
            return _lerp(y0, y1, u)
        h = (t1 - t0)[:, None]
        uu = u[:, None]
        h01 = uu * uu * (3 - 2 * uu)  # smoothstep weight of y1
        h10 = uu * (1 - uu) ** 2
        h11 = uu * uu * (uu - 1)
        tangents = h * (h10 * self.slopes[k] + h11 * self.slopes[k + 1])
        base = np.where(uu < 0.5, y0 + h01 * (y1 - y0), y1 - (1 - h01) * (y1 - y0))
        return base + tangents


def _quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a proper rotation matrix (3, 3) (Shepperd's method)."""
    trace = np.trace(m)
    cand = np.array([trace, m[0, 0], m[1, 1], m[2, 2]])
    i = int(np.argmax(cand))
    if i == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif i == 1:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif i == 2:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    return q / np.linalg.norm(q)


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (m, 3) by unit quaternions q (m, 4) (w, x, y, z)."""
    w, xyz = q[:, :1], q[:, 1:]
    t = 2.0 * np.cross(xyz, v)
    return v + w * t + np.cross(xyz, t)


def _slerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Slerp between unit quaternions q0, q1 (m, 4) (same hemisphere) at fractions w (m,)."""
    dot = np.clip(np.sum(q0 * q1, axis=1), -1.0, 1.0)
    half = np.arccos(dot)
    small = half < SLERP_EPS
    sin_half = np.where(small, 1.0, np.sin(half))
    c0 = np.where(small, 1.0 - w, np.sin((1.0 - w) * half) / sin_half)
    c1 = np.where(small, w, np.sin(w * half) / sin_half)
    q = c0[:, None] * q0 + c1[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _transport(v: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Apply the minimal rotation taking unit a to unit b to v (all (m, 3)).

    Where a and b are (nearly) opposite the rotation is undefined and v is returned unchanged.
    """
    k = np.cross(a, b)
    c = np.sum(a * b, axis=1, keepdims=True)
    opposite = c <= -1.0 + 1e-12
    denom = np.where(opposite, 1.0, 1.0 + c)
    kv = np.cross(k, v)
    out = v + kv + np.cross(k, kv) / denom
    return np.where(opposite, v, out)


# ----------------------------------------------------------------------------------- Keyframe


class Keyframe:
    """One camera pose at a time.

    Parameters
    ----------
    eye, target, up : array_like, shape (3,)
        As for :class:`~pointviz.camera.Camera` (validated the same way).
    fov_deg : float
        Vertical field of view, degrees, in (0, 180).
    time : float
        Seconds.
    """

    __slots__ = ("eye", "target", "up", "fov_deg", "time")

    def __init__(self, eye: Any, target: Any, up: Any = DEFAULT_UP,
                 fov_deg: float = DEFAULT_FOV_DEG, time: float = 0.0) -> None:
        eye, target, up = _vec3(eye, "eye"), _vec3(target, "target"), _vec3(up, "up")
        view_basis(eye, target, up)
        for arr in (eye, target, up):
            arr.setflags(write=False)
        object.__setattr__(self, "eye", eye)
        object.__setattr__(self, "target", target)
        object.__setattr__(self, "up", up)
        object.__setattr__(self, "fov_deg", _fov(fov_deg))
        object.__setattr__(self, "time", _real(time, "time"))

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("Keyframe is immutable; use replace()")

    @classmethod
    def from_camera(cls, camera: Camera, time: float = 0.0) -> Keyframe:
        """Keyframe with the camera's view (its image size is dropped)."""
        return cls(camera.eye, camera.target, camera.up, camera.fov_deg, time)

    def to_camera(self, width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT) -> Camera:
        return Camera(self.eye, self.target, self.up, self.fov_deg, width, height)

    def replace(self, **changes: Any) -> Keyframe:
        fields = {name: getattr(self, name) for name in self.__slots__}
        unknown = set(changes) - set(fields)
        if unknown:
            raise TypeError(f"Keyframe.replace() got unexpected field(s) {sorted(unknown)}")
        fields.update(changes)
        return Keyframe(**fields)

    def to_dict(self) -> dict[str, Any]:
        return {"eye": self.eye.tolist(), "target": self.target.tolist(), "up": self.up.tolist(),
                "fov_deg": self.fov_deg, "time": self.time}

    @classmethod
    def from_dict(cls, data: Any, where: str = "keyframe") -> Keyframe:
        """Keyframe from a mapping with eye, target, up, fov_deg, time.

        Raises InputError naming ``where`` and the bad field.
        """
        if not isinstance(data, dict):
            raise InputError(f"{where} must be a JSON object, got {type(data).__name__}")
        for key in ("eye", "target", "up", "fov_deg", "time"):
            if key not in data:
                raise InputError(f"{where}: missing key {key!r}")
        try:
            return cls(_vec3(data["eye"], f"{where}.eye"), _vec3(data["target"], f"{where}.target"),
                       _vec3(data["up"], f"{where}.up"), _fov(data["fov_deg"], f"{where}.fov_deg"),
                       _real(data["time"], f"{where}.time"))
        except InputError as exc:
            msg = str(exc)
            raise InputError(msg if msg.startswith(where) else f"{where}: {msg}") from exc

    def _key(self) -> tuple:
        return (tuple(self.eye.tolist()), tuple(self.target.tolist()), tuple(self.up.tolist()),
                self.fov_deg, self.time)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Keyframe):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __repr__(self) -> str:
        def vec(a: np.ndarray) -> str:
            return "(" + ", ".join(f"{x:.6g}" for x in a) + ")"

        return (f"Keyframe(eye={vec(self.eye)}, target={vec(self.target)}, up={vec(self.up)}, "
                f"fov_deg={self.fov_deg:.6g}, time={self.time:.6g})")

    def __reduce__(self):
        return (Keyframe, (self.eye.copy(), self.target.copy(), self.up.copy(), self.fov_deg,
                           self.time))


def _rotation_of(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Camera->world rotation with columns (right, true_up, -forward); proper, shape (3, 3)."""
    forward, right, true_up = view_basis(eye, target, up)
    return np.stack([right, true_up, -forward], axis=1)


class _Interpolator:
    """Precomputed curves and time maps of a path's keyframes (see the module docstring)."""

    def __init__(self, keyframes: Sequence[Keyframe], easing: str) -> None:
        times = np.array([kf.time for kf in keyframes])
        self.eye_curve = _CatmullRom(np.array([kf.eye for kf in keyframes]))
        self.target_curve = _CatmullRom(np.array([kf.target for kf in keyframes]))
        self.eye_map = _TimeMap(times, self.eye_curve.knots, easing)
        self.target_map = _TimeMap(times, self.target_curve.knots, easing)
        self.fov_map = _TimeMap(times, np.array([kf.fov_deg for kf in keyframes]), easing)
        quats = np.array([_quat_from_matrix(_rotation_of(kf.eye, kf.target, kf.up))
                          for kf in keyframes])
        for i in range(1, len(quats)):  # shortest arc: consecutive quaternions in one hemisphere
            if np.dot(quats[i - 1], quats[i]) < 0.0:
                quats[i] = -quats[i]
        self.quats = quats
        diff = np.linalg.norm(np.diff(quats, axis=0), axis=1)
        summ = np.linalg.norm(quats[1:] + quats[:-1], axis=1)
        self.angles = 4.0 * np.arctan2(diff, summ)  # rotation angle of each segment, radians
        self.angle_knots = _knots(self.angles) if len(quats) > 1 else np.zeros(1)
        self.angle_map = _TimeMap(times, self.angle_knots, easing)

    def __call__(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Eyes, targets, ups (m, 3) and fovs (m,) at times t (m,)."""
        eyes = self.eye_curve(self.eye_map(t)[:, 0])
        targets = self.target_curve(self.target_map(t)[:, 0])
        fovs = self.fov_map(t)[:, 0]
        if len(self.quats) == 1:
            quats = np.repeat(self.quats, len(t), axis=0)
        else:
            theta = self.angle_map(t)[:, 0]
            k = _segment(self.angle_knots, theta)
            w = (theta - self.angle_knots[k]) / (self.angle_knots[k + 1] - self.angle_knots[k])
            quats = _slerp(self.quats[k], self.quats[k + 1], w)
        m = len(t)
        up_s = _rotate(quats, np.tile([0.0, 1.0, 0.0], (m, 1)))
        forward_s = -_rotate(quats, np.tile([0.0, 0.0, 1.0], (m, 1)))
        view = targets - eyes
        dist = np.linalg.norm(view, axis=1, keepdims=True)
        degenerate = dist[:, 0] == 0.0  # eye and target curves cross: look along the slerp
        targets = np.where(degenerate[:, None], eyes + forward_s, targets)
        view = np.where(degenerate[:, None], forward_s, view / np.where(dist == 0, 1.0, dist))
        ups = _transport(up_s, forward_s, view)
        return eyes, targets, ups, fovs


# --------------------------------------------------------------------------------- CameraPath


def _easing(value: Any) -> str:
    if value not in EASINGS:
        raise InputError(f"easing must be one of {EASINGS}, got {value!r}")
    return value


def _fps(value: Any) -> float:
    fps = _real(value, "fps")
    if fps <= 0.0:
        raise InputError(f"fps must be > 0, got {fps}")
    return fps


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
        self._fps = _fps(fps)
        self._easing = _easing(easing)
        self._keyframes: list[Keyframe] = []
        self._interp: _Interpolator | None = None
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
    def _interpolator(self) -> _Interpolator:
        if not self._keyframes:
            raise InputError("the camera path has no keyframes")
        if self._interp is None:
            self._interp = _Interpolator(self._keyframes, self._easing)
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
        """One closed revolution around the cloud's bounding-sphere centre.

        The eye stays at ``distance`` from the centre (default: the :meth:`Camera.fit`
        distance, so the cloud is framed all along), ``elevation_deg`` above the plane
        orthogonal to ``up``, turning counter-clockwise seen from above (right-hand rule about
        up). It starts on the +Z side for a +Y up (on the -Y side for a +Z up; in general on
        the side of whichever of +Z, -Y is more orthogonal to up).

        The path lasts ``seconds`` and is closed: **the first and last frames coincide** (drop
        the last frame for a seamless loop). When ``seconds * fps`` is an integer there is a
        keyframe on every frame (subdivided so that keyframes are at most ORBIT_STEP_DEG
        apart), so frames are exactly on the circle: with ``easing="linear"`` the angle steps
        are exactly equal, with ``"ease-in-out"`` the angle follows smoothstep over the whole
        revolution (starting and ending at rest). Otherwise keyframes are ORBIT_STEP_DEG apart
        in angle (smoothstep-eased likewise) and frames fall between them (the distance to the
        centre then varies by ~1e-3 near the ends, where the phantom end points straighten the
        spline).

        Parameters
        ----------
        cloud : object with ``points`` (n, 3) and optional ``up``, or an (n, 3) array
        seconds : float
            Duration of the revolution (> 0).
        elevation_deg : float
            In (-90, 90).
        distance : float, optional
            Eye to centre distance (> 0).
        up : array_like, shape (3,), optional
            None: ``cloud.up`` when set, else +Y.
        """
        points, cloud_up = _cloud_points_and_up(cloud)
        centre, radius = bounding_sphere(points, "cloud.points")
        seconds = _real(seconds, "seconds")
        if seconds <= 0:
            raise InputError(f"seconds must be > 0, got {seconds}")
        elevation = _real(elevation_deg, "elevation_deg")
        if not -90.0 < elevation < 90.0:
            raise InputError(f"elevation_deg must be in (-90, 90), got {elevation}")
        if distance is None:
            distance = fit_distance(radius or DEGENERATE_RADIUS, fov_deg, width, height, margin)
        distance = _real(distance, "distance")
        if distance <= 0:
            raise InputError(f"distance must be > 0, got {distance}")
        if up is None:
            up = _vec3(cloud_up, "cloud.up") if cloud_up is not None else np.array(DEFAULT_UP)
        up = _vec3(up, "up")
        norm = float(np.linalg.norm(up))
        if norm == 0:
            raise InputError("up must be a non-zero vector")
        n = up / norm
        candidates = (np.array([0.0, 0.0, 1.0]), np.array([0.0, -1.0, 0.0]))
        a = min(candidates, key=lambda c: abs(float(c @ n)))
        a = a - (a @ n) * n
        a /= np.linalg.norm(a)
        b = np.cross(n, a)
        fps = _fps(fps)
        easing = _easing(easing)
        min_steps = math.ceil(360.0 / ORBIT_STEP_DEG)
        frames = seconds * fps
        if abs(frames - round(frames)) < FRAME_COUNT_EPS * max(1.0, frames) and round(frames) > 0:
            # a keyframe on every frame (and ORBIT_STEP_DEG apart at most): exact at frames
            per_frame = math.ceil(min_steps / round(frames))
            steps = round(frames) * per_frame
            times = np.arange(steps + 1) / per_frame / fps  # frame j is exactly at j / fps
        else:
            steps = min_steps
            times = seconds * np.arange(steps + 1) / steps
        fractions = np.arange(steps + 1) / steps
        if easing == "ease-in-out":
            fractions = fractions * fractions * (3.0 - 2.0 * fractions)  # smoothstep angle
        phi = 2.0 * math.pi * fractions
        el = math.radians(elevation)
        offsets = distance * (math.cos(el) * (np.outer(np.cos(phi), a) + np.outer(np.sin(phi), b))
                              + math.sin(el) * n)
        offsets[-1] = offsets[0]  # exactly closed
        path = cls(width=width, height=height, fps=fps, easing=easing)
        for time, off in zip(times, offsets):
            path.add(Keyframe(centre + off, centre, n, fov_deg, time))
        return path

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
        """Camera travelling along a polyline, looking ``look_ahead`` ahead along it.

        Keyframes are placed at the polyline's vertices and in between so that consecutive
        ones are at most ``look_ahead / FLY_SAMPLES_PER_LOOK_AHEAD`` apart (arc length); their
        times are proportional to arc length. Each keyframe looks at the polyline point
        ``look_ahead`` further on (past the end: along the last segment's direction), so the
        camera starts turning before a corner.

        Parameters
        ----------
        points : array_like, shape (k, 3), k >= 2
            Polyline vertices (consecutive duplicates are dropped).
        look_ahead : float, optional
            Arc length (> 0); default FLY_LOOK_AHEAD_FRACTION of the polyline length.
        seconds : float
            Duration (> 0).
        up : array_like, shape (3,)
            Up hint; must not be parallel to the flight direction anywhere.
        """
        pts = np.asarray(points)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.dtype.kind not in "iuf":
            raise InputError(f"points must be a (k, 3) numeric array, got shape {pts.shape}")
        pts = pts.astype(np.float64)
        if not np.all(np.isfinite(pts)):
            raise InputError("points contain NaN or inf")
        keep = np.concatenate([[True], np.any(np.diff(pts, axis=0) != 0, axis=1)])
        pts = pts[keep]
        if len(pts) < 2:
            raise InputError("points must hold at least 2 distinct consecutive points")
        seg_len = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(seg_len)])
        total = float(arc[-1])
        if look_ahead is None:
            look_ahead = FLY_LOOK_AHEAD_FRACTION * total
        look_ahead = _real(look_ahead, "look_ahead")
        if look_ahead <= 0:
            raise InputError(f"look_ahead must be > 0, got {look_ahead}")
        seconds = _real(seconds, "seconds")
        if seconds <= 0:
            raise InputError(f"seconds must be > 0, got {seconds}")
        up = _vec3(up, "up")
        spacing = look_ahead / FLY_SAMPLES_PER_LOOK_AHEAD
        samples = [arc[:1]]
        for i in range(len(seg_len)):
            count = max(1, math.ceil(seg_len[i] / spacing))
            samples.append(arc[i] + seg_len[i] * np.arange(1, count + 1) / count)
        s = np.concatenate(samples)
        s[-1] = total

        def at(arclen: np.ndarray) -> np.ndarray:
            k = np.clip(np.searchsorted(arc, arclen, side="right") - 1, 0, len(seg_len) - 1)
            w = (arclen - arc[k]) / seg_len[k]  # > 1 past the end: extrapolate the last segment
            return _lerp(pts[k], pts[k + 1], w)

        eyes, targets = at(s), at(s + look_ahead)
        eyes[-1] = pts[-1]
        path = cls(width=width, height=height, fps=fps, easing=easing)
        for j, (e, g, arclen) in enumerate(zip(eyes, targets, s)):
            try:
                kf = Keyframe(e, g, up, fov_deg, seconds * arclen / total)
            except InputError as exc:
                seg = int(np.clip(np.searchsorted(arc, arclen, side="right") - 1, 0,
                                  len(seg_len) - 1))
                raise InputError(f"fly_through: at arc length {arclen:.6g} (segment {seg} of "
                                 f"points): {exc}") from exc
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
        return atomic_write_text(path, _json_dumps(self.to_dict()), overwrite=overwrite)

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
        fps = _fps(fps)
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


# ------------------------------------------------------------------------------ rendering

#: Frame file names inside ``out_dir`` (``frame_00000.png`` ...).
FRAME_NAME = "frame_{:05d}.png"
FRAME_GLOB = "frame_*.png"
#: The manifest that ties ``out_dir`` to one scene, camera sequence and render settings.
MANIFEST_NAME = "pointviz_path.json"
MANIFEST_FORMAT = "pointviz.path_render"
MANIFEST_VERSION = 1
#: Render settings recorded in the manifest (``threads`` is not: results never depend on it).
_IMAGE_SETTINGS = ("shadows", "reflections", "spp", "lod_pixels", "seed", "ground")


def _settings_of(render_kwargs: dict) -> dict:
    """The image-affecting render settings, defaults filled in (so explicit defaults match)."""
    import inspect

    from .rendering import render

    defaults = {k: p.default for k, p in inspect.signature(render).parameters.items()
                if p.default is not inspect.Parameter.empty}
    unknown = set(render_kwargs) - set(defaults) - {"progress", "cancel"}
    if unknown:
        raise InputError(f"render_path: unknown render option(s) {sorted(unknown)}")
    if "progress" in render_kwargs or "cancel" in render_kwargs:
        raise InputError("render_path: progress and cancel apply to the whole path; pass them "
                         "as render_path(progress=..., cancel=...)")
    merged = {k: render_kwargs.get(k, defaults[k]) for k in _IMAGE_SETTINGS}
    return {k: (v if isinstance(v, (bool, int, float, str, type(None))) else repr(v))
            for k, v in merged.items()}


def _path_cameras(path: Any, width: int | None, height: int | None) -> tuple[list[dict], float]:
    """Camera dicts of every frame (at the requested size) and the path's fps."""
    if isinstance(path, (str, os.PathLike)):
        path = CameraPath.load(path)
    if not isinstance(path, CameraPath):
        raise InputError(f"path: expected a CameraPath or a path JSON file, got {type(path).__name__}")
    if path.n_frames == 0:
        raise InputError("path: the camera path has no keyframes")
    w = path.width if width is None else _size(width, "width")
    h = path.height if height is None else _size(height, "height")
    if width is not None and height is None:
        h = max(1, round(w * path.height / path.width))
    elif height is not None and width is None:
        w = max(1, round(h * path.width / path.height))
    return [cam.with_size(w, h).to_dict() for cam in path.cameras()], path.fps


def _digest(obj: Any) -> str:
    import hashlib

    return hashlib.sha256(_json_dumps(obj).encode()).hexdigest()


def _prepare_out_dir(out: Path, manifest: dict, resume: bool, overwrite: bool) -> None:
    """Create ``out`` or check that its frames belong to this render; write the manifest.

    A folder holding frames of another render (another scene, path or settings) is refused
    unless ``overwrite``, which deletes those frames (only ``frame_*.png`` and the manifest).
    """
    if out.exists() and not out.is_dir():
        raise InputError(f"out_dir: {out} is a file, not a folder")
    out.mkdir(parents=True, exist_ok=True)
    mpath = out / MANIFEST_NAME
    frames = sorted(out.glob(FRAME_GLOB))
    reason = None
    if mpath.exists():
        try:
            old = read_json_file(mpath)
        except (InputError, FileFormatError) as exc:
            old, reason = None, f"its manifest {mpath.name} is unreadable ({exc})"
        if old is not None and not isinstance(old, dict):
            old, reason = None, f"its manifest {mpath.name} is not a JSON object"
        if old is not None:
            changed = [k for k in ("scene", "cameras", "settings", "n_frames")
                       if old.get(k) != manifest[k]]
            if changed:
                what = {"scene": "the scene", "cameras": "the camera path or image size",
                        "settings": "the render settings", "n_frames": "the frame count"}
                reason = ("it holds frames of a different render (" +
                          ", ".join(what[k] for k in changed) + " changed)")
            elif not resume and frames:
                reason = "it holds frames of this render and resume=False"
    elif frames:
        reason = f"it holds {len(frames)} frame files but no {MANIFEST_NAME}"
    if reason is not None:
        if not overwrite:
            raise InputError(f"out_dir: {out}: {reason}; pass overwrite=True (CLI: --overwrite) "
                             f"to delete its frames, or choose another folder")
        for f in frames:
            f.unlink()
    for stale in out.glob(".frame_*.part"):  # left by a process killed mid-write
        stale.unlink()
    atomic_write_text(mpath, _json_dumps(manifest), overwrite=True)


def render_path(scene_or_cloud: Any, path: Any, out_dir: str | os.PathLike, *,
                width: int | None = None, height: int | None = None,
                video: str | os.PathLike | None = None, fps: float | None = None,
                scheduler: Any = None, workers: int = 2, retries: int = 3,
                resume: bool = True, overwrite: bool = False, progress: Any = True,
                cancel: Any = None, **render_kwargs: Any) -> dict:
    """Render every frame of a camera path to ``out_dir/frame_00000.png`` ..., optionally a video.

    Frames are written atomically (a temporary ``.frame_*.part`` file renamed into place), so
    a frame file either is complete or does not exist. ``out_dir`` also gets a manifest
    (MANIFEST_NAME) with digests of the scene, the cameras and the image settings: a rerun
    with the same inputs **resumes**, skipping frames whose file is a complete PNG; a rerun
    with different inputs is refused unless ``overwrite``.

    Parameters
    ----------
    scene_or_cloud : Scene, SurfelScene or PointCloud
    path : CameraPath or str
        A path object or its JSON file.
    out_dir : str or PathLike
        Created if missing (with its parents).
    width, height : int, optional
        Override the path's image size (one alone keeps the aspect ratio).
    video : str or PathLike, optional
        ``.mp4`` (H.264, yuv420p; odd sizes padded by one pixel) or ``.gif``, encoded from all
        the frames after rendering. An existing file is kept unless ``overwrite``.
    fps : float, optional
        Video frame rate; default the path's.
    scheduler : None, "local", "tcp://HOST:PORT" or dask.distributed.Client
        None renders in this process. "local" starts a LocalCluster of ``workers`` processes
        (one thread each); an address or Client uses an existing cluster. See
        :mod:`pointviz.distributed`. Frames are byte-identical either way.
    workers : int
        Worker processes of the "local" cluster.
    retries : int
        Dask re-runs of a failed frame.
    resume : bool
        Skip frames already rendered by a run with the same inputs. False re-renders them
        (which needs ``overwrite``).
    overwrite : bool
        Allow deleting frames of another render in ``out_dir`` and replacing ``video``.
    progress : bool or callable(done, total)
        True: a progress bar over frames on stderr (when it is a terminal). A callable gets
        the frames done (skipped ones included) and the total; returning False cancels.
    cancel : threading.Event or callable, optional
        Set (or returning True) to stop; :class:`CancelledError` is raised, finished frames
        are kept and a rerun resumes after them.
    **render_kwargs
        Options of :func:`pointviz.render` (spp, shadows, reflections, lod_pixels, seed,
        threads, ground). The same seed is used for every frame: the sampling pattern is fixed
        on screen, which avoids frame-to-frame noise.

    Returns
    -------
    dict
        ``frames`` (total), ``rendered``, ``skipped``, ``seconds`` (rendering wall time),
        ``fps`` (rendered frames per second of it), ``video_seconds``, ``out_dir``, ``video``,
        ``scheduler`` ("serial" or the scheduler address), ``workers``, ``scene_builds``
        (scene builds per worker pid) and ``startup_seconds`` (cluster start or connection and
        scene scatter, included in ``seconds``).
    """
    import time

    from .distributed import render_frames, scene_spec
    from .images import atomic_write_bytes
    from .rendering import _cancel_check

    cameras, path_fps = _path_cameras(path, width, height)
    fps = path_fps if fps is None else _fps(fps)
    if video is not None:
        from .video import check_video_path

        check_video_path(video, overwrite)
    settings = _settings_of(render_kwargs)
    is_cancelled = _cancel_check(cancel)
    if progress is True:
        from .progress import ProgressBar

        report = ProgressBar("path")
    elif progress is False or progress is None:
        report = None
    elif callable(progress):
        report = progress
    else:
        raise InputError("progress: expected True, False or a callable(done, total)")

    spec = scene_spec(scene_or_cloud)
    w, h = cameras[0]["width"], cameras[0]["height"]
    manifest = {"format": MANIFEST_FORMAT, "version": MANIFEST_VERSION, "scene": spec.key,
                "cameras": _digest(cameras), "settings": settings, "n_frames": len(cameras),
                "width": w, "height": h}
    out = Path(out_dir)
    _prepare_out_dir(out, manifest, resume, overwrite)
    files = [out / FRAME_NAME.format(i) for i in range(len(cameras))]
    todo = [i for i, f in enumerate(files) if not is_complete_png(f, w, h)]
    skipped = len(cameras) - len(todo)
    done = skipped

    def advance() -> bool:
        nonlocal done
        done += 1
        return report is None or report(done, len(cameras)) is not False

    if report is not None and report(done, len(cameras)) is False:
        raise CancelledError("path render cancelled")
    start = time.perf_counter()
    info: dict = {"scheduler": "serial", "workers": 0, "scene_builds": {}, "startup_seconds": 0.0}
    if todo and scheduler is None:
        scene, _ = spec.scene()
        for i in todo:
            if is_cancelled():
                raise CancelledError("path render cancelled")
            png = frame_png(scene, Camera.from_dict(cameras[i]), render_kwargs, cancel=cancel)
            atomic_write_bytes(files[i], png, overwrite=True)
            if not advance():
                raise CancelledError("path render cancelled")
            stage("first_frame")  # (pauses the first time only)
    elif todo:
        def on_frame(i: int, png: bytes, _info: dict) -> bool:
            atomic_write_bytes(files[i], png, overwrite=True)
            return advance()

        res = render_frames(spec, [(i, cameras[i]) for i in todo], render_kwargs, on_frame,
                            scheduler=scheduler, workers=workers, retries=retries,
                            cancel=is_cancelled)
        info = {"scheduler": res["address"], "workers": res["workers"],
                "scene_builds": res["scene_builds"], "startup_seconds": res["startup_seconds"]}
    seconds = time.perf_counter() - start
    video_seconds = 0.0
    if video is not None:
        from .video import write_video

        t0 = time.perf_counter()
        write_video(video, files, fps, overwrite=overwrite)
        video_seconds = time.perf_counter() - t0
    rendered = len(todo)
    return {"frames": len(cameras), "rendered": rendered, "skipped": skipped,
            "seconds": seconds, "fps": rendered / seconds if rendered and seconds > 0 else 0.0,
            "video_seconds": video_seconds, "out_dir": str(out),
            "video": None if video is None else str(video), **info}
