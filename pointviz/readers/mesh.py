"""Triangle meshes: OBJ, OFF and STL through Open3D, glTF through trimesh."""

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
    o3d = require("open3d", "io")
    with quiet_open3d(o3d):
        mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.vertices) == 0:
        raise FileFormatError(f"{path}: no vertices could be read (empty or unparsable file)")
    return mesh_from_o3d(path, mesh, sample, rng, merge=ext in (".obj", ".stl"))


