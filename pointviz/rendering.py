"""Final frames: ``pointviz.render(scene_or_cloud, camera, ...)`` and the :class:`Frame` it returns."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _core, interrupt
from .errors import CancelledError, InputError
from .geometry import Geometry
from .interrupt import stage
from .settings import DEFAULT_MAX_ERROR, DEFAULTS, RenderSettings, check_int, check_lod  # noqa: F401 (re-exported)

#: Nice increment of the tracer's threads in ``render(background=True)``: a GUI thread at normal
#: priority then wins the CPU whenever it has work (weight 1024 against 110 for nice 10 under
#: Linux CFS), and the tracer still gets every cycle the GUI leaves.
BACKGROUND_NICE = 10
#: Largest factor budget_scale gives. It was 16 while the automatic exposure followed the
#: frame's own pixels (what the object's pixels lost moved every pixel of the frame: a 200k
#: striped torus at 7.5x, 160x120, cost FLIP 0.0012 at 16x and 0.029 at 48x, 0.0009 at the
#: full-detail frame's exposure). Metered at full detail (:func:`metered_exposure`), 32 took
#: the far views' (7.5x) budget frames from FLIP 0.0011 / 0.0006 to 0.0021 / 0.0011 on the
#: dragon's raw scans and the Armadillo, 0.0035 -> 0.0036 on the 8M striped torus, and on
#: models held out of every calibration to 0.0010 (the bunny's raw scans, Lucy) and 0.0006
#: (the drill's scans), E = 0.005 (benchmarks/README.md, "Issue 18, the far views' budget
#: once the exposure holds still").
MAX_BUDGET_SCALE = 32.0
#: Mean FLIP per pixel the objects cover that footprint-sized offsets on rays leaving a surface
#: cost (RenderSettings.footprint_offsets: a footprint above the surface, hits within two
#: footprints ignored, as the size rule's rays start). Measured on the 8M striped torus (studio
#: frames, E = 0.005; benchmarks/README.md, "Issue 18, the budget's secondary-ray offsets"):
#: +0.0024 at 2.5x, where budget_scale is 6.3, so at least 0.0024 x 6.3 per covered pixel; at
#: 7.5x (budget_scale 16) it predicts 0.00094 where +0.0004 is measured.
OFFSETS_PIXEL_ERROR = 0.0151
#: The share of the budget above its floor (lod.h: kBudgetFloor) the offsets may take, as each
#: kind of secondary ray's visibility model may (lod.h: kShadowFlipWeight).
OFFSETS_BUDGET_SHARE = 0.25
#: Largest share scale the offsets' rule takes (OFFSETS_PIXEL_ERROR was measured up to 16).
OFFSETS_MAX_SCALE = 16.0
#: The error of a frame in which nothing stops (the core's lod.h: kBudgetFloor).
BUDGET_FLOOR = _core.BUDGET_FLOOR


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
    if isinstance(scene_or_cloud, (Geometry, list, tuple)) or hasattr(scene_or_cloud, "points"):
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


def budget_scale(bounds, camera) -> float:
    """Factor on the per-pixel error budget of primary rays (``lod_pixels="auto"``): the inverse
    of an upper bound on the share of the frame's pixels whose rays can reach the objects.

    The budget bounds the frame's *mean* FLIP and the predictor (benchmarks/README.md, "Issue
    18") is a sum over pixels of per-pixel terms, zero for rays that never meet a tree; so when
    the objects cover a share c of the frame, each pixel that sees them may take the budget / c.
    c is bounded twice, and the smaller bound kept: by the rectangle around the projected corners
    of ``bounds`` grown by a pixel and clipped to the frame (when every corner lies in front of
    the eye), and by the projection of the bounding sphere (an ellipse of area
    ``pi tan(a)^2 / cos(b)^3`` on the unit image plane, a = the sphere's angular radius, b = its
    centre's angle off the view axis; its equivalent radius grown by a pixel's diagonal, so that
    pixels its rim only grazes count) over the image plane's area. 1 when neither applies (the
    eye inside the sphere, or the sphere reaching 90 degrees off the axis).

    Parameters
    ----------
    bounds : tuple of ndarray, shape (3,), float64
        Axis-aligned bounds (lo, hi) of every object.
    camera : Camera

    Returns
    -------
    float
        In [1, MAX_BUDGET_SCALE].
    """
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    eye = np.asarray(camera.eye, dtype=np.float64)
    fwd = np.asarray(camera.forward, dtype=np.float64)
    w, h, tan_half = camera.width, camera.height, camera.tan_half
    share = 1.0
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])]) - eye
    depth = corners @ fwd
    if np.all(depth > 0):
        col = (corners @ np.asarray(camera.right, dtype=np.float64) / depth
               / (tan_half * w / h) + 1.0) * 0.5 * w
        row = (1.0 - corners @ np.asarray(camera.true_up, dtype=np.float64) / depth
               / tan_half) * 0.5 * h
        cols = np.clip([col.min() - 1.0, col.max() + 1.0], 0.0, w)
        rows = np.clip([row.min() - 1.0, row.max() + 1.0], 0.0, h)
        share = (cols[1] - cols[0]) * (rows[1] - rows[0]) / (w * h)
    to_c = 0.5 * (lo + hi) - eye
    dist, radius = float(np.linalg.norm(to_c)), 0.5 * float(np.linalg.norm(hi - lo))
    if dist > radius:
        a = np.arcsin(radius / dist)
        b = np.arccos(np.clip(to_c @ fwd / dist, -1.0, 1.0))
        if a + b < 0.5 * np.pi:
            pixel = 2.0 * tan_half / h  # a pixel's side on the unit image plane
            # the ellipse grown by a pixel's diagonal: every pixel a sample of which meets it
            reach = np.sqrt(np.tan(a) ** 2 / np.cos(b) ** 3) + np.sqrt(2.0) * pixel
            share = min(share, np.pi * reach ** 2 / (4.0 * tan_half ** 2 * w / h))
    return float(1.0 / max(share, 1.0 / MAX_BUDGET_SCALE))


def footprint_offsets(lod_pixels, max_error: float | None, share_scale: float | None) -> bool:
    """Whether rays leaving a surface start a footprint above it (RenderSettings.footprint_offsets).

    The size rule's (numeric ``lod_pixels``) always do. The budget's (``"auto"``) keep full
    detail's offsets unless the offsets' predicted error, OFFSETS_PIXEL_ERROR times the share
    of the frame the objects may cover (at most ``1 / share_scale``, see :func:`budget_scale`),
    fits in OFFSETS_BUDGET_SHARE of the budget above its floor. Footprint-sized offsets spare
    shadow and sky-visibility rays the full-detail nodes around their origin, which the
    visibility model never stops at (lod.h: kVisibilityClearance): the far frames' shadow phase
    drops below the 1 px frame's. E = 0.005 takes them from share_scale 13.4 (the striped torus
    at 7.5x), none below E = 0.0043 (the share scale is taken at most OFFSETS_MAX_SCALE).
    """
    if lod_pixels != "auto":
        return True
    if not max_error or share_scale is None:
        return False
    share_scale = min(share_scale, OFFSETS_MAX_SCALE)
    return OFFSETS_PIXEL_ERROR / share_scale <= OFFSETS_BUDGET_SHARE * (max_error - BUDGET_FLOOR)


def render(scene_or_cloud, camera, *, shadows: bool = DEFAULTS.shadows,
           reflections: int = DEFAULTS.reflections, spp: int = DEFAULTS.spp,
           lod_pixels: float | str = DEFAULTS.lod_pixels,
           max_error: float | None = DEFAULTS.max_error, seed: int = DEFAULTS.seed,
           threads: int | None = DEFAULTS.threads, progress=None, cancel=None,
           ground=DEFAULTS.ground, look=DEFAULTS.look, sides: str | None = DEFAULTS.sides,
           exposure: float | None = DEFAULTS.exposure,
           denoise=DEFAULTS.denoise, background: bool = False, sample_offset: int = 0,
           sequence_spp: int | None = None, phase_times: bool = False) -> Frame:
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
    lod_pixels : float or "auto"
        Level-of-detail threshold in pixels; 0 traces at full detail. "auto": every ray
        (primary, shadow, reflection) stops at the coarsest node whose predicted contribution to
        the image error fits in ``max_error`` (the model: benchmarks/README.md, "Issue 18").
    max_error : float, optional
        With ``lod_pixels="auto"`` only: the frame's mean FLIP against full detail the level of
        detail may cost, in [0, 1]; default DEFAULT_MAX_ERROR (0.005). 0 is full detail.
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
    sides : {"auto", "one", "two"}, optional
        Which sides of the surfels show: "one" culls back faces, "two" shows both, "auto" one
        where they close a surface seen from outside and two elsewhere (:mod:`pointviz.sides`).
        Default: each tree's own (a Scene built from clouds: "auto").
    exposure : float, optional
        The frame's exposure multiplier (``frame.exposure``: what :meth:`Frame.save` and the
        denoiser apply). Default: the look's, automatic (the objects' mean luminance keyed to
        ``pointviz.images.EXPOSURE_KEY``) for studio and outdoor, 1 for flat. The automatic
        exposure is metered on a small full-detail pass of the view (:func:`metered_exposure`),
        so every frame of one view is exposed alike whatever its level of detail, samples or
        denoiser. Frames of different views meant to be seen together (a camera path, a
        comparison) should share one: each view's own automatic exposure brightens or darkens
        the backdrop with what the objects show.
    denoise : bool, {"high", "balanced", "fast"} or pointviz.denoise.Denoiser
        Denoise the colour with Intel Open Image Denoise guided by the albedo and normal
        buffers (needs the ``denoise`` extra: ``pip install 'pointviz[denoise]'``); True is
        ``pointviz.denoise.DENOISE_QUALITY`` ("fast": the benchmark's choice). The tracer's
        colour stays in ``frame.noisy_color``.
    background : bool
        Trace at a lower CPU priority (BACKGROUND_NICE; Linux), so that a GUI stays responsive.
    sample_offset, sequence_spp : int
        Progressive rendering: trace samples ``sample_offset .. sample_offset + spp - 1`` of a
        sequence of ``sequence_spp`` samples per pixel (default ``spp``). The mean of the frames
        with offsets 0, spp, 2 spp, ... (same seed) is the frame rendered with all those samples
        at once, up to float rounding.
    phase_times : bool
        Add ``stats["phase_seconds"]``: the tracer's CPU time (summed over its threads) in
        closest-hit queries of camera rays (``primary``) and of reflection rays
        (``reflection``), in shadow and sky-visibility rays (``shadow``), in the rest of each
        bounce (``shading``) and in the tiles' setup and output (``tile``; a tile proven to show
        only background is written there whole, without a ray): each phase timed
        on the monotonic clock and scaled per tile to the thread's CPU time (one CPU-clock read,
        a system call, per tile).

    Returns
    -------
    Frame
    """
    if camera is None or not hasattr(camera, "pixel_angle"):
        raise InputError("camera: expected a pointviz.Camera")
    from .denoise import check_available, denoise_quality

    opts = RenderSettings(shadows=shadows, reflections=reflections, spp=spp,
                          lod_pixels=lod_pixels, max_error=max_error, seed=seed, threads=threads,
                          ground=ground, look=look, sides=sides, exposure=exposure,
                          denoise=denoise)
    quality = denoise_quality(opts.denoise)
    if quality is not None:
        check_available()  # before the expensive part
    kw = {} if ground is None else {"ground": ground}
    if look is not None:
        kw["look"] = look
    spp, reflections, seed, threads, lod_pixels = (
        opts.spp, opts.reflections, opts.seed, opts.threads, opts.lod_pixels)
    shadows = opts.shadows
    lod_pixels, max_error = check_lod(opts.lod_pixels, opts.max_error)

    rs, origin, share_scale, scene_look, _, _ = _core_scene(scene_or_cloud, kw, camera,
                                                            lod_pixels, max_error, opts.sides)
    settings = _core.RenderSettings()
    settings.spp = spp
    settings.reflections = reflections
    settings.shadows = bool(shadows)
    # the core only asks whether rays carry a footprint at all
    settings.lod_pixels = (1.0 if max_error else 0.0) if lod_pixels == "auto" else float(lod_pixels)
    settings.footprint_offsets = footprint_offsets(lod_pixels, max_error, share_scale)
    settings.seed = seed
    settings.sample_offset = check_int(sample_offset, "sample_offset", 0, 2**31 - 1)
    settings.sequence_spp = check_int(spp if sequence_spp is None else sequence_spp,
                                       "sequence_spp", 1, 2**31 - 1)
    settings.threads = threads or 0
    settings.phase_times = bool(phase_times)

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
    if not phase_times:
        del stats["phase_seconds"]
    else:
        stats["phase_seconds"] = dict(stats["phase_seconds"])
    total_rays = stats["primary_rays"] + stats["shadow_rays"] + stats["reflection_rays"]
    stats["rays_per_second"] = total_rays / max(stats["seconds"], 1e-9)
    stats["primary_rays_per_pixel"] = stats["primary_rays"] / (camera.width * camera.height)
    stats["settings"] = {"shadows": bool(shadows), "reflections": reflections, "spp": spp,
                         "lod_pixels": lod_pixels, "max_error": max_error, "seed": seed, "threads": threads,
                         "look": scene_look.name, "exposure": opts.exposure,
                         "denoise": quality or False}
    frame = Frame(bufs["color"], bufs["depth"], bufs["normal"], bufs["alpha"], stats, camera,
                  albedo=bufs["albedo"], object_alpha=bufs["object_alpha"])
    if opts.exposure is not None:
        frame.exposure = opts.exposure
    elif scene_look.auto_exposure:  # the mean is unbiased by noise: same with or without denoising
        frame.exposure = _metered_exposure(scene_or_cloud, kw, camera, opts, is_cancelled)
    if quality is not None:
        from .denoise import denoise_frame

        denoise_frame(frame, denoise, threads)
    if progress is not None:
        progress(stats["tiles_total"], stats["tiles_total"])
    return frame


