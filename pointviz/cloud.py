"""Point clouds as surfels: positions, normals, radii and optional colours.

:class:`PointCloud` validates and owns the arrays the renderer consumes. Normals and radii that
were not given are estimated lazily, on first access, from the ``k`` nearest neighbours of every
point (scipy's ``cKDTree``); normals are then oriented consistently, toward the scanner when the
viewpoints are known and by minimum-spanning-tree propagation otherwise.

Only numpy and scipy are needed here; Open3D and pyvista are imported inside the converters that
use them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .arrays import bounds
from .errors import InputError, require

# Neighbours used for the PCA normal of a point. 16 averages out the ~0.1 mm noise of raw
# triangulation scans (Stanford range scans) without rounding off features a few samples wide;
# fewer neighbours make normals of raw scans visibly noisy, many more blur creases.
NORMAL_K = 16

# Neighbours linked in the graph that propagates normal orientation (Hoppe et al. 1992 use a
# k-NN "Riemannian graph" with k ~ 8): enough to keep a sampled surface in one piece, few enough
# that the graph rarely jumps across thin parts (ears, fingers) to the other side.
ORIENT_K = 8

# Weight of the neighbour distance (in units of the median spacing) added to the Hoppe edge cost
# 1 - |n_i . n_j|. On flat parts that cost is ~0 for every edge, so without the distance term the
# tree may pick a long edge through a thin part; with it, short edges win ties.
ORIENT_DISTANCE_WEIGHT = 0.1

# A component of the neighbour graph whose normals point outward (away from its centroid) for a
# fraction in [0.5 - m, 0.5 + m] is "undecided" (typically an open, flat patch such as terrain);
# if an ``up`` hint is known such a component is oriented to face up instead.
OUTWARD_UNDECIDED_MARGIN = 0.1

# The radius of a point comes from the distance to its RADIUS_K-th nearest neighbour (not counting
# itself). The 8th neighbour reaches past the first ring of neighbours on a surface (6 on a
# hexagonal sampling, 8 on a square grid), so one point's radius does not collapse when a single
# neighbour happens to lie very close.
RADIUS_K = 8

# r_i = RADIUS_FACTOR * d_8(i). Measured with rays against a dense probe set (tests/test_cloud.py):
# the smallest factor that leaves no hole is 0.49 on a Fibonacci sphere (d_8 ~ 1.6 x NN spacing
# there), 0.53 on a grid jittered by +-0.25 spacing, 0.50 on an anisotropic 1:2 grid like a range
# scan's and 0.64 for +-0.4 jitter. 0.65 covers all of these, with a margin of >= 1.2x on the first
# three, while the mean radius stays 1.05x the mean nearest-neighbour spacing on the sphere and
# 1.36x on the +-0.25 jittered grid (jitter shortens the nearest-neighbour distance).
RADIUS_FACTOR = 0.65

# Largest extent of a cloud: surfels are stored in float32 relative to the cloud's centre, and
# squared distances (normal and radius estimation) must stay finite in float64.
MAX_EXTENT = 1e30

# Points per block when querying neighbours, to bound memory (~NORMAL_K * 3 * 8 bytes per point).
_BLOCK = 65536


# ---------------------------------------------------------------------------------------------
# validation helpers


def _numeric(name: str, value, *, allow_int: bool = True) -> np.ndarray:
    """``np.asarray(value)`` checked to be a real numeric array (not bool/object/complex/str)."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be converted to an array ({exc})") from None
    kinds = "iuf" if allow_int else "f"
    if arr.dtype.kind not in kinds:
        raise InputError(f"{name}: expected a real numeric array, got dtype {arr.dtype}")
    return arr


def _check_finite(name: str, arr: np.ndarray) -> None:
    """Raise :class:`InputError` naming the rows of ``arr`` that contain NaN or inf."""
    if arr.dtype.kind != "f":
        return
    finite = np.isfinite(arr)
    if finite.all():
        return
    bad = ~finite if arr.ndim == 1 else ~finite.all(axis=1)
    rows = np.flatnonzero(bad)
    what = "rows contain" if arr.ndim > 1 else "values are"
    raise InputError(f"{name}: {rows.size} {what} NaN or inf (first at row {rows[0]})")


