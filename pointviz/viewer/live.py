"""The live viewport: a ray-traced view that follows a moving camera (worker thread side).

While the camera moves, :class:`LiveRenderer` traces 1 sample per pixel at a reduced resolution
chosen by :class:`ResolutionController` to keep a target frame rate; the GUI shows the frame
upscaled to the viewport. Once the camera has held still for STILL_DELAY_S, it traces the full
resolution in passes that continue one deterministic sample sequence (``render(sample_offset=,
sequence_spp=)``), so the running mean converges to exactly the frame ``render(spp=N)`` makes;
the mean is denoised from DENOISE_FIRST_SPP samples on, whenever the count has grown
DENOISE_GROWTH times, after the pass's own picture has been handed over (so the sample count on
screen never waits for the denoiser).

A new camera cancels a still pass at once, and a moving frame once it has been stale for
STALE_MOVING_S (stale frames are cancelled, not finished; a moving frame that is almost done is
worth showing, else a camera that changes at every GUI tick would never see a frame). The GUI
thread only calls :meth:`LiveRenderer.update` (a lock held for a few assignments, never while
tracing) and receives :class:`LiveFrame` objects through ``on_frame``, called on the worker
thread, which must only hand them over (``post_to_main_thread``). Nothing here knows a GUI.
"""

from __future__ import annotations

import copy
import math
import os
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import CancelledError

#: Frame rate the moving view aims for while it can afford more than PREFERRED_FRACTION of the
#: pixels (aiming a bit above MIN_FPS keeps the measured rate above it when the machine's load
#: changes between frames).
TARGET_FPS = 10.0
#: The frame rate below which the moving view gives up pixels under PREFERRED_FRACTION (the
#: issue's 8 fps): between MIN_FPS and TARGET_FPS the resolution stays at PREFERRED_FRACTION
#: rather than trading pixels for frames nobody asked for.
MIN_FPS = 8.0
#: Fraction of the viewport's pixels the moving view keeps as long as it runs at MIN_FPS (half
#: the resolution on each axis: the issue's 1/4 of the pixels).
PREFERRED_FRACTION = 0.25
#: Range of the fraction of the viewport's pixels traced while moving. Below 1/16 (a quarter of
#: the resolution on each axis) the upscaled picture no longer shows the shape.
MIN_PIXEL_FRACTION = 1.0 / 16.0
MAX_PIXEL_FRACTION = 1.0
#: Smoothing of the measured cost per pixel (exponential moving average weight of the newest
#: frame): frame times on a shared machine jitter; one slow frame must not halve the resolution.
COST_SMOOTHING = 0.3
#: The camera counts as still once it has not changed for this long, seconds (GUI ticks deliver
#: an orbiting camera several times per traced frame; a pause shorter than this is still motion).
STILL_DELAY_S = 0.12
#: Target duration of one accumulation pass while still, seconds (the nearest whole number of
#: samples): the picture refreshes about this often, and a camera move waits at most one tile,
#: not one pass, so longer passes only cost refresh rate, while shorter ones pay the per-call
#: overhead and the window's redraw more often (under Xvfb's software rasteriser a redraw of the
#: window costs ~50 ms of CPU, taken from the tracer: 1-sample passes of a 0.19 s 640x480 frame
#: would redraw 5 times a second).
STILL_PASS_S = 0.4
#: Most samples per pixel of one accumulation pass, and of the whole accumulation.
MAX_PASS_SPP = 16
MAX_STILL_SPP = 1024
#: Samples per pixel at which the still view is first denoised; then each time the count has
#: grown DENOISE_GROWTH times. Denoising a 640x480 frame costs several passes' time (2.2 s
#: "fast", 4.9 s "high" measured on the 2-core machine at load 11), all taken from the
#: accumulation: early and frequent denoising would cut the samples reached 3 s after the
#: camera stops several times over.
DENOISE_FIRST_SPP = 16
DENOISE_GROWTH = 4
#: Open Image Denoise quality of the live view (the Render button's frame uses the settings').
LIVE_DENOISE_QUALITY = "fast"
#: Level-of-detail threshold while moving, pixels of the reduced frame (coarser than the still
#: default: a moving picture hides the difference, and it is what makes low resolutions cheap).
MOVING_LOD_PIXELS = 1.5
#: A moving frame whose camera has been replaced is cancelled after tracing this long, seconds
#: (twice the target frame time: an on-time frame finishes, a slow one is dropped).
STALE_MOVING_S = 2.0 / TARGET_FPS
#: How long :meth:`LiveRenderer.shutdown` waits for the thread by default, seconds.
SHUTDOWN_TIMEOUT_S = 10.0


