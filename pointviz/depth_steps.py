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
says it spans more than one surface (a depth edge, a corner). The point moves along its ray onto
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


# The upper triangle of a 3x3 covariance, in the order of the moment images' products.
_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def depth_steps(depth: np.ndarray) -> np.ndarray | None:
    """Each point's depth step (same units), measured from the frame's distinct depths, or None
    when the frame's depths are not stepped (more than :data:`STEPPED_LEVELS_FRACTION` distinct
    depths per point)."""
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
    step = np.median(windows, axis=1)
    return step[which.reshape(-1)]


def _smallest_eigen(cov: np.ndarray):
    """Smallest and middle eigenvalues and the smallest's unit eigenvector of each symmetric
    3x3 matrix of ``cov`` (m, 3, 3), in closed form (the trigonometric solution of the
    characteristic cubic; the eigenvector as the longest cross product of two rows of
    cov - lambda I): 5-10x faster than ``numpy.linalg.eigh`` on many small matrices."""
    a00, a01, a02 = cov[:, 0, 0], cov[:, 0, 1], cov[:, 0, 2]
    a11, a12, a22 = cov[:, 1, 1], cov[:, 1, 2], cov[:, 2, 2]
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
    r0 = np.column_stack([a00 - smallest, a01, a02])
    r1 = np.column_stack([a01, a11 - smallest, a12])
    r2 = np.column_stack([a02, a12, a22 - smallest])
    cand = np.stack([np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2)], axis=1)
    norm = np.linalg.norm(cand, axis=2)
    best = norm.argmax(axis=1)
    idx = np.arange(len(cov))
    with np.errstate(divide="ignore", invalid="ignore"):
        vec = cand[idx, best] / norm[idx, best][:, None]
    return smallest, middle, vec


def _summed_area(image: np.ndarray) -> np.ndarray:
    """The summed-area table of ``image`` (H, W, C): (H + 1, W + 1, C), zero first row and
    column."""
    h, w = image.shape[:2]
    sat = np.zeros((h + 1, w + 1) + image.shape[2:], dtype=np.float64)
    np.cumsum(np.cumsum(image, axis=0), axis=1, out=sat[1:, 1:])
    return sat


def _patch_sums(sat: np.ndarray, rows: np.ndarray, cols: np.ndarray, r: int) -> np.ndarray:
    """Sums over the (2r+1)^2 patch around each pixel (rows, cols), clipped at the frame's
    border, from the summed-area table ``sat``."""
    h, w = sat.shape[0] - 1, sat.shape[1] - 1
    r0, r1 = np.clip(rows - r, 0, h), np.clip(rows + r + 1, 0, h)
    c0, c1 = np.clip(cols - r, 0, w), np.clip(cols + r + 1, 0, w)
    return sat[r1, c1] - sat[r0, c1] - sat[r1, c0] + sat[r0, c0]


