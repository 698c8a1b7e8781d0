"""Triangle meshes: OBJ in the core (its positions, vertex colours and faces), STL with numpy
(binary and ASCII), OFF through Open3D, glTF through trimesh."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FileFormatError, require
from .common import is_number, mesh_cloud, mesh_from_o3d, quiet_open3d


def read_mesh(path: Path, sample, rng) -> PointCloud:
    ext = path.suffix.lower()
    if ext in (".glb", ".gltf"):
        trimesh = require("trimesh", "io")
        try:
            mesh = trimesh.load(str(path), force="mesh", process=False)
        except Exception as exc:  # trimesh raises many types for bad files
            raise FileFormatError(f"{path}: could not read the glTF file ({exc})") from exc
        vertices = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))))
        faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3), dtype=np.int64)))
        colors = None
        visual = getattr(mesh, "visual", None)
        if visual is not None and getattr(visual, "kind", None) == "vertex":
            colors = np.asarray(visual.vertex_colors)[:, :3]
        return mesh_cloud(path, vertices, faces, None, colors, sample=sample, rng=rng, merge=True)
    if ext == ".obj":
        return _read_obj(path, sample, rng)
    if ext == ".stl":
        return mesh_cloud(path, *read_stl(path), None, None, sample=sample, rng=rng, merge=True)
    o3d = require("open3d", "io")
    with quiet_open3d(o3d):
        mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.vertices) == 0:
        raise FileFormatError(f"{path}: no vertices could be read (empty or unparsable file)")
    return mesh_from_o3d(path, mesh, sample, rng)




def _read_obj(path: Path, sample, rng) -> PointCloud:
    """An OBJ file through the core's reader (``ext/include/pointviz/readers/obj.h``): normals
    from the faces (the file's ``vn`` are not read), exact duplicate positions merged."""
    from .. import _core
    from . import table

    try:
        mesh = _core.read_obj(str(path))
    except table.MalformedData as exc:
        raise FileFormatError(f"{path}: malformed OBJ: {exc}") from None
    except RuntimeError as exc:
        raise FileFormatError(f"{path}: could not read the OBJ file ({exc})") from None
    if len(mesh["vertices"]) == 0:
        raise FileFormatError(f"{path}: no vertices could be read (empty or unparsable file)")
    colors = mesh["colors"]
    if colors is not None:
        finite = colors[np.isfinite(colors)]
        scale = 255.0 if finite.size and finite.max() > 1.0 else 1.0  # 0-255 by some writers
        colors = np.clip(np.nan_to_num(colors / scale), 0.0, 1.0)
    cloud = mesh_cloud(path, mesh["vertices"], mesh["triangles"], None, colors, sample=sample,
                       rng=rng, merge=True)
    if mesh["polygons"]:
        cloud.notes.append(f"split {mesh['polygons']} polygons of more than three corners into "
                           "triangles")
    return cloud


#: A binary STL record: the facet normal, three corners (float32), an attribute count.
_STL_RECORD = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attr", "<u2")])
_STL_HEADER = 84


def read_stl(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (3m, 3) float64, faces (m, 3))`` of an STL file, binary or ASCII: three
    vertices per facet, in file order (the caller merges the copies a facet's neighbours
    share). The file's facet normals are not read: the winding says which side is out."""
    data = path.read_bytes()
    binary_size = None
    if len(data) >= _STL_HEADER:
        count = int(np.frombuffer(data, "<u4", 1, 80)[0])
        binary_size = _STL_HEADER + count * _STL_RECORD.itemsize
        if len(data) == binary_size:
            records = np.frombuffer(data, _STL_RECORD, count, _STL_HEADER)
            vertices = records["corners"].reshape(-1, 3).astype(np.float64)
            return vertices, np.arange(len(vertices)).reshape(-1, 3)
    if not data[:512].lstrip().lower().startswith(b"solid") or (
            binary_size is not None and b"vertex" not in data):
        if binary_size is None:
            raise FileFormatError(f"{path}: not an STL file ({len(data)} bytes: shorter than a "
                                  f"binary STL's {_STL_HEADER}-byte header, and not ASCII STL)")
        raise FileFormatError(
            f"{path}: malformed STL: a binary STL of {count} facets needs {binary_size} bytes, "
            f"the file has {len(data)} (and it is not ASCII STL)")
    import re

    corners = re.findall(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)", data)
    if len(corners) % 3:
        raise FileFormatError(f"{path}: malformed ASCII STL: {len(corners)} vertex lines, not "
                              "three per facet")
    try:
        vertices = np.array(corners, dtype=np.float64).reshape(-1, 3)
    except ValueError:
        bad = next(c for c in corners for t in c if not is_number(t))
        raise FileFormatError(f"{path}: malformed ASCII STL: a vertex holds a non-number "
                              f"({b' '.join(bad).decode('latin-1')!r})") from None
    return vertices, np.arange(len(vertices)).reshape(-1, 3)