#: Pixels of the pass the automatic exposure is metered on (about; :func:`meter_size`).
METER_PIXELS = 1200
#: Largest scale of that pass, each way, where the objects cover too few of its pixels.
METER_MAX_SCALE = 4
#: Side of the square pass a far object is metered on (:func:`meter_crop`).
METER_CROP = 20
#: Fewest pixels of that pass the objects must cover (else it is taken again, larger): the
#: mean luminance of fewer is at the mercy of a few shadowed or highlighted ones.
METER_MIN_COVERED = 32


def meter_size(width: int, height: int, scale: int = 1) -> tuple[int, int]:
    """Size of the pass a ``width`` x ``height`` frame's automatic exposure is metered on: about
    METER_PIXELS pixels of the frame's aspect (4:3: 40x30), times ``scale`` each way. It
    depends on the frame's aspect, not on its resolution: a view's frames at any size (the
    viewer's reduced moving frames and its full still ones, a thumbnail and the final Render)
    meter the same pass and take the same exposure."""
    aspect = width / height
    return (max(1, round(float(np.sqrt(METER_PIXELS * aspect)))) * scale,
            max(1, round(float(np.sqrt(METER_PIXELS / aspect)))) * scale)


def metered_exposure(scene_or_cloud, camera, *, shadows: bool = DEFAULTS.shadows,
                     reflections: int = DEFAULTS.reflections, seed: int = DEFAULTS.seed,
                     threads: int | None = DEFAULTS.threads, ground=DEFAULTS.ground,
                     look=DEFAULTS.look, sides: str | None = DEFAULTS.sides, cancel=None,
                     **ignored) -> float:
    """The automatic exposure :func:`render` gives a frame of ``camera`` (1 for a look without
    one), metered as it meters it (:func:`_metered_exposure`: a small full-detail pass of the
    view), without rendering the frame. The frame's level of detail, samples, denoiser and
    exposure do not enter (``ignored``: a frame's other settings, RenderSettings names, may be
    passed as they are)."""
    unknown = sorted(set(ignored) - set(RenderSettings.names()))
    if unknown:
        raise TypeError(f"metered_exposure() got unexpected keyword arguments: {unknown}")
    if camera is None or not hasattr(camera, "pixel_angle"):
        raise InputError("camera: expected a pointviz.Camera")
    opts = RenderSettings(shadows=shadows, reflections=reflections, seed=seed, threads=threads,
                          ground=ground, look=look, sides=sides)
    kw = {} if ground is None else {"ground": ground}
    if look is not None:
        kw["look"] = look
    return _metered_exposure(scene_or_cloud, kw, camera, opts, _cancel_check(cancel))


