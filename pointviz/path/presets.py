"""Ready-made camera paths as keyframes: an orbit (and its turntable special case) around a
cloud, and a fly-through along a polyline. :class:`~pointviz.path.CameraPath` turns them into
paths (:meth:`~pointviz.path.CameraPath.orbit`, ...)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..camera import DEFAULT_FOV_DEG, DEFAULT_HEIGHT, DEFAULT_WIDTH
from ..errors import InputError
from ..framing import (
    DEFAULT_MARGIN,
    DEFAULT_UP,
    DEGENERATE_RADIUS,
    _cloud_points_and_up,
    bounding_sphere,
    fit_distance,
)
from ..values import check_real as _real
from ..values import check_vec3 as _vec3
from .curves import lerp
from .keyframes import (
    DEFAULT_EASING,
    DEFAULT_FPS,
    FRAME_COUNT_EPS,
    Keyframe,
    check_easing,
    check_fps,
)

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


def orbit_keyframes(cloud: Any, seconds: float = DEFAULT_ORBIT_SECONDS, fps: float = DEFAULT_FPS,
                    elevation_deg: float = DEFAULT_ORBIT_ELEVATION_DEG,
                    distance: float | None = None, up: Any = None, width: int = DEFAULT_WIDTH,
                    height: int = DEFAULT_HEIGHT, fov_deg: float = DEFAULT_FOV_DEG,
                    easing: str = DEFAULT_EASING, margin: float = DEFAULT_MARGIN) -> list[Keyframe]:
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
    fps = check_fps(fps)
    easing = check_easing(easing)
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
    return [Keyframe(centre + off, centre, n, fov_deg, time) for time, off in zip(times, offsets)]


def fly_through_keyframes(points: Any, look_ahead: float | None = None,
                          seconds: float = DEFAULT_FLY_SECONDS, up: Any = DEFAULT_UP,
                          fov_deg: float = DEFAULT_FOV_DEG) -> list[Keyframe]:
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
        return lerp(pts[k], pts[k + 1], w)

    eyes, targets = at(s), at(s + look_ahead)
    eyes[-1] = pts[-1]
    keyframes = []
    for j, (e, g, arclen) in enumerate(zip(eyes, targets, s)):
        try:
            kf = Keyframe(e, g, up, fov_deg, seconds * arclen / total)
        except InputError as exc:
            seg = int(np.clip(np.searchsorted(arc, arclen, side="right") - 1, 0,
                              len(seg_len) - 1))
            raise InputError(f"fly_through: at arc length {arclen:.6g} (segment {seg} of "
                             f"points): {exc}") from exc
        keyframes.append(kf)
    return keyframes
