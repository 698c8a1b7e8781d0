"""Final frames: ``pointviz.render(scene_or_cloud, camera, ...)`` and the :class:`Frame` it returns."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _core, interrupt
from .errors import CancelledError, InputError
from .interrupt import stage

#: Nice increment of the tracer's threads in ``render(background=True)``: a GUI thread at normal
#: priority then wins the CPU whenever it has work (weight 1024 against 110 for nice 10 under
#: Linux CFS), and the tracer still gets every cycle the GUI leaves.
BACKGROUND_NICE = 10


@dataclass
class Frame:
    """A rendered frame. Buffers are row-major from the top-left pixel.

    Attributes
    ----------
    color : (h, w, 3) float32
        Linear RGB radiance.
    depth : (h, w) float32
        Mean distance along the primary rays that hit; inf where none did.
    normal : (h, w, 3) float32
        Mean shading normal (facing the camera); zero where nothing was hit.
    alpha : (h, w) float32
        Fraction of the pixel's samples that hit geometry (coverage).
    stats : dict
        ``seconds``, ray counts, ``rays_per_second`` and the settings used.
    albedo : (h, w, 3) float32
        Base colour seen by the samples in [0, 1] (first hit, followed through mirrors; the
        background on misses): the denoiser's guide.
    object_alpha : (h, w) float32
        Fraction of the samples that hit an object (not the ground).
    exposure : float
        Exposure that :meth:`save` and :meth:`to_srgb8` apply by default (the look's
        automatic exposure, else 1).
    noisy_color : (h, w, 3) float32 or None
        The tracer's colour before denoising (None when the frame was not denoised).
    """

    color: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    alpha: np.ndarray
    stats: dict = field(default_factory=dict)
    camera: object = None
    albedo: np.ndarray | None = None
    object_alpha: np.ndarray | None = None
    exposure: float = 1.0
    noisy_color: np.ndarray | None = None

    @property
    def width(self) -> int:
        return int(self.color.shape[1])

    @property
    def height(self) -> int:
        return int(self.color.shape[0])

    def to_srgb8(self, exposure: float | None = None, tonemap: str = "aces") -> np.ndarray:
        """(h, w, 3) uint8 display image (``exposure`` None: the frame's own)."""
        from .images import to_srgb8

        return to_srgb8(self.color, self.exposure if exposure is None else exposure, tonemap)

    def save(self, path, *, bits: int = 8, exposure: float | None = None, tonemap: str = "aces",
             alpha: bool = False, overwrite: bool = False) -> Path:
        """Write the frame: ``.png`` (sRGB, 8 or 16 bits, optional alpha) or ``.exr`` (linear).

        ``exposure`` None applies the frame's own (:attr:`exposure`). The file appears
        atomically; an existing file is kept unless ``overwrite=True``.
        """
        from .images import save_image

        return save_image(path, self.color, alpha=self.alpha if alpha else None, bits=bits,
                          exposure=self.exposure if exposure is None else exposure,
                          tonemap_mode=tonemap, overwrite=overwrite)


def as_scene(scene_or_cloud, **scene_kw):
    """A :class:`~pointviz.scene.Scene` for a PointCloud, a SurfelScene or a Scene."""
    from .scene import Scene

    if isinstance(scene_or_cloud, Scene):
        return scene_or_cloud
    if hasattr(scene_or_cloud, "points") or hasattr(scene_or_cloud, "cast_rays") or isinstance(
            scene_or_cloud, (list, tuple)):
        return Scene(scene_or_cloud, **scene_kw)
    raise InputError(
        f"scene_or_cloud: expected a PointCloud, SurfelScene or Scene, got {type(scene_or_cloud).__name__}")


def camera_model(camera, origin) -> _core.CameraModel:
    """The C++ camera for ``camera`` in a frame centred on ``origin``."""
    cm = _core.CameraModel()
    cm.eye = tuple(np.asarray(camera.eye, dtype=np.float64) - origin)
    cm.forward = tuple(camera.forward)
    cm.right = tuple(camera.right)
    cm.up = tuple(camera.true_up)
    cm.tan_half = float(camera.tan_half)
    cm.width = int(camera.width)
    cm.height = int(camera.height)
    return cm


def _check_int(value, name, lo, hi):
    if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and lo <= value <= hi):
        raise InputError(f"{name}: expected an integer in [{lo}, {hi}], got {value!r}")
    return int(value)


def check_render_options(*, spp: int = 4, reflections: int = 1, seed: int = 0,
                         threads: int | None = None, lod_pixels: float = 1.0, **_ignored):
    """The numeric options of :func:`render`, checked (InputError naming the bad one) and
    normalised: ``(spp, reflections, seed, threads, lod_pixels)``. Callers with expensive work
    before the render (the CLI: trees) check first."""
    spp = _check_int(spp, "spp", 1, 4096)
    reflections = _check_int(reflections, "reflections", 0, 16)
    seed = _check_int(seed, "seed", 0, 2**63 - 1)
    if threads is not None:
        threads = _check_int(threads, "threads", 1, 1024)
    if not (np.isfinite(lod_pixels) and lod_pixels >= 0):
        raise InputError(f"lod_pixels: expected a number >= 0, got {lod_pixels!r}")
    return spp, reflections, seed, threads, float(lod_pixels)


