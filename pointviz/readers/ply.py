"""PLY: header forensics (truncated files, lying counts, a wrong format line, crafted face lists
that crash Open3D) and the readers of points and meshes, which read the vertex rows and the face
records in the core at disk speed. Meshes of another layout (faces before the vertices, vertex
lists) go through Open3D after the same checks."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..cloud import PointCloud
from ..errors import FileFormatError, require
from ..validate import check_points_fit
from . import table
from .. import _core
from .common import (cloud_from_o3d_points, float_color_scale, is_number, mesh_cloud,
                     mesh_from_o3d, point_cloud, quiet_open3d)

# PLY property sizes in bytes
_PLY_SIZES = {
    "char": 1, "int8": 1, "uchar": 1, "uint8": 1,
    "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
    "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4,
    "double": 8, "float64": 8,
}  # fmt: skip

# PLY types that may count a list's items, and the numpy type of every PLY type.
_PLY_INT_TYPES = ("char", "int8", "uchar", "uint8", "short", "int16", "ushort", "uint16",
                  "int", "int32", "uint", "uint32")
_PLY_NUMPY = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4",
    "double": "f8", "float64": "f8",
}  # fmt: skip

# Largest PLY header we accept before deciding the file is not a PLY file; headers are read in
# blocks of _PLY_HEADER_BLOCK bytes (a few hundred bytes is usual), not the whole 1 MiB.
_PLY_MAX_HEADER = 1 << 20
_PLY_HEADER_BLOCK = 1 << 16

# A binary PLY whose first data bytes are all ASCII number characters is really an ASCII file
# with a wrong format line. Binary floats almost never consist only of these bytes: 64 such bytes
# in a row occur by chance with probability below (26/256)^64.
_PLY_TEXT_BYTES = b"0123456789+-.eEnaNAifIF \t\r\n"
_PLY_TEXT_PROBE = 4096
_PLY_TEXT_MIN = 64


def _ply_header(path: Path) -> dict:
    """Parse a PLY header.

    Returns
    -------
    dict
        ``format`` ('ascii', 'binary_little_endian', 'binary_big_endian'), ``header_bytes``
        and ``elements``: list of ``(name, count, properties)`` where each property is
        ``(name, type)`` or ``(name, ('list', count_type, item_type))``; ``obj_info``: the
        ``obj_info NAME VALUE`` lines as a dict of strings.
    """
    with open(path, "rb") as fh:
        head = fh.read(_PLY_HEADER_BLOCK)
        while (b"end_header" not in head or head.find(b"\n", head.find(b"end_header")) < 0) and \
                len(head) < _PLY_MAX_HEADER:
            block = fh.read(min(_PLY_HEADER_BLOCK, _PLY_MAX_HEADER - len(head)))
            if not block:
                break
            head += block
    if not head.startswith(b"ply"):
        raise FileFormatError(f"{path}: not a PLY file (it does not start with 'ply')")
    end = head.find(b"end_header")
    if end < 0:
        raise FileFormatError(f"{path}: PLY header has no 'end_header' line")
    nl = head.find(b"\n", end)
    header_bytes = len(head) if nl < 0 else nl + 1
    fmt, elements, info = None, [], {}
    lines = head[:end].decode("latin-1").splitlines()
    for lineno, line in enumerate(lines, start=1):
        f = line.split()
        if f and f[0] == "obj_info" and len(f) == 3:
            info[f[1]] = f[2]
        if not f or f[0] in ("ply", "comment", "obj_info"):
            continue
        try:
            if f[0] == "format":
                fmt = f[1]
            elif f[0] == "element":
                count = int(f[2])
                if count < 0:
                    raise ValueError(f"negative element count {count}")
                elements.append((f[1], count, []))
            elif f[0] == "property":
                if not elements:
                    raise ValueError("property before any element")
                if f[1] == "list":
                    if f[2] not in _PLY_INT_TYPES or f[3] not in _PLY_SIZES:
                        raise ValueError(f"bad list types {f[2]!r} {f[3]!r}")
                    prop = (f[4], ("list", f[2], f[3]))
                else:
                    if f[1] not in _PLY_SIZES:
                        raise ValueError(f"unknown property type {f[1]!r}")
                    prop = (f[2], f[1])
                if any(name == prop[0] for name, _ in elements[-1][2]):
                    raise ValueError(f"property {prop[0]!r} declared twice")
                elements[-1][2].append(prop)
            else:
                raise ValueError(f"unknown keyword {f[0]!r}")
        except (IndexError, ValueError) as exc:
            raise FileFormatError(
                f"{path}: malformed PLY header at line {lineno}: {line.strip()!r} ({exc})"
            ) from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise FileFormatError(f"{path}: unknown PLY format {fmt!r}")
    return {"format": fmt, "header_bytes": header_bytes, "elements": elements, "obj_info": info}


def _check_ascii_size(path: Path, header: dict, size: int) -> int:
    """Every ASCII data line takes at least two bytes ("0\\n"): a cheap bound on lying counts
    before anything is read. Returns the number of data lines the header declares."""
    rows = sum(count for _, count, _ in header["elements"])
    if 2 * rows > size - header["header_bytes"] + 1:
        raise FileFormatError(
            f"{path}: truncated PLY: the header declares {rows} data lines, the file has "
            f"only {size - header['header_bytes']} bytes of data"
        )
    return rows


def _check_ply_complete(path: Path, header: dict) -> None:
    """Raise if the data does not match the header: truncated, miscounted or the wrong format."""
    elements = header["elements"]
    size = path.stat().st_size
    if header["format"] == "ascii":
        rows = _check_ascii_size(path, header, size)
        with open(path, "rb") as fh:
            fh.seek(header["header_bytes"])
            data = fh.read()
        have = data.count(b"\n") + (0 if data.endswith(b"\n") or not data else 1)
        if have < rows:
            raise FileFormatError(
                f"{path}: truncated PLY: the header declares {rows} data lines, the file has {have}"
            )
        _check_ply_ascii_rows(path, data, elements)
        return
    _check_binary_not_text(path, header)
    need = header["header_bytes"]
    for name, count, props in elements:
        row = 0
        for _, ptype in props:
            if isinstance(ptype, tuple):  # a list: its count, and >= 3 items for a face
                row += _PLY_SIZES.get(ptype[1], 1)
                if name == "face":
                    row += 3 * _PLY_SIZES.get(ptype[2], 4)
            else:
                row += _PLY_SIZES.get(ptype, 4)
        need += count * row
    if size < need:
        raise FileFormatError(
            f"{path}: truncated PLY: the header's elements need at least {need} bytes, "
            f"the file has {size}"
        )
    _check_ply_binary_faces(path, header, size)
    fixed = all(not isinstance(ptype, tuple) for _, _, props in elements for _, ptype in props)
    if fixed and elements:
        last_row = sum(_PLY_SIZES.get(ptype, 4) for _, ptype in elements[-1][2])
        extra = size - need
        if last_row > 0 and extra >= last_row:
            raise FileFormatError(
                f"{path}: the PLY header's counts are wrong: the data holds {extra} bytes "
                f"(at least {extra // last_row} more '{elements[-1][0]}' rows) beyond the "
                f"{sum(c for _, c, _ in elements)} rows the header declares"
            )


def _check_binary_not_text(path: Path, header: dict) -> None:
    """Raise if a binary PLY's data is really ASCII text (a wrong format line)."""
    with open(path, "rb") as fh:
        fh.seek(header["header_bytes"])
        probe = fh.read(_PLY_TEXT_PROBE)
    if len(probe) >= _PLY_TEXT_MIN and not probe.translate(None, _PLY_TEXT_BYTES) and b"\n" in probe:
        raise FileFormatError(
            f"{path}: the PLY header says {header['format']} but the data is ASCII text "
            "(the header's format line is wrong)"
        )


