"""Exact shapes as points (from :mod:`pointviz.shapes`) and as fine triangulations, so that a
comparison on generated scenes has a reference without any data files."""

from __future__ import annotations

import numpy as np

from ..errors import InputError

#: Grid resolution of the reference triangulations: at 512 x 1024 cells the chord error of a unit
#: sphere is 1 - cos(pi / 1024) ~ 5e-6 radii, far below a pixel at any size we render.
REFERENCE_RES = 512


def _grid_faces(nu: int, nv: int, wrap_u: bool, wrap_v: bool) -> np.ndarray:
    """Two triangles per cell of an (nu, nv) vertex grid (indices i * nv + j)."""
    cu = nu if wrap_u else nu - 1
    cv = nv if wrap_v else nv - 1
    i, j = np.meshgrid(np.arange(cu), np.arange(cv), indexing="ij")
    i, j = i.ravel(), j.ravel()
    i1, j1 = (i + 1) % nu, (j + 1) % nv
    a, b, c, d = i * nv + j, i1 * nv + j, i1 * nv + j1, i * nv + j1
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)


def sphere_mesh(radius=1.0, center=(0.0, 0.0, 0.0), res: int = REFERENCE_RES, y_min: float = -2.0):
    """Latitude-longitude sphere (y is the pole axis); ``y_min`` > -1 keeps only the cap above
    that height (in radii). Returns (vertices (v, 3) float64, faces (f, 3) int32)."""
    lo = -np.pi / 2 if y_min <= -1 else np.arcsin(np.clip(y_min, -1, 1))
    lat = np.linspace(lo, np.pi / 2, res + 1)
    lon = np.linspace(0, 2 * np.pi, 2 * res, endpoint=False)
    la, lo_ = np.meshgrid(lat, lon, indexing="ij")
    v = np.stack([np.cos(la) * np.cos(lo_), np.sin(la), np.cos(la) * np.sin(lo_)], -1).reshape(-1, 3)
    f = _grid_faces(res + 1, 2 * res, False, True)
    return v * radius + np.asarray(center, float), f


def torus_mesh(major=1.0, minor=0.35, center=(0.0, 0.0, 0.0), res: int = REFERENCE_RES):
    """Torus around the y axis, as :func:`pointviz.shapes.torus`."""
    u = np.linspace(0, 2 * np.pi, 2 * res, endpoint=False)
    w = np.linspace(0, 2 * np.pi, res, endpoint=False)
    U, W = np.meshgrid(u, w, indexing="ij")
    ring = np.stack([np.cos(U), np.zeros_like(U), np.sin(U)], -1)
    n = ring * np.cos(W)[..., None] + np.array([0, 1.0, 0]) * np.sin(W)[..., None]
    v = (ring * major + n * minor).reshape(-1, 3) + np.asarray(center, float)
    return v, _grid_faces(2 * res, res, True, True)


def box_mesh(size=(1.0, 1.0, 1.0), center=(0.0, 0.0, 0.0)):
    """An axis-aligned box: 8 vertices, 12 triangles (exact)."""
    s = np.asarray(size, float) / 2
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * s
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.int32)
    return v + np.asarray(center, float), f


def plane_mesh(size=2.0, center=(0.0, 0.0, 0.0)):
    """A square in the y = center.y plane (2 triangles)."""
    h = size / 2
    v = np.array([[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]], float) + np.asarray(center, float)
    return v, np.array([[0, 2, 1], [0, 3, 2]], np.int32)


#: Generated inputs: name -> (points(n), reference mesh)
SHAPES = ("demo", "sphere", "torus", "box")


def shape(name: str, n: int):
    """(PointCloud, (vertices, faces)) for a generated input name (see :data:`SHAPES`);
    ``demo`` is the torus (curvature of both signs and a hole)."""
    from .. import shapes

    if name in ("demo", "torus"):
        return shapes.torus(n, 1.0, 0.35), torus_mesh(1.0, 0.35)
    if name == "sphere":
        return shapes.sphere(n, 1.0), sphere_mesh(1.0)
    if name == "box":
        return shapes.box(n, (1.0, 0.6, 0.8)), box_mesh((1.0, 0.6, 0.8))
    raise InputError(f"input: expected a file or one of {', '.join(SHAPES)}, got {name!r}")
