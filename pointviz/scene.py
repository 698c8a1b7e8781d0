"""What a frame shows: surfel clouds (or meshes) with materials, a ground plane, lights and a sky.

The scene model is deliberately small: one material per object, three kinds of light and an
optional infinite ground plane. ``Scene.to_core`` turns it into the C++ render scene; the same
scene with a mesh backend in place of the surfels renders with identical shading.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from . import _core
from . import extent as _extent_mod
from .errors import InputError
from .extent import (  # noqa: F401 - public here too
    GROUND_OUTLIER_FRACTION,
    GROUND_ROBUST_MIN_POINTS,
    cloud_extent,
)
from .geometry import Geometry

_Y_UP = (0.0, 1.0, 0.0)


def _rgb(value, name: str) -> tuple[float, float, float]:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.isfinite(arr).all() or (arr < 0).any():
        raise InputError(f"{name}: expected three finite non-negative numbers, got {value!r}")
    return tuple(float(v) for v in arr)


def _unit(value, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise InputError(f"{name}: expected three finite numbers, got {value!r}")
    n = np.linalg.norm(arr)
    if not n > 0:
        raise InputError(f"{name}: must not be the zero vector")
    return arr / n


def _in_range(value, name: str, lo: float, hi: float) -> float:
    v = float(value)
    if not (np.isfinite(v) and lo <= v <= hi):
        raise InputError(f"{name}: expected a number in [{lo}, {hi}], got {value!r}")
    return v


@dataclass(frozen=True)
class Material:
    """Surface appearance (linear RGB).

    Parameters
    ----------
    color : (3,) float
        Base colour; multiplied by per-point colours when ``use_point_colors`` and the cloud has
        them.
    diffuse, specular : float
        Lambert and Blinn–Phong weights; ``shininess`` is the lobe exponent.
    mirror : float in [0, 1]
        Reflectivity; ``roughness`` > 0 blurs reflections (glossy).
    checker, checker_size : optional
        Ground only: second colour and cell size of a checkerboard.
    """

    color: tuple = (0.7, 0.7, 0.7)
    use_point_colors: bool = True
    diffuse: float = 1.0
    specular: float = 0.15
    shininess: float = 48.0
    mirror: float = 0.0
    roughness: float = 0.0
    checker: tuple | None = None
    checker_size: float = 0.0

    def __post_init__(self):
        _rgb(self.color, "material.color")
        _in_range(self.mirror, "material.mirror", 0.0, 1.0)
        _in_range(self.roughness, "material.roughness", 0.0, 1.0)
        _in_range(self.diffuse, "material.diffuse", 0.0, 10.0)
        _in_range(self.specular, "material.specular", 0.0, 10.0)
        _in_range(self.shininess, "material.shininess", 0.0, 1e4)
        _in_range(self.checker_size, "material.checker_size", 0.0, 1e30)

    @classmethod
    def matte(cls, color=(0.8, 0.8, 0.8), **kw) -> Material:
        return cls(color=color, specular=0.05, **kw)

    @classmethod
    def glossy(cls, color=(0.8, 0.8, 0.8), **kw) -> Material:
        return cls(color=color, specular=0.4, shininess=96.0, mirror=0.25, roughness=0.08, **kw)

    @classmethod
    def reflective(cls, color=(0.9, 0.9, 0.9), mirror=0.85, **kw) -> Material:
        return cls(color=color, specular=0.0, mirror=mirror, **kw)

    def to_core(self) -> _core.Material:
        m = _core.Material()
        m.base_color = _rgb(self.color, "material.color")
        m.use_point_colors = bool(self.use_point_colors)
        m.diffuse = float(self.diffuse)
        m.specular = float(self.specular)
        m.shininess = float(self.shininess)
        m.mirror = float(self.mirror)
        m.roughness = float(self.roughness)
        if self.checker is not None and self.checker_size > 0:
            m.checker = _rgb(self.checker, "material.checker")
            m.checker_size = float(self.checker_size)
        return m


#: Ground presets by name (the CLI's ``--ground``).
GROUND_MATERIALS = {
    "matte": Material(color=(0.35, 0.35, 0.34), specular=0.02, use_point_colors=False),
    "mirror": Material(color=(0.6, 0.6, 0.62), specular=0.0, mirror=0.6, use_point_colors=False),
    "glossy": Material(color=(0.7, 0.7, 0.7), specular=0.2, mirror=0.3, roughness=0.05,
                       use_point_colors=False),
}


@dataclass(frozen=True)
class DirectionalLight:
    """Light from far away. ``direction`` points toward the light; ``angle_deg`` is its angular
    radius (0: hard shadows; the sun is 0.27)."""

    direction: tuple = (0.4, 1.0, 0.6)
    color: tuple = (1.0, 1.0, 1.0)
    intensity: float = 1.0
    angle_deg: float = 2.0
    shadows: bool = True

    def to_core(self) -> _core.Light:
        light = _core.Light()
        light.cast_shadows = bool(self.shadows)
        light.type = _core.LightType.directional
        light.direction = tuple(_unit(self.direction, "light.direction"))
        light.color = tuple(np.asarray(_rgb(self.color, "light.color")) * float(self.intensity))
        light.angle = np.radians(_in_range(self.angle_deg, "light.angle_deg", 0.0, 45.0))
        return light


@dataclass(frozen=True)
class PointLight:
    """Light from a point (``radius`` > 0: a spherical light, soft shadows); inverse-square."""

    position: tuple = (0.0, 2.0, 0.0)
    color: tuple = (1.0, 1.0, 1.0)
    intensity: float = 1.0
    radius: float = 0.0

    def to_core(self, origin) -> _core.Light:
        light = _core.Light()
        light.type = _core.LightType.point
        light.position = tuple(np.asarray(self.position, dtype=np.float64) - origin)
        light.color = tuple(np.asarray(_rgb(self.color, "light.color")) * float(self.intensity))
        light.radius = _in_range(self.radius, "light.radius", 0.0, 1e30)
        return light


@dataclass(frozen=True)
class AreaLight:
    """A parallelogram light with corner ``corner`` and edges ``edge_u``, ``edge_v``: soft
    shadows. ``intensity`` is the total, as for a point light at the same place."""

    corner: tuple = (-0.5, 2.0, -0.5)
    edge_u: tuple = (1.0, 0.0, 0.0)
    edge_v: tuple = (0.0, 0.0, 1.0)
    color: tuple = (1.0, 1.0, 1.0)
    intensity: float = 1.0

    def to_core(self, origin) -> _core.Light:
        light = _core.Light()
        light.type = _core.LightType.area
        light.position = tuple(np.asarray(self.corner, dtype=np.float64) - origin)
        light.edge_u = tuple(np.asarray(self.edge_u, dtype=np.float64))
        light.edge_v = tuple(np.asarray(self.edge_v, dtype=np.float64))
        if not np.linalg.norm(np.cross(light.edge_u, light.edge_v)) > 0:
            raise InputError("light.edge_u, light.edge_v: must span a parallelogram")
        light.color = tuple(np.asarray(_rgb(self.color, "light.color")) * float(self.intensity))
        return light


@dataclass(frozen=True)
class Look:
    """A named lighting set-up: what makes a mostly one-colour scan readable is light.

    Lights are placed relative to the camera at render time (so every view is lit from the
    front-left), lengths relative to the scene's bounding radius.

    Parameters
    ----------
    name : str
    ambient : float
        Strength of the sky's ambient light.
    occlusion : float
        Length of the sky-visibility (ambient occlusion) rays, in bounding radii; 0: none.
    key, key_angle_deg, key_elevation : float
        Intensity, angular radius (soft shadows) and height (the up component of its direction,
        before normalisation) of the key light over the camera's left shoulder; 0: no key.
    fill : float
        Intensity of a shadowless fill light from the camera's right; 0: none.
    sky : dict or None
        Sky colours (see :class:`Scene`); None: the default blue-grey gradient.
    background : (3,) float or None
        What primary rays that miss show; None: the sky (or the backdrop's colour).
    backdrop : bool
        The ground fades into a plain background beyond BACKDROP_FADE bounding radii (a studio
        cyclorama: no horizon line), the background matching the lit ground.
    ground : str
        The ground this look uses when the scene's ground is "auto".
    auto_exposure : bool
        Expose the frame from the lit objects' mean luminance (see
        :func:`pointviz.images.auto_exposure`); else exposure 1.
    """

    name: str
    ambient: float
    occlusion: float
    key: float
    key_angle_deg: float
    key_elevation: float
    fill: float
    sky: dict | None
    background: tuple | None
    backdrop: bool
    ground: str
    auto_exposure: bool

    def lights(self, camera, up) -> list:
        """The look's lights for a camera (directions relative to the view)."""
        up = np.asarray(up, dtype=np.float64)
        fwd, right = np.asarray(camera.forward), np.asarray(camera.right)
        out = []
        if self.key > 0:
            direction = self.key_elevation * up - 0.4 * fwd - 0.7 * right
            out.append(DirectionalLight(direction=tuple(direction), intensity=self.key,
                                        angle_deg=self.key_angle_deg))
        if self.fill > 0:
            direction = 0.3 * up - 0.6 * fwd + 0.7 * right
            out.append(DirectionalLight(direction=tuple(direction), intensity=self.fill,
                                        angle_deg=0.0, shadows=False))
        return out