def _face_error(path, k, what):
    return FileFormatError(f"{path}: corrupt PLY mesh: face {k} {what}")


def _check_ply_binary_faces(path: Path, header: dict, size: int) -> None:
    """Face lists must be polygons (>= 3 items) of valid vertex indices; Open3D does not check
    and crashes on garbage. Only the usual layout is walked: fixed-size elements before a face
    element whose only property is its index list."""
    elements = header["elements"]
    names = [name for name, _, _ in elements]
    if "face" not in names:
        return
    nvert = next((count for name, count, _ in elements if name == "vertex"), 0)
    end = ">" if header["format"] == "binary_big_endian" else "<"
    offset = header["header_bytes"]
    for name, count, props in elements:
        if name == "face":
            break
        if any(isinstance(ptype, tuple) for _, ptype in props):
            return  # variable-size rows before the faces: cannot locate them cheaply
        offset += count * sum(_PLY_SIZES[ptype] for _, ptype in props)
    _, nface, props = elements[names.index("face")]
    if nface == 0 or len(props) != 1 or not isinstance(props[0][1], tuple):
        return
    _, ctype, itype = props[0][1]
    cdt, idt = np.dtype(end + _PLY_NUMPY[ctype]), np.dtype(end + _PLY_NUMPY[itype])
    with open(path, "rb") as fh:
        fh.seek(offset)
        data = fh.read()
    if not data:
        raise FileFormatError(f"{path}: truncated PLY: no face data")
    k0 = int(np.frombuffer(data[: cdt.itemsize], cdt)[0])
    row = cdt.itemsize + k0 * idt.itemsize
    if k0 >= 3 and len(data) >= nface * row:  # fast path: every face has k0 corners
        rows = np.frombuffer(data[: nface * row], dtype=np.dtype([("n", cdt), ("i", idt, (k0,))]))
        if (rows["n"] == k0).all():
            bad = np.flatnonzero(((rows["i"] < 0) | (rows["i"] >= nvert)).any(axis=1))
            if bad.size:
                raise _face_error(path, int(bad[0]), f"has vertex indices outside 0..{nvert - 1}")
            return
    pos = 0
    for k in range(nface):  # mixed polygons: walk the rows
        if pos + cdt.itemsize > len(data):
            raise FileFormatError(f"{path}: truncated PLY: the data ends at face {k} of {nface}")
        n = int(np.frombuffer(data[pos:pos + cdt.itemsize], cdt)[0])
        pos += cdt.itemsize
        if n < 3:
            raise _face_error(path, k, f"has {n} corners")
        if pos + n * idt.itemsize > len(data):
            raise FileFormatError(f"{path}: truncated PLY: the data ends at face {k} of {nface}")
        idx = np.frombuffer(data[pos:pos + n * idt.itemsize], idt)
        pos += n * idt.itemsize
        if ((idx < 0) | (idx >= nvert)).any():
            raise _face_error(path, k, f"has vertex indices outside 0..{nvert - 1}")


