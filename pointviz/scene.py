"""What a frame shows: surfel clouds (or meshes) with materials, a ground plane, lights and a sky.

The scene model is deliberately small: one material per object, three kinds of light and an
optional infinite ground plane. ``Scene.to_core`` turns it into the C++ render scene; the same
scene with a mesh backend in place of the surfels renders with identical shading.
"""

from __future__ import annotations

import pickle
import threading
from collections.abc import Mapping
from dataclasses import FrozenInstanceError, dataclass, field
from types import MappingProxyType

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
from .lights import AreaLight, DirectionalLight, PointLight
from .looks import (  # noqa: F401 - public here too
    BACKDROP_FADE,
    COMPARE_LOOK,
    LOOKS,
    Look,
    default_lights,
    resolve_look,
)
from .materials import GROUND_MATERIALS, Material
from .values import in_range as _in_range
from .values import rgb as _rgb
from .values import unit as _unit

_Y_UP = (0.0, 1.0, 0.0)


@dataclass(frozen=True)
class SceneObject:
    """One object of a scene: a point cloud, surfel scene or mesh backend, and its material."""

    geometry: object
    material: Material = field(default_factory=Material)


#: What :meth:`Scene.replace` may change: the constructor's arguments except ``up`` and the
#: surfel options (new trees make a new scene: construct one; a new up: :meth:`Scene.with_up`).
REPLACEABLE = ("clouds", "materials", "lights", "ground", "background", "ambient", "sky", "look")
#: What the constructor may resolve from the scene's up when left to it: the "auto" look, and
#: the ground, ambient light and sky that come with the look. :meth:`Scene.with_up` resolves
#: again those a scene left to it.
UP_RESOLVED = ("look", "ground", "ambient", "sky")


class _Built:
    """What a scene builds on first use, in this process: the SurfelScene of each cloud object
    and each bare cloud's extent per up direction. Shared by the copies :meth:`Scene.replace`
    and :meth:`Scene.with_up` make with the same objects (their trees are built once, whichever
    copy asks first: a tree does not depend on the up); never pickled."""

    def __init__(self, n: int) -> None:
        self.lock = threading.Lock()
        self.geometries: list = [None] * n
        self.extents: dict = {}  # (object index, up tuple) -> (lo, hi, level)


def _portable(options) -> dict:
    """SurfelScene keyword arguments that rebuild the same tree in another process: the
    origin as plain floats, and no thread count (each process uses its own cores; results
    never depend on it)."""
    out = dict(options)
    out["threads"] = None
    if out.get("origin") is not None:
        out["origin"] = tuple(float(v) for v in np.asarray(out["origin"]).reshape(3))
    return out


def _hash_array(h, arr) -> None:
    if arr is None:
        h.update(b"none")
        return
    a = np.ascontiguousarray(arr)
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())


def _callback_digest(geometry) -> str:
    """A content digest of a geometry that is not a cloud: its pickle when it has one (meshes
    do), else its identity (then a resumed path render cannot tell it is the same geometry)."""
    import hashlib  # (here: it loads OpenSSL, which a render without keys does not need)

    try:
        return "callback:" + hashlib.sha256(pickle.dumps(geometry)).hexdigest()
    except Exception:  # noqa: BLE001 - unpicklable objects fall back to identity
        return f"callback-id:{type(geometry).__qualname__}:{id(geometry)}"


