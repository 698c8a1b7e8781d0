"""Loading point clouds, meshes, LiDAR and registered range scans as :class:`PointCloud`.

:func:`load` picks a reader by extension (:mod:`pointviz.readers.registry`):

=====================================  =================================================
``.ply .pcd .xyz .xyzn .xyzrgb``       the core's table and face readers (``.pts`` and PLY
                                       meshes of unusual layout through Open3D)
``.obj``                               the core (positions, colours, faces)
``.stl .off``                          numpy (STL binary and ASCII, ASCII OFF)
``.glb .gltf``                         trimesh (scenes are flattened with their transforms)
``.las .laz``                          laspy (LAZ through lazrs, decompressed in parallel)
``.vtp .vtk``                          pyvista
``.conf``                              Stanford registration of several range scans (read
                                       in parallel)
=====================================  =================================================

Every failure to read a file raises :class:`FileFormatError` naming the file. Headers are
checked against the file size and the rows read (Open3D reports errors only as printed warnings
and an empty or silently partial result, and crashes on some crafted headers).
"""

from __future__ import annotations

import os
from pathlib import Path

from .cloud import PointCloud, _unit_vector
from .errors import FileFormatError, InputError
from .readers.conf import RANGE_SCAN_VIEW_DISTANCE, parse_conf, quaternion_matrix
from .readers.registry import (
    CONF_EXTENSIONS,
    LIDAR_EXTENSIONS,
    MESH_EXTENSIONS,
    POINT_EXTENSIONS,
    SUPPORTED_EXTENSIONS,
    VTK_EXTENSIONS,
    read_file,
)
from .settings import check_int

__all__ = [
    "CONF_EXTENSIONS", "LIDAR_EXTENSIONS", "MESH_EXTENSIONS", "POINT_EXTENSIONS",
    "RANGE_SCAN_VIEW_DISTANCE", "SUPPORTED_EXTENSIONS", "VTK_EXTENSIONS", "estimate_radii_of",
    "load", "parse_conf", "quaternion_matrix",
]  # fmt: skip


def load(path, *, sample=None, estimate=True, fit=None, **kw) -> PointCloud:
    """Load a point cloud, mesh, LiDAR file or Stanford ``.conf`` registration.

    Parameters
    ----------
    path : str or os.PathLike
        The file; the reader is chosen by its (case-insensitive) extension, see
        :data:`SUPPORTED_EXTENSIONS`.
    sample : int or "auto", optional
        For meshes: draw this many points uniformly on the surface (normals and colours blended
        from the vertices', creases kept sharp) instead of using the vertices; ``"auto"``: the
        vertices, unless they lie too far apart for the picture
        (:func:`pointviz.readers.common.dense_sample_count`), then a seeded dense sampling. For
        point files: keep a uniformly random subset of this many points (all of them if the
        file has fewer; ``"auto"``: all).
    estimate : bool or "normals"
        If True (default), normals and radii the file does not provide are estimated before
        returning, so problems surface here with the file name and the cloud is ready to
        render. If False they are left to be estimated lazily on first access. "normals":
        as True for the fit and the normals, the radii left to the caller (who may estimate
        them while doing something else; :func:`estimate_radii_of` names the file in its
        errors as this function does).
    fit : bool, optional
        Move raw scans onto a robust fit of their surface and drop the points that add nothing
        where scans overlap (:meth:`PointCloud.fitted`; ``notes`` and ``fit_report`` say what
        changed). Default: with ``estimate`` and for raw scans only, i.e. files without normals
        whose scanner viewpoints are known (``.conf`` registrations; organised PCD clouds, one
        depth-camera frame each, up -y when in the camera's coordinates).
    **kw
        ``rng`` (numpy Generator or seed, for ``sample``), ``up`` and ``name`` (override what
        the loader sets: ``up=(0, 0, 1)`` for LAS/LAZ, the file name).

    Returns
    -------
    PointCloud
        With ``name`` set to the file name. Extra attributes: ``notes`` (what was dropped or
        assumed), ``intensity`` ((n,) float32, LAS/LAZ), ``scan_index`` ((n,) int32,
        ``.conf``) and ``scan_grid`` ((n, 2) int32, ``.conf`` of ASCII PLY range scans with a
        ``range_grid``: each point's row and column in its scanner's grid).

    Raises
    ------
    FileFormatError
        Missing file, unsupported extension, empty, truncated or unparsable file.
    InputError
        Bad arguments (unknown keyword, bad ``sample``).
    """
    unknown = set(kw) - {"rng", "up", "name"}
    if unknown:
        raise InputError(f"load: unknown keyword argument(s) {', '.join(sorted(unknown))}")
    if sample is not None and sample != "auto":
        check_int(sample, "sample")
    if estimate not in (True, False, "normals"):
        raise InputError(f"load: estimate must be True, False or 'normals', got {estimate!r}")
    path = Path(os.fspath(path))
    cloud = read_file(path, sample=sample, rng=kw.get("rng"))
    if "up" in kw:
        cloud.up = None if kw["up"] is None else _unit_vector("up", kw["up"])
    cloud.name = kw.get("name", path.name)
    if fit is None:
        fit = bool(estimate) and cloud.is_raw_scan
    if fit:
        try:
            cloud = cloud.fitted()
        except InputError as exc:
            raise FileFormatError(f"{path}: {exc}") from exc
    if estimate:
        try:
            cloud.normals  # noqa: B018 - computes and caches
        except InputError as exc:
            raise FileFormatError(f"{path}: {exc}") from exc
    if estimate and not isinstance(estimate, str):  # (True, or a numpy bool)
        estimate_radii_of(cloud, path)
    return cloud


def estimate_radii_of(cloud: PointCloud, path) -> None:
    """Estimate (and cache) the radii of a cloud loaded from ``path`` if the file gave none,
    an estimation error raised as :class:`FileFormatError` naming the file."""
    try:
        cloud.radii  # noqa: B018 - computes and caches
    except InputError as exc:
        raise FileFormatError(f"{path}: {exc}") from exc
