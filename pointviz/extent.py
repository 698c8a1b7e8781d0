"""Bounds of a cloud's disks and the level of a ground plane under it (one O(n) pass).

Its own module so that both :class:`pointviz.scene.Scene` and :class:`pointviz.SurfelScene`
(which caches it per ``up``) use it without importing each other.
"""

from __future__ import annotations

import numpy as np

from .arrays import bounds, dot3

#: Fraction of a large cloud's lowest points that may sink below the "auto" ground.
GROUND_OUTLIER_FRACTION = 0.0005
#: Clouds smaller than this rest on their lowest point.
GROUND_ROBUST_MIN_POINTS = 2000


def cloud_extent(points, radii, up) -> tuple[np.ndarray, np.ndarray, float]:
    """Bounds of a cloud's disks and the level of a ground plane under it.

    One O(n) pass; callers cache the result (see :meth:`Scene._extent`,
    :meth:`pointviz.SurfelScene.extent`).

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
    r = float(np.max(radii)) if radii is not None else 0.0
    lo, hi = bounds(points)
    lo, hi = lo - r, hi + r
    h = dot3(points, up)
    r99 = float(np.quantile(radii, 0.99)) if radii is not None else 0.0
    low = (np.quantile(h, GROUND_OUTLIER_FRACTION) if len(h) >= GROUND_ROBUST_MIN_POINTS
           else h.min())
    return lo, hi, float(low) - r99