def render(scene_or_cloud, camera, *, shadows: bool = True, reflections: int = 1, spp: int = 4,
           lod_pixels: float = 1.0, seed: int = 0, threads: int | None = None, progress=None,
           cancel=None, ground=None, look=None, denoise=False,
           background: bool = False) -> Frame:
    """Ray trace a frame.

    Parameters
    ----------
    scene_or_cloud : PointCloud, SurfelScene or Scene
        A SurfelScene's tree is reused; a PointCloud gets a scene with default lights and ground.
    camera : Camera
    shadows : bool
        Trace shadow rays (any-hit queries).
    reflections : int
        Mirror/glossy bounces (0..16).
    spp : int
        Samples per pixel, stratified (R2 sequence with a per-pixel shift); 1 = pixel centres.
    lod_pixels : float
        Level-of-detail threshold in pixels; 0 traces at full detail.
    seed : int
        The frame is a deterministic function of the seed, whatever ``threads`` is.
    threads : int, optional
        Default: all cores.
    progress : callable(done, total), optional
        Called from the calling thread every few ms while tiles complete (done, total in
        tiles); returning False cancels. An exception it raises stops the render and propagates.
    cancel : threading.Event or callable, optional
        Set (or returning True) to stop the render; :class:`CancelledError` is raised. The token
        of :mod:`pointviz.interrupt` in force (the CLI's Ctrl-C) stops it too.
    ground : str or Material, optional
        Overrides the scene's ground (for a PointCloud input).
    look : {"auto", "studio", "outdoor", "flat"} or Look, optional
        Lights, sky occlusion, backdrop and exposure (see :class:`pointviz.scene.Scene`);
        default: the scene's, "auto" for a PointCloud.
    denoise : bool, {"high", "balanced", "fast"} or pointviz.denoise.Denoiser
        Denoise the colour with Intel Open Image Denoise guided by the albedo and normal
        buffers (needs the ``denoise`` extra: ``pip install 'pointviz[denoise]'``); True is
        ``pointviz.denoise.DENOISE_QUALITY`` ("fast": the benchmark's choice). The tracer's
        colour stays in ``frame.noisy_color``.
    background : bool
        Trace at a lower CPU priority (BACKGROUND_NICE; Linux), so that a GUI stays responsive.

    Returns
    -------
    Frame
    """
    from .scene import Scene

    if camera is None or not hasattr(camera, "pixel_angle"):
        raise InputError("camera: expected a pointviz.Camera")
    from .denoise import check_available, denoise_quality

    quality = denoise_quality(denoise)
    if quality is not None:
        check_available()  # before the expensive part
    kw = {} if ground is None else {"ground": ground}
    if look is not None:
        kw["look"] = look
    scene = as_scene(scene_or_cloud, **kw)
    if isinstance(scene_or_cloud, Scene):
        if look is not None:
            scene = scene.with_look(look)
        if ground is not None:
            scene = scene.with_ground(ground)
    spp, reflections, seed, threads, lod_pixels = check_render_options(
        spp=spp, reflections=reflections, seed=seed, threads=threads, lod_pixels=lod_pixels)

    rs, origin = scene.to_core(camera, lod_pixels)
    settings = _core.RenderSettings()
    settings.spp = spp
    settings.reflections = reflections
    settings.shadows = bool(shadows)
    settings.lod_pixels = float(lod_pixels)
    settings.seed = seed
    settings.threads = threads or 0

    is_cancelled = _cancel_check(cancel)
    first_tile = [False]

    def poll(done, total):
        """Called by the core on this thread every few ms; False stops the render."""
        if done and not first_tile[0]:
            first_tile[0] = True
            stage("first_tile")
        if progress is not None and total and progress(int(done), int(total)) is False:
            return False  # (total 0: the core has not started counting)
        return not is_cancelled()  # after the report: a cancel it caused counts now

    try:
        bufs, stats = _core.render(rs, camera_model(camera, origin), settings, poll,
                                   nice=BACKGROUND_NICE if background else 0)
    except CancelledError:
        raise CancelledError("render cancelled") from None
    if not first_tile[0]:  # a render that ended before the first poll still passes the stage
        stage("first_tile")
    stats = dict(stats)
    total_rays = stats["primary_rays"] + stats["shadow_rays"] + stats["reflection_rays"]
    stats["rays_per_second"] = total_rays / max(stats["seconds"], 1e-9)
    stats["primary_rays_per_pixel"] = stats["primary_rays"] / (camera.width * camera.height)
    stats["settings"] = {"shadows": bool(shadows), "reflections": reflections, "spp": spp,
                         "lod_pixels": float(lod_pixels), "seed": seed, "threads": threads,
                         "look": scene.look.name, "denoise": quality or False}
    frame = Frame(bufs["color"], bufs["depth"], bufs["normal"], bufs["alpha"], stats, camera,
                  albedo=bufs["albedo"], object_alpha=bufs["object_alpha"])
    if scene.look.auto_exposure:  # the mean is unbiased by noise: same with or without denoising
        from .images import auto_exposure

        frame.exposure = auto_exposure(frame.color, frame.object_alpha)
    if quality is not None:
        from .denoise import denoise_frame

        denoise_frame(frame, denoise, threads)
    if progress is not None:
        progress(stats["tiles_total"], stats["tiles_total"])
    return frame


def _cancel_check(cancel):
    """``cancel`` (Event, callable or None) as a function, or'ed with the token in force
    (:mod:`pointviz.interrupt`: the CLI's Ctrl-C)."""
    if cancel is None:
        return interrupt.cancelled
    if isinstance(cancel, threading.Event) or hasattr(cancel, "is_set"):
        return lambda: cancel.is_set() or interrupt.cancelled()
    if callable(cancel):
        return lambda: bool(cancel()) or interrupt.cancelled()
    raise InputError("cancel: expected a threading.Event or a callable returning True to stop")