class ResolutionController:
    """Chooses the fraction of the viewport's pixels to trace while the camera moves.

    It keeps a smoothed estimate of the seconds one frame costs per unit pixel fraction (the cost
    of a frame is close to proportional to its pixel count) and inverts it: above
    ``preferred`` it aims at ``target_fps``; it keeps ``preferred`` while that runs at
    ``min_fps`` or faster, and only below that trades pixels for ``min_fps``.

    Parameters
    ----------
    target_fps : float
    lo, hi : float
        Range of the fraction.
    min_fps : float
    preferred : float
        Clipped to [lo, hi].
    """

    def __init__(self, target_fps: float = TARGET_FPS, lo: float = MIN_PIXEL_FRACTION,
                 hi: float = MAX_PIXEL_FRACTION, min_fps: float = MIN_FPS,
                 preferred: float = PREFERRED_FRACTION):
        self.target_s = 1.0 / float(target_fps)
        self.min_s = max(1.0 / float(min_fps), self.target_s)
        self.lo, self.hi = float(lo), float(hi)
        self.preferred = float(np.clip(preferred, self.lo, self.hi))
        self.cost_per_fraction: float | None = None
        self.fraction = self.preferred

    def observe(self, fraction: float, seconds: float) -> float:
        """Record that a frame of ``fraction`` took ``seconds``; return the next fraction."""
        cost = seconds / max(fraction, 1e-9)
        c = self.cost_per_fraction
        self.cost_per_fraction = cost if c is None else (1 - COST_SMOOTHING) * c + COST_SMOOTHING * cost
        f = self.target_s / self.cost_per_fraction
        if f < self.preferred:  # keep the preferred resolution while it makes min_fps
            f = min(self.preferred, self.min_s / self.cost_per_fraction)
        self.fraction = float(np.clip(f, self.lo, self.hi))
        return self.fraction


def scaled_camera(camera, fraction: float):
    """``camera`` with about ``fraction`` of its pixels (same view: the vertical field of view and
    the aspect are kept)."""
    from ..camera import Camera

    s = math.sqrt(max(fraction, 0.0))
    w = max(1, round(camera.width * s))
    h = max(1, round(camera.height * s))
    if (w, h) == (camera.width, camera.height):
        return camera
    return Camera(camera.eye, camera.target, camera.up, camera.fov_deg, w, h)


def orbit_camera(camera, center, up, angle_rad: float):
    """``camera`` turned by ``angle_rad`` around the axis through ``center`` along ``up``
    (Rodrigues' rotation of the eye and target; the up hint is the axis itself)."""
    from ..camera import Camera

    k = np.asarray(up, dtype=np.float64)
    k = k / np.linalg.norm(k)
    c = np.asarray(center, dtype=np.float64)
    cos, sin = math.cos(angle_rad), math.sin(angle_rad)

    def rot(p):
        v = np.asarray(p, dtype=np.float64) - c
        return c + v * cos + np.cross(k, v) * sin + k * (k @ v) * (1 - cos)

    return Camera(rot(camera.eye), rot(camera.target), camera.up, camera.fov_deg,
                  camera.width, camera.height)


def same_camera(a, b) -> bool:
    """Same eye, target, up, field of view and size (exact: a moved camera is a new view)."""
    if a is None or b is None:
        return a is b
    return (a.width, a.height, a.fov_deg) == (b.width, b.height, b.fov_deg) and all(
        np.array_equal(x, y) for x, y in ((a.eye, b.eye), (a.target, b.target), (a.up, b.up)))


@dataclass
class LiveFrame:
    """A picture for the viewport.

    Attributes
    ----------
    image : (h, w, 3) uint8
        sRGB, the traced size (the GUI upscales it to the viewport).
    frame : Frame
        Linear buffers behind ``image``: while still, the running mean (``noisy_color``: before
        denoising), so ``frame.color`` of an undenoised still frame equals ``render(spp=spp)``.
    camera : Camera
        The camera traced (reduced size while moving).
    generation : int
        The request it answers (:meth:`LiveRenderer.update` numbers them).
    moving : bool
        A 1-spp reduced-resolution frame (else a step of the still accumulation).
    fraction : float
        Fraction of the viewport's pixels traced.
    spp : int
        Samples per pixel in the picture.
    denoised : bool
    seconds : float
        Trace time of this frame or pass.
    """

    image: np.ndarray
    frame: object
    camera: object
    generation: int
    moving: bool
    fraction: float
    spp: int
    denoised: bool
    seconds: float