def _check_ply_ascii_rows(path: Path, data: bytes, elements) -> None:
    """Every declared ASCII row must hold numbers, as many as its element's properties say."""
    lines = data.splitlines()
    start = 0
    for name, count, props in elements:
        rows = lines[start:start + count]
        start += count
        n_scalar = sum(1 for _, ptype in props if not isinstance(ptype, tuple))
        has_list = n_scalar < len(props)
        for k, line in enumerate(rows):
            fields = line.split()
            if len(fields) < n_scalar or (not has_list and len(fields) != n_scalar):
                raise FileFormatError(
                    f"{path}: malformed ASCII PLY: {name} row {k} has {len(fields)} values, "
                    f"the header declares {len(props)} properties"
                )
        if name == "face" and len(props) == 1 and has_list:
            nvert = next((c for nm, c, _ in elements if nm == "vertex"), 0)
            for k, line in enumerate(rows):
                fields = line.split()
                try:
                    values = [int(v) for v in fields]
                except ValueError:
                    raise _face_error(path, k, "holds a non-integer") from None
                if values[0] < 3 or len(values) != values[0] + 1:
                    raise _face_error(path, k, f"declares {values[0]} corners, has {len(values) - 1}")
                if min(values[1:]) < 0 or max(values[1:]) >= nvert:
                    raise _face_error(path, k, f"has vertex indices outside 0..{nvert - 1}")
        if not rows or has_list:
            continue
        try:
            np.array(b" ".join(rows).split(), dtype=np.float64)
        except ValueError:
            bad = next(
                (k, f) for k, line in enumerate(rows) for f in line.split() if not is_number(f)
            )
            raise FileFormatError(
                f"{path}: malformed ASCII PLY: {name} row {bad[0]} holds a non-number "
                f"{bad[1].decode('latin-1')!r}"
            ) from None