#: Named looks (the CLI's ``--look``). Objects default to "studio", terrain tiles to "outdoor".
LOOKS = {
    # a soft key of 12 degrees' angular size, a fill, strong sky light shaped by occlusion,
    # on a plain backdrop
    "studio": Look("studio", ambient=0.3, occlusion=0.2, key=1.4, key_angle_deg=6.0,
                   key_elevation=0.9, fill=0.2, background=None,
                   sky={"zenith": (0.95, 0.96, 1.0), "horizon": (0.9, 0.9, 0.9),
                        "below": (0.3, 0.29, 0.28)},
                   backdrop=True, ground="matte", auto_exposure=True),
    # a low sun and a blue sky: relief reads from shading and cast shadows
    "outdoor": Look("outdoor", ambient=0.8, occlusion=0.04, key=1.3, key_angle_deg=0.5,
                    key_elevation=0.8, fill=0.0, sky=None, background=(0.8, 0.82, 0.85),
                    backdrop=False, ground="none",
                    auto_exposure=True),
    # colours as scanned: even white light, no shadows
    "flat": Look("flat", ambient=1.0, occlusion=0.0, key=0.0, key_angle_deg=0.0,
                 key_elevation=1.0, fill=0.0, background=(0.9, 0.9, 0.9),
                 sky={"zenith": (1.0, 1.0, 1.0), "horizon": (1.0, 1.0, 1.0),
                      "below": (1.0, 1.0, 1.0)},
                 backdrop=False, ground="none", auto_exposure=False),
}
#: Comparisons (surfels against meshes) render every backend with one fixed exposure: an
#: exposure keyed per frame would differ between methods and enter their image errors.
COMPARE_LOOK = replace(LOOKS["studio"], auto_exposure=False)
#: Where a backdrop's ground starts fading into the background (bounding radii from the centre);
#: it reaches the background at twice this.
BACKDROP_FADE = 1.5


