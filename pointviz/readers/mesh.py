"""Triangle meshes: OBJ in the core (its positions, vertex colours and faces), OFF and STL through
Open3D, glTF through trimesh."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FileFormatError, require
from .common import mesh_cloud, mesh_from_o3d, quiet_open3d


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
    o3d = require("open3d", "io")
    with quiet_open3d(o3d):
        mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.vertices) == 0:
        raise FileFormatError(f"{path}: no vertices could be read (empty or unparsable file)")
    return mesh_from_o3d(path, mesh, sample, rng, merge=ext in (".obj", ".stl"))




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
