"""Depth-camera frames whose depths come in steps: a fit over pixel patches as wide as the steps.

A structured-light or stereo depth camera (Kinect-class) measures disparity in fractions of a
pixel and converts it to depth, so a frame's depths take few distinct values, a step of about
z^2 / (f b) x the disparity's resolution apart: 1-5 cm at 2-4 m on PCL's Kinect frames,
2.5-7x the pixel spacing there. A slanted wall is then a staircase of terraces, each several pixels
wide, and a neighbourhood of 16-32 nearest points lies on one terrace: its plane is the
terrace's, not the wall's (the walls of ``office1.pcd`` rendered as a scale pattern of
differently shaded disks). Here each point's plane is fitted over a square patch of its frame's
pixel grid that grows until the step's noise leaves the plane's slope within
:data:`DEPTH_SLOPE_ERROR` (both measured on the frame: the step from the gaps between its
distinct depths, the pixel's footprint from its rays), and shrinks while the patch's residual
says it spans more than one surface (a corner). Patches do not reach across depth edges (a jump
between neighbouring pixels larger than a few steps, the noise and the slope a surface can
show): each holds only the pixels joined to its point without one. A depth camera's flying
pixels (mixed depths in mid-air between a foreground edge and the background, fitting neither
side) are found on the grid and dropped. The point moves along its ray onto
that plane and takes its normal; the surface fit (:func:`pointviz.estimation.fit_surface`) then
starts from those. Frames whose depths are not stepped (range scans, synthetic frames, frames
already smoothed) are left alone: :func:`depth_steps` returns None for them.
"""

from __future__ import annotations

import numpy as np

# A frame's depths come in steps when it has at most this many distinct depths per point
# (PCL's Kinect frames: 125-508 in 210-255k points, 1 in 500-2000; its stereo frame 940 in
# 209k; a frame of floats, noisy or not: about one per point).
STEPPED_LEVELS_FRACTION = 0.02
# ... and when those steps are a small part of the depth, as a quantiser's are (PCL's frames:
# median step 0.07-1.3 % of the depth, at most 2.8 %): a frame of a few surfaces at distinct
# depths (two walls, 0.5 m apart: 2 levels) has few distinct depths too, but its "steps" are the
# gaps between its surfaces, which a patch must not smooth over.
STEP_MAX_FRACTION = 0.05
# Each depth's step is the median gap between consecutive distinct depths among this many
# around it (a level the frame does not use doubles one gap; millimetre rounding of near
# depths makes gaps of 1 and 2 mm alternate).
STEP_WINDOW = 9
# Largest tolerated standard error of a patch plane's slope from the depth noise (tan of
# 2 degrees): the patch grows until the frame's noise (measured, at least the quantisation's
# uniform error of one step, RMS step / sqrt(12)) spread over its pixels leaves the slope this
# uncertain. 1 degree: 1.4x wider patches, on the virtual Kinect frame 1.3 instead of 1.8
# degrees of normal error, PCL's frames the same to the eye; 3 degrees: 2.4
# (benchmarks/README.md, "Depth-camera frames under Kinect noise").
DEPTH_SLOPE_ERROR = float(np.tan(np.radians(2.0)))
# The patch half-width over which the frame's noise is measured (7x7 pixels).
NOISE_RADIUS = 3
# ... on every NOISE_SAMPLE-th point (a median).
NOISE_SAMPLE = 4
# Half-widths of the square patches tried, in pixels (3x3 ... 33x33).
PATCH_RADII = (1, 2, 3, 4, 5, 6, 8, 10, 12, 16)
# A patch whose plane leaves an RMS residual above this many steps spans more than one surface
# (a depth edge or a corner: a quantised plane with noise of one step leaves about 0.3-0.6);
# the next smaller patch is taken.
PATCH_RESIDUAL_STEPS = 1.5
# ... or this many times the frame's measured noise, when that is larger.
PATCH_RESIDUAL_SIGMAS = 3.0
# A point moves onto its patch's plane only when it lies within this many steps of it, or
# PATCH_RESIDUAL_SIGMAS x the frame's noise (a point on the edge of a foreground object whose
# smallest patch is mostly background stays).
MOVE_STEPS = 2.0


