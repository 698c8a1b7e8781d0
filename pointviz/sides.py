"""Whether a tree's surfels close a surface: the test behind ``SurfelScene(cull="auto")``.

Back-face culling (the paper's normal cones) skips the disks that face away from a ray. On a
closed surface that loses nothing: a ray from outside meets a front face first, and the only
back faces it can meet are disks of the far side that reach past the near side's rim, at
silhouettes and the tips of thin parts. Shown two-sided, those are shaded with their normal
turned toward the viewer, which points into the object: its shadow and sky-visibility rays are
blocked, and the rim gets dark flecks (2.6 % of the dragon's raw scans' hit pixels in its
default view). On an open surface (a terrain tile, one range scan, a depth-camera frame) the back
faces are the surface seen from behind, which culling would hide.

:func:`back_face_share` casts rays at the tree from all around it with culling off and counts
the first hits that are back faces; :func:`closed` calls the surface closed when they are at
most CLOSED_BACK_SHARE of the hits. Measured on ``../shared/data`` (benchmarks/README.md,
"Rims of closed scans: one side or two"): reconstructions and registered scan sets of whole
objects 0.2-3 % (Armadillo, the bunny's 10 scans, Lucy, the pepper, Spot, the teapot, the
dragon's reconstruction), photogrammetry and scan sets with an unscanned base or an opening
3-11.2 % (Demosthenes, the SfM owl and vase, the dragon's 15 scans), open data 25-61 % (the
drill's scan set, single range scans, depth-camera frames, LiDAR tiles). A surface closed with
its normals pointing inward is not taken for closed (``horse_cyberware.ply``, a mesh saved
inside out: 99 % before reading learnt to turn such meshes, :func:`pointviz.cloud.outward_faces`;
0.6 % since).
"""

from __future__ import annotations

import numpy as np

#: Most back faces among the probe's first hits of a closed surface (see the module's text).
CLOSED_BACK_SHARE = 0.15
#: Directions the probe looks from (a Fibonacci sphere: all around, evenly).
PROBE_DIRECTIONS = 48
#: Parallel rays per direction: a PROBE_GRID x PROBE_GRID grid over the bounding sphere.
PROBE_GRID = 16


def probe_rays(centre, radius: float, directions: int = PROBE_DIRECTIONS,
               grid: int = PROBE_GRID) -> np.ndarray:
    """Rays toward a sphere from all around it: for each of ``directions`` directions on a
    Fibonacci sphere, a ``grid`` x ``grid`` square of parallel rays whose side is the sphere's
    diameter, starting twice its radius from its centre.

    Returns
    -------
    (directions * grid**2, 6) float64
        Origin and unit direction per row.
    """
    c = np.asarray(centre, dtype=np.float64).reshape(3)
    i = np.arange(directions) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / directions)
    turn = np.pi * (1.0 + 5.0 ** 0.5) * i
    dirs = np.stack([np.cos(turn) * np.sin(polar), np.sin(turn) * np.sin(polar), np.cos(polar)], 1)
    # a basis (a, b) across each direction
    helper = np.where(np.abs(dirs[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    a = np.cross(dirs, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(dirs, a)
    u = (np.arange(grid) + 0.5) / grid * 2.0 - 1.0
    uu, vv = (g.reshape(-1) for g in np.meshgrid(u, u))
    origins = (c - 2.0 * radius * dirs)[:, None, :] + radius * (
        uu[None, :, None] * a[:, None, :] + vv[None, :, None] * b[:, None, :])
    d = np.broadcast_to(dirs[:, None, :], origins.shape)
    return np.concatenate([origins, d], axis=2).reshape(-1, 6)


def back_face_share(scene) -> float | None:
    """Share of back faces among the first hits of :func:`probe_rays` around ``scene``'s
    bounding sphere, traced at full detail with culling off.

    Parameters
    ----------
    scene : SurfelScene

    Returns
    -------
    float or None
        In [0, 1]; None when no probe ray hits (nothing to decide from).
    """
    centre, radius = scene.bounding_sphere()
    if not (np.all(np.isfinite(centre)) and np.isfinite(radius) and radius > 0):
        return None
    rays = probe_rays(centre, radius)
    out = scene.cast_rays(rays, lod_pixels=0.0, stats=False, cull=False)
    hit = np.isfinite(out["t_hit"])
    if not hit.any():
        return None
    facing = np.einsum("ij,ij->i", out["normals"][hit], rays[hit, 3:])
    return float(np.count_nonzero(facing > 0.0)) / float(np.count_nonzero(hit))


def closed(share: float | None) -> bool:
    """Whether a :func:`back_face_share` says the surface is closed: at most
    CLOSED_BACK_SHARE of the probe's first hits are back faces (None: nothing was hit)."""
    return share is not None and share <= CLOSED_BACK_SHARE