def _sphere_in_view(camera, bounds):
    """Where the sphere around ``bounds`` (lo, hi) lies against the camera's view: ("inside",
    centre, radius, distance) when wholly inside its four side planes and in front of the eye,
    ("outside", ...) when wholly outside one of them or behind the eye, ("across", ...)
    otherwise; None when the bounds are not finite or the eye is within the sphere."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    centre, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    to_c = centre - np.asarray(camera.eye, dtype=np.float64)
    dist = float(np.linalg.norm(to_c))
    if not (np.isfinite(dist) and np.isfinite(radius) and dist > radius > 0.0):
        return None
    x, y = to_c @ np.asarray(camera.right), to_c @ np.asarray(camera.true_up)
    z = to_c @ np.asarray(camera.forward)
    th = float(camera.tan_half)
    tw = th * camera.width / camera.height
    # signed distances of the centre to the four side planes, positive outside
    sides = [(a - z * t) / np.sqrt(1.0 + t * t) for a, t in ((x, tw), (-x, tw), (y, th), (-y, th))]
    if z < -radius or max(sides) >= radius:
        where = "outside"
    elif z > radius and max(sides) <= -radius:
        where = "inside"
    else:
        where = "across"
    return where, centre, radius, dist


def meter_crop(camera, bounds):
    """The square camera a far object's exposure is metered with, or None: at the frame's eye,
    looking at the centre of the sphere around ``bounds`` (lo, hi) and seeing it edge to edge,
    METER_CROP pixels a side. Only where that sphere lies wholly inside the frame's view (so the
    crop sees no part of an object the frame does not) and the crop magnifies it: where the
    frame's metering pass (:func:`meter_size`) would see it less than METER_CROP pixels wide."""
    return _crop_of(camera, _sphere_in_view(camera, bounds))


