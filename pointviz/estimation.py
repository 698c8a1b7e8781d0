"""What raw points lack, estimated by the C++ core: neighbours, normals, orientation, radii and a
surface fit of noisy, overlapping scans.

Every function takes plain arrays and returns new ones; :class:`pointviz.PointCloud` calls them
lazily for the normals and radii a file did not provide, and :meth:`PointCloud.fitted` for the
surface fit. The work runs in the core on all cores (``threads=0``) with the GIL released, and
its results are the same for any thread count.

Pipeline for raw scans (no normals):

1. k nearest neighbours on a KD-tree (:func:`knn`).
2. Normals by weighted PCA over a neighbourhood chosen per point (:func:`estimate_normals`): it
   grows from :data:`NORMAL_K_MIN` to :data:`NORMAL_K_MAX` points while the normal stays within
   :data:`NORMAL_CONFIDENCE` standard errors of every smaller neighbourhood's (the
   intersection-of-confidence-intervals rule), so noisy flat parts use many points and curved or
   detailed parts few.
3. Orientation (:func:`orient_normals`): toward the scanner when viewpoints are known, else along
   a minimum spanning tree of the neighbour graph, each connected part facing outward.
4. Optionally (:func:`fit_surface`, on by default for registered scans): every point moves onto a
   robust quadric fit of its neighbourhood across all scans, and points that add nothing where
   scans overlap are dropped, and so are stray clusters (:func:`stray_clusters`): pieces of the
   neighbour graph too small to be part of the scanned object.
5. Radii that just cover the surface (:func:`coverage_radii`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import array_checks
from .errors import InputError

# Neighbourhood sizes of the normal (the point included). 8 is the first ring of samples around
# a point (6 on a hexagonal sampling, 8 on a grid); 32 averages the noise of raw range scans
# (0.1-0.4 % of the object) down to about 2 degrees on flat parts.
NORMAL_K_MIN = 8
NORMAL_K_MAX = 32
# Standard errors within which a larger neighbourhood's normal must agree with every smaller
# one's to be used (the noise level is the median residual variance of the first ring). Mean
# errors measured on a random torus sampling, clean / 40 % of the spacing noise, a clean box and
# virtual scans of a torus at 0.4 % noise (tests/test_estimation.py, benchmarks): 1.52 / 2.73 /
# 2.33 / 5.31 degrees at 3; fixed k = 8: 1.77 / 13.8 / 1.35 / 29.3; k = 32: 1.40 / 2.64 / 3.63 /
# 5.01. 2 stops too early in noise (3.70 on the noisy torus), 4 hardly adapts on edges.
NORMAL_CONFIDENCE = 3.0
# The largest size for a cloud seen from above (``from_above``: aerial and terrestrial LiDAR
# tiles): the 31-neighbour search was a third of lone-star.laz's start to PNG, and half of the
# tile is canopy, whose normals are no surface's. 19 neighbours instead of 31: normals_and_radii
# on lone-star 0.82 -> 0.64 s (two threads), its render within the sampling noise of main's
# (mean |difference| 2.0 of 255 against 2.2 between two seeds of main); on a sampled height
# field with 0.2 spacings of height noise the mean error 1.97 -> 2.96 degrees (16: 3.73, 24:
# 2.49); benchmarks/README.md, "LiDAR's first minute, part two".
NORMAL_K_MAX_ABOVE = 20
# The fixed neighbourhood size of earlier versions (k=...) and of callers that ask for one.
NORMAL_K = 16

# Neighbours linked in the graph that propagates normal orientation (Hoppe et al. 1992 use a
# k-NN "Riemannian graph" with k ~ 8): enough to keep a sampled surface in one piece, few enough
# that the graph rarely jumps across thin parts (ears, fingers) to the other side.
ORIENT_K = 8

# Weight of the neighbour distance (in units of the median spacing) added to the Hoppe edge cost
# 1 - |n_i . n_j|: on flat parts that cost is ~0 for every edge, and short edges must win ties.
ORIENT_DISTANCE_WEIGHT = 0.1

# A component whose normals point outward for a fraction in [0.5 - m, 0.5 + m] is "undecided"
# (an open patch such as terrain); with an ``up`` hint it is oriented to face up instead. Terrain
# is rarely flat: lidar/simple.las (a shallow valley) votes 0.605 for facing down, while closed
# scans vote > 0.8 for their outside.
OUTWARD_UNDECIDED_MARGIN = 0.2

# Orientation of a cloud seen from above (aerial and most terrestrial LiDAR, which never see a
# surface from below; PointCloud.seen_from_above, set by the LAS reader): a normal within
# acos(ORIENT_ABOVE_STEEP) = 72.5 degrees of the up faces up (beyond 45 degrees only when it
# agrees with half of its neighbours': the core's OrientOptions::flat, agree); a steeper one
# (walls, cliffs, trunks) takes the sign its oriented neighbours vote for (the core's orient_above, at most
# OrientOptions::rounds rounds of propagation). Linear and on all cores instead of the spanning
# tree's serial sort (benchmarks/README.md, "LiDAR's first minute").
ORIENT_ABOVE_STEEP = 0.3

# The spacing radius of a point comes from the distance to its RADIUS_K-th nearest neighbour (not
# counting itself): the 8th reaches past the first ring, so one close neighbour does not collapse
# the radius.
RADIUS_K = 8

# r_i = RADIUS_FACTOR * d_8(i): the smallest factor that leaves no hole on a Fibonacci sphere,
# jittered and anisotropic grids, with a margin (see tests/test_cloud.py).
RADIUS_FACTOR = 0.65

# Coverage radii (the core's CoverOptions): the radius of a point is COVER_MARGIN x the radius of
# its Voronoi cell in its tangent plane, measured along COVER_DIRECTIONS directions among its
# COVER_K nearest neighbours; capped at COVER_CAP x the COVER_K-th neighbour's distance and at
# COVER_GLOBAL_CAP x the cloud's 99th-percentile radius (a stray cluster's cell would reach the
# distant surface). Measured hole-free on Poisson-disk, uniform random, jittered and anisotropic
# samplings and on the Fibonacci sphere (tests/test_estimation.py).
COVER_K = 10
COVER_DIRECTIONS = 16
COVER_MARGIN = 1.2
COVER_CAP = 1.0
COVER_GLOBAL_CAP = 4.0
# Radii of points whose neighbourhood is not a surface (canopies, shrubs; the core's
# CoverOptions::volume_*): f = the fraction of the COVER_K neighbours within VOLUME_BAND x their
# in-plane distance of the point's tangent plane (~1 on sampled surfaces, noisy or curved, and
# beside creases such as a roof's ridge; ~0.2-0.4 among scattered returns); from
# VOLUME_SURFACE down to VOLUME_VOLUME the radius goes geometrically from the cell's to at most
# VOLUME_FACTOR x the distance to the nearest neighbour: a volume of returns is shown as the
# scatter it is, not as petals. A point taken for a surface whose neighbours mostly are not
# (returns of a canopy that happen to lie in a plane, all to one side) is bounded as they are. A measure of thickness (RMS height over RMS in-plane distance)
# was tried first: it also took the points beside a ridge for a volume and opened it (0.3-2.1 %
# of vertical rays missed 30-60 degree roofs, vs 0.00-0.015 % with this one and factor 1;
# factor 0.5 left 0.17-0.45 %): benchmarks/README.md, "LiDAR's first minute". With these bounds
# on, a point whose neighbours all lie to one side (some direction meets no bisector) leaves out
# of its cell the directions whose bisector lies beyond the neighbour that makes it (the core's
# CoverOptions::open_cos): the grazing far ends of the vegetation's "petals" (its radius p99
# 0.221 -> 0.191 m; uniform random planes stay hole-free): "LiDAR's first minute, part two".
VOLUME_BAND = 0.2
VOLUME_SURFACE = 0.6
VOLUME_VOLUME = 0.4
VOLUME_FACTOR = 1.0
# Sparse returns (water, dark roofs) keep disks of at most TYPICAL_CAP x the median radius of
# the surface points: a few returns over a river do not blot it out with disks that cover what
# they did not sample (0: off).
TYPICAL_CAP = 3.0

# Surface fit (the core's FitOptions, where the measurements behind these are). FIT_PASSES fits,
# each on the previous one's output (planes, then a quadric), over at least FIT_MIN_SUPPORT
# points, the last reweighted FIT_ROBUST_PASSES times with Welsch weights FIT_ROBUST_WIDTH RMS
# residuals wide (none by default: the reweighting made the virtual torus scans no better and
# took 0.3-0.4 s of the 1M-point sphere scans' 4.7 s of CPU; FitOptions::robust_passes); then a
# point is dropped when a kept one lies within FIT_THIN x its spacing in its own scan.
# The normals the fit starts from (when the cloud has none) grow from NORMAL_K_MIN to at most
# FIT_NORMAL_K_MAX points of the point's own scan, not NORMAL_K_MAX: the fit's plane pass
# replaces them by the slope of a plane through FIT_MIN_SUPPORT points across all scans, so they
# only set its frame and tell the two sides of a thin part apart. Every fit then takes
# FIT_MIN_SUPPORT points (before: the normal's support, 16-32, at least 16): the searches within
# scans ask for half as many neighbours and the normals fit 3 sizes instead of 5. Virtual scans
# of a torus (bench_preprocess.py, seed 11, 0.1 % / 0.4 % noise), normals up to 32 and fits of
# 16-32 points before / now: normal error 0.850 / 3.111 -> 0.837 / 2.946 degrees, holes 0.131 /
# 0.045 % -> 0.129 / 0.037 %, depth error 4.57e-4 / 1.06e-3 -> 4.71e-4 / 1.01e-3. Fits of 24
# points (a 23-neighbour search across scans) were worse (1.04 / 3.98 degrees), and so were
# initial normals of at most 8 or 12 points at 0.4 % noise (5.37 / 3.17 degrees). Their
# neighbours within the scan come from the 31 across all scans where those hold at least 10 of
# the point's own scan (then up to 15 of them; kScanRowsLeast in the core's scan_neighbours.h):
# where scans overlap a normal may rest on 11-15 points instead of 16, and the sphere scans'
# within-scan search is left with 40 % of its points.
FIT_NORMAL_K_MAX = 16
# Sizes of those starting normals: 8 then FIT_NORMAL_K_MAX (the size doubled; 1.5 tried 8, 12,
# 16): one plane fit and one 3x3 eigen-solve less per point. Torus scans (holes_over_seeds.py,
# seeds 1-3, 0.1 % / 0.4 % noise) with 8, 12, 16 / with 8, 16: normal error 0.8692 / 2.910 ->
# 0.8692 / 2.909 degrees, holes 0.1033 / 0.0419 % -> 0.1033 / 0.0409 %, depth error 5.668e-4 /
# 1.044e-3 -> 5.668e-4 / 1.047e-3; the sphere scans' normals 0.72 -> 0.62 s of CPU (one thread).
FIT_NORMAL_GROWTH = 2.0
FIT_MIN_SUPPORT = 32
FIT_PASSES = 2
FIT_ROBUST_PASSES = 0
FIT_ROBUST_WIDTH = 2.0
FIT_THIN = 0.75

# Stray clusters: neighbours searched per point, as many as the surface fit's table holds (its
# links, the spacing rule and the sizes below which a component is stray are the core's
# StrayOptions, where the measurements behind them are).
STRAY_K = FIT_MIN_SUPPORT - 1


def _core(step: str | None = None):
    """The core module; with ``step``, its calls report their progress under that name
    (:func:`pointviz.interrupt.step_named`: the command line's progress bars)."""
    from . import _core as core

    return core if step is None else _NamedStep(core, step)


class _NamedStep:
    """The core module whose calls run as the named step."""

    def __init__(self, core, step: str):
        self._core, self._step = core, step

    def __getattr__(self, attr):
        from .interrupt import step_named

        fn = getattr(self._core, attr)

        def call(*args, **kwargs):
            with step_named(self._step):
                return fn(*args, **kwargs)

        return call


def _points(value, name: str = "points", minimum: int = 1) -> np.ndarray:
    """(n, 3) finite float64, C-contiguous, with at least ``minimum`` rows."""
    pts = np.ascontiguousarray(array_checks.rows3(name, value, None), dtype=np.float64)
    if len(pts) < minimum:
        raise InputError(f"{name}: has {len(pts)} point(s), need at least {minimum}")
    return pts


def _normals(value, n: int) -> np.ndarray:
    return np.ascontiguousarray(array_checks.normals(value, n), dtype=np.float32)


def _viewpoints(value, n: int):
    if value is None:
        return None
    return array_checks.viewpoints(value, n)


def _groups(scan_index, viewpoints, n: int):
    """(n,) int32 scan of each point: ``scan_index``, else one scan per distinct viewpoint row
    (None without either, or with a single viewpoint for all points)."""
    if scan_index is not None:
        return array_checks.per_point("scan_index", scan_index, n, np.int32)
    if viewpoints is not None and viewpoints.ndim == 2 and len(viewpoints) == n:
        return np.unique(viewpoints, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int32)
    return None


def _grid(scan_grid, groups, n: int):
    """(n, 2) int32 grid cell (row, column) of each point in its scan, or None; needs scans."""
    if scan_grid is None:
        return None
    arr = array_checks.numeric("scan_grid", scan_grid)
    if arr.shape != (n, 2):
        raise InputError(f"scan_grid: expected shape ({n}, 2), got {arr.shape}")
    if arr.dtype.kind not in "iu":
        raise InputError(f"scan_grid: expected integers, got dtype {arr.dtype}")
    if groups is None:
        raise InputError("scan_grid: needs scan_index (the grid of which scan)")
    if arr.size and (arr.min() < -(2**31) or arr.max() >= 2**31):
        raise InputError("scan_grid: rows and columns must fit in 32 bits")
    return np.ascontiguousarray(arr, dtype=np.int32)


def _up(value):
    if value is None:
        return None
    return tuple(float(v) for v in array_checks.unit_vector("up", value))


def _orient(k: int | None = None):
    """The orientation settings the core takes: (neighbours, edge-length weight, margin)."""
    return (ORIENT_K if k is None else k, ORIENT_DISTANCE_WEIGHT, OUTWARD_UNDECIDED_MARGIN)


def _normal_points(points) -> np.ndarray:
    """The points of a normal estimate: at least 3, not all at one position."""
    pts = _points(points)
    if len(pts) < 3:
        raise InputError(f"normals: cannot be estimated from {len(pts)} point(s), need at "
                         "least 3; pass normals")
    _distinct(pts, "normals")
    return pts


def _k_max(from_above, viewpoints=None, scan_index=None) -> int:
    """The largest neighbourhood of the adaptive normals: NORMAL_K_MAX_ABOVE for a cloud seen
    from above (oriented from above: neither viewpoints nor scans), else NORMAL_K_MAX."""
    if (isinstance(from_above, (bool, np.bool_)) and from_above and viewpoints is None
            and scan_index is None):
        return NORMAL_K_MAX_ABOVE
    return NORMAL_K_MAX


def _above(from_above, up) -> float:
    """The core's ``above``: ORIENT_ABOVE_STEEP to orient a cloud seen from above, else 0."""
    if not isinstance(from_above, (bool, np.bool_)):
        raise InputError(f"from_above: expected True or False, got {from_above!r}")
    if not from_above:
        return 0.0
    if up is None:
        raise InputError("from_above: needs up (the side the sensor saw the surfaces from)")
    return ORIENT_ABOVE_STEEP


def _volume(volume) -> tuple:
    """The core's non-surface and sparse bounds of the radii (zeros: off)."""
    if not isinstance(volume, (bool, np.bool_)):
        raise InputError(f"volume: expected True or False, got {volume!r}")
    if not volume:
        return (VOLUME_BAND, VOLUME_SURFACE, VOLUME_VOLUME, 0.0, 0.0)
    return (VOLUME_BAND, VOLUME_SURFACE, VOLUME_VOLUME, VOLUME_FACTOR, TYPICAL_CAP)


def _count(name: str, value, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
        raise InputError(f"{name}: expected an integer >= {lo}, got {value!r}")
    return int(value)


def _threads(value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise InputError(f"threads: expected an integer >= 0 (0: all cores), got {value!r}")
    return int(value)


def _distinct(points: np.ndarray, what: str) -> None:
    # the first rows nearly always settle it; else one comparison pass over all of them (np.ptp
    # along axis 0 of an (n, 3) array is 8x slower: 0.2 s at 1M, the pass ~0.01 s)
    if not ((points[:1024] != points[0]).any() or (points != points[0]).any()):
        raise InputError(f"{what}: cannot be estimated, all {len(points)} points coincide")


# ---------------------------------------------------------------------------------------------


def knn(points, k: int, *, threads: int = 0):
    """The ``k`` nearest neighbours of every point, the point itself excluded.

    Parameters
    ----------
    points : (n, 3) array_like
        Finite positions.
    k : int
        Neighbours per point, >= 1; clamped to n - 1.
    threads : int
        Worker threads, 0 for all cores. Results do not depend on it.

    Returns
    -------
    dist : (n, min(k, n - 1)) float64
        Euclidean distances, ascending per row (ties by index).
    index : (n, min(k, n - 1)) int64
        Neighbour indices. Exact duplicates of a point are its neighbours at distance 0.
    """
    pts = _points(points)
    dist, idx = _core("neighbours").knn(pts, _count("k", k, 1), _threads(threads))
    return dist, idx.astype(np.int64)


def nearest(points, queries, *, threads: int = 0):
    """The nearest of ``points`` to each of ``queries``.

    Parameters
    ----------
    points : (n, 3) array_like
        Finite positions, n >= 1.
    queries : (m, 3) array_like
        Finite positions.
    threads : int
        Worker threads, 0 for all cores. Results do not depend on it.

    Returns
    -------
    dist : (m,) float64
        Euclidean distances.
    index : (m,) int64
        Index into ``points``; ties go to the lower index.
    """
    pts = _points(points)
    q = _points(queries, "queries", minimum=0)
    dist, idx = _core("neighbours").nearest(pts, q, _threads(threads))
    return dist, idx.astype(np.int64)


def estimate_normals(
    points,
    *,
    k: int | None = None,
    viewpoints=None,
    scan_index=None,
    scan_grid=None,
    up=None,
    from_above: bool = False,
    threads: int = 0,
    details: bool = False,
):
    """Unit normals of raw points, consistently oriented.

    Parameters
    ----------
    points : (n, 3) array_like
        Positions, n >= 3, not all on one line.
    k : int, optional
        A fixed neighbourhood size (the point included). By default the size is chosen per point
        between :data:`NORMAL_K_MIN` and :data:`NORMAL_K_MAX` (:data:`NORMAL_K_MAX_ABOVE` with
        ``from_above`` and neither viewpoints nor scans) from the local noise and sampling.
    viewpoints : (3,) or (n, 3) array_like, optional
        Scanner position(s): each normal is flipped to face its viewpoint. Otherwise normals are
        oriented along a minimum spanning tree (see :func:`orient_normals`).
    scan_index : (n,) array_like of int, optional
        Which scan each point came from. Each normal is then estimated from neighbours in its
        own scan only: a range scan sees one side of a thin part, while the registered scans
        together put both sides of a claw or spike into one neighbourhood and tilt its plane
        across the part. Without it, points with the same viewpoint form one scan.
    scan_grid : (n, 2) array_like of int, optional
        Row and column of each point in its scan's sampling grid (a range scanner's grid of
        rays, e.g. a PLY ``range_grid``; negative: none), with ``scan_index``. Neighbours within
        a scan are then found among the grid cells around a point instead of by a search of the
        whole scan (the same neighbours on surfaces the grid samples smoothly; see
        ``scan_neighbours.h`` in the core). Scans without it whose points share one viewpoint
        and lie within 60 degrees of their mean direction from it are binned by that
        direction instead, into a grid whose ring search stops only where it is exact (the
        same neighbours as the per-scan search, depth jumps included).
    up : (3,) array_like, optional
        Tie-break for open, flat parts without viewpoints.
    from_above : bool
        The sensor saw every surface from the ``up`` side (aerial and most terrestrial LiDAR):
        without viewpoints, normals are oriented by :func:`orient_normals` ``(from_above=True)``
        instead of the spanning tree. Needs ``up``.
    threads : int
        Worker threads, 0 for all cores; results do not depend on it.
    details : bool
        Also return a dict: ``support`` ((n,) int, neighbourhood size used), ``spread`` ((n,)
        float, RMS distance of that neighbourhood from its plane), ``borrowed`` (points on a
        line or a stack of duplicates, which took the normal of their nearest neighbour that
        has one), ``arbitrary`` (such points with no such neighbour: a direction
        perpendicular to their line), and with scans the points whose neighbours within their
        scan came from stored grids (``grid_neighbours``), grids of directions from their
        viewpoint (``view_grid_neighbours``) or a KD-tree of the scan (``tree_neighbours``).

    Returns
    -------
    normals : (n, 3) float32
        Unit normals, never NaN.
    """
    pts = _normal_points(points)
    n = len(pts)
    if k is None:
        k_min, k_max = NORMAL_K_MIN, _k_max(from_above, viewpoints, scan_index)
    else:
        k_min = k_max = max(3, _count("k", k, 3))
    vp = _viewpoints(viewpoints, n)
    groups = _groups(scan_index, vp, n)
    out = _core("normals").estimate_normals(
        pts, vp, groups, _up(up), min(k_min, n), min(k_max, n),
        NORMAL_CONFIDENCE, _orient(), _threads(threads), _grid(scan_grid, groups, n),
        above=_above(from_above, up),
    )
    normals = out.pop("normals")
    if details:
        return normals, out
    return normals


def normals_and_radii(points, *, up=None, from_above: bool = False, volume: bool = False,
                      threads: int = 0):
    """Normals and their coverage radii from one neighbour search, for a cloud without
    viewpoints or scans: ``estimate_normals(points, up=up, from_above=from_above)`` and
    ``coverage_radii(points, normals, volume=volume)``, but the radii take the first
    :data:`COVER_K` columns of the normals' own neighbour table (sorted rows of the same tree)
    instead of building a tree and searching again (lone-star.laz: 0.83 instead of 1.06 s).
    The normals are the same bit for bit; the radii too but where the 10th and 11th neighbours
    lie at the same distance (quantised LAS coordinates) and the two searches keep different
    ones (on autzen_trim.laz 0.006 % of the radii, by at most 2e-6 of their size), and without
    ``volume`` by a float's rounding here and there (1 ulp: that search visits its rows fused).

    Returns
    -------
    normals : (n, 3) float32
    radii : (n,) float32, positive
    """
    pts = _normal_points(points)
    n = len(pts)
    out = _core("normals").estimate_normals(
        pts, None, None, _up(up), min(NORMAL_K_MIN, n), min(_k_max(from_above), n),
        NORMAL_CONFIDENCE, _orient(), _threads(threads), None, above=_above(from_above, up),
        cover_k=min(COVER_K, n - 1), directions=COVER_DIRECTIONS, margin=COVER_MARGIN,
        cap=COVER_CAP, global_cap=COVER_GLOBAL_CAP, volume=_volume(volume),
    )
    normals = out["normals"]
    radii = out.get("radii")
    if radii is None:
        return normals, coverage_radii(pts, normals, volume=volume, threads=threads)
    bad = ~(radii > 0)
    if bad.any():  # stacks of duplicates, resolved as coverage_radii resolves them
        radii[bad] = estimate_radii(pts, threads=threads)[bad]
    return normals, radii


def orient_normals(points, normals, *, viewpoints=None, up=None, from_above: bool = False,
                   k: int = ORIENT_K, threads: int = 0) -> np.ndarray:
    """Flip normals so that they face their scanner, or agree with their neighbours.

    With ``viewpoints``, each normal is flipped to face its viewpoint. Without, signs propagate
    along a minimum spanning tree of the ``k``-nearest-neighbour graph with edge cost
    ``1 - |n_i . n_j| + ORIENT_DISTANCE_WEIGHT * d_ij / median(d)`` (Hoppe et al. 1992); each
    connected part then gets the sign under which most of its normals point away from its
    centroid, or, when that vote is undecided (an open, flat patch) and ``up`` is given, faces
    ``up``.

    Parameters
    ----------
    points : (n, 3) array_like
    normals : (n, 3) array_like
        Unit (or non-zero) normals of any sign.
    viewpoints : (3,) or (n, 3) array_like, optional
    up : (3,) array_like, optional
    from_above : bool
        The sensor saw every surface from the ``up`` side, never from below (aerial and most
        terrestrial LiDAR). Without viewpoints, a normal within acos(:data:`ORIENT_ABOVE_STEEP`)
        of vertical then faces ``up``; a steeper one (a wall, a cliff, a trunk) takes the sign
        its oriented neighbours among its ``k`` nearest vote for, in rounds (each on the state
        of the round before: the same for any thread count); one that none reaches faces up by
        the sign of its vertical part. Linear in n on all cores, where the spanning tree sorts
        every edge on one thread. Needs ``up``.
    k : int
        Neighbours linked per point.
    threads : int

    Returns
    -------
    normals : (n, 3) float64
        The same directions (normalised), flipped where needed.
    """
    pts = _points(points)
    nrm = _normals(normals, len(pts))
    out, _ = _core("orientation").orient_normals(pts, nrm, _viewpoints(viewpoints, len(pts)), _up(up),
                                    _orient(_count("k", k, 1)), _threads(threads),
                                    above=_above(from_above, up))
    return out.astype(np.float64)


def estimate_radii(points, *, k: int = RADIUS_K, factor: float = RADIUS_FACTOR,
                   threads: int = 0) -> np.ndarray:
    """Surfel radii from local spacing: ``r_i = factor * d_k(i)``.

    Parameters
    ----------
    points : (n, 3) array_like
    k : int
        Which neighbour's distance measures the spacing (itself not counted), clamped to n - 1.
    factor : float
        See :data:`RADIUS_FACTOR`.

    Returns
    -------
    radii : (n,) float32
        Positive radii. Duplicated points get the radius their position has in the cloud
        without duplicates (so stacks of coincident points never give d_k = 0).
    """
    pts = _points(points)
    n = len(pts)
    if n < 2:
        raise InputError("radii: cannot be estimated from a single point; pass radii")
    k = _count("k", k, 1)
    dk = knn(pts, min(k, n - 1), threads=threads)[0][:, -1]
    if not np.all(dk > 0):
        # stacks of duplicates: measure the spacing among distinct positions, so duplicates get
        # the radius of the position they share (a positive floor from the local spacing)
        uniq, inverse = np.unique(pts, axis=0, return_inverse=True)
        if len(uniq) == 1:
            raise InputError(f"radii: cannot be estimated, all {n} points coincide; pass radii")
        dk = knn(uniq, min(k, len(uniq) - 1), threads=threads)[0][:, -1][inverse.reshape(-1)]
    out = (factor * dk).astype(np.float32)
    # float32 rounding must not produce 0 for tiny (but positive) spacings
    return np.maximum(out, np.finfo(np.float32).tiny)


def coverage_radii(points, normals, *, k: int = COVER_K, margin: float = COVER_MARGIN,
                   cap: float = COVER_CAP, volume: bool = False, threads: int = 0) -> np.ndarray:
    """Per-point radii just large enough to cover the surface: margin x the Voronoi-cell radius.

    For each point, its ``k`` nearest neighbours are projected on its tangent plane; along each
    of COVER_DIRECTIONS directions the cell ends at the nearest perpendicular bisector. The
    cell's radius is the largest such distance over the directions that have a bisector
    (directions without one face an open boundary, which needs no cover beyond the samples).

    Parameters
    ----------
    points : (n, 3) array_like
    normals : (n, 3) array_like, unit normals
    k, margin, cap : see :data:`COVER_K`, :data:`COVER_MARGIN`, :data:`COVER_CAP`
    volume : bool
        Model returns that are not of a surface (LiDAR's canopies and shrubs, sparse returns
        over water; :class:`~pointviz.PointCloud` turns it on for clouds ``seen_from_above``):
        a point whose neighbours mostly lie off its tangent plane gets at most
        :data:`VOLUME_FACTOR` x its nearest neighbour's distance, and an isolated return (a cell
        wide in most directions, beyond :data:`TYPICAL_CAP` x the surface points' median) at
        most :data:`TYPICAL_CAP` x their median radius; a point whose neighbours all lie to one
        side leaves its grazing directions (a bisector beyond its own neighbour) out of its
        cell. Off by default: meshes and range scans
        are surfaces throughout (on coarse meshes 1.5-11 % of the vertices would be taken for a
        volume at curved details).
    threads : int

    Returns
    -------
    radii : (n,) float32, positive
    """
    pts = _points(points)
    n = len(pts)
    if n < 2:
        raise InputError("radii: cannot be estimated from a single point; pass radii")
    _distinct(pts, "radii")
    nrm = _normals(normals, n)
    out = _core("radii").coverage_radii(pts, nrm, min(_count("k", k, 1), n - 1), COVER_DIRECTIONS,
                                 float(margin), float(cap), COVER_GLOBAL_CAP, _threads(threads),
                                 volume=_volume(volume))
    bad = ~(out > 0)
    if bad.any():  # stacks of duplicates: the spacing-based estimate knows how to handle them
        out[bad] = estimate_radii(pts, threads=threads)[bad]
    return out


@dataclass
class SurfaceFit:
    """What :func:`fit_surface` produced.

    Attributes
    ----------
    points : (n, 3) float64
        Every input point moved onto the fitted surface (or left where it was, see ``unmoved``).
    normals : (n, 3) float32
        Unit normals of the fitted surface, oriented like the input's (or estimated) normals.
    keep : (n,) bool
        The points that add to the surface; the others lie within the spacing of a kept point
        where scans overlap.
    shift : (n,) float32
        How far each point moved.
    unmoved : int
        Points whose fit failed (too few or degenerate neighbours) or asked for a move beyond
        their neighbourhood: left in place with their input normal.
    spacing : float
        Median distance to the nearest point of the same scan before the fit, the unit of
        ``summary``.
    scan_neighbours : dict
        How the normals' neighbours within scans were found (points per way, when normals were
        estimated with scans): ``grid`` from the scans' stored grids, ``view_grid`` from grids
        of directions from each scan's viewpoint, ``tree`` from a KD-tree per scan,
        ``across`` from the fit's neighbours across all scans (those holding enough of the
        point's own scan, which need no search).
    radii : (n,) float32 or None
        With ``fit_surface(radii=True)``: the coverage radii of the kept points on their fitted
        positions and normals (0 for the others), as :func:`coverage_radii` of the kept points
        would give them, with each point's :data:`COVER_K` nearest kept points taken from the
        fit's own neighbours (see ``fit_surface``).
    radii_searched : int
        Kept points whose fit neighbours held fewer than :data:`COVER_K` kept points: their
        neighbours were searched.
    """

    points: np.ndarray
    normals: np.ndarray
    keep: np.ndarray
    shift: np.ndarray
    unmoved: int
    spacing: float
    stray_points: int = 0
    stray_clusters: int = 0
    scan_neighbours: dict = field(default_factory=dict)
    radii: np.ndarray | None = None
    radii_searched: int = 0

    @property
    def kept(self) -> int:
        return int(self.keep.sum())

    def summary(self) -> str:
        """One line: points kept and how far the points moved."""
        n = len(self.keep)
        mean = float(self.shift.mean()) if n else 0.0
        rel = f" ({mean / self.spacing:.2f} x the point spacing)" if self.spacing > 0 else ""
        text = (f"surface fit: kept {self.kept} of {n} points ({100.0 * self.kept / max(n, 1):.1f}%), "
                f"mean shift {mean:.3g}{rel}")
        if self.unmoved:
            text += f"; {self.unmoved} points not moved (degenerate neighbourhood)"
        if self.stray_points:
            text += (f"; dropped {self.stray_points} stray points in {self.stray_clusters} "
                     f"cluster{'s' if self.stray_clusters != 1 else ''}")
        return text


def fit_surface(points, normals=None, *, viewpoints=None, scan_index=None, scan_grid=None,
                up=None,
                thin: float = FIT_THIN, quadric: bool = True, passes: int = FIT_PASSES,
                robust_passes: int = FIT_ROBUST_PASSES, strays: bool = True,
                radii: bool = False, threads: int = 0) -> SurfaceFit:
    """Move points onto a robust local fit of the surface across all scans; mark the redundant.

    Each point's neighbourhood (:data:`FIT_MIN_SUPPORT` points across all scans) is fitted, in
    the frame of the point's normal, by a weighted plane; the point moves onto it and takes its
    normal. ``passes`` fits run in turn,
    each on the previous one's output (the last reweighted against outliers ``robust_passes``
    times, none by default); the last fits a height field
    ``z = a + b x + c y + d x^2 + e xy + f y^2`` (``quadric=False``: a plane again), which does
    not pull curved parts inward; it also gives back the pull of the plane passes before it
    (each plane lies on the concave side of a curved neighbourhood by its fit of the quadric's
    second-order part, averaged over the point's neighbours), so that the fitted surface lies
    where the points do, on average, not inside convex parts. Then, visiting the points seen most head-on first (by their
    viewpoints), a point is dropped when a kept point lies within ``thin`` x its spacing in its
    own scan: where scans overlap about one layer remains, a single scan keeps all its points.
    With ``passes`` > 1 the last pass fits only the points that a first, narrower thinning
    (0.8 x the radius, on the positions the pass before it left) keeps; the thinning proper
    then runs among those.
    With ``strays``, the points of stray clusters (see :func:`stray_clusters`) are not kept
    either.
    With ``radii``, the kept points' coverage radii (:func:`coverage_radii`, on the fitted
    positions and normals) come from the same call: each kept point's :data:`COVER_K` nearest
    kept points are the nearest, re-ranked on the fitted positions, among the kept points of
    its fit neighbours (its :data:`FIT_MIN_SUPPORT` - 1 nearest points before the fit); a
    point with fewer kept points there searches among all the kept points. The fit moves
    points by a fraction of their spacing, so a kept point just outside the row can be nearer
    than the last one taken (on the dragon's scans and the sphere scans of
    benchmarks/bench_pipeline.py about 1 point in 25 takes one other neighbour than the
    search would): the radii stay within the search's spread and cover as well
    (tests/test_estimation.py, benchmarks/README.md).

    Parameters
    ----------
    points : (n, 3) array_like
        n >= 3, not all on one line.
    normals : (n, 3) array_like, optional
        Oriented normals; estimated (and oriented) when omitted.
    viewpoints : (3,) or (n, 3) array_like, optional
        Scanner positions: orient estimated normals, and rank points for thinning.
    scan_index : (n,) array_like of int, optional
        Which scan each point came from. Without it, points with the same viewpoint form one
        scan (or all points, without viewpoints).
    scan_grid : (n, 2) array_like of int, optional
        Each point's cell in its scan's sampling grid, for the normals' neighbours within
        scans (see :func:`estimate_normals`).
    up : (3,) array_like, optional
        Orientation tie-break (see :func:`orient_normals`).
    thin : float
        See above; 0 keeps every point.
    quadric : bool
    passes : int
        >= 1 (see :data:`FIT_PASSES`).
    robust_passes : int
        Reweightings of the last pass's fits, >= 0.
    strays : bool
        Drop stray clusters (default).
    radii : bool
        Also the kept points' coverage radii (see above).
    threads : int

    Returns
    -------
    SurfaceFit
    """
    pts = _points(points)
    n = len(pts)
    if n < 3:
        raise InputError(f"surface fit: needs at least 3 points, got {n}")
    _distinct(pts, "surface fit")
    nrm = None if normals is None else _normals(normals, n)
    vp = _viewpoints(viewpoints, n)
    group = _groups(scan_index, vp, n)
    if not (np.isfinite(thin) and 0.0 <= thin <= 2.0):
        raise InputError(f"thin: expected a number in [0, 2], got {thin!r}")
    out = _core("surface fit").fit_surface(
        pts, nrm, vp, group, _up(up), min(NORMAL_K_MIN, n), min(FIT_NORMAL_K_MAX, n),
        NORMAL_CONFIDENCE, _orient(), FIT_MIN_SUPPORT, bool(quadric), _count("passes", passes, 1),
        _count("robust_passes", robust_passes, 0),
        FIT_ROBUST_WIDTH, float(thin), bool(strays), _threads(threads),
        _grid(scan_grid, group, n) if nrm is None else None,
        COVER_K if radii else 0, COVER_DIRECTIONS, COVER_MARGIN, COVER_CAP, COVER_GLOBAL_CAP,
        normal_growth=FIT_NORMAL_GROWTH,
    )
    keep = out["keep"].view(bool)
    rad = out.get("radii")
    if rad is not None:
        bad = keep & ~(rad > 0)
        if bad.any():  # stacks of duplicates: as coverage_radii resolves them, among the kept
            kept = np.flatnonzero(keep)
            est = estimate_radii(out["points"][kept], threads=threads)
            rad[bad] = est[np.searchsorted(kept, np.flatnonzero(bad))]
    return SurfaceFit(points=out["points"], normals=out["normals"], keep=keep,
                      shift=out["shift"], unmoved=int(out["unmoved"]),
                      spacing=float(out["median_spacing"]),
                      radii=rad, radii_searched=int(out["radii_searched"]),
                      stray_points=int(out["stray_points"]),
                      stray_clusters=int(out["stray_clusters"]),
                      scan_neighbours={"grid": int(out["grid_neighbours"]),
                                       "view_grid": int(out["view_grid_neighbours"]),
                                       "tree": int(out["tree_neighbours"]),
                                       "across": int(out["across_neighbours"])})


@dataclass
class StrayClusters:
    """What :func:`stray_clusters` found.

    Attributes
    ----------
    stray : (n,) bool
        Points of stray clusters.
    label : (n,) int64
        Connected component of each point, numbered in the order of their first points.
    components : int
        Connected components.
    clusters : int
        Stray components.
    """

    stray: np.ndarray
    label: np.ndarray
    components: int
    clusters: int

    @property
    def points(self) -> int:
        return int(self.stray.sum())


def stray_clusters(points, *, scan_index=None, k: int = STRAY_K, threads: int = 0) -> StrayClusters:
    """Small pieces of a scan that are not part of the scanned object.

    Two points are linked when one is among the other's ``k`` nearest neighbours and their
    distance is at most a few times the smaller of their spacings (each point's nearest
    distinct neighbour in its own scan). A connected component is stray when it has fewer
    points than an absolute count or than a fraction of the cloud (the core's StrayOptions);
    the largest component never is. :func:`fit_surface` drops them by default.

    Parameters
    ----------
    points : (n, 3) array_like
        Finite positions, n >= 2.
    scan_index : (n,) array_like of int, optional
        Which scan each point came from (the spacing is measured within a point's scan).
    k : int
        Neighbours per point, >= 1; clamped to n - 1.
    threads : int
        Worker threads, 0 for all cores. Results do not depend on it.

    Returns
    -------
    StrayClusters
    """
    pts = _points(points, minimum=2)
    n = len(pts)
    group = None if scan_index is None else array_checks.per_point(
        "scan_index", scan_index, n, np.int32)
    out = _core("stray clusters").stray_clusters(pts, group, min(_count("k", k, 1), n - 1), threads=_threads(threads))
    return StrayClusters(stray=out["stray"].astype(bool), label=out["label"].astype(np.int64),
                         components=int(out["components"]), clusters=int(out["clusters"]))
