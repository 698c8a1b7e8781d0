"""Bounds of a cloud's disks and the level of a ground plane under it (one O(n) pass).

Its own module so that both :class:`pointviz.scene.Scene` and :class:`pointviz.SurfelScene`
(which caches it per ``up``) use it without importing each other. The pass runs block by block
(EXTENT_BLOCK rows): the largest clouds get no whole-cloud temporaries, and the quantiles are
exact (:func:`blocked_quantile`), so the result is the whole-array formula's.
"""

from __future__ import annotations

import math

import numpy as np

from .arrays import bounds, dot3

#: Fraction of a large cloud's lowest points that may sink below the "auto" ground.
GROUND_OUTLIER_FRACTION = 0.0005
#: Clouds smaller than this rest on their lowest point.
GROUND_ROBUST_MIN_POINTS = 2000
#: Rows per block of :func:`cloud_extent`: bounds its temporaries (~40 bytes per row).
EXTENT_BLOCK = 1 << 18


def _keep_extreme(kept, values: np.ndarray, m: int, largest: bool):
    """The ``m`` smallest (or largest) of ``kept`` and ``values`` together, unordered (as a
    multiset: which of equal values is kept does not matter)."""
    if kept is not None and len(kept) == m:  # only values beyond kept's worst can enter
        worst = kept.min() if largest else kept.max()
        values = values[values > worst] if largest else values[values < worst]
        if len(values) == 0:
            return kept
    both = values if kept is None else np.concatenate((kept, values))
    if len(both) <= m:
        return both
    return np.partition(both, len(both) - m)[len(both) - m:] if largest else \
        np.partition(both, m - 1)[:m]


def blocked_quantile(blocks, n: int, q: float):
    """``np.quantile(np.concatenate(blocks), q)`` (method "linear", finite values) without
    holding the concatenation: only the ``min(q, 1 - q) * n + 2`` extreme values that can hold
    the two order statistics around the quantile are kept, and they are interpolated with
    numpy's own arithmetic, so the result is the same number.

    Parameters
    ----------
    blocks : iterable of 1-D arrays
        Together ``n`` finite values (one dtype).
    n : int
        Their count (>= 1).
    q : float
        In [0, 1].

    Returns
    -------
    numpy scalar of the blocks' dtype
    """
    q = float(q)
    virtual = float((n - 1) * np.float64(q))
    lower = min(int(math.floor(virtual)), n - 1)
    upper = min(lower + 1, n - 1)
    largest = q > 0.5
    m = n - lower if largest else upper + 1  # every value at or beyond the two order statistics
    kept = None
    for block in blocks:
        kept = _keep_extreme(kept, np.asarray(block).ravel(), m, largest)
    first = n - m if largest else 0  # the full order's index of kept's smallest
    kept = np.sort(kept)
    a, b = kept[lower - first:lower - first + 1], kept[upper - first:upper - first + 1]
    if virtual >= n - 1:
        return b[0]
    t = virtual - lower
    # numpy's _lerp (function_base): from the nearer end, so that t = 0 and 1 are exact
    diff = b - a
    out = np.add(a, diff * t)
    np.subtract(b, diff * (1 - t), out=out, where=t >= 0.5, casting="unsafe",
                dtype=type(out.dtype))
    return out[0]


def cloud_extent(points, radii, up) -> tuple[np.ndarray, np.ndarray, float]:
    """Bounds of a cloud's disks and the level of a ground plane under it.

    One O(n) pass in blocks of EXTENT_BLOCK rows; callers cache the result (see
    :meth:`Scene._extent`, :meth:`pointviz.SurfelScene.extent`).

    Parameters
    ----------
    points : (n, 3) float
    radii : (n,) float or None
        Disk radii: the bounds grow by the largest, the ground sinks by the 99th percentile.
    up : (3,) float, unit

    Returns
    -------
    lo, hi : (3,) float64
        Axis-aligned bounds including the largest radius.
    level : float
        Height along ``up`` of the ground: the lowest point, ignoring the lowest
        :data:`GROUND_OUTLIER_FRACTION` of a cloud with at least
        :data:`GROUND_ROBUST_MIN_POINTS` points.
    """
    n = len(points)
    starts = range(0, n, EXTENT_BLOCK)
    r, r99 = 0.0, 0.0
    if radii is not None:
        r = float(max(np.max(radii[b:b + EXTENT_BLOCK]) for b in starts))
        r99 = float(blocked_quantile((radii[b:b + EXTENT_BLOCK] for b in starts), n, 0.99))
    ext = [bounds(points[b:b + EXTENT_BLOCK]) for b in starts]
    lo = np.min([e[0] for e in ext], axis=0) - r
    hi = np.max([e[1] for e in ext], axis=0) + r
    heights = (dot3(points[b:b + EXTENT_BLOCK], up) for b in starts)
    if n >= GROUND_ROBUST_MIN_POINTS:
        low = blocked_quantile(heights, n, GROUND_OUTLIER_FRACTION)
    else:
        low = min(h.min() for h in heights)
    return lo, hi, float(low) - r99