@dataclass
class PointsPlan:
    """How the core reads a PLY file's points: the table of vertex rows and its columns."""

    path: Path
    header: dict
    spec: object  # _core.TableSpec of the vertex rows
    names: list  # the wanted property names, in the order of the table's columns
    types: list  # their PLY types
    other_rows: int  # rows of the elements after the vertices (ASCII: lines to find)


#: PLY property names read as colour, in order: the usual and the "diffuse_" spelling.
_COLOR_NAMES = (("red", "green", "blue"), ("diffuse_red", "diffuse_green", "diffuse_blue"))
#: Largest value of each integer PLY colour type (colours are scaled to [0, 1] by it).
_COLOR_SCALE = {"char": 127.0, "int8": 127.0, "uchar": 255.0, "uint8": 255.0,
                "short": 32767.0, "int16": 32767.0, "ushort": 65535.0, "uint16": 65535.0,
                "int": 2147483647.0, "int32": 2147483647.0,
                "uint": 4294967295.0, "uint32": 4294967295.0}  # fmt: skip


def points_plan(path: Path, affine=None, header: dict | None = None) -> PointsPlan | None:
    """Check a PLY file and plan reading its points in the core.

    ``affine`` ``(m, t)`` places the points as they are read (``p @ m + t``, see
    :func:`table.spec`). Returns None for what the core path does not cover (meshes, vertex elements with lists or
    after other elements): :func:`read_ply` then uses Open3D after the same checks. ``header``:
    the file's parsed header, when the caller has it.
    """
    header = _ply_header(path) if header is None else header
    elements = header["elements"]
    counts = {name: count for name, count, _ in elements}
    nvert = counts.get("vertex", 0)
    if nvert == 0:
        raise FileFormatError(f"{path}: the PLY file declares no vertices")
    if counts.get("face", 0) > 0 or elements[0][0] != "vertex":
        return None
    vprops = elements[0][2]
    if any(isinstance(t, tuple) for _, t in vprops):
        return None
    others = elements[1:]
    ascii_ = header["format"] == "ascii"
    if ascii_ and any(not isinstance(t, tuple) for _, _, props in others for _, t in props):
        return None  # scalar rows after the vertices: checked row by row on the Open3D path
    if ascii_:
        _check_ascii_size(path, header, path.stat().st_size)
    else:
        _check_ply_complete(path, header)
    return _vertex_plan(path, header, affine)


def _vertex_plan(path: Path, header: dict, affine) -> PointsPlan:
    """The PointsPlan of a checked PLY file's vertex rows (its first element, scalars only)."""
    elements = header["elements"]
    nvert, vprops, others = elements[0][1], elements[0][2], elements[1:]
    check_points_fit(nvert, str(path))
    names = [n for n, _ in vprops]
    want = [n for n in ("x", "y", "z") if n in names]
    if len(want) < 3:
        raise FileFormatError(f"{path}: the PLY vertices have no x, y and z properties")
    if all(n in names for n in ("nx", "ny", "nz")):
        want += ["nx", "ny", "nz"]
    color = next((c for c in _COLOR_NAMES if all(n in names for n in c)), None)
    if color is not None:
        want += list(color)
    types = dict(vprops)
    spec = table.spec(
        path, offset=header["header_bytes"], encoding=header["format"],
        columns=[table.PLY_SCALARS[t] for _, t in vprops], rows=nvert,
        wanted=[names.index(n) for n in want], affine=affine, grid=_range_grid(header),
    )
    return PointsPlan(path, header, spec, want, [types[n] for n in want],
                      sum(c for _, c, _ in others))