def default_lights(camera, up) -> list:
    """The studio look's lights: a soft key over the camera's left shoulder and a fill."""
    return LOOKS["studio"].lights(camera, up)


def resolve_look(look, geometry, up) -> Look:
    """The :class:`Look` named by ``look``; "auto" decides from the geometry's shape."""
    if isinstance(look, Look):
        return look
    if look == "auto":
        from .camera import shape_kind

        cloud = getattr(geometry, "cloud", geometry)
        pts = getattr(cloud, "points", None)
        if hasattr(geometry, "shape_kind") and hasattr(geometry, "tree"):  # a SurfelScene
            kind = geometry.shape_kind(up)  # kept with the scene: every frame asks again
        else:
            kind = shape_kind(pts, up) if pts is not None else "object"
        return LOOKS["outdoor" if kind == "terrain" else "studio"]
    if look not in LOOKS:
        raise InputError(f"look: expected one of auto, {', '.join(LOOKS)}, got {look!r}")
    return LOOKS[look]


@dataclass
class SceneObject:
    """One object of a scene: a surfel scene (or a mesh backend) and its material."""

    geometry: object
    material: Material = field(default_factory=Material)


class Scene:
    """One or more clouds with materials, a ground plane, lights and a sky.

    Parameters
    ----------
    clouds : PointCloud, SurfelScene or a list of them
        What to show; a PointCloud gets a default SurfelScene.
    lights : list of DirectionalLight/PointLight/AreaLight, optional
        Default: a soft key light placed relative to the camera at render time.
    ground : {"auto", "matte", "mirror", "glossy", "none"} or Material or None
        A plane under the clouds ("auto": the look's, matte for studio, none outdoors).
    background : "sky" or (3,) float
        What primary rays that miss show.
    materials : Material or list of Material, optional
        One per cloud.
    up : (3,) float, optional
        Default: the first cloud's ``up`` hint, else +Y.
    ambient : float, optional
        Strength of the sky's ambient light (default: the look's).
    sky : (3,) float or dict, optional
        One colour for the whole sky, or ``{"zenith": rgb, "horizon": rgb, "below": rgb}``;
        default the look's.
    look : {"auto", "studio", "outdoor", "flat"} or Look
        Lights, sky light and occlusion, backdrop and exposure together (see :data:`LOOKS`);
        "auto" picks "outdoor" for a terrain tile and "studio" for an object
        (:func:`pointviz.camera.shape_kind` of the first cloud).
    two_sided : bool
        Show surfels from both sides: the SurfelScenes built here skip the paper's normal-cone
        culling (``cull=False``), which hides open scans (terrain, one-sided scans) seen from
        behind; culling saves 0-10% of a frame (benchmarks/README.md). Set False for closed
        models, or pass ``cull=`` explicitly.
    **scene_options
        Passed to the SurfelScene built for each PointCloud (e.g. ``interpolation``).
    """

    def __init__(self, clouds, lights=None, ground="auto", background="sky", materials=None,
                 up=None, ambient: float | None = None, sky=None, two_sided: bool = True,
                 look="auto", **scene_options):
        from .surfels import SurfelScene

        if not isinstance(clouds, (list, tuple)):
            clouds = [clouds]
        if len(clouds) == 0:
            raise InputError("clouds: a scene needs at least one cloud")
        if materials is None:
            materials = [Material() for _ in clouds]
        elif isinstance(materials, Material):
            materials = [materials for _ in clouds]
        if len(materials) != len(clouds):
            raise InputError(f"materials: {len(materials)} given for {len(clouds)} clouds")
        if up is None:
            first = clouds[0].cloud if isinstance(clouds[0], SurfelScene) else clouds[0]
            up = getattr(first, "up", None)
        self.up = _unit(_Y_UP if up is None else up, "up")
        if two_sided:
            scene_options.setdefault("cull", False)
        self._scene_options = scene_options
        self.objects: list[SceneObject] = []
        for c, m in zip(clouds, materials):
            if not isinstance(m, Material):
                raise InputError(f"materials: expected Material, got {type(m).__name__}")
            if not (isinstance(c, Geometry) or hasattr(c, "points")):
                raise InputError(f"clouds: cannot render a {type(c).__name__}")
            self.objects.append(SceneObject(c, m))
        self.lights = None if lights is None else list(lights)
        self.look = resolve_look(look, self.objects[0].geometry, self.up)
        if isinstance(ground, str):
            if ground == "auto":
                ground = self.look.ground
            if ground == "none":
                ground = None
            elif ground in GROUND_MATERIALS:
                ground = GROUND_MATERIALS[ground]
            else:
                raise InputError(
                    f"ground: expected one of auto, none, {', '.join(GROUND_MATERIALS)}, got {ground!r}")
        if ground is not None and not isinstance(ground, Material):
            raise InputError(f"ground: expected a name or a Material, got {type(ground).__name__}")
        self.ground = ground
        if isinstance(background, str):
            if background != "sky":
                raise InputError(f"background: expected 'sky' or an RGB triple, got {background!r}")
            self.background = None
        else:
            self.background = _rgb(background, "background")
        self.ambient = _in_range(self.look.ambient if ambient is None else ambient, "ambient",
                                 0.0, 10.0)
        if sky is None:
            self.sky = dict(self.look.sky or {})
        elif isinstance(sky, dict):
            unknown = set(sky) - {"zenith", "horizon", "below"}
            if unknown:
                raise InputError(f"sky: unknown keys {sorted(unknown)}")
            self.sky = {k: _rgb(v, f"sky.{k}") for k, v in sky.items()}
        else:
            c = _rgb(sky, "sky")
            self.sky = {"zenith": c, "horizon": c, "below": c}

    # -- geometry -----------------------------------------------------------------------------
    def geometry(self, i: int) -> Geometry:
        """The :class:`~pointviz.geometry.Geometry` of object i: a cloud becomes a SurfelScene
        on first use (its tree is built once)."""
        from .surfels import SurfelScene

        obj = self.objects[i]
        if not isinstance(obj.geometry, Geometry):
            obj.geometry = SurfelScene(obj.geometry, **self._scene_options)
        return obj.geometry

    def surfel_scene(self, i: int):
        """The SurfelScene of object i, built on first use (a mesh object is returned as is)."""
        return self.geometry(i)

    def _extent(self, obj) -> tuple[np.ndarray, np.ndarray, float]:
        """Bounds (with disk radii) and ground level of one object, computed once per geometry:
        every frame of a path or viewer session would otherwise scan all points again. A
        SurfelScene keeps its own (so a new Scene around it, as ``render(surfel_scene)`` makes
        for every frame, costs nothing that grows with the cloud); a bare cloud's is kept here."""
        g = obj.geometry
        cloud = getattr(g, "cloud", g)
        cache = self.__dict__.setdefault("_extents", {})
        hit = cache.get(id(cloud))
        if hit is not None and hit[0] is cloud:  # also when the cloud has become a SurfelScene
            return hit[1]
        if isinstance(g, Geometry):  # a SurfelScene keeps its own, a mesh's is cheap
            return g.extent(self.up)
        ext = _extent_mod.cloud_extent(cloud.points, getattr(cloud, "radii", None), self.up)
        cache[id(cloud)] = (cloud, ext)
        return ext

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds of every object (including disk radii)."""
        ext = [self._extent(obj) for obj in self.objects]
        return np.min([e[0] for e in ext], axis=0), np.max([e[1] for e in ext], axis=0)

    @property
    def points(self) -> np.ndarray:
        """Corners of the scene's bounds, so that ``Camera.fit(scene)`` frames the scene."""
        lo, hi = self.bounds()
        return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                         for z in (lo[2], hi[2])])

    def ground_point(self) -> np.ndarray:
        """A point of the ground plane: just under the objects along ``up``.

        The lowest GROUND_OUTLIER_FRACTION of a large cloud's points are ignored, so that a few
        stray points of a raw scan do not float the object high above its floor.
        """
        lo, hi = self.bounds()
        center = 0.5 * (lo + hi)
        level = min(self._extent(obj)[2] for obj in self.objects)
        return center + (level - center @ self.up) * self.up

    def to_core(self, camera, lod_pixels: float | str, max_error: float | None = None):
        """The C++ render scene and its local origin (float64): everything is re-centred on it
        so that georeferenced scans keep float32 precision."""
        lo, hi = self.bounds()
        origin = 0.5 * (lo + hi)
        rs = _core.RenderScene()
        rs.scale = float(max(np.linalg.norm(hi - lo) * 0.5, 1e-12))
        for i, obj in enumerate(self.objects):
            self.geometry(i).add_to(rs, origin, obj.material.to_core(), lod_pixels, max_error)
        if self.ground is not None:
            rs.set_ground(tuple(self.ground_point() - origin), tuple(self.up), self.ground.to_core())
        lights = self.lights if self.lights is not None else self.look.lights(camera, self.up)
        for light in lights:
            if isinstance(light, DirectionalLight):
                rs.add_light(light.to_core())
            elif isinstance(light, (PointLight, AreaLight)):
                rs.add_light(light.to_core(origin))
            else:
                raise InputError(f"lights: unknown light type {type(light).__name__}")
        sky = _core.Sky()
        for key, value in self.sky.items():
            setattr(sky, key, value)
        sky.up = tuple(self.up)
        sky.ambient = self.ambient
        sky.occlusion_distance = float(self.look.occlusion * rs.scale)
        background = self.background if self.background is not None else self.look.background
        if background is not None:
            sky.background_is_sky = False
            sky.background = background
        if self.look.backdrop and self.ground is not None:
            sky.ground_fade = float(BACKDROP_FADE * rs.scale)
            if background is None:
                sky.background_is_sky = False
                sky.background = self._lit_ground(sky, lights)
        rs.sky = sky
        return rs, origin

    def _lit_ground(self, sky, lights) -> tuple:
        """Radiance of the unshadowed ground under the sky and the directional lights: the
        backdrop's background, so that the faded ground meets it without a seam."""
        top = 0.5 * (np.asarray(sky.zenith) + np.asarray(sky.horizon)) * self.ambient
        e = top.copy()
        for light in lights:
            if isinstance(light, DirectionalLight):
                cos = float(_unit(light.direction, "light.direction") @ self.up)
                e += np.asarray(light.color) * light.intensity * max(cos, 0.0)
        return tuple(float(v) for v in np.asarray(self.ground.color) * e * self.ground.diffuse)

    def with_look(self, look) -> Scene:
        """A shallow copy with another look (objects and their trees are shared): its lights
        (unless the scene has its own), sky light, occlusion, backdrop and exposure. The ground
        stays the scene's."""
        s = Scene.__new__(Scene)
        s.__dict__.update(self.__dict__)
        s.look = resolve_look(look, self.objects[0].geometry, self.up)
        s.ambient = s.look.ambient
        s.sky = dict(s.look.sky or {})
        return s

    def with_ground(self, ground) -> Scene:
        """A shallow copy with another ground (objects and their trees are shared)."""
        s = Scene.__new__(Scene)
        s.__dict__.update(self.__dict__)
        s.objects = [replace(o) for o in self.objects]
        tmp = Scene([o.geometry for o in self.objects[:1]], ground=ground, up=self.up, look=self.look)
        s.ground = tmp.ground
        return s

    def __repr__(self) -> str:
        return (f"Scene({len(self.objects)} objects, ground={'none' if self.ground is None else 'yes'}, "
                f"lights={'default' if self.lights is None else len(self.lights)})")