@dataclass
class _Request:
    camera: object
    settings: object
    generation: int
    time: float = field(default_factory=time.monotonic)


class LiveRenderer:
    """Traces the live view on a daemon thread.

    Parameters
    ----------
    on_frame : callable(LiveFrame)
        Called on the worker thread for every finished frame or accumulation pass.
    prepare : callable(settings) -> (scene, dict)
        Called on the worker thread with the settings of a request: the scene to trace and the
        :func:`pointviz.render` options (``spp`` and ``denoise`` are the live view's own). It may
        be slow the first time (tree builds); its result is reused while the settings compare
        equal.
    on_error : callable(exception), optional
        Called on the worker thread when a frame fails (not for cancellations); the loop goes on
        with the next request.
    render_fn : callable, optional
        :func:`pointviz.render` (tests substitute a wrapper).
    threads : int, optional
        Tracer threads; default: all cores (see the viewer's worker module for the measurement).
    background : bool
        Trace at a lower CPU priority.
    denoise : bool
        Denoise the still view (needs the ``denoise`` extra; silently off without it).
    target_fps : float
    """

    def __init__(self, on_frame, prepare, on_error=None, render_fn=None, threads=None,
                 background=True, denoise=True, target_fps=TARGET_FPS):
        self._on_frame = on_frame
        self._prepare = prepare
        self._prepared = None  # (settings, scene, kwargs) of the last request traced
        self._on_error = on_error or (lambda exc: None)
        self._render_fn = render_fn
        self.threads = threads
        self.background = background
        self.denoise = denoise  # whether the denoiser is installed is checked on the worker
                                # thread (importing it takes ~0.2 s the GUI must not wait)
        self.controller = ResolutionController(target_fps)
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._request: _Request | None = None
        self._generation = 0
        self._stop = False
        self.cancelled_frames = 0
        self.moving_frames = 0
        self.still_passes = 0
        self._thread = threading.Thread(target=self._loop, name="pointviz-live", daemon=True)
        self._thread.start()

    # ----------------------------------------------------------------- any thread (the GUI)
    @property
    def thread(self) -> threading.Thread:
        return self._thread

    def update(self, camera, settings) -> int:
        """Show ``camera`` (full viewport size) with these settings (see ``prepare``).

        Returns at once. A request that differs from the current one cancels the frame being
        traced. Returns the request's generation number.
        """
        with self._lock:
            r = self._request
            if r is not None and same_camera(r.camera, camera) and r.settings == settings:
                return r.generation
            self._generation += 1
            self._request = _Request(camera, settings, self._generation)
            self._wake.notify_all()
            return self._generation

    def shutdown(self, timeout: float = SHUTDOWN_TIMEOUT_S) -> bool:
        """Cancel the frame being traced and end the thread; True once it has ended."""
        with self._lock:
            self._stop = True
            self._wake.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)
        return not self._thread.is_alive()

    # ----------------------------------------------------------------- worker thread
    def _next(self, shown: int, more: bool):
        """Wait for work: (request, moving), or None to stop.

        A request not shown yet gets a moving frame; the request shown gets still passes (while
        ``more``) once the camera has held still for STILL_DELAY_S.
        """
        with self._lock:
            while not self._stop:
                r = self._request
                if r is not None and r.generation != shown:
                    return r, True
                if r is not None and more:
                    wait_s = STILL_DELAY_S - (time.monotonic() - r.time)
                    if wait_s <= 0:
                        return r, False
                    self._wake.wait(wait_s)
                else:
                    self._wake.wait()
            return None

    def _loop(self) -> None:
        from ..rendering import render

        self.denoise = self.denoise and _denoise_available()
        render_fn = self._render_fn or render
        shown = 0          # generation of the request the last frame answered
        acc = None         # still accumulation of request `shown`
        more = True        # request `shown` still wants passes
        while True:
            job = self._next(shown, more)
            if job is None:
                return
            req, moving = job
            cancel = _StaleToken(self, req.generation, STALE_MOVING_S if moving else 0.0)
            try:
                scene, kwargs = self._scene_and_options(req.settings)
                if moving:
                    out = self._moving_frame(render_fn, req, scene, kwargs, cancel)
                    acc = None
                else:
                    if acc is None:
                        acc = _Accumulator(req.camera)
                    out = self._still_pass(render_fn, req, scene, kwargs, cancel, acc)
            except CancelledError:
                self.cancelled_frames += 1
                continue
            except Exception as exc:  # noqa: BLE001 - reported, the loop goes on
                self._on_error(exc)
                shown, acc, more = req.generation, None, False
                continue
            shown = req.generation
            more = acc is None or acc.spp < MAX_STILL_SPP
            self._on_frame(out)
            if not moving and acc.denoise_due and not cancel.is_set():
                try:
                    self._on_frame(self._denoised(out, acc))
                except Exception as exc:  # noqa: BLE001 - reported; accumulation goes on
                    acc.denoise_due, acc.next_denoise = False, MAX_STILL_SPP + 1
                    self._on_error(exc)

    def _scene_and_options(self, settings):
        p = self._prepared
        if p is None or p[0] != settings:
            scene, kwargs = self._prepare(settings)
            kwargs = dict(kwargs)
            kwargs.pop("spp", None)
            kwargs.pop("denoise", None)
            kwargs.setdefault("background", self.background)
            if kwargs.get("threads") is None:
                kwargs["threads"] = self.threads or (os.cpu_count() or 1)
            p = self._prepared = (settings, scene, kwargs)
        return p[1], dict(p[2])

    def _moving_frame(self, render_fn, req, scene, kwargs, cancel) -> LiveFrame:
        fraction = self.controller.fraction
        camera = scaled_camera(req.camera, fraction)
        fraction = camera.width * camera.height / (req.camera.width * req.camera.height)
        kwargs["lod_pixels"] = max(float(kwargs.get("lod_pixels", 1.0)), MOVING_LOD_PIXELS)
        t0 = time.perf_counter()
        frame = render_fn(scene, camera, spp=1, cancel=cancel, **kwargs)
        seconds = time.perf_counter() - t0
        self.controller.observe(fraction, seconds)
        self.moving_frames += 1
        return LiveFrame(frame.to_srgb8(), frame, camera, req.generation, True, fraction, 1,
                         False, seconds)

    def _still_pass(self, render_fn, req, scene, kwargs, cancel, acc) -> LiveFrame:
        n = acc.next_pass_spp()
        t0 = time.perf_counter()
        frame = render_fn(scene, req.camera, spp=n, sample_offset=acc.spp,
                          sequence_spp=MAX_STILL_SPP, cancel=cancel, **kwargs)
        seconds = time.perf_counter() - t0
        acc.add(frame, n, seconds)
        self.still_passes += 1
        mean = acc.frame(frame)
        acc.denoise_due = self.denoise and acc.spp >= acc.next_denoise
        # the pass is shown at once (the denoised picture, if any, of fewer samples until the
        # first denoising); denoising follows it (:meth:`_denoised`), so its cost never holds
        # back the sample count on screen
        image = acc.denoised_image if acc.denoised_image is not None else mean.to_srgb8()
        return LiveFrame(image, mean, req.camera, req.generation, False, 1.0, acc.spp,
                         acc.denoised_image is not None, seconds)

    def _denoised(self, out: LiveFrame, acc) -> LiveFrame:
        """``out`` (a still pass) denoised; the accumulation's next denoising is scheduled.

        With ``background``, the denoiser runs on a helper thread at the tracer's priority: the
        denoiser's own worker threads, started by its first call, inherit it (at nice 0 they
        took the cores from the window's redraws for the ~1 s a 640x480 denoising lasts)."""
        from ..denoise import denoise_frame
        from ..rendering import BACKGROUND_NICE

        frame = copy.copy(out.frame)  # the shown pass keeps its undenoised buffers
        failure = []

        def run():
            if self.background:
                _lower_thread_priority(BACKGROUND_NICE)
            try:
                denoise_frame(frame, LIVE_DENOISE_QUALITY)
            except BaseException as exc:  # noqa: BLE001 - re-raised on the live thread
                failure.append(exc)

        helper = threading.Thread(target=run, name="pointviz-live-denoise", daemon=True)
        helper.start()
        helper.join()
        if failure:
            raise failure[0]
        acc.next_denoise = DENOISE_GROWTH * acc.spp
        acc.denoise_due = False
        acc.denoised_image = frame.to_srgb8()
        return LiveFrame(acc.denoised_image, frame, out.camera, out.generation, False, 1.0,
                         out.spp, True, out.seconds)