def _range_grid(header: dict):
    """``(cells, columns, count type, index type)`` of a range scan's ``range_grid`` element
    right after its vertices (Stanford/Cyberware scans: ``obj_info num_cols`` x ``num_rows``
    cells, each listing the vertices it holds), else None."""
    elements, info = header["elements"], header.get("obj_info", {})
    if len(elements) < 2:
        return None
    name, cells, props = elements[1]
    if name != "range_grid" or len(props) != 1 or not isinstance(props[0][1], tuple):
        return None
    try:
        cols, rows = int(info.get("num_cols", "")), int(info.get("num_rows", ""))
    except ValueError:
        return None
    _, count, index = props[0][1]
    if (cols <= 0 or rows <= 0 or cols * rows != cells or count not in _PLY_INT_TYPES
            or index not in _PLY_INT_TYPES):
        return None
    return cells, cols, table.PLY_SCALARS[count], table.PLY_SCALARS[index]


def points_from_table(plan: PointsPlan, data) -> dict:
    """The arrays of a planned PLY file from its vertex table (a :class:`table.TableData`):
    ``points`` (n, 3) float64, ``normals`` (n, 3) or None, ``colors`` (n, 3) in [0, 1] or None,
    ``grid`` (n, 2) int32 (each vertex's cell of a range scan's grid, -1: none) or None."""
    path = plan.path
    values, lines_after = data.values, data.lines_after
    if plan.header["format"] == "ascii" and lines_after < plan.other_rows:
        nvert = len(values)
        raise FileFormatError(
            f"{path}: truncated PLY: the header declares {nvert + plan.other_rows} data lines, "
            f"the file has {nvert + lines_after}"
        )
    out = {"points": values[:, :3], "normals": None, "colors": None, "grid": data.grid}
    k = 3
    if "nx" in plan.names:
        out["normals"] = values[:, 3:6]
        k = 6
    if len(plan.names) > k:
        rgb = values[:, k:k + 3]
        scale = _COLOR_SCALE.get(plan.types[k])
        if scale is None:  # float colours
            scale = float_color_scale(rgb)
        out["colors"] = np.clip(rgb / scale, 0.0, 1.0)
    return out


def core_error(path: Path, fmt: str, exc: Exception) -> FileFormatError:
    """The FileFormatError for a core reader error on a PLY file."""
    if isinstance(exc, table.TruncatedData):
        return FileFormatError(f"{path}: truncated PLY: {exc}")
    if isinstance(exc, table.MalformedData):
        kind = "ASCII PLY" if fmt == "ascii" else "PLY"
        what = "" if str(exc).startswith("range_grid") else "vertex "
        return FileFormatError(f"{path}: malformed {kind}: {what}{exc}")
    return FileFormatError(f"{path}: could not read the PLY file ({exc})")


def read_ply(path: Path, sample, rng) -> PointCloud:
    """A PLY file: points (with normals and colours when present) in the core; meshes in the
    core too when their vertices come first and their faces right after them (the usual
    layout), else through Open3D."""
    header = _ply_header(path)
    if any(name == "face" and count > 0 for name, count, _ in header["elements"]):
        mesh = mesh_plan(path, header)
        return _load_ply(path, sample, rng) if mesh is None else read_core_mesh(mesh, sample, rng)
    plan = points_plan(path, header=header)
    if plan is None:
        return _load_ply(path, sample, rng)
    try:
        (data,) = table.read([plan.spec])
    except (table.TruncatedData, table.MalformedData, RuntimeError) as exc:
        raise core_error(path, plan.header["format"], exc) from None
    arrays = points_from_table(plan, data)
    arrays.pop("grid")  # one scan's grid: used by registrations (conf.py), which know the scans
    return point_cloud(path, **arrays, sample=sample, rng=rng)


#: Names of a face element's vertex-index list.
_FACE_INDEX_NAMES = ("vertex_indices", "vertex_index")


@dataclass
class MeshPlan:
    """How the core reads a PLY mesh: its vertex rows (as for points) and its face records."""

    points: PointsPlan
    faces: object  # _core.FaceSpec of the face records


