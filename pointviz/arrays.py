"""Passes over (n, 3) point arrays that numpy makes slow when written the obvious way.

A reduction over the short axis of a C-ordered (n, 3) array (``points.min(axis=0)``, ``np.ptp``)
runs an inner loop of length 3 per row, and ``points @ v`` goes through BLAS threads: on 1M
points both are 10-100x slower than the same work done column by column.
"""

from __future__ import annotations

import numpy as np


def bounds(points) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds of (n, 3) points (n >= 1), column by column.

    Returns
    -------
    lo, hi : (3,) float64
    """
    pts = np.asarray(points)
    cols = [pts[:, k] for k in range(3)]
    return (np.array([c.min() for c in cols], dtype=np.float64),
            np.array([c.max() for c in cols], dtype=np.float64))


def dot3(points, v) -> np.ndarray:
    """``points @ v`` for (n, 3) points and a (3,) vector, without BLAS.

    Returns
    -------
    (n,) float64
    """
    pts = np.asarray(points)
    v = np.asarray(v, dtype=np.float64).reshape(3)
    return pts[:, 0] * v[0] + pts[:, 1] * v[1] + pts[:, 2] * v[2]
