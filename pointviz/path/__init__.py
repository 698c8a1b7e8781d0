"""Camera paths: keyframes, their interpolation, and rendering a path to frames and video.

Modules, in the direction data flows:

* :mod:`~pointviz.path.curves`: centripetal Catmull-Rom splines, monotone time maps, slerp;
* :mod:`~pointviz.path.keyframes`: :class:`Keyframe` and the interpolation of a keyframe list;
* :mod:`~pointviz.path.presets`: orbit, turntable and fly-through keyframes;
* :mod:`~pointviz.path.camera_path`: :class:`CameraPath` (keyframes, frames, JSON files);
* :mod:`~pointviz.path.exposure`: the one exposure a path's frames share;
* :mod:`~pointviz.path.batch`: :func:`render_path`, resumable, in this process or on Dask
  (:mod:`pointviz.distributed`), with the video written by :mod:`pointviz.video`.

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

from ..frames import frame_png, is_complete_png
from .batch import AUTO, FRAME_GLOB, FRAME_NAME, LOCAL, MANIFEST_NAME, SERIAL, render_path
from .camera_path import DEFAULT_KEYFRAME_STEP, MIN_KEYFRAME_GAP, PATH_FORMAT, CameraPath
from .curves import CATMULL_ROM_ALPHA
from .keyframes import DEFAULT_EASING, DEFAULT_FPS, EASINGS, Keyframe
from .presets import (
    DEFAULT_FLY_SECONDS,
    DEFAULT_ORBIT_ELEVATION_DEG,
    DEFAULT_ORBIT_SECONDS,
    fly_through_keyframes,
    orbit_keyframes,
)

__all__ = [
    "AUTO", "CATMULL_ROM_ALPHA", "DEFAULT_EASING", "DEFAULT_FLY_SECONDS", "DEFAULT_FPS",
    "DEFAULT_KEYFRAME_STEP", "DEFAULT_ORBIT_ELEVATION_DEG", "DEFAULT_ORBIT_SECONDS", "EASINGS",
    "FRAME_GLOB", "FRAME_NAME", "LOCAL", "MANIFEST_NAME", "MIN_KEYFRAME_GAP", "PATH_FORMAT", "SERIAL",
    "CameraPath", "Keyframe", "fly_through_keyframes", "frame_png", "is_complete_png",
    "orbit_keyframes", "render_path",
]
