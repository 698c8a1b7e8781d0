"""Surface reconstruction from the same points the surfels use (Open3D): screened Poisson, ball
pivoting and alpha shapes. Every step is timed.

Each function returns a :class:`Reconstruction` whose ``timings`` holds the seconds of each
step; normals are the cloud's own (given, or estimated and oriented by :class:`PointCloud` and
timed by the caller as part of preprocessing).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError, require

#: Poisson vertices whose sampling density is below this quantile are removed: the screened
#: Poisson solve closes every surface, and the low-density part is the surface it invented over
#: holes and open boundaries (Open3D's own example trims at 0.01..0.1).
POISSON_TRIM_QUANTILE = 0.02

#: Open3D's multithreaded Poisson solve is not bit-reproducible (the vertex sums of three runs on
#: the same 12k points differ in the 6th digit), one thread is, and on a 2-core machine costs
#: little: the default keeps identical settings giving identical metrics.
POISSON_THREADS = 1

#: Ball-pivoting radii, in mean nearest-neighbour spacings: one ball of the spacing closes most
#: triangles; larger balls bridge the sparser places (Bernardini et al. use a few growing radii).
BPA_RADIUS_FACTORS = (1.0, 2.0, 4.0)

#: Alpha-shape alpha, in mean nearest-neighbour spacings. The mean spacing understates the gaps
#: of irregular sampling: on a randomly sampled torus (12k points) 3 spacings leave 74% of the
#: silhouette as holes and 5 still leave gaps; 8 closes it without filling the hole of the torus.
ALPHA_FACTOR = 8.0


@dataclass
class Reconstruction:
    """A triangle mesh reconstructed from points.

    Attributes
    ----------
    vertices : (v, 3) float64
    faces : (f, 3) int32
    colors : (v, 3) float32 or None
    timings : dict of str -> float
        Seconds per step (``reconstruct``, ``trim``...).
    params : dict
        The settings used.
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None
    timings: dict = field(default_factory=dict)
    params: dict = field(default_factory=dict)

    @property
    def seconds(self) -> float:
        return float(sum(self.timings.values()))


def _o3d_cloud(cloud):
    o3d = require("open3d", "compare")
    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(np.array(cloud.points, dtype=np.float64))
    pcd.normals = o3d.utility.Vector3dVector(np.array(cloud.normals, dtype=np.float64))
    if cloud.colors is not None:
        pcd.colors = o3d.utility.Vector3dVector(np.array(cloud.colors, dtype=np.float64))
    return o3d, pcd


def _result(mesh, timings, params, cloud) -> Reconstruction:
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.triangles, dtype=np.int32).reshape(-1, 3)
    # Open3D gives every mesh black vertex colours when the points had none: keep only real ones
    c = None
    if cloud.colors is not None and mesh.has_vertex_colors():
        c = np.clip(np.asarray(mesh.vertex_colors, dtype=np.float32), 0.0, 1.0)
    return Reconstruction(v, f, c, timings, params)


def mean_spacing(cloud) -> float:
    """Mean distance from a point to its nearest neighbour (float)."""
    from .estimation import knn

    d, _ = knn(np.asarray(cloud.points), 1)
    return float(np.mean(d[:, 0]))


def poisson(cloud, depth: int = 8, trim_quantile: float = POISSON_TRIM_QUANTILE,
            threads: int = POISSON_THREADS) -> Reconstruction:
    """Screened Poisson reconstruction (Kazhdan & Hoppe 2013) at octree ``depth``.

    Parameters
    ----------
    cloud : PointCloud
    depth : int
        Octree depth (6..12): resolution 2**depth over the bounding cube.
    trim_quantile : float in [0, 1)
        Remove vertices whose density is below this quantile (0: keep the closed surface).
    threads : int
        Solver threads (-1: all; not reproducible bit for bit).
    """
    if not (isinstance(depth, (int, np.integer)) and 1 <= depth <= 14):
        raise InputError(f"depth: expected an integer in [1, 14], got {depth!r}")
    if not (0.0 <= trim_quantile < 1.0):
        raise InputError(f"trim_quantile: expected a number in [0, 1), got {trim_quantile!r}")
    o3d, pcd = _o3d_cloud(cloud)
    t0 = time.perf_counter()
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            pcd, depth=int(depth), n_threads=int(threads))
    t1 = time.perf_counter()
    dens = np.asarray(dens)
    if trim_quantile > 0 and len(dens):
        mesh.remove_vertices_by_mask(dens < np.quantile(dens, trim_quantile))
    t2 = time.perf_counter()
    return _result(mesh, {"reconstruct": t1 - t0, "trim": t2 - t1},
                   {"depth": int(depth), "trim_quantile": float(trim_quantile)}, cloud)


def ball_pivoting(cloud, factors=BPA_RADIUS_FACTORS, spacing: float | None = None) -> Reconstruction:
    """Ball pivoting (Bernardini et al. 1999) with ball radii ``factors`` x the mean spacing."""
    o3d, pcd = _o3d_cloud(cloud)
    t0 = time.perf_counter()
    s = mean_spacing(cloud) if spacing is None else float(spacing)
    radii = [float(f) * s for f in factors]
    t1 = time.perf_counter()
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(
        pcd, o3d.utility.DoubleVector(radii))
    t2 = time.perf_counter()
    return _result(mesh, {"spacing": t1 - t0, "reconstruct": t2 - t1},
                   {"radii_spacings": [float(f) for f in factors], "spacing": s}, cloud)


def alpha_shape(cloud, factor: float = ALPHA_FACTOR, spacing: float | None = None) -> Reconstruction:
    """Alpha shape (Edelsbrunner & Mücke 1994) with alpha = ``factor`` x the mean spacing."""
    o3d, pcd = _o3d_cloud(cloud)
    t0 = time.perf_counter()
    s = mean_spacing(cloud) if spacing is None else float(spacing)
    t1 = time.perf_counter()
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_alpha_shape(pcd, factor * s)
    t2 = time.perf_counter()
    return _result(mesh, {"spacing": t1 - t0, "reconstruct": t2 - t1},
                   {"alpha_spacings": float(factor), "spacing": s}, cloud)