def _rows3(name: str, value, n: int | None) -> np.ndarray:
    """Validate an (n, 3) real array; return it as float64 (not yet copied)."""
    arr = _numeric(name, value)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name}: expected shape (n, 3), got {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise InputError(f"{name}: has {arr.shape[0]} rows but points has {n}")
    _check_finite(name, arr)
    return arr


def _unit_vector(name: str, value) -> np.ndarray:
    arr = _numeric(name, value)
    if arr.shape != (3,):
        raise InputError(f"{name}: expected shape (3,), got {arr.shape}")
    _check_finite(name, arr)
    norm = float(np.linalg.norm(arr))
    if norm == 0.0:
        raise InputError(f"{name}: must not be the zero vector")
    return np.ascontiguousarray(arr / norm, dtype=np.float64)


def _validate_normals(value, n: int) -> np.ndarray:
    arr = _rows3("normals", value, n).astype(np.float64)
    length = np.linalg.norm(arr, axis=1)
    zero = np.flatnonzero(length == 0.0)
    if zero.size:
        raise InputError(
            f"normals: {zero.size} rows have zero length (first at row {zero[0]}); "
            "give a direction for every point or leave normals out to estimate them"
        )
    return np.ascontiguousarray(arr / length[:, None], dtype=np.float32)


def _validate_radii(value, n: int) -> np.ndarray:
    arr = _numeric("radii", value)
    if arr.ndim == 0:
        arr = np.full(n, arr, dtype=np.float64)
    if arr.shape != (n,):
        raise InputError(f"radii: expected shape ({n},) or a scalar, got {arr.shape}")
    _check_finite("radii", arr)
    bad = np.flatnonzero(~(arr > 0))
    if bad.size:
        raise InputError(
            f"radii: {bad.size} values are zero or negative (first at row {bad[0]}: {arr[bad[0]]})"
        )
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(arr, dtype=np.float32)
    if not (out > 0).all():  # positive float64 values that underflow float32
        raise InputError("radii: values too small for float32 (underflow to 0)")
    if not np.isfinite(out).all():
        bad = np.flatnonzero(~np.isfinite(out))
        raise InputError(f"radii: {bad.size} values overflow float32 (first at row {bad[0]}: {arr[bad[0]]})")
    return out


def _validate_colors(value, n: int) -> np.ndarray:
    arr = _numeric("colors", value)
    if arr.ndim != 2 or arr.shape[1] not in (3, 4):
        raise InputError(f"colors: expected shape (n, 3), got {arr.shape}")
    if arr.shape[0] != n:
        raise InputError(f"colors: has {arr.shape[0]} rows but points has {n}")
    arr = arr[:, :3]  # RGBA: alpha is dropped, surfels are opaque
    if arr.dtype.kind in "iu":
        lo, hi = (int(arr.min()), int(arr.max())) if arr.size else (0, 0)
        if arr.dtype == np.uint16:
            scale = 65535.0
        elif lo >= 0 and hi <= 255:
            scale = 255.0
        else:
            raise InputError(
                f"colors: integer colours must be 8-bit (0..255) or uint16, got range {lo}..{hi}"
            )
        return np.ascontiguousarray(arr / scale, dtype=np.float32)
    _check_finite("colors", arr)
    outside = np.flatnonzero(((arr < 0) | (arr > 1)).any(axis=1))
    if outside.size:
        raise InputError(
            f"colors: {outside.size} rows are outside [0, 1] (first at row {outside[0]}); "
            "float colours must be in [0, 1], integer ones 0..255"
        )
    return np.ascontiguousarray(arr, dtype=np.float32)


def _validate_viewpoints(value, n: int) -> np.ndarray:
    arr = _numeric("viewpoints", value)
    if arr.shape == (3,):
        _check_finite("viewpoints", arr)
        return np.ascontiguousarray(arr, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] != n:
        raise InputError(f"viewpoints: expected shape (3,) or ({n}, 3), got {arr.shape}")
    _check_finite("viewpoints", arr)
    return np.ascontiguousarray(arr, dtype=np.float64)


def _validate_per_point(name: str, value, n: int, dtype) -> np.ndarray:
    arr = _numeric(name, value)
    if arr.shape != (n,):
        raise InputError(f"{name}: expected shape ({n},), got {arr.shape}")
    _check_finite(name, arr)
    return np.ascontiguousarray(arr, dtype=dtype)


# ---------------------------------------------------------------------------------------------
# estimation


def _knn(points: np.ndarray, k: int, tree=None):
    """Distances and indices of the ``k`` nearest neighbours of every point, itself excluded.

    Returns
    -------
    dist : (n, k) float64
    idx : (n, k) int64
    """
    from scipy.spatial import cKDTree

    if tree is None:
        tree = cKDTree(points)
    dist, idx = tree.query(points, k=k + 1, workers=-1)
    # a point is its own nearest neighbour except among exact duplicates, where any duplicate
    # may come first; dropping column 0 drops a zero distance either way
    return dist[:, 1:], idx[:, 1:]


def estimate_normals(
    points: np.ndarray,
    *,
    k: int = NORMAL_K,
    viewpoints: np.ndarray | None = None,
    up: np.ndarray | None = None,
) -> np.ndarray:
    """PCA normals over the ``k`` nearest neighbours, consistently oriented.

    Parameters
    ----------
    points : (n, 3) float64
        Positions, n >= 3.
    k : int
        Neighbours per point (itself included), clamped to n.
    viewpoints : (3,) or (n, 3) float64, optional
        Scanner position(s): each normal is flipped to face its viewpoint.
    up : (3,) float64, optional
        Tie-break for open, flat components without viewpoints (see :func:`orient_normals`).

    Returns
    -------
    normals : (n, 3) float32
        Unit normals.
    """
    from scipy.spatial import cKDTree

    n = len(points)
    if n < 3:
        raise InputError(
            f"normals: cannot be estimated from {n} point(s), need at least 3; pass normals"
        )
    k = min(k, n)
    tree = cKDTree(points)
    normals = np.empty((n, 3), dtype=np.float64)
    graph_k = min(ORIENT_K, n - 1)
    nb_idx = np.empty((n, graph_k), dtype=np.int64) if viewpoints is None else None
    nb_dist = np.empty((n, graph_k), dtype=np.float64) if viewpoints is None else None
    for start in range(0, n, _BLOCK):
        stop = min(start + _BLOCK, n)
        dist, idx = tree.query(points[start:stop], k=k, workers=-1)
        nb = points[idx]  # (b, k, 3) float64
        nb -= nb.mean(axis=1, keepdims=True)  # centre first: coordinates may be ~1e6
        cov = np.einsum("bki,bkj->bij", nb, nb)
        _, vecs = np.linalg.eigh(cov)  # ascending eigenvalues
        normals[start:stop] = vecs[:, :, 0]
        if nb_idx is not None:
            # column 0 is (normally) the point itself; keep the next graph_k neighbours
            nb_idx[start:stop] = idx[:, 1 : graph_k + 1]
            nb_dist[start:stop] = dist[:, 1 : graph_k + 1]
    if viewpoints is not None:
        to_view = np.asarray(viewpoints, dtype=np.float64) - points
        flip = np.einsum("ij,ij->i", normals, to_view) < 0
        normals[flip] *= -1
    else:
        normals = orient_normals(points, normals, nb_idx, nb_dist, up=up)
    return np.ascontiguousarray(normals, dtype=np.float32)


def orient_normals(
    points: np.ndarray,
    normals: np.ndarray,
    nb_idx: np.ndarray,
    nb_dist: np.ndarray,
    *,
    up: np.ndarray | None = None,
) -> np.ndarray:
    """Flip normals so that neighbours agree, then point each connected part outward.

    Signs propagate along a minimum spanning tree of the neighbour graph with edge cost
    ``1 - |n_i . n_j| + ORIENT_DISTANCE_WEIGHT * d_ij / median(d)`` (Hoppe et al. 1992). Each
    connected component then gets the global sign under which most of its normals point away
    from its centroid; when that vote is undecided (an open, flat patch) and ``up`` is given,
    the component faces ``up`` instead.

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float
        Unoriented unit normals.
    nb_idx : (n, m) int
        Neighbour indices per point (itself excluded).
    nb_dist : (n, m) float
        Matching distances.
    up : (3,) float, optional

    Returns
    -------
    normals : (n, 3) float64
        The same directions, flipped where needed.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import (
        breadth_first_order,
        connected_components,
        minimum_spanning_tree,
    )

    n = len(points)
    normals = np.asarray(normals, dtype=np.float64).copy()
    rows = np.repeat(np.arange(n), nb_idx.shape[1])
    cols = nb_idx.ravel()
    keep = rows != cols
    rows, cols = rows[keep], cols[keep]
    dist = nb_dist.ravel()[keep]
    scale = np.median(dist[dist > 0]) if np.any(dist > 0) else 1.0
    dots = np.abs(np.einsum("ij,ij->i", normals[rows], normals[cols]))
    # the constant keeps every weight > 0: scipy's sparse graphs drop explicit zeros
    weight = (1.0 - dots) + ORIENT_DISTANCE_WEIGHT * dist / scale + 1e-9
    graph = coo_matrix((weight, (rows, cols)), shape=(n, n)).tocsr()
    tree = minimum_spanning_tree(graph)
    tree = (tree + tree.T).tocoo()
    ncomp, label = connected_components(tree, directed=False)
    # one BFS from a virtual root n linked to a representative of every component
    reps = np.unique(label, return_index=True)[1]
    r = np.concatenate([tree.row, np.full(ncomp, n), reps])
    c = np.concatenate([tree.col, reps, np.full(ncomp, n)])
    full = coo_matrix((np.ones(r.size), (r, c)), shape=(n + 1, n + 1)).tocsr()
    _, pred = breadth_first_order(full, n, directed=False, return_predecessors=True)
    pred = pred[:n].astype(np.int64)
    is_root = pred == n
    parent = np.where(is_root, np.arange(n), pred)
    # sign relative to the parent, then the product along the path to the root by pointer jumping
    rel = np.where(np.einsum("ij,ij->i", normals, normals[parent]) < 0, -1.0, 1.0)
    rel[is_root] = 1.0
    sign, jump = rel, parent
    # invariant: sign[i] is the product of rel along the path from i up to (excluding) jump[i];
    # roots are fixed points with sign 1, so once every jump[i] is a root we are done
    while True:
        up_two = jump[jump]
        if np.array_equal(up_two, jump):
            break
        sign = sign * sign[jump]
        jump = up_two
    normals *= sign[:, None]

    # global sign per component: majority outward from the component's centroid
    counts = np.bincount(label, minlength=ncomp)
    centroid = (
        np.stack(
            [np.bincount(label, weights=points[:, j], minlength=ncomp) for j in range(3)], axis=1
        )
        / counts[:, None]
    )
    small = counts < ORIENT_K  # a few stray points: their own centroid says nothing
    centroid[small] = points.mean(axis=0)
    outward = np.einsum("ij,ij->i", normals, points - centroid[label])
    votes = np.bincount(label, weights=(outward > 0).astype(float), minlength=ncomp)
    decided = np.bincount(label, weights=(outward != 0).astype(float), minlength=ncomp)
    frac = np.divide(votes, decided, out=np.full(ncomp, 0.5), where=decided > 0)
    flip = frac < 0.5
    if up is not None:
        undecided = np.abs(frac - 0.5) <= OUTWARD_UNDECIDED_MARGIN
        facing = np.bincount(label, weights=(normals @ up > 0).astype(float), minlength=ncomp)
        flip = np.where(undecided, facing < counts / 2, flip)
    normals[flip[label]] *= -1
    return normals


def estimate_radii(points: np.ndarray, *, k: int = RADIUS_K, factor: float = RADIUS_FACTOR):
    """Surfel radii from local spacing: ``r_i = factor * d_k(i)``.

    Parameters
    ----------
    points : (n, 3) float64
    k : int
        Which neighbour's distance measures the spacing (itself not counted), clamped to n - 1.
    factor : float
        See :data:`RADIUS_FACTOR` for how it was chosen.

    Returns
    -------
    radii : (n,) float32
        Positive radii. Duplicated points get the radius their position has in the cloud
        without duplicates (so stacks of coincident points never give d_k = 0).
    """
    n = len(points)
    if n < 2:
        raise InputError("radii: cannot be estimated from a single point; pass radii")
    dk = _knn(points, min(k, n - 1))[0][:, -1]
    if not np.all(dk > 0):
        # stacks of duplicates: measure the spacing among distinct positions, so duplicates get
        # the radius of the position they share (a positive floor from the local spacing)
        uniq, inverse = np.unique(points, axis=0, return_inverse=True)
        if len(uniq) == 1:
            raise InputError(f"radii: cannot be estimated, all {n} points coincide; pass radii")
        dk = _knn(uniq, min(k, len(uniq) - 1))[0][:, -1][inverse.reshape(-1)]
    out = (factor * dk).astype(np.float32)
    # float32 rounding must not produce 0 for tiny (but positive) spacings
    return np.maximum(out, np.finfo(np.float32).tiny)


# The coverage radius of a point is the radius of its Voronoi cell in its tangent plane: the
# farthest point of the surface that is closer to it than to any other sample. Disks of that
# radius cover the surface exactly (Voronoi cells tile it); a margin adds the overlap that the
# interpolation blends over and absorbs curvature and the sampled directions' underestimate.
COVER_K = 10
# Directions sampled around each point when measuring its Voronoi cell (underestimates the
# cell's radius by at most 1 - cos(pi / 16), 2%).
COVER_DIRECTIONS = 16
# Margin over the Voronoi radius: measured hole-free on Poisson-disk, uniform random, jittered
# and anisotropic samplings and on the Fibonacci sphere (tests/test_cloud.py).
COVER_MARGIN = 1.2
# Cap in units of the COVER_K-th neighbour distance: an open boundary has no bisector on its
# outer side, and a near-tangent one would put the cell's far end at a huge distance.
COVER_CAP = 1.0
# Global cap in units of the cloud's 99th-percentile radius: a small stray cluster (a few
# points off the surface, common in raw scans) has no neighbours around it, and its cell would
# reach out to the distant surface: disks a hundred times the typical size (seen on the dragon
# scans). Surfaces sampled over 4x more sparsely than the sparsest percent of the cloud get
# small holes instead.
COVER_GLOBAL_CAP = 4.0


def coverage_radii(points: np.ndarray, normals: np.ndarray, *, k: int = COVER_K,
                   margin: float = COVER_MARGIN, cap: float = COVER_CAP, tree=None) -> np.ndarray:
    """Per-point radii just large enough to cover the surface: margin x the Voronoi-cell radius.

    For each point, its ``k`` nearest neighbours are projected on its tangent plane; along each
    of COVER_DIRECTIONS directions the cell ends at the nearest perpendicular bisector. The
    cell's radius is the largest such distance over the directions that have a bisector
    (directions without one face an open boundary, which needs no cover beyond the samples).

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float unit normals

    Returns
    -------
    radii : (n,) float32, positive
    """
    n = len(points)
    if n < 2:
        raise InputError("radii: cannot be estimated from a single point; pass radii")
    k = min(k, n - 1)
    dist, idx = _knn(points, k, tree)
    ang = np.linspace(0.0, 2 * np.pi, COVER_DIRECTIONS, endpoint=False)
    out = np.empty(n, np.float32)
    block = 16384
    for b0 in range(0, n, block):
        b1 = min(n, b0 + block)
        nn = np.asarray(normals[b0:b1], dtype=np.float64)
        q = points[idx[b0:b1]] - points[b0:b1, None, :]             # (m, k, 3)
        # tangent basis (t1, t2) per point
        helper = np.where(np.abs(nn[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        t1 = np.cross(nn, helper)
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
        t2 = np.cross(nn, t1)
        x = np.einsum("mkj,mj->mk", q, t1).astype(np.float32)
        y = np.einsum("mkj,mj->mk", q, t2).astype(np.float32)
        r2 = x * x + y * y                                           # (m, k)
        proj = x[:, :, None] * np.cos(ang, dtype=np.float32) + y[:, :, None] * np.sin(ang, dtype=np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(proj > 1e-12 * np.sqrt(r2[:, :, None]) + 0.0, r2[:, :, None] / (2 * proj), np.inf)
        s[~(r2[:, :, None] > 0) | np.isnan(s)] = np.inf
        edge = s.min(axis=1)                                         # (m, D)
        finite = np.isfinite(edge)
        cell = np.where(finite, edge, 0.0).max(axis=1)
        dk = dist[b0:b1, -1]
        r = np.minimum(margin * cell, cap * dk)
        # isolated or degenerate (no bisector anywhere): half the nearest-neighbour distance
        fallback = ~(r > 0)
        if fallback.any():
            d1 = dist[b0:b1, 0]
            r[fallback] = np.maximum(0.5 * d1[fallback], cap * dk[fallback])
        out[b0:b1] = r
    bad = ~(out > 0)
    if bad.any():  # stacks of duplicates: the spacing-based estimate knows how to handle them
        out[bad] = estimate_radii(points)[bad]
    if n >= 100:  # too few points for a meaningful percentile below that
        np.minimum(out, np.float32(COVER_GLOBAL_CAP * np.quantile(out, 0.99)), out=out)
    return out


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals of a triangle mesh (follows the face winding).

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int

    Returns
    -------
    normals : (v, 3) float64
        Unit normals; rows of vertices not used by any (non-degenerate) face are zero.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # |cross| = 2 * area
    acc = np.zeros_like(v)
    for j in range(3):
        np.add.at(acc, f[:, j], cross)
    length = np.linalg.norm(acc, axis=1)
    return np.divide(acc, length[:, None], out=np.zeros_like(acc), where=length[:, None] > 0)


def _check_faces(faces, nverts: int) -> np.ndarray:
    arr = _numeric("faces", faces)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"faces: expected shape (f, 3) of triangle indices, got {arr.shape}")
    if arr.dtype.kind == "f" and not (np.all(np.isfinite(arr)) and np.all(arr == np.round(arr))):
        raise InputError("faces: expected integer vertex indices")
    arr = arr.astype(np.int64)
    if arr.size and (arr.min() < 0 or arr.max() >= nverts):
        raise InputError(f"faces: indices must be in 0..{nverts - 1}, got {arr.min()}..{arr.max()}")
    return arr


def _rng(rng) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(rng)


# ---------------------------------------------------------------------------------------------


class PointCloud:
    """A surfel cloud: positions, normals, radii, optional colours.

    Parameters
    ----------
    points : (n, 3) array_like
        Positions, any real dtype; stored as C-contiguous float64 (georeferenced scans sit at
        1e6..1e7, where float32 keeps only decimetres).
    normals : (n, 3) array_like, optional
        Normals; normalised. Zero rows are an error. If omitted they are estimated on first
        access (PCA over :data:`NORMAL_K` neighbours, consistently oriented) and cached.
    radii : (n,) array_like or scalar, optional
        Disk radii > 0. If omitted they are estimated on first access from the local spacing
        (``RADIUS_FACTOR * d_k`` with ``k = RADIUS_K``) and cached.
    colors : (n, 3) array_like, optional
        sRGB colours: floats in [0, 1] or 8-bit integers 0..255 (uint16 is scaled by 65535).
        An RGBA array's alpha is dropped. Stored as float32 in [0, 1].
    up : (3,) array_like, optional
        "Up" hint (normalised), e.g. +Z for airborne LiDAR, +Y for the Stanford models.
    name : str, optional
        A label, e.g. the file name.
    viewpoints : (3,) or (n, 3) array_like, optional
        Scanner position(s); estimated normals are oriented toward them.
    intensity : (n,) array_like, optional
        Per-point return intensity (LiDAR), stored as float32.
    scan_index : (n,) array_like of int, optional
        Which scan each point came from (registered range scans), stored as int32.
    notes : list of str, optional
        Human-readable remarks from loading (e.g. how many non-finite points were dropped).

    Raises
    ------
    InputError
        If an array has the wrong shape or dtype, contains NaN/inf, a normal has zero length, a
        radius is <= 0, a colour is outside [0, 1], the lengths differ, or the cloud is empty.
    """

    def __init__(
        self,
        points,
        normals=None,
        radii=None,
        colors=None,
        *,
        up=None,
        name=None,
        viewpoints=None,
        intensity=None,
        scan_index=None,
        notes: Sequence[str] | None = None,
    ):
        pts = _rows3("points", points, None)
        n = pts.shape[0]
        if n == 0:
            raise InputError("points: the cloud is empty (0 points)")
        self._points = np.ascontiguousarray(pts, dtype=np.float64)
        lo, hi = bounds(self._points)
        extent = float(np.max(hi - lo))
        if not extent <= MAX_EXTENT:
            raise InputError(
                f"points: the cloud spans {extent:.3g} units, beyond what float32 surfels can "
                f"resolve (limit {MAX_EXTENT:.0e}); check for corrupt or mis-scaled coordinates")
        self._points.setflags(write=False)
        self._normals = None if normals is None else _validate_normals(normals, n)
        self._normals_given = normals is not None
        self._radii = None if radii is None else _validate_radii(radii, n)
        self._radii_given = radii is not None
        self._colors = None if colors is None else _validate_colors(colors, n)
        self.up = None if up is None else _unit_vector("up", up)
        if name is not None and not isinstance(name, str):
            raise InputError(f"name: expected a str, got {type(name).__name__}")
        self.name = name
        self.viewpoints = None if viewpoints is None else _validate_viewpoints(viewpoints, n)
        self.intensity = (
            None
            if intensity is None
            else _validate_per_point("intensity", intensity, n, np.float32)
        )
        if scan_index is not None:
            si = _numeric("scan_index", scan_index)
            if si.dtype.kind not in "iu":
                raise InputError(f"scan_index: expected integers, got dtype {si.dtype}")
            scan_index = _validate_per_point("scan_index", si, n, np.int32)
        self.scan_index = scan_index
        self.notes: list[str] = list(notes) if notes is not None else []
        for arr in (self._normals, self._radii, self._colors):
            if arr is not None:
                arr.setflags(write=False)

    # -- attributes ---------------------------------------------------------------------------

    @property
    def points(self) -> np.ndarray:
        """(n, 3) float64, C-contiguous, read-only positions."""
        return self._points

    @property
    def normals(self) -> np.ndarray:
        """(n, 3) float32 unit normals; estimated (and cached) on first access if not given."""
        if self._normals is None:
            est = estimate_normals(self._points, viewpoints=self.viewpoints, up=self.up)
            est.setflags(write=False)
            self._normals = est
        return self._normals

    @property
    def radii(self) -> np.ndarray:
        """(n,) float32 disk radii > 0; estimated (and cached) on first access if not given."""
        if self._radii is None:
            if len(self._points) < 2 or not np.ptp(self._points, axis=0).any():
                est = estimate_radii(self._points)  # raises the specific error
            else:
                est = coverage_radii(self._points, self.normals)
            est.setflags(write=False)
            self._radii = est
        return self._radii

    @property
    def colors(self) -> np.ndarray | None:
        """(n, 3) float32 sRGB colours in [0, 1], or None."""
        return self._colors

    @property
    def has_normals(self) -> bool:
        """Whether normals were given or loaded (False when they are, or would be, estimated)."""
        return self._normals_given

    @property
    def has_radii(self) -> bool:
        """Whether radii were given or loaded (False when they are, or would be, estimated)."""
        return self._radii_given

    @property
    def has_colors(self) -> bool:
        """Whether the cloud has colours."""
        return self._colors is not None

    def __len__(self) -> int:
        return self._points.shape[0]

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi)``: (3,) float64 corners of the axis-aligned bounding box of the points."""
        return bounds(self._points)

    @property
    def center(self) -> np.ndarray:
        """(3,) float64 centre of the bounding box."""
        lo, hi = self.bounds
        return (lo + hi) / 2

    @property
    def diagonal(self) -> float:
        """Length of the bounding box diagonal."""
        lo, hi = self.bounds
        return float(np.linalg.norm(hi - lo))

    def __repr__(self) -> str:
        parts = [f"{len(self)} points"]
        parts.append("normals" if self.has_normals else "normals estimated lazily")
        if self.has_colors:
            parts.append("colors")
        if self.name:
            parts.insert(0, repr(self.name))
        return f"PointCloud({', '.join(parts)})"

    # -- derived clouds -----------------------------------------------------------------------

    def _derive(self, points, normals, normals_given, radii, radii_given, colors, **extra):
        out = PointCloud.__new__(PointCloud)
        out._points = np.ascontiguousarray(points, dtype=np.float64)
        out._points.setflags(write=False)
        out._normals, out._normals_given = normals, normals_given
        out._radii, out._radii_given = radii, radii_given
        out._colors = colors
        for arr in (out._normals, out._radii, out._colors):
            if arr is not None:
                arr.setflags(write=False)
        out.up = extra.get("up", self.up)
        out.name = self.name
        out.viewpoints = extra.get("viewpoints")
        out.intensity = extra.get("intensity")
        out.scan_index = extra.get("scan_index")
        out.notes = list(self.notes)
        return out

    def subset(self, index_or_mask) -> PointCloud:
        """A new cloud with the selected points and every per-point attribute that is present.

        Parameters
        ----------
        index_or_mask : (n,) bool array, integer index array or slice
            Which points to keep (order and repeats of an index array are kept).

        Returns
        -------
        PointCloud
            Given normals/radii/colours, intensity, scan_index and per-point viewpoints are
            carried over. Normals already estimated are carried over too (orientation is local);
            estimated radii are not, since they depend on the density of the subset.
        """
        sel = index_or_mask
        if not isinstance(sel, slice):
            sel = np.asarray(sel)
            if sel.dtype == bool:
                if sel.shape != (len(self),):
                    raise InputError(
                        f"index_or_mask: boolean mask must have shape ({len(self)},), "
                        f"got {sel.shape}"
                    )
            elif sel.dtype.kind in "iu":
                if sel.ndim != 1:
                    raise InputError(f"index_or_mask: expected a 1-d index, got shape {sel.shape}")
                if sel.size and (sel.min() < -len(self) or sel.max() >= len(self)):
                    raise InputError(
                        f"index_or_mask: indices must be in -{len(self)}..{len(self) - 1}"
                    )
            else:
                raise InputError(
                    f"index_or_mask: expected a boolean mask or integer indices, got {sel.dtype}"
                )
        pts = self._points[sel]
        if len(pts) == 0:
            raise InputError("index_or_mask: selects no points (the cloud would be empty)")

        def take(a):
            return None if a is None else np.ascontiguousarray(a[sel])

        vp = self.viewpoints
        if vp is not None and vp.ndim == 2:
            vp = take(vp)
        return self._derive(
            pts,
            take(self._normals),
            self._normals_given,
            take(self._radii) if self._radii_given else None,
            self._radii_given,
            take(self._colors),
            viewpoints=vp,
            intensity=take(self.intensity),
            scan_index=take(self.scan_index),
        )

    def transformed(self, matrix) -> PointCloud:
        """A copy moved by an affine 4x4 matrix (column vectors: ``p' = M @ [p, 1]``).

        Normals use the inverse transpose of the linear part (so they stay perpendicular to the
        surface, and outward under reflections too); radii are scaled by ``|det A|^(1/3)``
        (exact for rotations and uniform scales); viewpoints move like points, ``up`` like a
        direction.

        Parameters
        ----------
        matrix : (4, 4) array_like
            Affine transform; the last row must be ``[0, 0, 0, 1]``.

        Returns
        -------
        PointCloud
        """
        m = _numeric("matrix", matrix).astype(np.float64)
        if m.shape != (4, 4):
            raise InputError(f"matrix: expected shape (4, 4), got {m.shape}")
        if not np.all(np.isfinite(m)):
            raise InputError("matrix: contains NaN or inf")
        if not np.allclose(m[3], [0, 0, 0, 1]):
            raise InputError(f"matrix: last row must be [0, 0, 0, 1] (affine), got {m[3]}")
        a, t = m[:3, :3], m[:3, 3]
        det = float(np.linalg.det(a))
        if abs(det) < 1e-300:
            raise InputError("matrix: the linear part is singular")
        pts = self._points @ a.T + t
        normals = None
        if self._normals is not None:
            nt = self._normals.astype(np.float64) @ np.linalg.inv(a)  # (A^-T n) as rows
            nt /= np.linalg.norm(nt, axis=1, keepdims=True)
            normals = nt.astype(np.float32)
        radii = None
        if self._radii is not None:
            radii = np.maximum(
                (self._radii * abs(det) ** (1.0 / 3.0)).astype(np.float32),
                np.finfo(np.float32).tiny,
            )
        up = None
        if self.up is not None:
            u = a @ self.up
            up = u / np.linalg.norm(u)
        vp = None if self.viewpoints is None else self.viewpoints @ a.T + t
        return self._derive(
            pts,
            normals,
            self._normals_given,
            radii,
            self._radii_given,
            None if self._colors is None else self._colors.copy(),
            up=up,
            viewpoints=vp,
            intensity=None if self.intensity is None else self.intensity.copy(),
            scan_index=None if self.scan_index is None else self.scan_index.copy(),
        )

    # -- conversions --------------------------------------------------------------------------

    @classmethod
    def from_mesh(cls, vertices, faces, sample=None, rng=None, **kw) -> PointCloud:
        """Surfels from a triangle mesh.

        Parameters
        ----------
        vertices : (v, 3) array_like
        faces : (f, 3) array_like of int
        sample : int, optional
            If given, draw this many points uniformly (by area) on the surface, each with the
            normal of its face. Otherwise use the vertices, with area-weighted normals from the
            faces; a vertex no face uses takes the normal of the nearest vertex one does (and
            ``notes`` says how many did).
        rng : numpy.random.Generator or int, optional
            Randomness for ``sample``.
        **kw
            Passed on to :class:`PointCloud` (``colors`` for the vertices, ``up``, ``name``...).

        Returns
        -------
        PointCloud
            Normals follow the face winding (counter-clockwise seen from outside = outward).
        """
        v = _rows3("vertices", vertices, None).astype(np.float64)
        f = _check_faces(faces, len(v))
        if len(f) == 0:
            raise InputError("faces: the mesh has no faces")
        if sample is not None:
            if isinstance(sample, bool) or not isinstance(sample, (int, np.integer)) or sample < 1:
                raise InputError(f"sample: expected a positive integer, got {sample!r}")
            kw.pop("colors", None)  # vertex colours do not apply to sampled points
            a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
            cross = np.cross(b - a, c - a)
            area2 = np.linalg.norm(cross, axis=1)
            if not np.any(area2 > 0):
                raise InputError("faces: every face is degenerate (zero area)")
            gen = _rng(rng)
            face = gen.choice(len(f), size=int(sample), p=area2 / area2.sum())
            u, w = gen.random(int(sample)), gen.random(int(sample))
            su = np.sqrt(u)
            pts = (
                (1 - su)[:, None] * a[face]
                + (su * (1 - w))[:, None] * b[face]
                + (su * w)[:, None] * c[face]
            )
            nrm = cross[face] / area2[face][:, None]
            return cls(pts, nrm, **kw)
        nrm = vertex_normals(v, f)
        ok = np.linalg.norm(nrm, axis=1) > 0
        notes = list(kw.pop("notes", None) or [])
        colors = kw.pop("colors", None)
        if not ok.any():
            raise InputError("faces: every face is degenerate (zero area)")
        if not ok.all():
            # loose vertices (e.g. left over from zippering scans) lie on the surface too:
            # they borrow the normal of the nearest vertex that a face uses
            from scipy.spatial import cKDTree

            used = np.flatnonzero(ok)
            _, near = cKDTree(v[used]).query(v[~ok], workers=-1)
            nrm[~ok] = nrm[used[near]]
            notes.append(
                f"{int((~ok).sum())} of {len(v)} vertices are in no (non-degenerate) face: "
                "they took the normal of the nearest vertex that is"
            )
        return cls(v, nrm, colors=colors, notes=notes, **kw)

    @classmethod
    def from_open3d(cls, geometry, **kw) -> PointCloud:
        """From an ``open3d.geometry.PointCloud`` or ``TriangleMesh`` (its vertices).

        Normals and colours are kept when present; a mesh without vertex normals gets them from
        its triangles. ``**kw`` is passed on to :class:`PointCloud`.
        """
        o3d = require("open3d", "io")
        if isinstance(geometry, o3d.geometry.PointCloud):
            pts = np.asarray(geometry.points)
            normals = np.asarray(geometry.normals) if geometry.has_normals() else None
            colors = np.asarray(geometry.colors) if geometry.has_colors() else None
            return cls(pts, normals, colors=colors, **kw)
        if isinstance(geometry, o3d.geometry.TriangleMesh):
            v = np.asarray(geometry.vertices)
            colors = np.asarray(geometry.vertex_colors) if geometry.has_vertex_colors() else None
            if geometry.has_vertex_normals():
                return cls(v, np.asarray(geometry.vertex_normals), colors=colors, **kw)
            if geometry.has_triangles():
                return cls.from_mesh(v, np.asarray(geometry.triangles), colors=colors, **kw)
            return cls(v, colors=colors, **kw)
        raise InputError(
            "geometry: expected an open3d.geometry.PointCloud or TriangleMesh, got "
            f"{type(geometry).__name__}"
        )

    @classmethod
    def from_pyvista(cls, dataset, sample=None, rng=None, **kw) -> PointCloud:
        """From a ``pyvista`` dataset (PolyData or any other point set).

        Point-data normals (``Normals`` / active normals) and colours (``RGB``, ``RGBA``,
        ``Colors``, ``colors``) are used when present; polygonal faces give normals otherwise
        and allow ``sample=N``. ``**kw`` is passed on to :class:`PointCloud`.
        """
        pv = require("pyvista", "io")
        if not isinstance(dataset, pv.DataSet):
            raise InputError(f"dataset: expected a pyvista DataSet, got {type(dataset).__name__}")
        pts = np.asarray(dataset.points, dtype=np.float64)
        pdata = dataset.point_data
        normals = None
        for key in ("Normals", "normals", "Normal"):
            if key in pdata and np.asarray(pdata[key]).shape == pts.shape:
                normals = np.asarray(pdata[key])
                break
        colors = None
        for key in ("RGB", "RGBA", "Colors", "colors", "rgb", "rgba"):
            if key in pdata:
                arr = np.asarray(pdata[key])
                if arr.ndim == 2 and arr.shape[1] in (3, 4):
                    colors = arr
                    break
        faces = None
        if isinstance(dataset, pv.PolyData) and dataset.faces.size > 0:
            tri = dataset.triangulate()
            # the polygons of a triangulated PolyData are stored as [3, a, b, c, 3, ...]
            faces = np.asarray(tri.faces).reshape(-1, 4)[:, 1:]
        if faces is not None and (sample is not None or normals is None):
            return cls.from_mesh(pts, faces, sample=sample, rng=rng, colors=colors, **kw)
        return cls(pts, normals, colors=colors, **kw)

    def to_open3d(self, *, normals: bool = True):
        """An ``open3d.geometry.PointCloud`` with points, normals (estimated if needed unless
        ``normals=False``) and colours."""
        o3d = require("open3d", "io")
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(self._points)))
        if normals:
            pcd.normals = o3d.utility.Vector3dVector(np.array(self.normals, dtype=np.float64))
        if self._colors is not None:
            pcd.colors = o3d.utility.Vector3dVector(np.array(self._colors, dtype=np.float64))
        return pcd
