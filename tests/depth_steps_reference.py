"""The test oracle for :mod:`pointviz.depth_steps`: its patch planes as first written (1d4f9d4,
before they were restructured for speed), kept unchanged so that ``tests/test_io.py`` can compare
the numpy version (``patch_planes_numpy``) with it bit for bit and the core's (``patch_planes``)
within a float tolerance. The constants, :func:`depth_steps` and :func:`depth_segments` (not
restructured) come from the package. Not imported by the package."""

from __future__ import annotations

import numpy as np

from pointviz.depth_steps import (DEPTH_SLOPE_ERROR, EDGE_FOOTPRINTS, EDGE_SIGMAS, EDGE_STEPS,
                                  FLYING_SPANS, MOVE_STEPS, NOISE_RADIUS, NOISE_SAMPLE,
                                  PATCH_RADII, PATCH_RESIDUAL_SIGMAS, PATCH_RESIDUAL_STEPS,
                                  SMALL_SEGMENT, _PAIRS, depth_segments)


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


def _shifted(image: np.ndarray, dr: int, dc: int) -> np.ndarray:
    """``out[r, c] = image[r + dr, c + dc]``, NaN where that falls outside the frame."""
    h, w = image.shape
    out = np.full_like(image, np.nan)
    a0, a1, b0, b1 = max(0, -dr), min(h, h - dr), max(0, -dc), min(w, w - dc)
    if a0 < a1 and b0 < b1:
        out[a0:a1, b0:b1] = image[a0 + dr:a1 + dr, b0 + dc:b1 + dc]
    return out


def flying_pixels(ranges: np.ndarray, jump: np.ndarray) -> np.ndarray:
    """Which pixels of a range image (h, w; NaN: no point) are flying (module docstring,
    :data:`FLYING_SPANS`): between two surfaces along a row, column or diagonal, farther than
    ``jump`` (h, w) from both and from both extended to it."""
    fly = np.zeros(ranges.shape, dtype=bool)
    r, j = ranges, jump
    with np.errstate(invalid="ignore"):
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            for a, b in FLYING_SPANS:
                near_a = _shifted(r, -a * dr, -a * dc)
                far_a = _shifted(r, -(a + 1) * dr, -(a + 1) * dc)
                near_b = _shifted(r, b * dr, b * dc)
                far_b = _shifted(r, (b + 1) * dr, (b + 1) * dc)
                between = (((near_a < r - j) & (near_b > r + j))
                           | ((near_a > r + j) & (near_b < r - j)))
                smooth = (np.abs(near_a - far_a) <= j) & (np.abs(near_b - far_b) <= j)
                neither = ((np.abs(r - near_a - a * (near_a - far_a)) > j)
                           & (np.abs(r - near_b - b * (near_b - far_b)) > j))
                fly |= between & smooth & neither
    return fly


def patch_planes(points: np.ndarray, grid: np.ndarray, viewpoint, step: np.ndarray,
                 edges: bool = True):
    """:func:`pointviz.depth_steps.patch_planes_numpy` as first written (same parameters and
    results)."""
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

    def moments(sel):
        """The 10 moments (1, p, pp^T) of the points ``sel``: (len(sel), 10)."""
        cs = c[sel]
        out = np.empty((len(sel), 10))
        out[:, 0] = 1.0
        out[:, 1:4] = cs
        for m, (p, q) in enumerate(_PAIRS):
            out[:, 4 + m] = cs[:, p] * cs[:, q]
        return out

    def moment_table(sel, r0, c0, hh, ww):
        """Summed-area table of the moment images of the points ``sel`` over the window of the
        frame from (r0, c0), hh x ww pixels."""
        chan = np.zeros((hh, ww, 10))
        chan[rows[sel] - r0, cols[sel] - c0] = moments(sel)
        return _summed_area(chan)

    def plane_of(sums, sel):
        """Plane of each point of ``sel`` from its patch's moment sums: normal, mean point, RMS
        residual along its ray, and whether the patch determines a plane."""
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
    sat = moment_table(np.flatnonzero(seen), 0, 0, h, w)
    _, _, res, fine = plane_of(_patch_sums(sat, rows[sample], cols[sample], NOISE_RADIUS),
                               sample)
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
    final = np.zeros(n, dtype=np.intp) - 1
    flying = np.zeros(n, dtype=bool)

    def fit_patches(sel, table, r0, c0):
        """From each point of ``sel``'s chosen patch down (moment sums from ``table``, whose
        window starts at (r0, c0)): the first whose residual says one surface."""
        todo = np.zeros(n, dtype=bool)
        todo[sel] = True
        for level in range(len(radii) - 1, -1, -1):
            at = np.flatnonzero(todo & (choice >= level))
            if not len(at):
                continue
            sums = _patch_sums(table, rows[at] - r0, cols[at] - c0, int(radii[level]))
            nrm, mu, res, fine = plane_of(sums, at)
            one = fine & (res <= limit[at])
            # the smallest patch is taken even when it spans two surfaces (the point stays)
            good = one | ((level == 0) & fine)
            take = at[good]
            out_n[take] = nrm[good]
            mean[take] = mu[good]
            final[take] = level
            stays[take] = ~one[good]
            todo[take] = False

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
                             for col in moments(small).T], axis=1)[sl]
            nrm, mu, res, fine = plane_of(sums, small)
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
            r0, c0 = int(rows[sel].min()), int(cols[sel].min())
            hh, ww = int(rows[sel].max()) + 1 - r0, int(cols[sel].max()) + 1 - c0
            fit_patches(sel, moment_table(sel, r0, c0, hh, ww), r0, c0)
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
    return moved, out_n.astype(np.float32), radius, flying