def _crop_of(camera, place):
    """:func:`meter_crop` for the sphere's ``place`` (:func:`_sphere_in_view`)."""
    from .camera import Camera

    if place is None or place[0] != "inside":
        return None
    _, centre, radius, dist = place
    th = float(camera.tan_half)
    eye = np.asarray(camera.eye, dtype=np.float64)
    half = float(np.arcsin(radius / dist))
    if np.tan(half) / th * meter_size(camera.width, camera.height)[1] >= METER_CROP:
        return None
    return Camera.look_at(eye, centre, up=camera.true_up, fov_deg=2.0 * np.degrees(half),
                          width=METER_CROP, height=METER_CROP)


def _metered_exposure(scene_or_cloud, kw: dict, camera, opts, is_cancelled) -> float:
    """The automatic exposure of a frame: :func:`pointviz.images.auto_exposure` of a pass of the
    same view at full detail, one sample per pixel (its centre), no denoiser, and the frame's
    other settings (shadows, reflections, ground, look, sides, seed, and the lights the frame's
    camera places). The pass: a far object's :func:`meter_crop`, else the view at
    :func:`meter_size`; a pass in which the objects cover fewer than METER_MIN_COVERED pixels
    is taken again at twice the size each way, up to METER_MAX_SCALE times, unless the objects'
    bounding sphere lies wholly outside the view (then the pass's whole frame keys it, as
    :func:`pointviz.images.auto_exposure` does where no object shows).

    Every frame of a view is exposed alike whatever its level of detail, samples or
    resolution: a coarser level of detail changes what the objects' pixels show a little
    (lod_pixels="auto" bounds the mean FLIP against full detail), and metered on its own pixels
    that change moved the exposure, and with it every pixel of the frame (the dragon's raw scans
    at 7.5x the framing distance, E = 0.005: exposure -4.4 %, FLIP against full detail 0.0011 at
    full detail's exposure, 0.063 at its own). The pass costs about METER_PIXELS camera samples
    (1/256 of a 640x480 frame's pixels; 0.6-2.5 ms on the dragon's raw scans, one thread); its
    mean luminance over the objects' pixels is unbiased by sampling, so it keys the frame as its
    own pixels would, within the sampling error of that mean (within 6 % of the full-detail
    frame's own on the dragon's scans and the Armadillo from the framing distance to 15x it).
    What a view meters is kept with its full-detail RenderScene (the memo of
    :func:`_core_scene`), so that the frames of one view (the viewer's passes, a benchmark's
    variants) meter it once.
    """
    # the frame's RenderScene at full detail: its lights are placed for the frame's camera
    rs, origin, _, look, bounds, metered = _core_scene(scene_or_cloud, kw, camera, 0.0, None,
                                                       opts.sides)
    if not look.auto_exposure:  # (render() asks only for looks that have one)
        return 1.0
    key = (bool(opts.shadows), opts.reflections, opts.seed)
    known = metered.get(key)
    if known is not None:  # this view's, metered by an earlier frame
        return known
    exposure = _meter(rs, origin, bounds, camera, opts, is_cancelled)
    metered[key] = exposure
    return exposure


