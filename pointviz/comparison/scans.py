"""Virtual range scans of exact shapes: what a scanner would give, with a known truth.

A scan is a grid of rays from a viewpoint toward the shape, each traced to the exact surface
(sphere tracing of the shape's signed distance, which is exact for a sphere and a torus), its
depth perturbed by Gaussian noise; each scan is then moved by a small random rigid motion, the
misregistration that remains after aligning real scans. Points carry their scan's viewpoint and
index, like registered Stanford ``.conf`` scans, and no normals.

The exact shape answers the questions a test or a benchmark asks of estimated surfels: the
distance of any point to the surface and the true normal there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..cloud import PointCloud
from ..errors import InputError
from . import analytic

#: Sphere-tracing steps; a step moves by the signed distance, so rays converge geometrically
#: except at grazing angles, where the last steps stop them short of the surface.
TRACE_STEPS = 200
#: A ray hits when its distance to the surface falls below this fraction of the shape's size.
HIT_TOLERANCE = 1e-7
#: Viewpoints stand this many shape sizes from the centre (a tabletop scanner's standoff).
VIEW_DISTANCE = 2.0


@dataclass(frozen=True)
class ExactShape:
    """A shape with an exact distance: ``"sphere"`` (radius 1) or ``"torus"`` (major radius 1,
    minor 0.35, around the y axis, as :func:`pointviz.comparison.analytic.torus_mesh`)."""

    name: str

    @property
    def size(self) -> float:
        """Diameter of the shape."""
        return 2.0 if self.name == "sphere" else 2.0 * (1.0 + 0.35)

    def _nearest(self, points: np.ndarray):
        """(centre of the nearest generating sphere (n, 3), its radius)."""
        p = np.asarray(points, dtype=np.float64)
        if self.name == "sphere":
            return np.zeros_like(p), 1.0
        ring = np.linalg.norm(p[:, [0, 2]], axis=1, keepdims=True)
        c = np.zeros_like(p)
        c[:, [0, 2]] = p[:, [0, 2]] / np.maximum(ring, 1e-300)
        return c, 0.35

    def signed_distance(self, points) -> np.ndarray:
        """(n,) exact signed distance (negative inside)."""
        c, r = self._nearest(points)
        return np.linalg.norm(np.asarray(points, dtype=np.float64) - c, axis=1) - r

    def normal(self, points) -> np.ndarray:
        """(n, 3) outward unit normal at the surface point nearest to each point."""
        c, _ = self._nearest(points)
        d = np.asarray(points, dtype=np.float64) - c
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def mesh(self, res: int = analytic.REFERENCE_RES):
        """A fine reference triangulation: (vertices (v, 3) float64, faces (f, 3) int32)."""
        if self.name == "sphere":
            return analytic.sphere_mesh(1.0, res=res)
        return analytic.torus_mesh(1.0, 0.35, res=res)


def _trace(shape: ExactShape, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(n,) distance along each unit ray to the first hit, NaN where the ray misses."""
    t = np.zeros(len(dirs))
    active = np.arange(len(dirs))
    hit = np.full(len(dirs), np.nan)
    limit = 2.0 * VIEW_DISTANCE * shape.size
    tol = HIT_TOLERANCE * shape.size
    for _ in range(TRACE_STEPS):
        if active.size == 0:
            break
        d = shape.signed_distance(origin + t[active, None] * dirs[active])
        done = d < tol
        hit[active[done]] = t[active[done]]
        t[active] += np.maximum(d, 0.0)
        active = active[~done & (t[active] < limit)]
    return hit


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def virtual_scans(shape: str = "torus", *, scans: int = 8, resolution: int = 160,
                  noise: float = 0.001, misregistration: float = 0.0005, seed: int = 0):
    """Registered range scans of an exact shape, with depth noise and misregistration.

    Parameters
    ----------
    shape : {"sphere", "torus"}
    scans : int
        Viewpoints, spread evenly (Fibonacci) over a sphere around the shape, alternately a
        little above and below its equator so that every part is seen.
    resolution : int
        Rays per side of each scan's square grid.
    noise : float
        Standard deviation of the depth noise, as a fraction of the shape's size.
    misregistration : float
        Standard deviation of each scan's rigid motion: translation per axis as a fraction of
        the size, rotation angle in radians.
    seed : int

    Returns
    -------
    cloud : PointCloud
        Points without normals, ``viewpoints`` (n, 3), ``scan_index`` and ``scan_grid`` (each
        point's ray in its scan's grid).
    exact : ExactShape
    """
    if shape not in ("sphere", "torus"):
        raise InputError(f"shape: expected 'sphere' or 'torus', got {shape!r}")
    if scans < 1 or resolution < 2:
        raise InputError("scans and resolution: need at least 1 scan of 2 x 2 rays")
    exact = ExactShape(shape)
    rng = np.random.default_rng(seed)
    size = exact.size
    i = np.arange(scans) + 0.5
    y = 1.0 - 2.0 * i / scans
    y = np.clip(0.8 * y, -0.8, 0.8)  # no scan straight down the torus's axis only
    phi = np.pi * (1.0 + 5**0.5) * i
    views = np.stack([np.sqrt(1 - y * y) * np.cos(phi), y, np.sqrt(1 - y * y) * np.sin(phi)], 1)
    views *= VIEW_DISTANCE * size
    half = np.arctan(0.55 * size / (VIEW_DISTANCE * size))  # the shape fills the view
    s = np.tan(half) * np.linspace(-1.0, 1.0, resolution)
    gu, gv = np.meshgrid(s, s, indexing="ij")
    pts, vps, idx, cells = [], [], [], []
    for k, eye in enumerate(views):
        fwd = -eye / np.linalg.norm(eye)
        right = np.cross(fwd, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        dirs = fwd + gu.reshape(-1, 1) * right + gv.reshape(-1, 1) * up
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        t = _trace(exact, eye, dirs)
        ok = np.isfinite(t)
        t = t[ok] + rng.normal(0.0, noise * size, ok.sum())
        p = eye + t[:, None] * dirs[ok]
        rot = _rotation(rng.normal(size=3), rng.normal(0.0, misregistration))
        shift = rng.normal(0.0, misregistration * size, 3)
        pts.append(p @ rot.T + shift)
        vps.append(np.repeat((rot @ eye + shift)[None], ok.sum(), axis=0))
        idx.append(np.full(ok.sum(), k, np.int32))
        cells.append(np.stack(np.divmod(np.flatnonzero(ok), resolution), 1).astype(np.int32))
    cloud = PointCloud(np.concatenate(pts), viewpoints=np.concatenate(vps),
                       scan_index=np.concatenate(idx), scan_grid=np.concatenate(cells),
                       name=f"{shape} scans",
                       notes=[f"{scans} virtual scans of a {shape}, depth noise {noise:g} x size, "
                              f"misregistration {misregistration:g}"])
    return cloud, exact
