"""Keyframes (one camera pose at a time) and their interpolation by the curves of
:mod:`pointviz.path.curves` (see :mod:`pointviz.path` for the scheme)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..camera import DEFAULT_FOV_DEG, DEFAULT_HEIGHT, DEFAULT_WIDTH, Camera, view_basis
from ..errors import InputError
from ..framing import DEFAULT_UP
from ..frozen import ArrayValue, set_fields
from ..values import check_fov as _fov
from ..values import check_real as _real
from ..values import check_vec3 as _vec3
from .curves import (
    CatmullRom,
    TimeMap,
    cumulative_knots,
    quat_from_matrix,
    quat_rotate,
    segment_index,
    slerp,
    transport,
)

#: Easing names accepted by :class:`CameraPath`.
EASINGS = ("ease-in-out", "linear")
DEFAULT_EASING = "ease-in-out"
DEFAULT_FPS = 30.0
#: Added to ``duration * fps`` before the floor so that e.g. 0.7 s * 30 fps gives 22 frames.
FRAME_COUNT_EPS = 1e-9


@dataclass(frozen=True, eq=False, repr=False)
class Keyframe(ArrayValue):
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

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray = DEFAULT_UP
    fov_deg: float = DEFAULT_FOV_DEG
    time: float = 0.0

    def __post_init__(self) -> None:
        eye, target, up = _vec3(self.eye, "eye"), _vec3(self.target, "target"), _vec3(self.up, "up")
        view_basis(eye, target, up)
        set_fields(self, eye=eye, target=target, up=up, fov_deg=_fov(self.fov_deg),
                   time=_real(self.time, "time"))

    @classmethod
    def from_camera(cls, camera: Camera, time: float = 0.0) -> Keyframe:
        """Keyframe with the camera's view (its image size is dropped)."""
        return cls(camera.eye, camera.target, camera.up, camera.fov_deg, time)

    def to_camera(self, width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT) -> Camera:
        return Camera(self.eye, self.target, self.up, self.fov_deg, width, height)

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


def rotation_of(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Camera->world rotation with columns (right, true_up, -forward); proper, shape (3, 3)."""
    forward, right, true_up = view_basis(eye, target, up)
    return np.stack([right, true_up, -forward], axis=1)


class KeyframeInterpolator:
    """Precomputed curves and time maps of a path's keyframes (see the module docstring)."""

    def __init__(self, keyframes: Sequence[Keyframe], easing: str) -> None:
        times = np.array([kf.time for kf in keyframes])
        self.eye_curve = CatmullRom(np.array([kf.eye for kf in keyframes]))
        self.target_curve = CatmullRom(np.array([kf.target for kf in keyframes]))
        self.eye_map = TimeMap(times, self.eye_curve.knots, easing)
        self.target_map = TimeMap(times, self.target_curve.knots, easing)
        self.fov_map = TimeMap(times, np.array([kf.fov_deg for kf in keyframes]), easing)
        quats = np.array([quat_from_matrix(rotation_of(kf.eye, kf.target, kf.up))
                          for kf in keyframes])
        for i in range(1, len(quats)):  # shortest arc: consecutive quaternions in one hemisphere
            if np.dot(quats[i - 1], quats[i]) < 0.0:
                quats[i] = -quats[i]
        self.quats = quats
        diff = np.linalg.norm(np.diff(quats, axis=0), axis=1)
        summ = np.linalg.norm(quats[1:] + quats[:-1], axis=1)
        self.angles = 4.0 * np.arctan2(diff, summ)  # rotation angle of each segment, radians
        self.angle_knots = cumulative_knots(self.angles) if len(quats) > 1 else np.zeros(1)
        self.angle_map = TimeMap(times, self.angle_knots, easing)

    def __call__(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Eyes, targets, ups (m, 3) and fovs (m,) at times t (m,)."""
        eyes = self.eye_curve(self.eye_map(t)[:, 0])
        targets = self.target_curve(self.target_map(t)[:, 0])
        fovs = self.fov_map(t)[:, 0]
        if len(self.quats) == 1:
            quats = np.repeat(self.quats, len(t), axis=0)
        else:
            theta = self.angle_map(t)[:, 0]
            k = segment_index(self.angle_knots, theta)
            w = (theta - self.angle_knots[k]) / (self.angle_knots[k + 1] - self.angle_knots[k])
            quats = slerp(self.quats[k], self.quats[k + 1], w)
        m = len(t)
        up_s = quat_rotate(quats, np.tile([0.0, 1.0, 0.0], (m, 1)))
        forward_s = -quat_rotate(quats, np.tile([0.0, 0.0, 1.0], (m, 1)))
        view = targets - eyes
        dist = np.linalg.norm(view, axis=1, keepdims=True)
        degenerate = dist[:, 0] == 0.0  # eye and target curves cross: look along the slerp
        targets = np.where(degenerate[:, None], eyes + forward_s, targets)
        view = np.where(degenerate[:, None], forward_s, view / np.where(dist == 0, 1.0, dist))
        ups = transport(up_s, forward_s, view)
        return eyes, targets, ups, fovs


def check_easing(value: Any) -> str:
    if value not in EASINGS:
        raise InputError(f"easing must be one of {EASINGS}, got {value!r}")
    return value


def check_fps(value: Any) -> float:
    fps = _real(value, "fps")
    if fps <= 0.0:
        raise InputError(f"fps must be > 0, got {fps}")
    return fps