# Depth edges. Two grid neighbours (row or column) whose ranges differ by more than the largest
# of EDGE_STEPS steps, EDGE_SIGMAS x the frame's noise and EDGE_FOOTPRINTS pixel footprints (a
# surface seen at up to 80 degrees from its normal changes by tan 80 = 5.7 footprints a pixel)
# lie on two surfaces: no patch reaches across (each point's patch holds only the pixels joined
# to it through neighbours without such a jump).
EDGE_STEPS = 4.0
EDGE_SIGMAS = 4.0
EDGE_FOOTPRINTS = 6.0
# A segment (pixels joined without a jump) of fewer points than this takes one plane over all of
# its points instead of square patches.
SMALL_SEGMENT = 64
# Flying pixels: a point whose grid neighbours on opposite sides (along a row, column or
# diagonal; one or two pixels away) lie on two surfaces, both farther than an edge's jump from
# it, each continuing smoothly away from it and neither reaching it when extended, lies in mid
# air between them (a depth camera's mixed pixel at a depth edge): it is dropped.
FLYING_SPANS = ((1, 1), (1, 2), (2, 1))


# Points per chunk of the plane fits (numpy temporaries of 128 KB stay in cache).
_CHUNK = 16384

# The upper triangle of a 3x3 covariance, in the order of the moment images' products.
_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def depth_steps(depth: np.ndarray) -> np.ndarray | None:
    """Each point's depth step (same units), measured from the frame's distinct depths, or None
    when the frame's depths are not stepped (more than :data:`STEPPED_LEVELS_FRACTION` distinct
    depths per point, or steps over :data:`STEP_MAX_FRACTION` of the depth)."""
    z = np.asarray(depth, dtype=np.float32)
    n = len(z)
    levels, which = np.unique(z, return_inverse=True)
    if n < 64 or len(levels) < 2 or len(levels) > STEPPED_LEVELS_FRACTION * n:
        return None
    gaps = np.diff(levels.astype(np.float64))
    # each level's step: the median of the STEP_WINDOW gaps around it
    half = STEP_WINDOW // 2
    padded = np.pad(gaps, (half, half + 1), mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, STEP_WINDOW)[: len(levels)]
    step = np.median(windows, axis=1)[which.reshape(-1)]
    seen = np.abs(z) > 0  # (zero-coded invalid pixels aside)
    if not seen.any() or np.median(step[seen] / np.abs(z[seen])) > STEP_MAX_FRACTION:
        return None
    return step


