"""The curves a camera path is made of: centripetal Catmull-Rom splines, monotone time maps, and
quaternion slerp (see :mod:`pointviz.path` for how they compose)."""

from __future__ import annotations

import math

import numpy as np

#: Catmull-Rom exponent: 0.5 is the centripetal variant (no cusps or self-intersections).
CATMULL_ROM_ALPHA = 0.5
#: Knot increments are floored at this fraction of the largest one (repeated keyframe positions).
KNOT_FLOOR = 1e-9
#: Below this quaternion half angle (radians) slerp falls back to normalised lerp.
SLERP_EPS = 1e-9


def lerp(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``a + w (b - a)``, exact at ``w == 0`` (gives a) and ``w == 1`` (gives b).

    ``a, b`` shape (m, d) or (d,), ``w`` shape (m,). Written in difference form so that
    coincident ``a == b`` give exactly ``a`` even for large extrapolation weights.
    """
    w = w[:, None]
    diff = b - a
    return np.where(w < 0.5, a + w * diff, b - (1.0 - w) * diff)


def cumulative_knots(increments: np.ndarray) -> np.ndarray:
    """Cumulative knots (starting at 0) from non-negative increments, floored to stay increasing.

    Parameters
    ----------
    increments : ndarray, shape (m,), float64

    Returns
    -------
    ndarray, shape (m + 1,), float64, strictly increasing
    """
    largest = float(increments.max()) if increments.size else 0.0
    if largest == 0.0:
        increments = np.ones_like(increments)
    else:
        increments = np.maximum(increments, KNOT_FLOOR * largest)
    return np.concatenate([[0.0], np.cumsum(increments)])


def segment_index(knots: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Index k of the segment ``[knots[k], knots[k+1]]`` holding each x (clipped to valid)."""
    return np.clip(np.searchsorted(knots, x, side="right") - 1, 0, len(knots) - 2)


class CatmullRom:
    """Centripetal Catmull-Rom spline through points, phantom ends by reflection.

    Parameters
    ----------
    points : ndarray, shape (n, d), float64, n >= 1
    """

    def __init__(self, points: np.ndarray) -> None:
        self.n = len(points)
        if self.n == 1:
            self.points = points
            self.knots = np.zeros(1)
            return
        ext = np.concatenate([2 * points[:1] - points[1:2], points, 2 * points[-1:] - points[-2:-1]])
        steps = np.linalg.norm(np.diff(ext, axis=0), axis=1) ** CATMULL_ROM_ALPHA
        self.ext = ext
        self.ext_knots = cumulative_knots(steps)  # (n + 2,)
        self.knots = self.ext_knots[1:-1]  # knot of keyframe k
        self.points = points

    def __call__(self, tau: np.ndarray) -> np.ndarray:
        """Evaluate at knot values ``tau`` (m,) -> (m, d) (Barry-Goldman pyramid)."""
        if self.n == 1:
            return np.repeat(self.points, len(tau), axis=0)
        k = segment_index(self.knots, tau)
        p, t = self.ext, self.ext_knots
        q0, q1, q2, q3 = p[k], p[k + 1], p[k + 2], p[k + 3]
        t0, t1, t2, t3 = t[k], t[k + 1], t[k + 2], t[k + 3]
        a1 = lerp(q0, q1, (tau - t0) / (t1 - t0))
        a2 = lerp(q1, q2, (tau - t1) / (t2 - t1))
        a3 = lerp(q2, q3, (tau - t2) / (t3 - t2))
        b1 = lerp(a1, a2, (tau - t0) / (t2 - t0))
        b2 = lerp(a2, a3, (tau - t1) / (t3 - t1))
        return lerp(b1, b2, (tau - t1) / (t2 - t1))


class TimeMap:
    """Map from time to a scalar through (times[k], values[k]) for each easing mode.

    ``linear``: piecewise linear. ``ease-in-out``: C1 monotone cubic Hermite with
    Fritsch-Butland slopes inside and zero slopes at both ends.

    Parameters
    ----------
    times : ndarray, shape (n,), strictly increasing
    values : ndarray, shape (n,) or (n, d)
    easing : str
    """

    def __init__(self, times: np.ndarray, values: np.ndarray, easing: str) -> None:
        self.times = times
        self.values = values.reshape(len(times), -1)
        self.linear = easing == "linear"
        n = len(times)
        self.slopes = np.zeros_like(self.values)
        if n >= 3 and not self.linear:
            h = np.diff(times)[:, None]
            delta = np.diff(self.values, axis=0) / h
            d0, d1 = delta[:-1], delta[1:]
            w1 = 2 * h[1:] + h[:-1]
            w2 = h[1:] + 2 * h[:-1]
            same_sign = d0 * d1 > 0
            with np.errstate(divide="ignore", invalid="ignore"):
                mean = (w1 + w2) / (w1 / d0 + w2 / d1)
            self.slopes[1:-1] = np.where(same_sign, mean, 0.0)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Evaluate at times ``t`` (m,) -> (m, d)."""
        if len(self.times) == 1:
            return np.repeat(self.values, len(t), axis=0)
        k = segment_index(self.times, t)
        t0, t1 = self.times[k], self.times[k + 1]
        y0, y1 = self.values[k], self.values[k + 1]
        u = (t - t0) / (t1 - t0)
        if self.linear:
            return lerp(y0, y1, u)
        h = (t1 - t0)[:, None]
        uu = u[:, None]
        h01 = uu * uu * (3 - 2 * uu)  # smoothstep weight of y1
        h10 = uu * (1 - uu) ** 2
        h11 = uu * uu * (uu - 1)
        tangents = h * (h10 * self.slopes[k] + h11 * self.slopes[k + 1])
        base = np.where(uu < 0.5, y0 + h01 * (y1 - y0), y1 - (1 - h01) * (y1 - y0))
        return base + tangents


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a proper rotation matrix (3, 3) (Shepperd's method)."""
    trace = np.trace(m)
    cand = np.array([trace, m[0, 0], m[1, 1], m[2, 2]])
    i = int(np.argmax(cand))
    if i == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif i == 1:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif i == 2:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    return q / np.linalg.norm(q)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (m, 3) by unit quaternions q (m, 4) (w, x, y, z)."""
    w, xyz = q[:, :1], q[:, 1:]
    t = 2.0 * np.cross(xyz, v)
    return v + w * t + np.cross(xyz, t)


def slerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Slerp between unit quaternions q0, q1 (m, 4) (same hemisphere) at fractions w (m,)."""
    dot = np.clip(np.sum(q0 * q1, axis=1), -1.0, 1.0)
    half = np.arccos(dot)
    small = half < SLERP_EPS
    sin_half = np.where(small, 1.0, np.sin(half))
    c0 = np.where(small, 1.0 - w, np.sin((1.0 - w) * half) / sin_half)
    c1 = np.where(small, w, np.sin(w * half) / sin_half)
    q = c0[:, None] * q0 + c1[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def transport(v: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Apply the minimal rotation taking unit a to unit b to v (all (m, 3)).

    Where a and b are (nearly) opposite the rotation is undefined and v is returned unchanged.
    """
    k = np.cross(a, b)
    c = np.sum(a * b, axis=1, keepdims=True)
    opposite = c <= -1.0 + 1e-12
    denom = np.where(opposite, 1.0, 1.0 + c)
    kv = np.cross(k, v)
    out = v + kv + np.cross(k, kv) / denom
    return np.where(opposite, v, out)