def _meter(rs, origin, bounds, camera, opts, is_cancelled) -> float:
    """:func:`_metered_exposure`'s passes, on the frame's full-detail RenderScene ``rs``."""
    from .images import EXPOSURE_COVERAGE, auto_exposure

    st = _core.RenderSettings()
    st.spp = 1
    st.reflections = opts.reflections
    st.shadows = bool(opts.shadows)
    st.lod_pixels = 0.0
    st.footprint_offsets = footprint_offsets(0.0, None, None)
    st.seed = opts.seed
    st.sample_offset = 0
    st.sequence_spp = 1
    st.threads = opts.threads or 0
    st.phase_times = False

    def meter(mcam):
        try:
            bufs, _ = _core.render(rs, camera_model(mcam, origin), st,
                                   lambda done, total: not is_cancelled())
        except CancelledError:
            raise CancelledError("render cancelled") from None
        covered = int(np.count_nonzero(bufs["object_alpha"] >= EXPOSURE_COVERAGE))
        return auto_exposure(bufs["color"], bufs["object_alpha"]), covered

    place = _sphere_in_view(camera, bounds)
    crop = _crop_of(camera, place)
    if crop is not None:
        exposure, covered = meter(crop)
        if covered >= METER_MIN_COVERED:
            return exposure
    in_view = place is None or place[0] != "outside"
    scale = 1
    while True:
        exposure, covered = meter(camera.with_size(*meter_size(camera.width, camera.height,
                                                               scale)))
        # larger passes only while the objects may show
        if covered >= METER_MIN_COVERED or not in_view or scale >= METER_MAX_SCALE:
            return exposure
        scale *= 2