class Scene:
    """One or more clouds with materials, a ground plane, lights and a sky: a frozen value.

    Attributes cannot be set after construction; :meth:`replace` makes a validated copy that
    shares the objects' trees. A scene pickles without its C++ trees: the clouds' arrays
    (normals and radii estimated first) and the surfel options travel, and the trees are
    rebuilt on first use in the receiving process, once per scene object there (an unpickled
    scene's ``objects`` hold the clouds; :meth:`geometry` gives their rebuilt SurfelScenes).

    Parameters
    ----------
    clouds : PointCloud, SurfelScene or a list of them
        What to show; a PointCloud gets a default SurfelScene (built on first use).
    lights : list of DirectionalLight/PointLight/AreaLight, optional
        Default: a soft key light placed relative to the camera at render time. Kept as a
        tuple.
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
        (:func:`pointviz.framing.shape_kind` of the first cloud).
    two_sided : bool or "auto"
        Whether surfels show from both sides. ``"auto"`` (default): the SurfelScenes built here
        cull back faces where the surfels close a surface seen from outside and show both
        sides otherwise (``cull="auto"``, :mod:`pointviz.sides`): a closed scan's far-side disks
        that reach past its rims then leave no dark flecks, and open scans (terrain, one range
        scan, a depth-camera frame) stay visible from behind. True: never cull (``cull=False``);
        False: the SurfelScene's own default (culling). Culling saves 0-10% of a frame
        (benchmarks/README.md). ``cull=`` passed explicitly wins.
    **scene_options
        Passed to the SurfelScene built for each PointCloud (e.g. ``interpolation``).

    Attributes
    ----------
    objects : tuple of SceneObject
    lights : tuple or None
    ground : Material or None
    background : (3,) float or None
        None: the sky (or the look's background).
    up : (3,) float64, read-only
    ambient : float
    sky : mapping of str to (3,) float, read-only
    look : Look
    """

    def __init__(self, clouds, lights=None, ground="auto", background="sky", materials=None,
                 up=None, ambient: float | None = None, sky=None, two_sided: bool | str = "auto",
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
        auto = frozenset(name for name, value in (("look", look), ("ground", ground),
                                                  ("ambient", ambient), ("sky", sky))
                         if value is None or (isinstance(value, str) and value == "auto"))
        if up is None:
            first = clouds[0].cloud if isinstance(clouds[0], SurfelScene) else clouds[0]
            up = getattr(first, "up", None)
        up = _unit(_Y_UP if up is None else up, "up")
        up.setflags(write=False)
        if isinstance(two_sided, str) and two_sided != "auto":
            raise InputError(f"two_sided: expected True, False or 'auto', got {two_sided!r}")
        if two_sided == "auto":
            scene_options.setdefault("cull", "auto")
        elif two_sided:
            scene_options.setdefault("cull", False)
        objects = []
        for c, m in zip(clouds, materials):
            if not isinstance(m, Material):
                raise InputError(f"materials: expected Material, got {type(m).__name__}")
            if not (isinstance(c, Geometry) or hasattr(c, "points")):
                raise InputError(f"clouds: cannot render a {type(c).__name__}")
            objects.append(SceneObject(c, m))
        look = resolve_look(look, objects[0].geometry, up)
        if isinstance(ground, str):
            if ground == "auto":
                ground = look.ground
            if ground == "none":
                ground = None
            elif ground in GROUND_MATERIALS:
                ground = GROUND_MATERIALS[ground]
            else:
                raise InputError(
                    f"ground: expected one of auto, none, {', '.join(GROUND_MATERIALS)}, got {ground!r}")
        if ground is not None and not isinstance(ground, Material):
            raise InputError(f"ground: expected a name or a Material, got {type(ground).__name__}")
        if isinstance(background, str):
            if background != "sky":
                raise InputError(f"background: expected 'sky' or an RGB triple, got {background!r}")
            background = None
        else:
            background = _rgb(background, "background")
        ambient = _in_range(look.ambient if ambient is None else ambient, "ambient", 0.0, 10.0)
        if sky is None:
            sky = dict(look.sky or {})
        elif isinstance(sky, Mapping):
            unknown = set(sky) - {"zenith", "horizon", "below"}
            if unknown:
                raise InputError(f"sky: unknown keys {sorted(unknown)}")
            sky = {k: _rgb(v, f"sky.{k}") for k, v in sky.items()}
        else:
            c = _rgb(sky, "sky")
            sky = {"zenith": c, "horizon": c, "below": c}
        options = MappingProxyType(dict(scene_options))
        self._init(objects=tuple(objects), lights=None if lights is None else tuple(lights),
                   look=look, ground=ground, background=background, up=up, ambient=ambient,
                   sky=MappingProxyType(sky), _scene_options=options,
                   _build_options=(options,) * len(objects), _built=_Built(len(objects)),
                   _memo={}, _auto=auto)

    def _init(self, **values) -> None:
        for name, value in values.items():
            object.__setattr__(self, name, value)

    def __setattr__(self, name: str, value) -> None:
        hint = f"; use scene.replace({name}=...)" if name in REPLACEABLE else ""
        raise FrozenInstanceError(f"cannot assign to field {name!r}: a Scene is frozen{hint}")

    def __delattr__(self, name: str) -> None:
        raise FrozenInstanceError(f"cannot delete field {name!r}: a Scene is frozen")

    # -- copies and pickling ------------------------------------------------------------------
    def replace(self, **changes) -> Scene:
        """A copy with some of :data:`REPLACEABLE` changed, validated like a new scene.

        Unchanged objects keep their trees: the copy shares what this scene has built, and
        what either builds later. A new ``look`` brings its own ambient and sky unless those
        are given too; the ground, lights and background stay the scene's unless given.

        Raises
        ------
        TypeError
            For a name that :meth:`replace` cannot change.
        InputError
            For a value the constructor refuses.
        """
        unknown = set(changes) - set(REPLACEABLE)
        if unknown:
            hint = "; a new up: Scene.with_up()" if "up" in unknown else ""
            raise TypeError(f"Scene.replace() got unexpected field(s) {sorted(unknown)} "
                            f"(it changes {', '.join(REPLACEABLE)}{hint})")
        return self._copy(self.up, changes)

    def with_up(self, up) -> Scene:
        """A copy seen with another up direction; the objects and their trees are shared (a
        tree does not depend on the up), the ground level and bounds along the new up are
        computed on first use, and what the constructor resolved from the old up because it
        was left to it (an "auto" look, and the ground, ambient light and sky that came with
        the look: :data:`UP_RESOLVED`) is resolved again, as ``Scene(..., up=up)`` would.
        Lights given in world coordinates stay where they are.

        Raises
        ------
        InputError
            For an up that is not a non-zero, finite 3-vector.
        """
        up = _unit(up, "up")
        if np.array_equal(up, self.up):
            return self
        auto = {"look": "auto", "ground": "auto", "ambient": None, "sky": None}
        return self._copy(up, {name: auto[name] for name in self._auto}, resolve=True)

    def _copy(self, up, changes: dict, resolve: bool = False) -> Scene:
        """:meth:`replace`'s and :meth:`with_up`'s copy: ``changes`` applied, ``up`` set."""
        new_look = "look" in changes and not resolve
        same_objects = "clouds" not in changes
        kw = {"clouds": [o.geometry for o in self.objects],
              "materials": [o.material for o in self.objects],
              "lights": self.lights, "ground": "none" if self.ground is None else self.ground,
              "background": "sky" if self.background is None else self.background,
              "ambient": None if new_look else self.ambient,
              "sky": None if new_look else (dict(self.sky) or None), "look": self.look,
              **changes}
        # two_sided=False: the options already hold the resolved ``cull``
        s = Scene(up=up, two_sided=False, **kw, **self._scene_options)
        # what was left to the constructor stays so unless given now (a new look's ambient and
        # sky are left to it again: the constructor saw None)
        s._init(_auto=s._auto | (self._auto - set(changes)))
        if same_objects:
            s._init(_build_options=self._build_options, _built=self._built)
        else:  # a cloud kept from this scene keeps its surfel options (an unpickled one's too)
            mine = {id(o.geometry): opts for o, opts in zip(self.objects, self._build_options)}
            s._init(_build_options=tuple(mine.get(id(o.geometry), opts)
                                         for o, opts in zip(s.objects, s._build_options)))
        return s

    def with_look(self, look) -> Scene:
        """A copy with another look (objects and their trees are shared): its lights (unless
        the scene has its own), sky light, occlusion, backdrop and exposure. The ground stays
        the scene's."""
        return self.replace(look=look)

    def with_ground(self, ground) -> Scene:
        """A copy with another ground (objects and their trees are shared)."""
        return self.replace(ground=ground)

    def _sources(self) -> list[tuple[object, dict | None]]:
        """Per object, what rebuilds it in another process: (cloud, SurfelScene options) for
        surfels, (geometry, None) for any other geometry. Normals and radii are estimated
        here, once, so that every process renders the same surfels."""
        from .surfels import SurfelScene

        out = []
        for obj, options in zip(self.objects, self._build_options):
            g = obj.geometry
            if isinstance(g, SurfelScene):
                if g.cloud is None:
                    raise InputError("scene: a SurfelScene(keep_cloud=False) cannot be pickled "
                                     "or hashed: its cloud is gone")
                out.append((g.cloud, _portable(g.settings)))
            elif isinstance(g, Geometry):
                out.append((g, None))
            else:
                _ = g.normals, g.radii
                out.append((g, _portable(options)))
        return out

    def __getstate__(self) -> dict:
        """The scene without its trees: clouds (normals and radii estimated), the options that
        rebuild their trees, materials, lights, ground, sky and look."""
        return {"objects": tuple((src, obj.material, options)
                                 for obj, (src, options) in zip(self.objects, self._sources())),
                "lights": self.lights, "look": self.look, "ground": self.ground,
                "background": self.background, "up": tuple(float(v) for v in self.up),
                "ambient": self.ambient, "sky": dict(self.sky),
                "scene_options": dict(self._scene_options), "key": self._memo.get("key"),
                "auto": sorted(self._auto)}

    def __setstate__(self, state: dict) -> None:
        up = np.array(state["up"], dtype=np.float64)
        up.setflags(write=False)
        objects = state["objects"]
        self._init(objects=tuple(SceneObject(src, m) for src, m, _ in objects),
                   lights=state["lights"], look=state["look"], ground=state["ground"],
                   background=state["background"], up=up, ambient=state["ambient"],
                   sky=MappingProxyType(dict(state["sky"])),
                   _scene_options=MappingProxyType(dict(state["scene_options"])),
                   _build_options=tuple(MappingProxyType({} if o is None else o)
                                        for _, _, o in objects),
                   _built=_Built(len(objects)),
                   _memo={} if state.get("key") is None else {"key": state["key"]},
                   _auto=frozenset(state.get("auto", ())))

    @property
    def key(self) -> str:
        """SHA-256 (hex) of everything that affects the image: the clouds' arrays and surfel
        options, other geometries' pickles, materials, lights, ground, background, up, sky and
        look. Equal scenes (in any process, e.g. a pickled copy) have equal keys; computed
        once per scene (estimating missing normals and radii)."""
        key = self._memo.get("key")
        if key is None:
            import hashlib  # (here: it loads OpenSSL, which a render without keys does not need)

            h = hashlib.sha256()
            for obj, (src, options) in zip(self.objects, self._sources()):
                if options is None:
                    h.update(_callback_digest(src).encode())
                else:
                    for name in ("points", "normals", "radii", "colors"):
                        _hash_array(h, getattr(src, name, None))
                    h.update(repr(sorted(options.items())).encode())
                h.update(repr(obj.material).encode())
            rest = (None if self.lights is None else list(self.lights), self.ground,
                    self.background, tuple(float(v) for v in self.up), self.ambient,
                    sorted(self.sky.items()), self.look)
            h.update(repr(rest).encode())
            key = self._memo.setdefault("key", h.hexdigest())
        return key

    # -- geometry -----------------------------------------------------------------------------
    def _geometry(self, i: int) -> tuple[Geometry, bool]:
        """Object i's geometry and whether this call built it."""
        g = self.objects[i].geometry
        if isinstance(g, Geometry):
            return g, False
        built = self._built
        if built.geometries[i] is not None:
            return built.geometries[i], False
        with built.lock:  # one build per object, whichever thread asks first
            if built.geometries[i] is not None:
                return built.geometries[i], False
            from .surfels import SurfelScene

            built.geometries[i] = SurfelScene(g, **self._build_options[i])
            return built.geometries[i], True

    def geometry(self, i: int) -> Geometry:
        """The :class:`~pointviz.geometry.Geometry` of object i: a cloud becomes a SurfelScene
        on first use (its tree is built once per process, and shared with this scene's
        :meth:`replace` copies)."""
        return self._geometry(i)[0]

    def surfel_scene(self, i: int):
        """The SurfelScene of object i, built on first use (a mesh object is returned as is)."""
        return self.geometry(i)

    def build(self) -> int:
        """Build every object's tree now (thread-safe); the number this call built."""
        return sum(self._geometry(i)[1] for i in range(len(self.objects)))

    def _extent(self, i: int) -> tuple[np.ndarray, np.ndarray, float]:
        """Bounds (with disk radii) and ground level of object i, computed once: every frame of
        a path or viewer session would otherwise scan all points again. A geometry keeps its
        own (so a new Scene around a SurfelScene, as ``render(surfel_scene)`` makes for every
        frame, costs nothing that grows with the cloud); a bare cloud's is kept with the
        scene's built trees."""
        g = self.objects[i].geometry
        if isinstance(g, Geometry):
            return g.extent(self.up)
        built = self._built
        key = (i, tuple(float(v) for v in self.up))
        extent = built.extents.get(key)
        if extent is None:  # also once the cloud's SurfelScene exists
            extent = built.extents.setdefault(
                key, _extent_mod.cloud_extent(g.points, getattr(g, "radii", None), self.up))
        return extent

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds of every object (including disk radii)."""
        ext = [self._extent(i) for i in range(len(self.objects))]
        return np.min([e[0] for e in ext], axis=0), np.max([e[1] for e in ext], axis=0)

    @property
    def points(self) -> np.ndarray:
        """Corners of the scene's bounds, so that ``Camera.fit(scene)`` frames the scene."""
        lo, hi = self.bounds()
        return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                         for z in (lo[2], hi[2])])

    @property
    def viewpoints(self):
        """The one viewpoint (3,) a single-object scene's cloud was taken from (a depth
        camera's frame), else None: ``Camera.fit(scene)`` then looks from there."""
        if len(self.objects) != 1:
            return None
        vp = getattr(self.objects[0].geometry, "viewpoints", None)
        return vp if vp is not None and np.shape(vp) == (3,) else None

    def ground_point(self) -> np.ndarray:
        """A point of the ground plane: just under the objects along ``up``.

        The lowest GROUND_OUTLIER_FRACTION of a large cloud's points are ignored, so that a few
        stray points of a raw scan do not float the object high above its floor.
        """
        lo, hi = self.bounds()
        center = 0.5 * (lo + hi)
        level = min(self._extent(i)[2] for i in range(len(self.objects)))
        return center + (level - center @ self.up) * self.up

    def to_core(self, camera, lod_pixels: float | str, max_error: float | None = None,
                sides: str | None = None):
        """The C++ render scene and its local origin (float64): everything is re-centred on it
        so that georeferenced scans keep float32 precision. ``sides``: which sides of the
        surfels show (:meth:`pointviz.SurfelScene.culls`; None: each tree's own)."""
        lo, hi = self.bounds()
        origin = 0.5 * (lo + hi)
        rs = _core.RenderScene()
        rs.scale = float(max(np.linalg.norm(hi - lo) * 0.5, 1e-12))
        for i, obj in enumerate(self.objects):
            self.geometry(i).add_to(rs, origin, obj.material.to_core(), lod_pixels, max_error,
                                    sides)
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

    def __repr__(self) -> str:
        return (f"Scene({len(self.objects)} objects, ground={'none' if self.ground is None else 'yes'}, "
                f"lights={'default' if self.lights is None else len(self.lights)})")