def _smallest_eigen(a00, a01, a02, a11, a12, a22):
    """Smallest and middle eigenvalues and the smallest's unit eigenvector (m, 3) of each
    symmetric 3x3 matrix given by its upper triangle's entries (each (m,)), in closed form (the
    trigonometric solution of the characteristic cubic; the eigenvector as the longest cross
    product of two rows of cov - lambda I): 5-10x faster than ``numpy.linalg.eigh`` on many
    small matrices. Works on the entries one array each (no (m, 3, 3) stacks)."""
    m = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - m, a11 - m, a22 - m
    p = (b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6.0
    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
           + a02 * (a01 * a12 - b11 * a02))
    sp = np.sqrt(p)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.arccos(np.clip(det / (2.0 * p * sp), -1.0, 1.0)) / 3.0
    phi = np.nan_to_num(phi)
    largest = m + 2.0 * sp * np.cos(phi)
    smallest = m + 2.0 * sp * np.cos(phi + 2.0 * np.pi / 3.0)
    middle = 3.0 * m - largest - smallest
    # rows of cov - smallest I: r0 = (d0, a01, a02), r1 = (a01, d1, a12), r2 = (a02, a12, d2)
    d0, d1, d2 = a00 - smallest, a11 - smallest, a22 - smallest
    # r0 x r1, r0 x r2, r1 x r2 (as numpy.cross: a1 b2 - a2 b1, a2 b0 - a0 b2, a0 b1 - a1 b0)
    cand = (((a01 * a12 - a02 * d1), (a02 * a01 - d0 * a12), (d0 * d1 - a01 * a01)),
            ((a01 * d2 - a02 * a12), (a02 * a02 - d0 * d2), (d0 * a12 - a01 * a02)),
            ((d1 * d2 - a12 * a12), (a12 * a02 - a01 * d2), (a01 * a12 - d1 * a02)))
    norm = np.empty((len(m), 3))
    for k, (x, y, z) in enumerate(cand):
        norm[:, k] = np.sqrt(x * x + y * y + z * z)
    best = norm.argmax(axis=1)
    pick = [best == 1, best == 2]
    length = np.where(pick[1], norm[:, 2], np.where(pick[0], norm[:, 1], norm[:, 0]))
    vec = np.empty((len(m), 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        for i in range(3):
            comp = np.where(pick[1], cand[2][i], np.where(pick[0], cand[1][i], cand[0][i]))
            np.divide(comp, length, out=vec[:, i])
    return smallest, middle, vec


def _summed_area(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, shape) -> np.ndarray:
    """The summed-area table (H + 1, W + 1, C), zero first row and column, of the image
    (H, W) = ``shape`` that holds ``image`` (m, C) at the pixels (rows, cols) and zeros
    elsewhere (the cumulative sums taken in place: rows, then columns)."""
    h, w = shape
    sat = np.zeros((h + 1, w + 1, image.shape[1]), dtype=np.float64)
    sat.reshape((h + 1) * (w + 1), -1)[(rows + 1) * (w + 1) + (cols + 1)] = image
    body = sat[1:, 1:]
    for i in range(1, h):  # down the rows: one row's sums at a time (as numpy.cumsum adds)
        np.add(body[i], body[i - 1], out=body[i])
    np.cumsum(body, axis=1, out=body)
    return sat


def _patch_sums(sat: np.ndarray, rows: np.ndarray, cols: np.ndarray, r: int) -> np.ndarray:
    """Sums over the (2r+1)^2 patch around each pixel (rows, cols), clipped at the frame's
    border, from the summed-area table ``sat``."""
    h, w = sat.shape[0] - 1, sat.shape[1] - 1
    r0, r1 = np.clip(rows - r, 0, h), np.clip(rows + r + 1, 0, h)
    c0, c1 = np.clip(cols - r, 0, w), np.clip(cols + r + 1, 0, w)
    flat = sat.reshape((h + 1) * (w + 1), -1)
    r0 *= w + 1
    r1 *= w + 1
    out = np.take(flat, r1 + c1, axis=0)
    out -= np.take(flat, r0 + c1, axis=0)
    out -= np.take(flat, r1 + c0, axis=0)
    out += np.take(flat, r0 + c0, axis=0)
    return out


def flying_pixels(ranges: np.ndarray, jump: np.ndarray) -> np.ndarray:
    """Which pixels of a range image (h, w; NaN: no point) are flying (module docstring,
    :data:`FLYING_SPANS`): between two surfaces along a row, column or diagonal, farther than
    ``jump`` (h, w) from both and from both extended to it."""
    fly = np.zeros(ranges.shape, dtype=bool)
    reach = max(max(a, b) for a, b in FLYING_SPANS) + 1
    h, w = ranges.shape
    # views of the image shifted by up to ``reach`` pixels: NaN (no point) past the border
    padded = np.pad(ranges, reach, constant_values=np.nan)
    band = max(1, _CHUNK // max(w, 1))  # rows at a time (the temporaries stay in cache)
    with np.errstate(invalid="ignore"):
        for y0 in range(0, h, band):
            y1 = min(y0 + band, h)
            r, j, out = ranges[y0:y1], jump[y0:y1], fly[y0:y1]
            lo, hi = r - j, r + j
            for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
                # the image shifted k pixels along the direction, each k once
                at = {k: padded[reach + k * dr + y0:reach + k * dr + y1,
                                reach + k * dc:reach + k * dc + w]
                      for k in range(-reach, reach + 1) if k}
                below = {k: at[k] < lo for k in at if abs(k) < reach}
                above = {k: at[k] > hi for k in at if abs(k) < reach}
                smooth = {k: np.abs(at[k] - at[k + (1 if k > 0 else -1)]) <= j
                          for k in at if abs(k) < reach}
                for a, b in FLYING_SPANS:
                    near_a, far_a = at[-a], at[-(a + 1)]
                    near_b, far_b = at[b], at[b + 1]
                    between = (below[-a] & above[b]) | (above[-a] & below[b])
                    between &= smooth[-a]
                    between &= smooth[b]
                    between &= np.abs(r - near_a - a * (near_a - far_a)) > j
                    between &= np.abs(r - near_b - b * (near_b - far_b)) > j
                    out |= between
    return fly


def depth_segments(ranges: np.ndarray, jump: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Label image (h, w; -1 where not ``valid``) of the pieces of surface: pixels joined through
    row and column neighbours whose ranges differ by at most the smaller of their ``jump``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    h, w = ranges.shape
    ids = np.arange(h * w).reshape(h, w)
    src, dst = [], []
    with np.errstate(invalid="ignore"):
        for sl_a, sl_b in (((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
                           ((slice(None, -1), slice(None)), (slice(1, None), slice(None)))):
            ok = (valid[sl_a] & valid[sl_b]
                  & (np.abs(ranges[sl_a] - ranges[sl_b]) <= np.minimum(jump[sl_a], jump[sl_b])))
            src.append(ids[sl_a][ok])
            dst.append(ids[sl_b][ok])
    src, dst = np.concatenate(src), np.concatenate(dst)
    graph = coo_matrix((np.ones(len(src), dtype=np.int8), (src, dst)), shape=(h * w, h * w))
    _, labels = connected_components(graph, directed=False)
    labels = labels.reshape(h, w)
    labels[~valid] = -1
    return labels


def patch_planes(points: np.ndarray, grid: np.ndarray, viewpoint, step: np.ndarray,
                 edges: bool = True, threads: int = 0):
    """Planes over pixel patches sized to the depth steps (module docstring), in the C++ core
    (``ext/src/preprocess_depth.cpp``: the per-point table reads, moments, eigen solve and patch
    growth fused and threaded; depth edges with the core's union-find, so scipy is not
    imported). Same parameters and results as :func:`patch_planes_numpy`, whose arithmetic it
    follows in the same order: equal to it up to the rounding of arccos / cos (libm's against
    numpy's). ``threads``: 0, all cores.
    """
    from . import _core
    from .interrupt import step_named

    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    cells = np.ascontiguousarray(grid, dtype=np.int32).reshape(-1, 2)
    vp = [float(v) for v in np.asarray(viewpoint, dtype=np.float64).reshape(3)]
    steps = np.ascontiguousarray(step, dtype=np.float64).reshape(-1)
    if not len(pts):
        raise ValueError("patch_planes: no points")
    with step_named("depth planes"):
        moved, normals, radius, flying, _ = _core.depth_patch_planes(
            pts, cells, vp, steps, bool(edges), DEPTH_SLOPE_ERROR, NOISE_RADIUS, NOISE_SAMPLE,
            list(PATCH_RADII), PATCH_RESIDUAL_STEPS, PATCH_RESIDUAL_SIGMAS, MOVE_STEPS,
            EDGE_STEPS, EDGE_SIGMAS, EDGE_FOOTPRINTS, SMALL_SEGMENT, threads=int(threads))
    return moved, normals, radius, flying.view(bool)


def patch_planes_numpy(points: np.ndarray, grid: np.ndarray, viewpoint, step: np.ndarray,
                       edges: bool = True):
    """Planes over pixel patches sized to the depth steps (module docstring), in numpy: the
    oracle of :func:`patch_planes` (the core's), and the reference for its arithmetic.

    Parameters
    ----------
    points : (n, 3) float
        The frame's points (finite).
    grid : (n, 2) int
        Each point's row and column in the frame.
    viewpoint : (3,) float
        The camera's position.
    step : (n,) float
        Each point's depth step (:func:`depth_steps`).
    edges : bool
        Patches stop at depth edges and flying pixels are found (default); False: square
        patches across edges, no point flying (the fit before depth edges were handled).

    Returns
    -------
    points : (n, 3) float64
        Each point moved along its ray onto its patch's plane (unmoved where it lies farther
        than :data:`MOVE_STEPS` steps from it, where even its 3x3 patch spans two surfaces,
        or where no patch determines a plane).
    normals : (n, 3) float32
        The patch planes' normals, facing the camera.
    radius : (n,) int
        Each point's patch half-width in pixels (0: no plane, the normal toward the camera).
    flying : (n,) bool
        The flying pixels (:func:`flying_pixels`), to be dropped.
    """
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    vp = np.asarray(viewpoint, dtype=np.float64).reshape(3)
    rows, cols = grid[:, 0].astype(np.intp), grid[:, 1].astype(np.intp)
    h, w = int(rows.max()) + 1, int(cols.max()) + 1
    rel = pts - vp
    rng = np.linalg.norm(rel, axis=1)
    rng[~(rng > 0)] = np.inf  # a point at the camera (some grabbers' invalid pixels)
    # the angle between neighbouring pixels' rays (median over the frame): a pixel's
    # footprint is its range times that
    index = np.full((h, w), -1, dtype=np.int64)
    index[rows, cols] = np.arange(n)
    ray = rel / rng[:, None]
    ray[np.isinf(rng)] = (0.0, 0.0, 1.0)
    a, b = index[:, :-1].ravel(), index[:, 1:].ravel()
    both = (a >= 0) & (b >= 0)
    if both.any():
        a, b = a[both], b[both]
        gap = np.zeros(len(a))
        for k in range(3):  # |ray_a - ray_b| as numpy.linalg.norm adds it: (x^2 + y^2) + z^2
            d = ray[a, k] - ray[b, k]
            d *= d
            gap += d
        angle = float(np.median(np.sqrt(gap, out=gap)))
    else:
        angle = 0.0
    footprint = np.where(np.isfinite(rng), rng, 0.0) * angle
    # the moment images: 1, x, y, z and the products (centred on the frame's mean point),
    # each point's row of them computed once
    centre = pts.mean(axis=0)
    c = pts - centre
    seen = np.isfinite(rng)  # points at the camera are no measurement: not in any patch
    mom = np.empty((n, 10))
    mom[:, 0] = 1.0
    mom[:, 1:4] = c
    for m, (p, q) in enumerate(_PAIRS):
        np.multiply(c[:, p], c[:, q], out=mom[:, 4 + m])

    def moment_table(sel, r0, c0, hh, ww):
        """Summed-area table of the moment images of the points ``sel`` over the window of the
        frame from (r0, c0), hh x ww pixels."""
        return _summed_area(mom[sel], rows[sel] - r0, cols[sel] - c0, (hh, ww))

    def plane_of(sel, sums_of):
        """Plane of each point of ``sel`` from its patch's moment sums (``sums_of(i, j)``: those
        of ``sel[i:j]``): normal, mean point, RMS residual along its ray, and whether the patch
        determines a plane. Worked through in chunks of :data:`_CHUNK` points (the temporaries
        stay in cache; each point's arithmetic is the same)."""
        m = len(sel)
        nrm, mu, res, fine = np.empty((m, 3)), np.empty((m, 3)), np.empty(m), np.empty(m, bool)
        for i in range(0, m, _CHUNK):
            j = min(i + _CHUNK, m)
            nrm[i:j], mu[i:j], res[i:j], fine[i:j] = plane_chunk(sums_of(i, j), sel[i:j])
        return nrm, mu, res, fine

    def plane_chunk(sums, sel):
        """:func:`plane_of` for one chunk, from its moment sums."""
        cnt = sums[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            mu = sums[:, 1:4] / cnt[:, None]
            cov = [sums[:, 4 + m] / cnt - mu[:, p] * mu[:, q]
                   for m, (p, q) in enumerate(_PAIRS)]
        fine = cnt >= 3
        for entry in cov:
            fine &= np.isfinite(entry)
        if not fine.all():
            out = ~fine
            for entry, (p, q) in zip(cov, _PAIRS):
                entry[out] = 1.0 if p == q else 0.0
        small, middle, nrm = _smallest_eigen(*cov)
        ray_s = ray[sel]
        fine &= middle > 0
        fine &= np.isfinite(nrm).all(axis=1)
        if not fine.all():
            nrm[~fine] = -ray_s[~fine]
        cos = np.maximum(np.abs(np.einsum("ij,ij->i", nrm, ray_s)), 0.1)
        np.maximum(small, 0.0, out=small)
        np.sqrt(small, out=small)
        small /= cos
        return nrm, mu, small, fine

    # the frame's noise in steps: the median over its points of the RMS residual of their
    # NOISE_RADIUS patches (quantisation alone: 1/sqrt(12) on a slope spanning steps, 0 on a
    # terrace; a patch across an edge is rarer than the median)
    sample = np.flatnonzero(seen)[::NOISE_SAMPLE]
    sat = moment_table(np.flatnonzero(seen), 0, 0, h, w)
    _, _, res, fine = plane_of(sample, lambda i, j: _patch_sums(
        sat, rows[sample[i:j]], cols[sample[i:j]], NOISE_RADIUS))
    step_s = step[sample]
    noise = float(np.median(res[fine] / step_s[fine])) if fine.any() else 0.0
    sigma = step * max(noise, 1.0 / np.sqrt(12.0))
    limit = np.maximum(PATCH_RESIDUAL_STEPS * step, PATCH_RESIDUAL_SIGMAS * sigma)
    # the smallest patch whose slope error from that noise is within DEPTH_SLOPE_ERROR:
    # sigma / (sqrt(N) x RMS in-plane offset) for N = (2r+1)^2 pixels of footprint a
    radii = np.asarray(PATCH_RADII)
    rr = radii.astype(np.float64)
    width, spread = 2 * rr + 1, np.sqrt(rr * (rr + 1) / 3.0)
    fp = np.maximum(footprint, 1e-300)
    choice = np.full(n, len(radii) - 1)
    undecided = np.arange(n)
    for level in range(len(radii) - 1):
        se = sigma[undecided] / (width[level] * fp[undecided] * spread[level])
        ok = se <= DEPTH_SLOPE_ERROR
        choice[undecided[ok]] = level
        undecided = undecided[~ok]
    out_n = np.zeros((n, 3))
    mean = np.zeros((n, 3))
    stays = np.zeros(n, dtype=bool)
    final = np.zeros(n, dtype=np.intp) - 1
    flying = np.zeros(n, dtype=bool)

    def fit_patches(sel, table, r0, c0):
        """From each point of ``sel``'s chosen patch down (moment sums from ``table``, whose
        window starts at (r0, c0)): the first whose residual says one surface. Each level
        works on the points whose patch starts there and those a larger patch failed."""
        by_level = sel[np.argsort(choice[sel], kind="stable")]
        starts = np.searchsorted(choice[by_level], np.arange(len(radii) + 1))
        left = by_level[:0]
        for level in range(len(radii) - 1, -1, -1):
            fresh = by_level[starts[level]:starts[level + 1]]
            at = np.concatenate([left, fresh]) if len(left) else fresh
            if not len(at):
                continue
            radius = int(radii[level])
            nrm, mu, res, fine = plane_of(at, lambda i, j: _patch_sums(
                table, rows[at[i:j]] - r0, cols[at[i:j]] - c0, radius))
            one = fine & (res <= limit[at])
            # the smallest patch is taken even when it spans two surfaces (the point stays)
            good = one | fine if level == 0 else one
            take = at[good]
            out_n[take] = nrm[good]
            mean[take] = mu[good]
            final[take] = level
            stays[take] = ~one[good]
            left = at[~good]

    if not edges:
        fit_patches(np.flatnonzero(seen), sat, 0, 0)
    else:
        del sat
        # depth edges and flying pixels, on the range image
        jump = np.maximum(np.maximum(EDGE_STEPS * step, EDGE_SIGMAS * sigma),
                          EDGE_FOOTPRINTS * footprint)
        rimg = np.full((h, w), np.nan)
        jimg = np.full((h, w), np.nan)
        rimg[rows[seen], cols[seen]] = rng[seen]
        jimg[rows[seen], cols[seen]] = jump[seen]
        fly_img = flying_pixels(rimg, jimg)
        flying = fly_img[rows, cols] & seen
        valid = np.isfinite(rimg) & ~fly_img
        labels = depth_segments(rimg, jimg, valid)[rows, cols]
        labels[~seen | flying] = -1
        member = np.flatnonzero(labels >= 0)
        lab = labels[member]
        size = np.bincount(lab)
        # small segments: one plane over each
        small = member[size[lab] < SMALL_SEGMENT]
        if len(small):
            sl = labels[small]
            sums = np.stack([np.bincount(sl, weights=col, minlength=len(size))
                             for col in mom[small].T], axis=1)[sl]
            nrm, mu, res, fine = plane_of(small, lambda i, j: sums[i:j])
            take = small[fine]
            out_n[take] = nrm[fine]
            mean[take] = mu[fine]
            final[take] = 0
            stays[take] = res[fine] > limit[take]
        # large segments: square patches over the segment's own pixels
        order = member[np.argsort(lab, kind="stable")]
        bounds = np.concatenate([[0], np.cumsum(size)])
        for seg in np.flatnonzero(size >= SMALL_SEGMENT):
            sel = order[bounds[seg]:bounds[seg + 1]]
            rs, cs = rows[sel], cols[sel]
            r0, c0 = int(rs.min()), int(cs.min())
            hh, ww = int(rs.max()) + 1 - r0, int(cs.max()) + 1 - c0
            fit_patches(sel, moment_table(sel, r0, c0, hh, ww), r0, c0)
    # normals toward the camera; each point onto its plane along its ray
    flip = np.einsum("ij,ij->i", out_n, rel) > 0
    out_n *= np.where(flip, -1.0, 1.0)[:, None]
    dn = np.einsum("ij,ij->i", out_n, ray)  # < 0: facing the camera
    dist = np.einsum("ij,ij->i", out_n, c - mean)  # the point's height over its plane
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -dist / dn  # along the ray
    cap = np.maximum(MOVE_STEPS * step, PATCH_RESIDUAL_SIGMAS * sigma)
    move = (final >= 0) & ~stays & (np.abs(dn) > 0.1) & (np.abs(t) <= cap)
    # (t = 0 elsewhere: the point plus 0 x its ray is the point, to the bit)
    moved = pts + np.where(move, t, 0.0)[:, None] * ray
    bad = final < 0
    out_n[bad] = -ray[bad]
    radius = np.where(final >= 0, radii[np.maximum(final, 0)], 0)
    return moved, out_n.astype(np.float32), radius, flying
