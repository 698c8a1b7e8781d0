"""Triangle meshes: OBJ in the core (its positions, vertex colours and faces), STL and OFF with
numpy, glTF through trimesh. None of them imports Open3D (a second of a first render)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FileFormatError, require
from .common import float_color_scale, is_number, mesh_cloud


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
    if ext == ".off":
        vertices, faces, colors, polygons = read_off(path)
        return mesh_cloud(path, vertices, faces, None, colors, sample=sample, rng=rng,
                          polygons=polygons)
    raise FileFormatError(f"{path}: not a mesh format pointviz reads")


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
        colors = np.clip(np.nan_to_num(colors / float_color_scale(colors)), 0.0, 1.0)
    return mesh_cloud(path, mesh["vertices"], mesh["triangles"], None, colors, sample=sample,
                      rng=rng, merge=True, polygons=mesh["polygons"])


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


def read_off(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, int]:
    """``(vertices (n, 3), triangles (m, 3), colours (n, 3) or None, polygons split)`` of an
    ASCII OFF file (``OFF``, ``COFF``, ``NOFF``, ``CNOFF``...: normals, when declared, are not
    read; colours are, scaled to [0, 1]). Faces beyond three corners become fans; a face's own
    colour after its indices is ignored. Comments start with ``#``."""
    text = path.read_bytes()
    if b"\0" in text[:4096]:
        raise FileFormatError(f"{path}: binary OFF is not supported (only ASCII OFF)")
    lines = [line.split(b"#", 1)[0].split() for line in text.splitlines()]
    lines = [tokens for tokens in lines if tokens]
    if not lines or not lines[0][0].upper().endswith(b"OFF"):
        raise FileFormatError(f"{path}: not an OFF file (it does not start with OFF)")
    kind = lines[0][0].upper()[:-3]
    head = lines[0][1:] or (lines[1] if len(lines) > 1 else [])
    body = lines[1:] if lines[0][1:] else lines[2:]
    try:
        nv, nf = int(head[0]), int(head[1])
    except (IndexError, ValueError):
        raise FileFormatError(f"{path}: malformed OFF: the counts line is not 'vertices faces "
                              "edges'") from None
    if nv < 0 or nf < 0 or nv + nf > len(body):
        raise FileFormatError(f"{path}: truncated OFF: the header declares {nv} vertices and "
                              f"{nf} faces, the file has {len(body)} lines after it")
    try:
        rows = [np.array(tokens, dtype=np.float64) for tokens in body[:nv]]
    except ValueError:
        raise FileFormatError(f"{path}: malformed OFF: a vertex holds a non-number") from None
    width = min((len(r) for r in rows), default=3)
    if width < 3:
        raise FileFormatError(f"{path}: malformed OFF: a vertex has fewer than 3 values")
    table = np.array([r[:width] for r in rows]) if rows else np.zeros((0, 3))
    vertices = table[:, :3]
    colors = None
    first = 6 if b"N" in kind else 3
    if b"C" in kind and width >= first + 3:
        colors = table[:, first:first + 3]
        colors = np.clip(colors / float_color_scale(colors), 0.0, 1.0)
    triangles, polygons = [], 0
    for k, tokens in enumerate(body[nv:nv + nf]):
        try:
            n = int(tokens[0])
            corners = [int(t) for t in tokens[1:1 + n]]
        except ValueError:
            raise FileFormatError(f"{path}: malformed OFF: face {k} holds a non-integer") from None
        if n < 3 or len(corners) != n:
            raise FileFormatError(f"{path}: corrupt OFF mesh: face {k} declares {n} corners, "
                                  f"has {len(corners)}")
        if min(corners) < 0 or max(corners) >= nv:
            raise FileFormatError(f"{path}: corrupt OFF mesh: face {k} has vertex indices "
                                  f"outside 0..{nv - 1}")
        polygons += n > 3
        triangles += [(corners[0], corners[i], corners[i + 1]) for i in range(1, n - 1)]
    return vertices, np.array(triangles, dtype=np.int64).reshape(-1, 3), colors, polygons
