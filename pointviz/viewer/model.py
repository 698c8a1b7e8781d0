"""The viewer's model: one settings object (the single source of truth) and the pure functions
that turn it into a preview (subset, colours, point size), a render scene and a render camera.

Nothing here touches a widget or a GUI toolkit, so every function runs on any thread and is
tested without a display. Both backends (:mod:`.o3d_app`, :mod:`.pv_app`) read the settings and
call these functions; their handlers only change the settings and then re-apply them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from ..errors import InputError
from ..settings import DEFAULTS, RenderSettings, check_int
from ..values import AXES, axis

#: Ways of colouring the preview.
COLOR_MODES = ("rgb", "normal", "height", "intensity")
#: Grounds offered by the viewer (a subset of :data:`pointviz.settings.GROUNDS`).
GROUNDS = ("none", "matte", "mirror")
#: The render settings the viewer offers (ground and look are the scene's, see render_scene).
RENDER_FIELDS = ("shadows", "reflections", "spp", "lod_pixels", "max_error", "seed", "threads",
                 "sides", "exposure", "denoise")
#: How the ray-traced frame is shown: next to the preview, or over it (toggled).
DISPLAYS = ("side", "overlay")
#: Most points drawn by the preview. Above this the preview shows a spatially even subset (one
#: point per stretch of a Z-order curve through the cloud) whose disks are enlarged to keep the
#: surface closed; the ray tracer always uses all. A 640x480 viewport has 307k pixels, of which an
#: object covers a fraction, and a splat is 2 px across or more: more points only add work for
#: Mesa's software rasteriser (llvmpipe), whose queued frames the GUI thread waits for
#: (benchmarks/o3d_preview_cost.py).
DEFAULT_PREVIEW_MAX_POINTS = 200_000
#: The preview's points are drawn unlit, their colours shaded beforehand like the ray tracer's
#: studio lights (:func:`shade_colors`: an ambient floor, a sky term brighter on surfaces facing
#: up, the key light and the fill light opposite it, all Lambert), so they still read as lit:
#: Filament's lit point shader costs the software rasteriser about 1.5x the CPU per frame, and
#: its queued frames keep the GUI thread waiting (benchmarks/o3d_preview_cost.py).
PREVIEW_SHADE = {"ambient": 0.15, "sky": 0.35, "key": 0.8, "fill": 0.25}
#: Bits per axis of the Z-order (Morton) code that orders a cloud for the preview's subset.
MORTON_BITS = 21
#: Preview background (sRGB), close to the ray tracer's sky at the horizon.
PREVIEW_BACKGROUND = (0.82, 0.86, 0.92, 1.0)
#: Seed of the preview subset, so the same cloud always previews the same points.
PREVIEW_SUBSET_SEED = 0
#: Default light, degrees: azimuth around ``up`` from the scene's first horizontal axis, and
#: elevation above the horizon (a key light from above one side).
DEFAULT_LIGHT_AZIMUTH_DEG = 135.0
DEFAULT_LIGHT_ELEVATION_DEG = 50.0
#: The look's fill light comes from the other side of the key, low: azimuth offset and height.
FILL_AZIMUTH_OFFSET_DEG = 160.0
FILL_ELEVATION_DEG = 20.0
#: Largest preview point size in pixels (Open3D and VTK clamp huge points anyway).
MAX_POINT_SIZE_PX = 64.0
#: Smallest preview point size in pixels (1 px points leave holes; 2 px closes them).
MIN_POINT_SIZE_PX = 2.0
#: Viridis anchors (matplotlib's, every 1/6) for the height colour map, without matplotlib.
_VIRIDIS = np.array([[0.267, 0.005, 0.329], [0.255, 0.267, 0.530], [0.164, 0.471, 0.558],
                     [0.128, 0.567, 0.551], [0.135, 0.659, 0.518], [0.478, 0.821, 0.318],
                     [0.993, 0.906, 0.144]], dtype=np.float32)
#: Percentiles that span the intensity colour scale (robust to a few saturated returns).
INTENSITY_PERCENTILES = (1.0, 99.0)
#: The Up control's choices: world axes by label.
UP_AXES = {f"{sign}{name.upper()}": axis(sign + name) for sign in "+-" for name in AXES}
#: Vertical field of view of the camera that frames the scene when the viewer opens and when the
#: up changes, degrees.
VIEW_FOV_DEG = 40.0


@dataclass
class ViewerSettings:
    """Everything the user can change in the viewer. Handlers replace fields, then the backend
    re-applies the whole object (``_apply_settings``); nothing else holds UI state.

    Attributes
    ----------
    color_mode : {"rgb", "normal", "height", "intensity"}
        Preview colouring (the ray tracer always uses the point colours and materials).
    point_scale : float
        Multiplies the preview point size computed from the surfel radii and the zoom.
    preview_max_points : int
        Level-of-detail threshold of the preview (see DEFAULT_PREVIEW_MAX_POINTS).
    shadows : bool
    reflections : int
        Mirror/glossy bounces, 0..16.
    spp : int
        Samples per pixel, 1..4096.
    lod_pixels : float or "auto"
        Ray tracer level-of-detail threshold in pixels (0 = full detail), or "auto": the error
        budget ``max_error`` (see :func:`pointviz.render`).
    max_error : float or None
        With ``lod_pixels="auto"``: mean FLIP the level of detail may cost (default 0.005).
    light_azimuth_deg, light_elevation_deg : float
        Direction toward the (single directional) light, relative to the scene's up.
    light_intensity : float
    ground : {"none", "matte", "mirror"}, or None to keep the input scene's own ground.
    sides : {"auto", "one", "two"}, or None to keep the input scene's own (see
        :func:`pointviz.render`).
    width, height : int
        Output size of the ray-traced frame; 0 follows the preview's size (and aspect).
    display : {"side", "overlay"}
    seed : int
    threads : int or None
    exposure : float or None
        Exposure multiplier of the ray-traced frame; None: the look's (automatic for studio
        and outdoor).
    denoise : bool
        Denoise the ray-traced frame (Open Image Denoise, the ``denoise`` extra).
    up : (3,) float or None
        The scene's up direction as the viewer shows it (a unit vector; an axis label such as
        "+Z" or "z" is accepted), or None: the input scene's own (see :func:`scene_with_up`).
    """

    color_mode: str = "rgb"
    point_scale: float = 1.0
    preview_max_points: int = DEFAULT_PREVIEW_MAX_POINTS
    shadows: bool = DEFAULTS.shadows
    reflections: int = DEFAULTS.reflections
    spp: int = DEFAULTS.spp
    lod_pixels: float | str = DEFAULTS.lod_pixels
    max_error: float | None = DEFAULTS.max_error
    light_azimuth_deg: float = DEFAULT_LIGHT_AZIMUTH_DEG
    light_elevation_deg: float = DEFAULT_LIGHT_ELEVATION_DEG
    light_intensity: float = 1.1
    ground: str | None = "matte"
    sides: str | None = None
    width: int = 0
    height: int = 0
    display: str = "side"
    seed: int = DEFAULTS.seed
    threads: int | None = DEFAULTS.threads
    exposure: float | None = DEFAULTS.exposure
    denoise: bool = DEFAULTS.denoise
    up: tuple | None = None

    def __post_init__(self) -> None:
        if self.up is not None:
            self.up = up_vector(self.up)
        self.validate()

    def validate(self) -> ViewerSettings:
        """Raise InputError naming the first invalid field; return self."""
        if self.color_mode not in COLOR_MODES:
            raise InputError(f"color_mode: expected one of {COLOR_MODES}, got {self.color_mode!r}")
        if self.ground is not None and self.ground not in GROUNDS:
            raise InputError(f"ground: expected one of {GROUNDS} or None, got {self.ground!r}")
        if self.display not in DISPLAYS:
            raise InputError(f"display: expected one of {DISPLAYS}, got {self.display!r}")
        self.render_settings()  # the render settings, checked where they are defined
        for name, lo, hi in (("width", 0, 16384), ("height", 0, 16384),
                             ("preview_max_points", 1, 2**40)):
            check_int(getattr(self, name), name, lo, hi)
        for name in ("point_scale", "light_intensity"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"{name}: expected a finite number >= 0, got {v!r}")
        if not -90.0 <= float(self.light_elevation_deg) <= 90.0:
            raise InputError(f"light_elevation_deg: expected [-90, 90], got {self.light_elevation_deg!r}")
        return self

    def updated(self, **changes) -> ViewerSettings:
        """A validated copy with some fields replaced."""
        if not isinstance(changes.get("lod_pixels", "auto"), str):
            changes.setdefault("max_error", None)  # a threshold typed in ends the budget
        return replace(self, **changes)

    def render_settings(self) -> RenderSettings:
        """The :class:`~pointviz.settings.RenderSettings` these settings hold (the ground is
        the viewer's own choice, applied to the scene by :func:`render_scene`)."""
        return RenderSettings(**{name: getattr(self, name) for name in RENDER_FIELDS})

    def render_kwargs(self) -> dict:
        """Keyword arguments of :func:`pointviz.render` for these settings."""
        return {name: getattr(self.render_settings(), name) for name in RENDER_FIELDS}

    def to_dict(self) -> dict:
        return asdict(self)


# ------------------------------------------------------------------------------------ geometry


def horizontal_basis(up) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Right-handed basis ``(e1, e2, up)`` with e1, e2 spanning the plane normal to ``up``.

    ``e1`` is the world axis (X, else Z) projected on that plane, so azimuth 0 points along +X
    for a Y-up or Z-up scene.
    """
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    ref = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    e1 = ref - (ref @ u) * u
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    return e1, e2, u


def light_direction(azimuth_deg: float, elevation_deg: float, up) -> np.ndarray:
    """Unit vector toward the light, shape (3,) float64 (see :func:`horizontal_basis`)."""
    e1, e2, u = horizontal_basis(up)
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    d = math.cos(el) * (math.cos(az) * e1 + math.sin(az) * e2) + math.sin(el) * u
    return d / np.linalg.norm(d)


def light_angles(direction, up) -> tuple[float, float]:
    """Inverse of :func:`light_direction`: (azimuth_deg, elevation_deg)."""
    e1, e2, u = horizontal_basis(up)
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    el = math.degrees(math.asin(float(np.clip(d @ u, -1.0, 1.0))))
    az = math.degrees(math.atan2(float(d @ e2), float(d @ e1)))
    return az, el


def up_vector(value) -> tuple[float, float, float]:
    """A unit up vector from an axis label ("+Z", "-y", "x": :data:`UP_AXES`) or three numbers.

    Raises
    ------
    InputError
        Naming ``up``, for anything else (a zero or non-finite vector).
    """
    if isinstance(value, str):
        named = axis(value)
        if named is None:
            raise InputError(f"up: expected one of {', '.join(UP_AXES)} or three numbers, "
                             f"got {value!r}")
        return named
    try:
        v = np.asarray(value, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise InputError(f"up: expected one of {', '.join(UP_AXES)} or three numbers, "
                         f"got {value!r}") from None
    n = float(np.linalg.norm(v))
    if not (np.all(np.isfinite(v)) and n > 0):
        raise InputError(f"up: expected a non-zero finite vector, got {value!r}")
    return tuple(float(x) for x in v / n)


def up_label(up) -> str:
    """The Up control's text for an up vector: its axis label (:data:`UP_AXES`) when it is one,
    else its components (a depth camera's gravity, ``--up X,Y,Z``)."""
    v = np.asarray(up_vector(up))
    for label, axis in UP_AXES.items():
        if np.allclose(v, axis, rtol=0.0, atol=1e-9):
            return label
    return "(" + ", ".join(f"{x:.3g}" for x in v) + ")"


def up_choices(up) -> list[str]:
    """The Up control's items: the six axes, after the scene's own up when it is none of them."""
    label = up_label(up)
    return list(UP_AXES) if label in UP_AXES else [label, *UP_AXES]


def scene_with_up(scene, up):
    """``scene`` seen with ``up`` (a vector or label; None: the scene's own), sharing its
    trees (:meth:`pointviz.scene.Scene.with_up`); the scene itself when the up is its own."""
    if up is None:
        return scene
    return scene.with_up(up_vector(up))


def view_camera(scene, width: int, height: int, fov_deg: float = VIEW_FOV_DEG):
    """The camera the viewer opens on, and frames the scene with after an up change: the whole
    scene for its up (:meth:`pointviz.camera.Camera.fit`), at the preview's size."""
    from ..camera import Camera

    return Camera.fit(scene, fov_deg=fov_deg, width=int(width), height=int(height))


@dataclass(frozen=True)
class UpChange:
    """What the Up control changes: the settings (their ``up``), the scene shown and traced
    (the input scene with that up, trees shared), and the camera that frames it."""

    settings: ViewerSettings
    scene: object
    camera: object


def change_up(source_scene, settings: ViewerSettings, up, width: int, height: int,
              fov_deg: float = VIEW_FOV_DEG) -> UpChange:
    """The Up control: ``up`` (a label or vector) applied to the viewer's input scene
    ``source_scene``; the camera re-framed for it at the preview's ``width`` x ``height``.

    Nothing is read or fitted again: the trees are shared, and the ground level along the new
    up is computed on first use (once per up). The light's azimuth and elevation are relative
    to the up, so the light, the ground and the preview's shading turn with it.
    """
    new = settings.updated(up=up_vector(up))
    scene = scene_with_up(source_scene, new.up)
    return UpChange(new, scene, view_camera(scene, width, height, fov_deg))


def as_scene(source):
    """The :class:`~pointviz.scene.Scene` shown by the viewer (a cloud gets default lights)."""
    from ..rendering import as_scene as _as_scene

    return _as_scene(source)


def initial_settings(scene, **overrides) -> ViewerSettings:
    """Settings that start from the scene's own first directional light and ground."""
    from ..scene import DirectionalLight

    kw = {"ground": None}
    for light in scene.lights or ():
        if isinstance(light, DirectionalLight):
            az, el = light_angles(light.direction, scene.up)
            kw.update(light_azimuth_deg=round(az, 3), light_elevation_deg=round(el, 3),
                      light_intensity=float(light.intensity))
            break
    if scene.ground is None:
        kw["ground"] = "none"
    kw.update(overrides)
    return ViewerSettings(**kw)


def render_scene(scene, settings: ViewerSettings):
    """The scene to ray trace: ``scene`` with the settings' ground and light (trees shared).

    The settings describe a single directional light (its softness comes from the scene's first
    directional light). Builds the scene's surfel trees on first use, so call it on the render
    worker's thread, not the GUI thread. With the settings' ``up`` the scene is seen with that
    up (:func:`scene_with_up`: the ground, the light and an "auto" look follow it).
    """
    from ..scene import DirectionalLight

    scene = scene_with_up(scene, settings.up)
    scene.build()  # the trees, once (shared with the copy returned)
    ground = scene.ground if settings.ground is None else settings.ground
    if scene.lights is None and scene.look.key <= 0:  # a look without a key light ("flat")
        return scene.with_ground(ground)
    angle = scene.look.key_angle_deg
    for light in scene.lights or ():
        if isinstance(light, DirectionalLight):
            angle = light.angle_deg
            break
    direction = light_direction(settings.light_azimuth_deg, settings.light_elevation_deg, scene.up)
    lights = [DirectionalLight(direction=tuple(float(v) for v in direction),
                               intensity=float(settings.light_intensity), angle_deg=angle)]
    if scene.lights is None and scene.look.fill > 0:  # the look's shadowless fill, opposite
        fill = light_direction(settings.light_azimuth_deg + FILL_AZIMUTH_OFFSET_DEG,
                               FILL_ELEVATION_DEG, scene.up)
        lights.append(DirectionalLight(direction=tuple(float(v) for v in fill),
                                       intensity=scene.look.fill, angle_deg=0.0, shadows=False))
    return scene.replace(ground=ground, lights=lights)


def scene_clouds(scene) -> list:
    """(cloud, material) pairs of the scene's point objects (callback geometries are skipped)."""
    out = []
    for obj in scene.objects:
        cloud = getattr(obj.geometry, "cloud", obj.geometry)
        if hasattr(cloud, "points"):
            out.append((cloud, obj.material))
    return out


@dataclass
class PreviewData:
    """What the preview draws (all float32 except points).

    Attributes
    ----------
    points : (m, 3) float64
    normals : (m, 3) float32
    colors : (m, 3) float32 in [0, 1]
    radii : (m,) float32
        Surfel radii, enlarged by ``sqrt(total / m)`` for a subset so the surface stays closed.
    total : int
        Points in the scene; ``m < total`` means a level-of-detail subset.
    note : str
        Status-bar text (subset, missing intensity).
    """

    points: np.ndarray
    normals: np.ndarray
    colors: np.ndarray
    radii: np.ndarray
    total: int
    note: str = ""

    @property
    def is_subset(self) -> bool:
        return len(self.points) < self.total


def _colormap(values: np.ndarray) -> np.ndarray:
    """Viridis-like RGB for values in [0, 1]; (n,) -> (n, 3) float32."""
    x = np.clip(values, 0.0, 1.0) * (len(_VIRIDIS) - 1)
    return np.stack([np.interp(x, np.arange(len(_VIRIDIS)), _VIRIDIS[:, c]) for c in range(3)],
                    axis=1).astype(np.float32)


def _normalise(values: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(values, INTENSITY_PERCENTILES) if len(values) else (0.0, 1.0)
    return (values - lo) / (hi - lo) if hi > lo else np.zeros_like(values)


def preview_colors(cloud, material, index, mode: str, up) -> tuple[np.ndarray, str]:
    """Colours of the selected points for a colour mode; (k, 3) float32 and a note."""
    note = ""
    if mode == "normal":
        return (0.5 * (np.asarray(cloud.normals)[index] + 1.0)).astype(np.float32), note
    if mode == "height":
        h = np.asarray(cloud.points)[index] @ np.asarray(up, dtype=np.float64)
        lo, hi = (float(h.min()), float(h.max())) if len(h) else (0.0, 1.0)
        return _colormap((h - lo) / (hi - lo) if hi > lo else np.zeros_like(h)), note
    base = np.asarray(material.color, dtype=np.float32)
    if cloud.colors is not None and material.use_point_colors:
        rgb = np.asarray(cloud.colors)[index] * (base / max(float(base.max()), 1e-6))
    else:
        rgb = np.broadcast_to(base, (len(index), 3))
    rgb = np.clip(rgb, 0.0, 1.0).astype(np.float32)
    if mode == "intensity":
        intensity = getattr(cloud, "intensity", None)
        if intensity is not None:
            g = _normalise(np.asarray(intensity, dtype=np.float64)[index]).astype(np.float32)
        else:
            g = rgb @ np.array([0.2126, 0.7152, 0.0722], np.float32)
            note = "no intensity: showing luminance"
        return np.repeat(np.clip(g, 0, 1)[:, None], 3, axis=1).astype(np.float32), note
    return rgb, note


def morton_codes(points: np.ndarray) -> np.ndarray:
    """Z-order codes of ``points`` (n, 3) quantised to MORTON_BITS per axis over their bounds;
    (n,) uint64. Points close along the curve are close in space."""
    p = np.asarray(points, dtype=np.float64)
    lo, hi = p.min(axis=0), p.max(axis=0)
    scale = (2**MORTON_BITS - 1) / np.maximum(hi - lo, 1e-300)
    code = np.zeros(len(p), dtype=np.uint64)
    for axis in range(3):
        x = ((p[:, axis] - lo[axis]) * scale[axis]).astype(np.uint64)
        for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF),
                            (8, 0x100F00F00F00F00F), (4, 0x10C30C30C30C30C3),
                            (2, 0x1249249249249249)):
            x = (x | (x << np.uint64(shift))) & np.uint64(mask)
        code |= x << np.uint64(axis)
    return code


def stratified_subset(points: np.ndarray, m: int, rng) -> np.ndarray:
    """Sorted indices of ``m`` of ``points``, spread evenly over the cloud: the points ordered
    along a Z-order curve are cut into ``m`` equal stretches and one point is drawn from each
    (a random subset leaves clumps and holes that enlarged disks only partly hide)."""
    n = len(points)
    if m >= n:
        return np.arange(n)
    order = np.argsort(morton_codes(points), kind="stable")
    pick = ((np.arange(m) + rng.random(m)) * (n / m)).astype(np.int64)
    return np.sort(order[np.minimum(pick, n - 1)])


def preview_data(scene, settings: ViewerSettings) -> PreviewData:
    """Points, normals, colours and radii the preview draws (an even subset if too many)."""
    pairs = scene_clouds(scene)
    if not pairs:
        raise InputError("scene: nothing to preview (no point clouds)")
    total = sum(len(c.points) for c, _ in pairs)
    keep = min(1.0, settings.preview_max_points / total)
    rng = np.random.default_rng(PREVIEW_SUBSET_SEED)
    pts, nrm, col, rad, notes = [], [], [], [], []
    for cloud, mat in pairs:
        n = len(cloud.points)
        if keep < 1.0:
            index = stratified_subset(np.asarray(cloud.points), max(1, int(n * keep)), rng)
        else:
            index = np.arange(n)
        c, note = preview_colors(cloud, mat, index, settings.color_mode, scene.up)
        pts.append(np.asarray(cloud.points)[index])
        nrm.append(np.asarray(cloud.normals, dtype=np.float32)[index])
        col.append(c)
        rad.append(np.asarray(cloud.radii, dtype=np.float32)[index] * np.float32(math.sqrt(n / len(index))))
        if note:
            notes.append(note)
    data = PreviewData(np.concatenate(pts), np.concatenate(nrm), np.concatenate(col),
                       np.concatenate(rad), total)
    if data.is_subset:
        notes.insert(0, f"preview: LoD subset of {len(data.points):,} / {total:,} points "
                        "(Render traces all)")
    else:
        notes.insert(0, f"preview: {total:,} points")
    data.note = "; ".join(dict.fromkeys(notes))
    return data


def shade_colors(colors: np.ndarray, normals: np.ndarray, settings: ViewerSettings,
                 up) -> np.ndarray:
    """``colors`` (n, 3) in [0, 1] shaded for the preview by the settings' key light, its fill
    (as :func:`render_scene` places them) and a sky above ``up``, weights PREVIEW_SHADE; (n, 3)
    float32 clipped to [0, 1]. View-independent, so computed once per light."""
    w = PREVIEW_SHADE
    key = light_direction(settings.light_azimuth_deg, settings.light_elevation_deg, up)
    fill = light_direction(settings.light_azimuth_deg + FILL_AZIMUTH_OFFSET_DEG,
                           FILL_ELEVATION_DEG, up)
    u = np.asarray(up, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float32)
    directions = np.stack([key, fill, u / np.linalg.norm(u)]).astype(np.float32)
    cos = n @ directions.T                                     # (n, 3)
    k = (w["ambient"] + w["key"] * np.maximum(cos[:, 0], 0.0)
         + w["fill"] * np.maximum(cos[:, 1], 0.0) + w["sky"] * (0.5 + 0.5 * cos[:, 2]))
    return np.clip(np.asarray(colors, dtype=np.float32) * k[:, None].astype(np.float32),
                   0.0, 1.0)


def point_size_px(radius: float, distance: float, height_px: int, fov_deg: float,
                  scale: float = 1.0) -> float:
    """Preview point size: the diameter in pixels of a disk of ``radius`` at ``distance``.

    Clamped to [MIN_POINT_SIZE_PX, MAX_POINT_SIZE_PX].
    """
    focal = height_px / (2.0 * math.tan(math.radians(fov_deg) / 2.0))
    px = 2.0 * radius * focal / max(distance, 1e-12) * scale
    return float(min(MAX_POINT_SIZE_PX, max(MIN_POINT_SIZE_PX, px)))


# ------------------------------------------------------------------------------------ cameras


def camera_from_gl(view, projection, width: int, height: int, target_distance: float):
    """The :class:`~pointviz.camera.Camera` of an OpenGL-style view and projection matrix.

    Parameters
    ----------
    view : (4, 4) array_like
        World -> camera, camera looking down -Z with +Y up (Open3D's ``get_view_matrix``,
        VTK's view transform).
    projection : (4, 4) array_like
        Perspective projection; ``P[1, 1] = 1 / tan(vfov / 2)``.
    width, height : int
        Output image size. The vertical field of view is kept, so a different aspect shows
        more or less horizontally.
    target_distance : float
        How far along the view direction the camera's target is put.
    """
    from ..camera import Camera

    v = np.asarray(view, dtype=np.float64).reshape(4, 4)
    p = np.asarray(projection, dtype=np.float64).reshape(4, 4)
    inv = np.linalg.inv(v)
    eye = inv[:3, 3]
    forward = -inv[:3, 2]
    up = inv[:3, 1]
    if not p[1, 1] > 0:
        raise InputError("projection: not a perspective projection (P[1,1] <= 0)")
    fov = math.degrees(2.0 * math.atan(1.0 / p[1, 1]))
    return Camera(eye, eye + forward * float(target_distance), up, fov, int(width), int(height))


def output_size(settings: ViewerSettings, view_width: int, view_height: int) -> tuple[int, int]:
    """Frame size: the settings' size, a missing side following the preview's aspect."""
    w, h = int(settings.width), int(settings.height)
    if w and h:
        return w, h
    if w:
        return w, max(1, round(w * view_height / view_width))
    if h:
        return max(1, round(h * view_width / view_height)), h
    return int(view_width), int(view_height)


def up_option(up, source_up) -> str:
    """The ``--up`` option that gives ``pointviz render``/``path`` the viewer's ``up`` when it is
    not the file's own ``source_up`` (else ""): ``--up z``, ``--up=-x``, ``--up=X,Y,Z``."""
    v = np.asarray(up_vector(up))
    if np.allclose(v, up_vector(source_up), rtol=0.0, atol=1e-9):
        return ""
    label = up_label(v)
    if label in UP_AXES:
        return f"--up {label[1].lower()}" if label[0] == "+" else f"--up=-{label[1].lower()}"
    return "--up=" + ",".join(f"{x:.6g}" for x in v)


def camera_json(camera) -> str:
    """The camera as the JSON text ``pointviz render --camera`` reads."""
    import json

    from ..camera import CAMERA_FORMAT, CAMERA_FORMAT_VERSION

    return json.dumps({"format": CAMERA_FORMAT, "version": CAMERA_FORMAT_VERSION,
                       **camera.to_dict()}, indent=2) + "\n"