class _StaleToken:
    """The cancel token of one frame (``render(cancel=)`` polls ``is_set``): set once the
    renderer stops, or a newer request has existed for ``grace`` seconds of this frame."""

    def __init__(self, renderer: LiveRenderer, generation: int, grace: float):
        self._r = renderer
        self._generation = generation
        self._deadline = time.monotonic() + grace

    def is_set(self) -> bool:
        r = self._r
        return r._stop or (r._generation != self._generation
                           and time.monotonic() >= self._deadline)

    def wait(self, timeout: float) -> bool:
        """Block until set (or ``timeout`` seconds); returns ``is_set()``."""
        end = time.monotonic() + timeout
        with self._r._wake:
            while not self.is_set():
                left = min(end, max(self._deadline, time.monotonic() + 1e-3)) - time.monotonic()
                if time.monotonic() >= end:
                    break
                self._r._wake.wait(max(left, 1e-3))
        return self.is_set()


class _Accumulator:
    """Running sums of one still view's passes (worker thread only)."""

    def __init__(self, camera):
        self.camera = camera
        self.spp = 0
        self.sums: dict = {}
        self._scratch: dict = {}  # one float64 buffer per sum (a pass of n samples times n)
        self.seconds_per_sample: float | None = None
        self.next_denoise = DENOISE_FIRST_SPP
        self.denoise_due = False
        self.denoised_image = None

    def next_pass_spp(self) -> int:
        if self.seconds_per_sample is None:
            return 1
        n = round(STILL_PASS_S / max(self.seconds_per_sample, 1e-6))
        return int(np.clip(n, 1, min(MAX_PASS_SPP, MAX_STILL_SPP - self.spp)))

    def add(self, frame, n: int, seconds: float) -> None:
        for name in ("color", "albedo", "alpha", "object_alpha"):
            buf = getattr(frame, name)
            if buf is None:
                continue
            if name not in self.sums:  # float64 sums: exact for any float32 pass mean x n
                self.sums[name] = np.zeros(buf.shape, np.float64)
                self._scratch[name] = np.empty(buf.shape, np.float64)
            if n == 1:
                np.add(self.sums[name], buf, out=self.sums[name])
            else:
                tmp = self._scratch[name]
                np.multiply(buf, n, out=tmp, dtype=np.float64)
                np.add(self.sums[name], tmp, out=self.sums[name])
        # depth and normal: the newest pass's (the denoiser's guide; means of normals and of
        # infinite depths are not what the buffers hold)
        self.depth, self.normal = frame.depth, frame.normal
        self.spp += n
        self.seconds_per_sample = seconds / n

    def frame(self, last):
        """The mean as a :class:`~pointviz.rendering.Frame` (float32 buffers), exposed as the
        passes are: the settings' exposure, or the automatic one, which render() meters on a
        full-detail pass of the view whatever the samples (the same for every pass), so that the
        accumulated frame is exposed as ``render(spp=N)`` exposes it."""
        from ..rendering import Frame

        inv = 1.0 / self.spp
        m = {k: np.multiply(v, inv, out=np.empty(v.shape, np.float32), casting="same_kind")
             for k, v in self.sums.items()}  # new arrays: frames already shown keep theirs
        stats = dict(last.stats, spp=self.spp)
        out = Frame(m["color"], self.depth, self.normal, m["alpha"], stats, self.camera,
                    albedo=m.get("albedo"), object_alpha=m.get("object_alpha"),
                    exposure=last.exposure)
        return out


def _lower_thread_priority(nice: int) -> None:
    """Add ``nice`` to the calling thread's nice value (Linux; best effort); the threads it
    starts afterwards inherit it."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + nice)
    except (AttributeError, OSError):
        pass


def _denoise_available() -> bool:
    try:
        from ..denoise import check_available

        check_available()
        return True
    except Exception:  # noqa: BLE001 - any failure: no denoising
        return False


__all__ = ["LiveFrame", "LiveRenderer", "ResolutionController", "orbit_camera",
           "same_camera", "scaled_camera"]
