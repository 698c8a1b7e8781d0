"""The surfel scene: a point cloud's hierarchy and the ray queries on it (``cast_rays``, ``occluded``).

The traversal variants reproduce the comparison of Zakaria et al. (GRAPP 2006, section 3):

========== ===== ====== ======================================
variant    LoD   culling bounds
========== ===== ====== ======================================
kdtree     no    no      none: split planes only (the paper's KD-tree, kdtree.h)
bvh        no    no      boxes at every level of the hierarchy
lod        yes   no      spheres at every level
lod+cull   yes   yes     spheres at every level
full       yes   yes     boxes near the top, spheres below
========== ===== ====== ======================================

Each knob can also be set on its own (``lod=``, ``cull=``, ``box_depth=``).
"""

from __future__ import annotations

import numpy as np

from . import _core
from . import extent as _extent_mod
from .arrays import bounds
from .errors import InputError
from .settings import INTERPOLATIONS, check_int, check_lod

#: The paper's traversal variants, as knob settings.
VARIANTS = {
    "kdtree": {"lod": False, "cull": False, "box_depth": 0, "tree": "kdtree"},
    "bvh": {"lod": False, "cull": False, "box_depth": "all"},
    "lod": {"lod": True, "cull": False, "box_depth": 0},
    "lod+cull": {"lod": True, "cull": True, "box_depth": 0},
    "full": {"lod": True, "cull": True, "box_depth": "auto"},
}


#: Default interpolation: the most accurate in tests/test_surfels.py and benchmarks/bench_interp.py.
DEFAULT_INTERPOLATION = "smooth"

#: Most surfels per leaf: 8 surfels (256 bytes, four cache lines) per leaf keeps the tree at about
#: a third of a node per surfel (about 11 bytes per surfel) while a leaf is still cheap to test.
DEFAULT_LEAF_SIZE = 8
#: Mean FLIP the paper's size rule at 1 px costs at most in the measured frames (0.0026: an
#: 8M-surfel analytic scene at the framing distance; under 0.0012 on the 1M calibration
#: frames). The automatic level of detail adds the size rule at min(1, max_error / this) px.
SIZE_RULE_ERROR = 0.003

#: With box_depth="auto", boxes are kept for the top levels while their total stays within this
#: many bytes per surfel: boxes are tighter than spheres but cost 24 bytes per node, and the top
#: of the tree, which every ray visits, is where tightness pays (the paper's section 2.2.2).
AUTO_BOX_BYTES_PER_SURFEL = 1.5

_ALL_LEVELS = 255

#: Instruction sets of the traversal kernels ("auto": the best this CPU runs, :func:`best_isa`).
ISAS = ("auto", "base", "sse42", "avx2", "avx512")
#: Traversals of the surfel tree (``SurfelScene(traversal=...)``): the wide one by default.
TRAVERSALS = ("wide", "binary")


def available_isas() -> tuple[str, ...]:
    """The instruction sets whose kernels this build has and this CPU runs ("base" always).

    Every one gives the same hits, bit for bit; they differ only in speed.

    Returns
    -------
    tuple of str
        Names from :data:`ISAS`, "base" first.
    """
    return tuple(name for name in ISAS[1:] if _core.isa_available(getattr(_core.Isa, name)))


def best_isa() -> str:
    """The instruction set that ``isa="auto"`` runs on this CPU (a name from :data:`ISAS`)."""
    return _core.best_isa().name

#: Most surfels in one tree (27 bits of index in the 32-byte node).
MAX_SURFELS = 2**27 - 1


def _auto_box_depth(n_surfels: int, leaf_size: int) -> int:
    budget_nodes = AUTO_BOX_BYTES_PER_SURFEL * n_surfels / 24.0
    depth, nodes = 0, 1.0
    while nodes <= budget_nodes and depth < 40:
        depth += 1
        nodes = 2.0**depth
    return depth