#: Where _core_scene keeps its answers: on the Scene (its memo) or on the SurfelScene a frame was
#: asked of (its ``__dict__``; the answers hold the tree, not the SurfelScene, so no reference
#: cycle keeps a dropped cloud's tree alive).
_CORE_MEMO = "_core_scene"
#: How many answers a scene keeps (the oldest goes first): one per variant of a view that
#: benchmarks and comparisons interleave (bench_lod.py renders nine per view).
CORE_SCENES_KEPT = 16


def _core_scene(scene_or_cloud, kw: dict, camera, lod_pixels, max_error, sides=None):
    """The core's RenderScene of a frame, its local origin, the budget's share scale
    (:func:`budget_scale`, None unless ``lod_pixels == "auto"``), the scene's look, the
    objects' bounds, and a dict in which :func:`_metered_exposure` keeps what it metered for
    the view (kept and dropped with the rest).

    The last CORE_SCENES_KEPT answers are kept with the Scene or SurfelScene the frame was
    asked of, keyed by everything they are made from that may differ between two frames of that
    scene: the camera (its lights follow the view, the share scale the frame), ``lod_pixels``
    and ``max_error``, the ground, look and sides asked for, and each tree's traversal options (read
    when the scene is made, and settable in place). The rest (objects, materials, lights, sky,
    ground) is frozen with the scene. A kept RenderScene is never changed after it is made (so
    frames on other threads may share it), and is kept only when every object is a
    SurfelScene (a geometry behind a Python callback is given each render's cancel flag).
    Frames of one view (the viewer's progressive samples, a benchmark's interleaved variants)
    then pay none of this Python again.
    """
    from .scene import Scene
    from .surfels import SurfelScene

    holder = None
    if isinstance(scene_or_cloud, Scene):
        holder = scene_or_cloud._memo
    elif isinstance(scene_or_cloud, SurfelScene):
        holder = scene_or_cloud.__dict__
    key = None
    if holder is not None:
        try:
            key = (tuple(sorted(kw.items())), _camera_key(camera), lod_pixels, max_error, sides)
            hash(key)
        except TypeError:  # a ground or look that is not hashable: made anew every frame
            key = None
    kept = holder.get(_CORE_MEMO) if key is not None else None
    if kept is not None:
        trees, entries = kept
        hit = entries.get(key)
        if hit is not None and hit[0] == _options_key([scene_or_cloud] if trees is None else trees):
            return hit[1]
    scene = as_scene(scene_or_cloud, **kw)
    if isinstance(scene_or_cloud, Scene):
        if "look" in kw:
            scene = scene.with_look(kw["look"])
        if "ground" in kw:
            scene = scene.with_ground(kw["ground"])
    rs, origin = scene.to_core(camera, lod_pixels, max_error, sides)
    share_scale = None
    if lod_pixels == "auto":
        share_scale = budget_scale(scene.bounds(), camera)
        rs.set_budget_scale(share_scale)
    out = (rs, origin, share_scale, scene.look, scene.bounds(), {})
    if key is not None:
        trees = [scene.geometry(i) for i in range(len(scene.objects))]
        if all(isinstance(t, SurfelScene) for t in trees):
            if kept is None:
                # (a SurfelScene does not keep itself: that cycle would outlive its last reference)
                mine = None if scene_or_cloud is not scene and trees == [scene_or_cloud] else trees
                kept = holder.setdefault(_CORE_MEMO, (mine, {}))
            entries = kept[1]
            entries[key] = (_options_key(trees), out)
            while len(entries) > CORE_SCENES_KEPT:  # the oldest first (a dict keeps its order)
                try:
                    del entries[next(iter(entries))]
                except (KeyError, RuntimeError, StopIteration):  # another thread's frame
                    break
    return out


def _camera_key(camera) -> tuple:
    """What of a camera a frame's RenderScene depends on (values, not the object)."""
    return (tuple(np.asarray(camera.eye, dtype=np.float64).tolist()),
            tuple(np.asarray(camera.forward, dtype=np.float64).tolist()),
            tuple(np.asarray(camera.right, dtype=np.float64).tolist()),
            tuple(np.asarray(camera.true_up, dtype=np.float64).tolist()),
            float(camera.tan_half), int(camera.width), int(camera.height))


def _options_key(trees) -> tuple:
    """The traversal options of each tree, as values (they are settable in place)."""
    return tuple(t.options_key() for t in trees)


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
