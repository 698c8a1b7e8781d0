"""Analytic surfel shapes: exact positions and normals, for demos and as test oracles.

Every generator returns a :class:`~pointviz.cloud.PointCloud` with exact normals and radii
derived from the sampling density, and optionally a colour.
"""

from __future__ import annotations

import numpy as np

from .cloud import PointCloud
from .settings import check_int

_GOLDEN = np.pi * (3.0 - np.sqrt(5.0))

#: Disk radius per sample spacing for lattice-sampled shapes: sqrt(2)/2 of the spacing covers
#: a square lattice; the margin covers the irregular Fibonacci lattice and mild curvature.
LATTICE_RADIUS_FACTOR = 0.9


def _count(n, name="n") -> int:
    return check_int(n, name)


def _colored(points, normals, radii, color, **kw) -> PointCloud:
    colors = None
    if color is not None:
        colors = np.broadcast_to(np.asarray(color, dtype=np.float32), points.shape).copy()
    return PointCloud(points, normals=normals, radii=radii, colors=colors, **kw)


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) float64 unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    n = _count(n)
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = _GOLDEN * i
    return np.stack([r * np.cos(phi), z, r * np.sin(phi)], axis=1)


def sphere(n: int = 20000, radius: float = 1.0, center=(0.0, 0.0, 0.0), color=None) -> PointCloud:
    """Surfels on a sphere (y is the pole axis); normals point outward."""
    u = fibonacci_sphere(n)
    spacing = radius * np.sqrt(4 * np.pi / n)
    radii = np.full(len(u), LATTICE_RADIUS_FACTOR * spacing, np.float32)
    return _colored(u * radius + np.asarray(center, float), u, radii, color)


def torus(n: int = 30000, major: float = 1.0, minor: float = 0.35, center=(0.0, 0.0, 0.0),
          color=None) -> PointCloud:
    """Surfels on a torus around the y axis, sampled uniformly by area."""
    n = _count(n)
    rng = np.random.default_rng(12345)
    # Uniform by area: accept the tube angle with probability proportional to the local radius.
    u = rng.uniform(0, 2 * np.pi, 4 * n)
    v = rng.uniform(0, 2 * np.pi, 4 * n)
    keep = rng.uniform(0, 1, 4 * n) < (major + minor * np.cos(v)) / (major + minor)
    u, v = u[keep][:n], v[keep][:n]
    ring = np.stack([np.cos(u), np.zeros_like(u), np.sin(u)], axis=1)
    normals = ring * np.cos(v)[:, None] + np.array([0.0, 1.0, 0.0]) * np.sin(v)[:, None]
    points = ring * major + normals * minor + np.asarray(center, float)
    area = 4 * np.pi**2 * major * minor
    # Random (not lattice) sampling leaves larger gaps: use per-point spacing estimates.
    cloud = _colored(points, normals, None, color)
    del area
    return cloud


def box(n: int = 24000, size=(1.0, 1.0, 1.0), center=(0.0, 0.0, 0.0), color=None) -> PointCloud:
    """Surfels on the six faces of an axis-aligned box (square lattices), outward normals."""
    n = _count(n)
    size = np.asarray(size, dtype=np.float64)
    areas = 2 * np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]])
    spacing = np.sqrt(areas.sum() / n)
    pts, nrm = [], []
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        na = max(1, int(round(size[a] / spacing)))
        nb = max(1, int(round(size[b] / spacing)))
        ga = (np.arange(na) + 0.5) / na * size[a] - size[a] / 2
        gb = (np.arange(nb) + 0.5) / nb * size[b] - size[b] / 2
        A, B = np.meshgrid(ga, gb, indexing="ij")
        for sign in (-1.0, 1.0):
            p = np.zeros((A.size, 3))
            p[:, a], p[:, b] = A.ravel(), B.ravel()
            p[:, axis] = sign * size[axis] / 2
            nn = np.zeros_like(p)
            nn[:, axis] = sign
            pts.append(p)
            nrm.append(nn)
    points = np.concatenate(pts) + np.asarray(center, float)
    normals = np.concatenate(nrm)
    radii = np.full(len(points), LATTICE_RADIUS_FACTOR * spacing, np.float32)
    return _colored(points, normals, radii, color)


def plane(n: int = 10000, size: float = 2.0, center=(0.0, 0.0, 0.0), color=None,
          jitter: float = 0.0, seed: int = 0) -> PointCloud:
    """Surfels on a square in the y = center.y plane, normals +y; ``jitter`` in spacings."""
    k = max(1, int(round(np.sqrt(_count(n)))))
    g = (np.arange(k) + 0.5) / k * size - size / 2
    X, Z = np.meshgrid(g, g, indexing="ij")
    spacing = size / k
    pts = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], axis=1)
    if jitter > 0:
        rng = np.random.default_rng(seed)
        pts[:, [0, 2]] += rng.uniform(-0.5, 0.5, (len(pts), 2)) * jitter * spacing
    normals = np.tile([0.0, 1.0, 0.0], (len(pts), 1))
    factor = LATTICE_RADIUS_FACTOR * (1.0 + jitter)
    radii = np.full(len(pts), factor * spacing, np.float32)
    return _colored(pts + np.asarray(center, float), normals, radii, color)


def demo_scene(detail: float = 1.0):
    """The built-in demo: a sphere, a torus and a box of surfels over a mirror floor.

    Returns
    -------
    (Scene, Camera)
    """
    from .camera import Camera
    from .scene import DirectionalLight, Material, Scene

    k = max(detail, 0.01)
    objs = [
        sphere(int(60000 * k), 0.8, (-1.2, 0.8, 0.0), color=(0.85, 0.22, 0.15)),
        torus(int(90000 * k), 0.75, 0.28, (1.15, 0.28, 0.35), color=(0.95, 0.75, 0.3)),
        box(int(40000 * k), (0.7, 0.7, 0.7), (0.1, 0.35, -1.3), color=(0.25, 0.45, 0.85)),
    ]
    mats = [Material(specular=0.5, shininess=80), Material.glossy(), Material(specular=0.2)]
    ground = Material(color=(0.55, 0.56, 0.6), checker=(0.35, 0.36, 0.4), checker_size=0.5,
                      specular=0.0, mirror=0.45, use_point_colors=False)
    lights = [DirectionalLight(direction=(-0.5, 1.0, 0.55), intensity=1.2, angle_deg=4.0)]
    scene = Scene(objs, lights=lights, ground=ground, materials=mats, up=(0, 1, 0))
    camera = Camera.look_at((0.6, 2.4, 5.2), (0.0, 0.45, -0.2), fov_deg=40, width=800, height=500)
    return scene, camera