def as_rays(rays, name: str = "rays") -> np.ndarray:
    """Check the shape and type of rays; return a C-contiguous (n, 6) float32 or float64 array.

    Values (NaN/inf, zero directions) are checked by the core while it traces, which names the
    first bad row; an array that is already contiguous float32/float64 is not copied.

    Parameters
    ----------
    rays : (n, 6) array_like of float
        Origin xyz and direction xyz per row; directions need not be unit length.
    """
    try:
        arr = np.asarray(rays)
    except Exception as exc:  # noqa: BLE001 - anything numpy cannot read
        raise InputError(f"{name}: cannot be read as an array ({exc})") from None
    if arr.dtype.kind not in "fiu":
        raise InputError(f"{name}: expected a float array, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 6:
        raise InputError(f"{name}: expected shape (n, 6) (origin, direction), got {arr.shape}")
    dtype = arr.dtype if arr.dtype in (np.float32, np.float64) else np.float64
    return np.ascontiguousarray(arr, dtype=dtype)


def _core_call(fn, *args, **kw):
    """Call the core, turning its value errors (bad rows) into InputError."""
    try:
        return fn(*args, **kw)
    except ValueError as exc:
        raise InputError(str(exc)) from None


#: The traversal options a SurfelScene hands to each query (SurfelScene.trace_options).
_OPTION_FIELDS = ("lod", "cull", "box_depth", "lod_pixels", "interpolation", "window",
                  "lod_criterion", "lod_max_extent", "slabs", "max_error", "isa", "wide", "packets",
                  "shadow_flip_weight", "sky_flip_weight", "colour_pixel_response")


class SurfelScene:
    """A point cloud's surfel hierarchy, ready for ray queries.

    Parameters
    ----------
    cloud : PointCloud
        Anything with ``points`` (n, 3), ``normals`` (n, 3), ``radii`` (n,) and ``colors``
        ((n, 3) or None).
    variant : {"full", "lod+cull", "lod", "bvh", "kdtree"}
        The paper's traversal variant; the knobs below override it one by one. ``"kdtree"`` is
        a separate structure (split planes only; ``lod``, ``box_depth``, ``slabs`` and
        ``leaf_size`` do not apply to it).
    interpolation : {"smooth", "paper", "none"}
        How the disks around a hit are blended (see ``pointviz._core.Interpolation``).
    lod, cull : bool, optional
        Level of detail (needs a pixel footprint at query time) and normal-cone culling.
        ``cull="auto"``: culling when the surfels close a surface seen from outside, and
        two-sided otherwise (:mod:`pointviz.sides`: rays cast at the tree from all
        around it meet at most 15 % back faces; :attr:`back_face_share` keeps the share).
    box_depth : int or "auto" or "all", optional
        Tree levels above this use boxes, the rest spheres.
    lod_pixels : float
        LoD threshold: stop descending when a node's sphere projects below this many pixels.
    window : float
        Depth window of the interpolation, in radii of the nearest disk.
    leaf_size : int
        Most surfels per leaf (1..31).
    slabs : bool
        Cut each node's sphere by the slab around its mean plane (beyond the paper; much
        tighter for the nearly flat patches low in the tree). ``False`` reproduces the paper's
        plain spheres.
    lod_criterion : {"size", "deviation"}
        When LoD stops descending: the paper's projected sphere size, or the projected deviation
        of the node from its mean plane (flat regions stop earlier).
    traversal : {"wide", "binary"}
        ``"wide"`` (default) tests two tree levels' bounds at once with SIMD (the wide nodes
        collapsed from the binary tree, 12-17 bytes per surfel more); ``"binary"`` visits the
        binary tree one node at a time and builds no wide nodes.
        Both take the same decisions (level of detail, culling, boxes): hits agree, and any-hit
        results are identical. The wide traversal applies when the options' ``box_depth`` is the
        tree's (otherwise the binary one runs).
    isa : {"auto", "base", "sse42", "avx2", "avx512"}
        Instruction set of the traversal kernels; "auto" (default) runs the best this CPU has
        (:func:`best_isa`). Results never depend on it.
    threads : int, optional
        Worker threads for the build and queries; default all cores. Results never depend on it.
    keep_cloud : bool
        Keep a reference to ``cloud`` (default). ``False`` drops it once the tree is built (the
        tree holds its own 32-byte copy of each surfel), so that the caller's arrays can be
        freed: the largest clouds then need no second copy. Such a scene cannot be pickled, and
        :meth:`extent` reads the tree's surfels instead.
    consume_cloud : bool
        Take the cloud's arrays (:meth:`PointCloud.hand_over`, implies ``keep_cloud=False``) and
        free each as soon as the build has copied it: positions after the first stage, normals,
        radii and colours after the second (if nothing else holds them). The build's peak then
        stays near the tree's own size instead of the cloud's plus the tree's: a whole process
        at 100M surfels peaks at ~72 bytes per surfel, ~100 with the cloud kept. The cloud can
        no longer be used afterwards (:attr:`PointCloud.handed_over`), even if the build fails;
        the tree is the same as with the cloud kept, bit for bit.
    origin : (3,) float, optional
        Local frame origin; default the cloud's bounding-box centre (keeps float32 precise for
        georeferenced clouds).
    """

    def __init__(self, cloud, *, variant: str = "full", interpolation: str | None = None,
                 lod: bool | None = None, cull: bool | str | None = None, box_depth=None,
                 lod_pixels: float = 1.0, window: float = 1.0, leaf_size: int = DEFAULT_LEAF_SIZE,
                 lod_criterion: str = "size", slabs: bool = True, traversal: str = "wide",
                 isa: str = "auto",
                 threads: int | None = None, origin=None, keep_cloud: bool = True,
                 consume_cloud: bool = False):
        if variant not in VARIANTS:
            raise InputError(f"variant: expected one of {sorted(VARIANTS)}, got {variant!r}")
        interpolation = DEFAULT_INTERPOLATION if interpolation is None else interpolation
        if interpolation not in INTERPOLATIONS:
            raise InputError(
                f"interpolation: expected one of {INTERPOLATIONS}, got {interpolation!r}")
        if not (np.isfinite(lod_pixels) and lod_pixels > 0):
            raise InputError(f"lod_pixels: must be a positive number, got {lod_pixels!r}")
        if not (np.isfinite(window) and window >= 0):
            raise InputError(f"window: must be a non-negative number, got {window!r}")
        if lod_criterion not in ("size", "deviation"):
            raise InputError(f"lod_criterion: expected 'size' or 'deviation', got {lod_criterion!r}")
        if not (isinstance(leaf_size, (int, np.integer)) and 1 <= leaf_size <= 31):
            raise InputError(f"leaf_size: must be an integer in 1..31, got {leaf_size!r}")
        if consume_cloud:
            keep_cloud = False
            if not callable(getattr(cloud, "hand_over", None)):
                raise InputError("consume_cloud=True: needs a PointCloud (something with "
                                 f"hand_over()), got {type(cloud).__name__}")
            if getattr(cloud, "handed_over", False):
                raise InputError("consume_cloud=True: this cloud's arrays were handed over "
                                 "already")
        if not keep_cloud and VARIANTS[variant].get("tree") == "kdtree":
            raise InputError("keep_cloud=False: the kdtree variant keeps no copy of the surfels "
                             "to answer extent() from; use another variant or keep the cloud")
        if traversal not in TRAVERSALS:
            raise InputError(f"traversal: expected one of {TRAVERSALS}, got {traversal!r}")
        if isa not in ISAS:
            raise InputError(f"isa: expected one of {ISAS}, got {isa!r}")
        if isa != "auto" and isa not in available_isas():
            raise InputError(f"isa: {isa!r} kernels do not run here (available: "
                             f"{', '.join(available_isas())})")
        self.threads = _check_threads(threads)
        self.cloud = cloud
        # Everything needed to build the same tree again (pickling, distributed workers).
        self._init_kwargs = dict(variant=variant, interpolation=interpolation, lod=lod, cull=cull,
                                 box_depth=box_depth, lod_pixels=lod_pixels, window=window,
                                 leaf_size=leaf_size, lod_criterion=lod_criterion, slabs=slabs,
                                 traversal=traversal, isa=isa, threads=threads, origin=origin)
        self.variant = variant
        self.interpolation = interpolation
        knobs = dict(VARIANTS[variant])
        if lod is not None:
            knobs["lod"] = bool(lod)
        auto_cull = isinstance(cull, str)
        if auto_cull and cull != "auto":
            raise InputError(f"cull: expected True, False or 'auto', got {cull!r}")
        if cull is not None:
            # "auto": decided once the tree is built (culls); the kdtree variant never culls
            knobs["cull"] = False if auto_cull else bool(cull)
        if box_depth is not None:
            knobs["box_depth"] = box_depth
        points = np.ascontiguousarray(cloud.points, dtype=np.float64)
        n = len(points)
        if n == 0:
            raise InputError("cloud: has no points")
        if n > MAX_SURFELS:
            raise InputError(f"cloud: {n} points, more than one tree holds ({MAX_SURFELS}); "
                             "split the cloud into several scene objects")
        bd = knobs["box_depth"]
        if bd == "auto":
            bd = _auto_box_depth(n, leaf_size)
        elif bd == "all":
            bd = _ALL_LEVELS
        elif not (isinstance(bd, (int, np.integer)) and bd >= 0):
            raise InputError(f"box_depth: expected an integer >= 0, 'auto' or 'all', got {bd!r}")
        if origin is None:
            lo, hi = bounds(points)
            origin = 0.5 * (lo + hi)
        origin = np.asarray(origin, dtype=np.float64).reshape(3)
        origin = tuple(float(v) for v in origin)
        if knobs.get("tree") == "kdtree":  # split planes only: no LoD, cones or boxes
            colors = getattr(cloud, "colors", None)
            self._tree = _core_call(
                _core.KdTree, points, np.ascontiguousarray(cloud.normals, dtype=np.float32),
                np.ascontiguousarray(cloud.radii, dtype=np.float32),
                None if colors is None else np.ascontiguousarray(colors, dtype=np.float32),
                origin)
        else:
            held = {"points": points}
            del points  # held's is the only reference of this call: the build may drop it
            self._tree = self._build_tree(cloud, held, origin, int(leaf_size),
                                          int(min(bd, _ALL_LEVELS)), consume_cloud,
                                          traversal == "wide")
        if not keep_cloud:
            # Drop every reference to the caller's arrays.
            self.cloud = None
        self._options = _core.TraceOptions()
        self._options.lod = knobs["lod"]
        self._options.cull = knobs["cull"]
        self._options.box_depth = int(min(bd, _ALL_LEVELS))
        self._options.lod_pixels = float(lod_pixels)
        self._options.window = float(window)
        self._options.interpolation = getattr(_core.Interpolation, interpolation)
        self._options.lod_criterion = getattr(_core.LodCriterion, lod_criterion)
        self._options.slabs = bool(slabs)
        self._options.isa = getattr(_core.Isa, isa)
        self._options.wide = traversal == "wide"
        self.last_stats: dict = {}
        #: cull="auto": the probe's share of back faces (pointviz.sides), None when not probed
        self.back_face_share = None
        self._probed = False
        if auto_cull:
            self._options.cull = self.culls("auto")

    def _build_tree(self, cloud, held: dict, origin, leaf_size: int, box_depth: int,
                    consume: bool, wide: bool):
        """The tree, built in the core's three stages (:class:`pointviz._core.SurfelTreeBuild`)
        from ``held["points"]`` (popped: the caller keeps no reference) and the cloud's other
        arrays. With ``consume`` the cloud hands its arrays over and each is released as soon as
        its stage has copied it, so that the build's peak memory holds at most part of the
        cloud. ``wide``: also build the wide nodes (the binary traversal does not need them)."""
        if consume:
            held.update(cloud.hand_over())
        points = held.pop("points")
        build = _core.SurfelTreeBuild(points, origin, leaf_size=leaf_size, box_depth=box_depth,
                                      threads=self.threads or 0, wide=wide)
        del points
        if consume:
            normals, radii, colors = (held.pop(k) for k in ("normals", "radii", "colors"))
        else:
            normals, radii, colors = cloud.normals, cloud.radii, getattr(cloud, "colors", None)
        build.add_surfels(np.ascontiguousarray(normals, dtype=np.float32),
                          np.ascontiguousarray(radii, dtype=np.float32),
                          None if colors is None else np.ascontiguousarray(colors, dtype=np.float32))
        del normals, radii, colors
        return build.finish()

    def __reduce__(self):
        """Pickle as the cloud and the settings: the tree is rebuilt (deterministically) on load,
        so a scene sent to another process traces exactly the same hits."""
        if self.cloud is None:
            raise InputError("SurfelScene(keep_cloud=False) cannot be pickled: its cloud is gone")
        kwargs = dict(self._init_kwargs)
        kwargs["origin"] = self.origin  # the resolved origin, so the local frame is identical
        return (_rebuild, (self.cloud, kwargs))

    @property
    def settings(self) -> dict:
        """The constructor's keyword arguments (origin resolved)."""
        kwargs = dict(self._init_kwargs)
        kwargs["origin"] = self.origin
        return kwargs

    # -- properties -------------------------------------------------------------------------
    @property
    def lod(self) -> bool:
        return self._options.lod

    @property
    def cull(self) -> bool:
        return self._options.cull

    @property
    def box_depth(self) -> int:
        return self._tree.box_depth

    @property
    def lod_pixels(self) -> float:
        return self._options.lod_pixels

    @property
    def memory_bytes(self) -> int:
        """Bytes held by the core: surfels, nodes, boxes and the index permutation."""
        return int(self._tree.memory_bytes)

    @property
    def build_seconds(self) -> float:
        return float(self._tree.build_seconds)

    @property
    def n_surfels(self) -> int:
        return int(self._tree.n_surfels)

    @property
    def n_nodes(self) -> int:
        return int(self._tree.n_nodes)

    @property
    def nodes_per_surfel(self) -> float:
        return self.n_nodes / self.n_surfels

    @property
    def depth(self) -> int:
        return int(self._tree.depth)

    @property
    def origin(self) -> np.ndarray:
        return np.array(self._tree.origin)

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """Centre (world coordinates) and radius of the root node's sphere: every disk lies
        within it."""
        cx, cy, cz, r = self._tree.root_sphere()
        return np.array([cx, cy, cz], dtype=np.float64) + self.origin, float(r)

    @property
    def tree(self):
        """The core tree object (``pointviz._core.SurfelTree``), for renderers and diagnostics."""
        return self._tree

    def extent(self, up) -> tuple[np.ndarray, np.ndarray, float]:
        """Bounds of the disks and the ground level along ``up`` (see
        :func:`pointviz.extent.cloud_extent`), computed on first use per ``up`` and reused, so
        that a frame costs nothing that grows with the cloud."""
        return self._per_up("_extents", up, self._compute_extent)

    def _compute_extent(self, key: tuple):
        if self.cloud is not None:
            return _extent_mod.cloud_extent(self.cloud.points, getattr(self.cloud, "radii", None),
                                            key)
        # keep_cloud=False: the tree's own surfels, in its local frame
        view = self._tree.surfel_view()
        lo, hi, level = _extent_mod.cloud_extent(view[:, :3], view[:, 3], key)
        o = self.origin
        return lo + o, hi + o, level + float(np.dot(o, key))

    def shape_kind(self, up) -> str:
        """``"terrain"`` or ``"object"`` (see :func:`pointviz.camera.shape_kind`, which picks the
        "auto" look), decided on first use per ``up`` and reused like :meth:`extent`."""
        from . import camera
        from .framing import fit_sample

        def compute(key):
            if self.cloud is not None:
                return camera.shape_kind(self.cloud.points, key)
            # keep_cloud=False: the tree's own surfel centres, back in world coordinates; only
            # the rows shape_kind looks at (fit_sample), not a float64 copy of the whole cloud
            return camera.shape_kind(fit_sample(self._tree.surfel_view())[:, :3] + self.origin,
                                     key)

        return self._per_up("_shape_kinds", up, compute)

    def _per_up(self, name: str, up, compute):
        """``compute(up)`` cached in the dict attribute ``name``, keyed by the ``up`` tuple."""
        key = tuple(float(v) for v in np.asarray(up, dtype=np.float64).reshape(3))
        cache = self.__dict__.setdefault(name, {})
        if key not in cache:
            cache[key] = compute(key)
        return cache[key]

    def add_to(self, render_scene, origin, material, lod_pixels: float | str,
               max_error: float | None = None, sides: str | None = None) -> None:
        """Add this tree to a core RenderScene whose frame is centred on ``origin`` (see
        :class:`pointviz.geometry.Geometry`); ``sides`` as :meth:`culls` takes it."""
        offset = tuple(float(v) for v in (np.asarray(origin, dtype=np.float64) - self.origin))
        opts = self.trace_options(lod_pixels, max_error)
        opts.cull = self.culls(sides)
        render_scene.add_surfels(self._tree, opts, offset, material)

    def culls(self, sides: str | None = None) -> bool:
        """Whether back faces are culled when a frame asks for ``sides``: None, this scene's
        own choice (:attr:`cull`); "one" yes; "two" no; "auto" when the surfels close a surface
        (:func:`pointviz.sides.closed`, probed on first use unless ``cull="auto"`` did)."""
        if sides is None:
            return self.cull
        if sides not in ("auto", "one", "two"):
            raise InputError(f"sides: expected one of auto, one, two or None, got {sides!r}")
        if sides != "auto":
            return sides == "one"
        if VARIANTS[self.variant].get("tree") == "kdtree":  # the paper's baseline: as built
            return self.cull
        from . import sides as sides_mod

        if not self._probed:
            self.back_face_share = sides_mod.back_face_share(self)
            self._probed = True
        return sides_mod.closed(self.back_face_share)

    def options_key(self) -> tuple:
        """The traversal options' values (what :meth:`trace_options` copies): they are settable
        in place, so a frame's kept RenderScene is keyed by them."""
        o = self._options
        return tuple(getattr(o, k) for k in _OPTION_FIELDS)

    def trace_options(self, lod_pixels: float | str | None = None, max_error: float | None = None):
        """A copy of the traversal options, optionally with another LoD threshold, or with the
        error budget (``lod_pixels="auto"``, ``max_error``: mean FLIP, see
        :func:`pointviz.rendering.render`)."""
        o = _core.TraceOptions()
        for k in _OPTION_FIELDS:
            setattr(o, k, getattr(self._options, k))
        if isinstance(lod_pixels, str):
            _, max_error = check_lod(lod_pixels, max_error)
            o.lod = o.lod and max_error > 0
            o.lod_criterion = _core.LodCriterion.budget
            o.max_error = max_error
            # The size rule joins the budget in proportion to it: at 1 px it costs up to
            # SIZE_RULE_ERROR, so it runs at full strength once the budget covers that.
            o.lod_pixels = min(1.0, max_error / SIZE_RULE_ERROR)
            return o
        if lod_pixels is not None:
            if not (np.isfinite(lod_pixels) and lod_pixels >= 0):
                raise InputError(f"lod_pixels: must be a non-negative number, got {lod_pixels!r}")
            o.lod = o.lod and lod_pixels > 0
            o.lod_pixels = float(lod_pixels) if lod_pixels > 0 else 1.0
        return o

    def __repr__(self) -> str:
        return (f"SurfelScene({self.n_surfels} surfels, variant={self.variant!r}, "
                f"interpolation={self.interpolation!r}, depth={self.depth}, "
                f"{self.memory_bytes / self.n_surfels:.1f} B/surfel)")

    # -- queries ----------------------------------------------------------------------------
    def cast_rays(self, rays, *, pixel_angle: float | None = None, camera=None,
                  lod_pixels: float | str | None = None, stats: bool = True,
                  max_error: float | None = None, cull: bool | None = None) -> dict:
        """Closest hits with interpolated attributes.

        Parameters
        ----------
        rays : (n, 6) float32 or float64
            Origin and direction per row (world coordinates).
        pixel_angle : float, optional
            Angle of one pixel in radians: enables level of detail. Without it (and without a
            camera) rays are traced at full detail.
        camera : Camera, optional
            Takes ``pixel_angle`` from the camera.
        lod_pixels : float or "auto", optional
            Overrides the scene's LoD threshold for this call; 0 disables LoD; "auto" stops
            by the error budget ``max_error`` (see :func:`pointviz.render`).
        stats : bool
        max_error : float, optional
            With ``lod_pixels="auto"``: the budget (mean FLIP).
        cull : bool, optional
            Overrides the scene's back-face culling for this call.

        Returns
        -------
        dict
            ``t_hit`` (n,) float32 (inf on a miss, in units of the given directions),
            ``normals`` (n, 3) float32 unit, ``colors`` (n, 3) float32, ``radii`` (n,) float32
            (blended disk radius), ``index`` (n,) int32 (input index of the nearest surfel,
            -1 miss, -2 a LoD node), ``count`` (n,) uint8 (disks blended),
            ``positions`` (n, 3) float64 (inf on a miss).
        """
        arr = as_rays(rays)
        pa = _pixel_angle(pixel_angle, camera)
        opts = self.trace_options(lod_pixels, max_error)
        if cull is not None:
            opts.cull = bool(cull)
        out, st = _core_call(self._tree.cast, arr, opts, pixel_angle=pa,
                             threads=self.threads or 0, stats=stats)
        self.last_stats = dict(st)
        return out

    def occluded(self, rays, t_max, *, t_min: float = 0.0, pixel_angle: float | None = None,
                 stats: bool = True) -> np.ndarray:
        """Any-hit query for shadow rays: whether anything lies in ``(t_min, t_max)``.

        Parameters
        ----------
        rays : (n, 6) float
        t_max : float or (n,) float
            Far end of each ray's interval, in units of the given directions.
        t_min : float
            Near end (skip the surface a shadow ray starts on).

        Returns
        -------
        (n,) bool
        """
        arr = as_rays(rays)
        try:
            tm = np.ascontiguousarray(np.broadcast_to(np.asarray(t_max, dtype=np.float32), (len(arr),)))
        except (ValueError, TypeError):
            raise InputError(f"t_max: expected a number or {len(arr)} numbers") from None
        if not np.isfinite(t_min) or t_min < 0:
            raise InputError(f"t_min: must be a finite number >= 0, got {t_min!r}")
        pa = _pixel_angle(pixel_angle, None)
        opts = self.trace_options()
        if pa == 0.0:
            opts.lod = False
        hit, st = _core_call(self._tree.occluded, arr, tm, opts, t_min=float(t_min),
                             pixel_angle=pa, threads=self.threads or 0, stats=stats)
        self.last_stats = dict(st)
        return hit.astype(bool)


def _rebuild(cloud, kwargs):
    return SurfelScene(cloud, **kwargs)


def _pixel_angle(pixel_angle, camera) -> float:
    if camera is not None:
        pixel_angle = camera.pixel_angle
    if pixel_angle is None:
        return 0.0
    pa = float(pixel_angle)
    if not (np.isfinite(pa) and 0 <= pa < np.pi):
        raise InputError(f"pixel_angle: must be in [0, pi) radians, got {pixel_angle!r}")
    return pa


def _check_threads(threads):
    if threads is None:
        return None
    return check_int(threads, "threads", note=" or None")
