"""The readers by file extension, and the one entry point that picks among them.

=====================================  =================================================
``.ply``                               the core (points and meshes); Open3D for other layouts
``.pcd``                               the core (ASCII, binary, compressed)
``.xyz .xyzn .xyzrgb``                 the core; ``.pts`` through Open3D
``.obj``                               the core (positions, colours, faces)
``.stl .off``                          numpy (STL binary and ASCII, ASCII OFF)
``.glb .gltf``                         trimesh (scenes are flattened with their transforms)
``.las .laz``                          laspy (LAZ through lazrs, decompressed in parallel)
``.vtp .vtk``                          pyvista
``.conf``                              Stanford registration of several range scans
=====================================  =================================================
"""

from __future__ import annotations

from pathlib import Path

from ..cloud import PointCloud
from ..errors import FileFormatError, MissingDependencyError, PointvizError
from .conf import read_conf
from .las import read_las
from .mesh import read_mesh
from .pcd import read_pcd
from .ply import read_ply
from .text import read_text
from .vtk import read_vtk

#: Reader of each extension: ``reader(path, sample, rng) -> PointCloud``. A registration reads
#: its scans back through this registry (``read_file``), whatever their format.
READERS = {
    ".ply": read_ply, ".pcd": read_pcd,
    ".xyz": read_text, ".xyzn": read_text, ".xyzrgb": read_text, ".pts": read_text,
    ".obj": read_mesh, ".off": read_mesh, ".stl": read_mesh, ".glb": read_mesh, ".gltf": read_mesh,
    ".las": read_las, ".laz": read_las,
    ".vtp": read_vtk, ".vtk": read_vtk,
    ".conf": lambda path, sample, rng: read_conf(path, sample, rng, read_scan=read_file),
}  # fmt: skip

POINT_EXTENSIONS = (".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts")
MESH_EXTENSIONS = (".obj", ".off", ".stl", ".glb", ".gltf")
LIDAR_EXTENSIONS = (".las", ".laz")
VTK_EXTENSIONS = (".vtp", ".vtk")
CONF_EXTENSIONS = (".conf",)
SUPPORTED_EXTENSIONS = (
    POINT_EXTENSIONS + MESH_EXTENSIONS + LIDAR_EXTENSIONS + VTK_EXTENSIONS + CONF_EXTENSIONS
)


def read_file(path: Path, *, sample=None, rng=None) -> PointCloud:
    """Read one file with the reader of its extension.

    Raises
    ------
    FileFormatError
        Missing file, a directory, unsupported extension, empty file, or anything the reader
        finds wrong; the message always names the file.
    """
    if not path.exists():
        raise FileFormatError(f"{path}: no such file")
    if path.is_dir():
        raise FileFormatError(f"{path}: is a directory, not a file")
    ext = path.suffix.lower()
    if ext not in READERS:
        raise FileFormatError(
            f"{path}: unsupported extension {path.suffix!r}; supported: "
            + " ".join(SUPPORTED_EXTENSIONS)
        )
    if path.stat().st_size == 0:
        raise FileFormatError(f"{path}: the file is empty")
    try:
        return READERS[ext](path, sample, rng)
    except MissingDependencyError:
        raise
    except PointvizError as exc:
        if str(path) in str(exc):
            raise
        raise FileFormatError(f"{path}: {exc}") from exc