def patch_planes(points: np.ndarray, grid: np.ndarray, viewpoint, step: np.ndarray):
    """Planes over pixel patches sized to the depth steps (module docstring).

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
    angle = (float(np.median(np.linalg.norm(ray[a[both]] - ray[b[both]], axis=1)))
             if both.any() else 0.0)
    footprint = np.where(np.isfinite(rng), rng, 0.0) * angle
    # the moment images: 1, x, y, z and the products (centred on the frame's mean point)
    centre = pts.mean(axis=0)
    c = pts - centre
    seen = np.isfinite(rng)  # points at the camera are no measurement: not in any patch
    vr, vc, vcen = rows[seen], cols[seen], c[seen]
    chan = np.zeros((h, w, 10))
    chan[vr, vc, 0] = 1.0
    chan[vr, vc, 1:4] = vcen
    for m, (p, q) in enumerate(_PAIRS):
        chan[vr, vc, 4 + m] = vcen[:, p] * vcen[:, q]
    sat = _summed_area(chan)
    del chan

    def planes(sel, r):
        """Plane of each point of ``sel`` over its patch of half-width r: normal, mean point,
        RMS residual along its ray, and whether the patch determines a plane."""
        sums = _patch_sums(sat, rows[sel], cols[sel], r)
        cnt = sums[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            mu = sums[:, 1:4] / cnt[:, None]
            cov = np.empty((len(sel), 3, 3))
            for m, (p, q) in enumerate(_PAIRS):
                cov[:, p, q] = cov[:, q, p] = sums[:, 4 + m] / cnt - mu[:, p] * mu[:, q]
        fine = (cnt >= 3) & np.isfinite(cov).all(axis=(1, 2))
        cov[~fine] = np.eye(3)
        small, middle, nrm = _smallest_eigen(cov)
        fine &= (middle > 0) & np.isfinite(nrm).all(axis=1)
        nrm[~fine] = -ray[sel][~fine]
        cos = np.maximum(np.abs(np.einsum("ij,ij->i", nrm, ray[sel])), 0.1)
        return nrm, mu, np.sqrt(np.maximum(small, 0.0)) / cos, fine

    # the frame's noise in steps: the median over its points of the RMS residual of their
    # NOISE_RADIUS patches (quantisation alone: 1/sqrt(12) on a slope spanning steps, 0 on a
    # terrace; a patch across an edge is rarer than the median)
    sample = np.flatnonzero(seen)[::NOISE_SAMPLE]
    _, _, res, fine = planes(sample, NOISE_RADIUS)
    step_s = step[sample]
    noise = float(np.median(res[fine] / step_s[fine])) if fine.any() else 0.0
    sigma = step * max(noise, 1.0 / np.sqrt(12.0))
    limit = np.maximum(PATCH_RESIDUAL_STEPS * step, PATCH_RESIDUAL_SIGMAS * sigma)
    # the smallest patch whose slope error from that noise is within DEPTH_SLOPE_ERROR:
    # sigma / (sqrt(N) x RMS in-plane offset) for N = (2r+1)^2 pixels of footprint a
    radii = np.asarray(PATCH_RADII)
    rr = radii.astype(np.float64)
    se = sigma[:, None] / ((2 * rr + 1) * np.maximum(footprint, 1e-300)[:, None]
                           * np.sqrt(rr * (rr + 1) / 3.0))
    ok = se <= DEPTH_SLOPE_ERROR
    choice = np.where(ok.any(axis=1), ok.argmax(axis=1), len(radii) - 1)
    out_n = np.zeros((n, 3))
    mean = np.zeros((n, 3))
    stays = np.zeros(n, dtype=bool)
    todo = seen.copy()
    final = np.zeros(n, dtype=np.intp) - 1
    # from each point's chosen patch down: the first whose residual says one surface
    for level in range(len(radii) - 1, -1, -1):
        sel = np.flatnonzero(todo & (choice >= level))
        if not len(sel):
            continue
        nrm, mu, res, fine = planes(sel, int(radii[level]))
        one = fine & (res <= limit[sel])
        # the smallest patch is taken even when it spans two surfaces (the point stays)
        good = one | ((level == 0) & fine)
        take = sel[good]
        out_n[take] = nrm[good]
        mean[take] = mu[good]
        final[take] = level
        stays[take] = ~one[good]
        todo[take] = False
    # normals toward the camera; each point onto its plane along its ray
    flip = np.einsum("ij,ij->i", out_n, rel) > 0
    out_n[flip] *= -1
    moved = pts.copy()
    dn = np.einsum("ij,ij->i", out_n, ray)  # < 0: facing the camera
    dist = np.einsum("ij,ij->i", out_n, c - mean)  # the point's height over its plane
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -dist / dn  # along the ray
    cap = np.maximum(MOVE_STEPS * step, PATCH_RESIDUAL_SIGMAS * sigma)
    move = (final >= 0) & ~stays & (np.abs(dn) > 0.1) & (np.abs(t) <= cap)
    moved[move] += t[move, None] * ray[move]
    bad = final < 0
    out_n[bad] = -ray[bad]
    radius = np.where(final >= 0, radii[np.maximum(final, 0)], 0)
    return moved, out_n.astype(np.float32), radius