def mesh_plan(path: Path, header: dict) -> MeshPlan | None:
    """Check a PLY mesh and plan reading it in the core, or None for a layout the core does not
    read (anything but scalar vertex properties first and a face element with one vertex-index
    list right after them; elements after the faces are ignored): :func:`read_ply` then uses
    Open3D after its checks."""
    elements = header["elements"]
    if len(elements) < 2 or elements[0][0] != "vertex" or elements[1][0] != "face":
        return None
    nvert, vprops = elements[0][1], elements[0][2]
    nface, fprops = elements[1][1], elements[1][2]
    lists = [k for k, (name, t) in enumerate(fprops)
             if isinstance(t, tuple) and name in _FACE_INDEX_NAMES]
    if nvert == 0 or any(isinstance(t, tuple) for _, t in vprops) or len(lists) != 1:
        return None
    size = path.stat().st_size
    if header["format"] == "ascii":
        _check_ascii_size(path, header, size)
    else:
        _check_binary_not_text(path, header)
    points = _vertex_plan(path, header, None)
    if nface > size:  # every face record takes at least one byte
        raise FileFormatError(f"{path}: truncated PLY: the header declares {nface} faces, the "
                              f"file has only {size} bytes")
    spec = _core.FaceSpec()
    spec.path = str(path)
    spec.encoding = getattr(_core.Encoding, header["format"])
    if header["format"] == "ascii":
        spec.offset, spec.skip_lines = header["header_bytes"], nvert
    else:
        row = sum(_PLY_SIZES[t] for _, t in vprops)
        spec.offset, spec.skip_lines = header["header_bytes"] + nvert * row, 0
    properties = []
    for _, t in fprops:
        prop = _core.FaceProperty()
        prop.list = isinstance(t, tuple)
        if prop.list:
            prop.count, prop.item = (getattr(_core.Scalar, table.PLY_SCALARS[x]) for x in t[1:])
        else:
            prop.item = getattr(_core.Scalar, table.PLY_SCALARS[t])
        properties.append(prop)
    spec.properties, spec.indices = properties, lists[0]
    spec.faces, spec.vertices = nface, nvert
    return MeshPlan(points, spec)


def read_core_mesh(plan: MeshPlan, sample, rng) -> PointCloud:
    """The PointCloud of a planned PLY mesh: its vertices (normals from the file, else from the
    faces) or ``sample`` points on its faces, as :func:`pointviz.readers.common.mesh_cloud`."""
    path = plan.points.path
    try:
        (data,) = table.read([plan.points.spec])
    except (table.TruncatedData, table.MalformedData, RuntimeError) as exc:
        raise core_error(path, plan.points.header["format"], exc) from None
    arrays = points_from_table(plan.points, data)
    try:
        faces = _core.read_faces(plan.faces)
    except table.TruncatedData as exc:
        raise FileFormatError(f"{path}: truncated PLY: {exc}") from None
    except table.MalformedData as exc:
        raise FileFormatError(f"{path}: corrupt PLY mesh: {exc}") from None
    except RuntimeError as exc:
        raise FileFormatError(f"{path}: could not read the PLY faces ({exc})") from None
    return mesh_cloud(path, arrays["points"], faces["triangles"], arrays["normals"],
                      arrays["colors"], sample=sample, rng=rng, polygons=faces["polygons"])


def _load_ply(path: Path, sample, rng) -> PointCloud:
    o3d = require("open3d", "io")
    header = _ply_header(path)
    counts = {name: count for name, count, _ in header["elements"]}
    nvert = counts.get("vertex", 0)
    if nvert == 0:
        raise FileFormatError(f"{path}: the PLY file declares no vertices")
    _check_ply_complete(path, header)
    check_points_fit(nvert, str(path))
    with quiet_open3d(o3d):
        if counts.get("face", 0) > 0:
            mesh = o3d.io.read_triangle_mesh(str(path))
            if len(mesh.vertices) != nvert or len(mesh.triangles) == 0:
                raise FileFormatError(
                    f"{path}: could not read the PLY mesh (read {len(mesh.vertices)} of "
                    f"{nvert} vertices, {len(mesh.triangles)} triangles)"
                )
            return mesh_from_o3d(path, mesh, sample, rng)
        pcd = o3d.io.read_point_cloud(
            str(path), remove_nan_points=False, remove_infinite_points=False
        )
    if len(pcd.points) != nvert:
        raise FileFormatError(
            f"{path}: could not read the PLY points (read {len(pcd.points)} of {nvert})"
        )
    return cloud_from_o3d_points(path, pcd, sample, rng)

