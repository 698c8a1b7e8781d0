"""PLY meshes read in the core (vertex rows and face records) against two oracles: Open3D's
reader on every mesh of the shared data and on files it reads, and faces written here by numpy
(polygons as fans, properties around the index list, both byte orders and ASCII)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pointviz import _core
from pointviz.errors import FileFormatError
from pointviz.io import load
from pointviz.readers import ply


def _o3d():
    return pytest.importorskip("open3d")


def read_core(path: Path):
    """(vertices, triangles, normals, colours, polygons) as the core reads them."""
    plan = ply.mesh_plan(path, ply._ply_header(path))
    assert plan is not None, f"{path}: not planned for the core"
    (data,) = ply.table.read([plan.points.spec])
    arrays = ply.points_from_table(plan.points, data)
    faces = _core.read_faces(plan.faces)
    return (arrays["points"], faces["triangles"], arrays["normals"], arrays["colors"],
            faces["polygons"])


def _shared_meshes(root: Path) -> list[Path]:
    out = []
    for path in sorted(root.rglob("*.ply")):
        with open(path, "rb") as fh:
            if b"element face" in fh.read(4096):
                out.append(path)
    return out


def test_every_shared_mesh_equals_open3ds_reading(shared_data):
    """Vertices, triangles, normals and colours bit for bit as Open3D reads them (ASCII, both
    byte orders, a face property before the index list, elements after the faces)."""
    o3d = _o3d()
    meshes = _shared_meshes(shared_data)
    assert len(meshes) >= 10
    for path in meshes:
        v, t, n, c, _ = read_core(path)
        mesh = o3d.io.read_triangle_mesh(str(path))
        assert np.array_equal(v, np.asarray(mesh.vertices)), path
        assert np.array_equal(t, np.asarray(mesh.triangles)), path
        assert (n is None) == (not mesh.has_vertex_normals()), path
        if n is not None:
            assert np.allclose(n, np.asarray(mesh.vertex_normals), rtol=0, atol=1e-7), path
        assert (c is None) == (not mesh.has_vertex_colors()), path
        if c is not None:
            assert np.allclose(c, np.asarray(mesh.vertex_colors), rtol=0, atol=1e-7), path


def test_loading_a_mesh_does_not_import_open3d(shared_data, tmp_path):
    """The first minute on a PLY mesh: read without Open3D's import (a second or more)."""
    import subprocess
    import sys

    path = shared_data / "stanford_bunny" / "reconstruction" / "bun_zipper_res3.ply"
    code = ("import sys; from pointviz.io import load; c = load(sys.argv[1]); "
            "print(len(c), 'open3d' in sys.modules, 'scipy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == ["1889", "False", "False"], out


# ---- files written here: every layout the core reads -------------------------------------


def _polygons(rng, nvert, sizes):
    """Faces of the given corner counts over distinct vertices each."""
    return [rng.choice(nvert, size=k, replace=False) for k in sizes]


def _fans(polys):
    """The oracle: each polygon (v0, ..., vn-1) as the triangles (v0, vk, vk+1)."""
    tris = [(p[0], p[k], p[k + 1]) for p in polys for k in range(1, len(p) - 1)]
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


_NP = {"uchar": "u1", "char": "i1", "ushort": "u2", "short": "i2", "int": "i4", "uint": "u4",
       "float": "f4", "double": "f8"}


def write_mesh(path, verts, polys, fmt="binary_little_endian", count="uchar", index="int",
               before=(), after=(), trailing=0, normals=None):
    """A PLY mesh; ``before`` / ``after``: face properties around the index list, each
    ``(name, type)`` (a scalar, written as the face's number) or ``(name, ("list", c, i))``
    (a list of two items); ``trailing``: rows of an element after the faces."""
    vprops = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    rows = verts if normals is None else np.hstack([verts, normals])
    head = ["ply", f"format {fmt} 1.0", f"element vertex {len(verts)}"]
    head += [f"property float {p}" for p in vprops]
    head += [f"element face {len(polys)}"]

    def decl(name, t):
        return (f"property list {t[1]} {t[2]} {name}" if isinstance(t, tuple)
                else f"property {t} {name}")

    props = list(before) + [("vertex_indices", ("list", count, index))] + list(after)
    head += [decl(n, t) for n, t in props]
    if trailing:
        head += [f"element extra {trailing}", "property float w"]
    head += ["end_header"]
    data = ("\n".join(head) + "\n").encode()
    if fmt == "ascii":
        lines = [" ".join(repr(float(x)) for x in r) for r in rows]  # exact round trip
        for f, p in enumerate(polys):
            tok = []
            for name, t in props:
                if name == "vertex_indices":
                    tok += [str(len(p))] + [str(i) for i in p]
                elif isinstance(t, tuple):
                    tok += ["2", str(f % 7), str(f % 5)]
                else:
                    tok += [str(f % 100)]
            lines.append(" ".join(tok))
        lines += ["0.5"] * trailing
        data += ("\n".join(lines) + "\n").encode()
    else:
        e = "<" if fmt == "binary_little_endian" else ">"
        data += rows.astype(e + "f4").tobytes()
        for f, p in enumerate(polys):
            for name, t in props:
                if name == "vertex_indices":
                    data += np.array([len(p)], e + _NP[count]).tobytes()
                    data += np.asarray(p).astype(e + _NP[index]).tobytes()
                elif isinstance(t, tuple):
                    data += np.array([2], e + _NP[t[1]]).tobytes()
                    data += np.array([f % 7, f % 5]).astype(e + _NP[t[2]]).tobytes()
                else:
                    data += np.array([f % 100]).astype(e + _NP[t]).tobytes()
        data += np.full(trailing, 0.5, e + "f4").tobytes()
    Path(path).write_bytes(data)


FORMATS = ["ascii", "binary_little_endian", "binary_big_endian"]


@pytest.mark.parametrize("fmt", FORMATS)
def test_polygons_become_fans_with_properties_around_the_index_list(tmp_path, rng, fmt):
    verts = rng.normal(size=(40, 3)).astype(np.float32).astype(np.float64)
    sizes = rng.integers(3, 8, size=60)
    polys = _polygons(rng, 40, sizes)
    path = tmp_path / "m.ply"
    write_mesh(path, verts, polys, fmt=fmt, count="ushort", index="uint",
               before=[("flags", "uchar"), ("uv", ("list", "uchar", "float"))],
               after=[("w", "double")], trailing=3)
    v, t, n, c, poly = read_core(path)
    assert np.array_equal(v, verts)
    assert np.array_equal(t, _fans(polys))
    assert poly == int(np.count_nonzero(sizes > 3))
    assert n is None and c is None


@pytest.mark.parametrize("fmt", FORMATS)
def test_triangle_meshes_equal_open3ds_reading(tmp_path, rng, fmt):
    o3d = _o3d()
    verts = rng.normal(size=(30, 3)).astype(np.float32).astype(np.float64)
    normals = rng.normal(size=(30, 3)).astype(np.float32).astype(np.float64)
    polys = _polygons(rng, 30, [3] * 50)
    path = tmp_path / "t.ply"
    write_mesh(path, verts, polys, fmt=fmt, normals=normals)
    v, t, n, _, _ = read_core(path)
    mesh = o3d.io.read_triangle_mesh(str(path))
    assert np.array_equal(v, np.asarray(mesh.vertices))
    assert np.array_equal(t, np.asarray(mesh.triangles))
    assert np.allclose(n, np.asarray(mesh.vertex_normals), rtol=0, atol=1e-7)


def test_load_of_a_mesh_reports_its_polygons(tmp_path, rng):
    verts = rng.normal(size=(20, 3))
    path = tmp_path / "q.ply"
    write_mesh(path, verts, _polygons(rng, 20, [4, 4, 3]))
    cloud = load(path)
    assert len(cloud) == 20 and cloud.has_normals
    assert any("split 2 polygons" in note for note in cloud.notes), cloud.notes


def test_layouts_the_core_does_not_plan_go_through_open3d(tmp_path, rng):
    """Faces before the vertices: planned as None (read_ply uses Open3D's reader)."""
    path = tmp_path / "swap.ply"
    head = ("ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\n"
            "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "end_header\n3 0 1 2\n0 0 0\n1 0 0\n0 1 0\n")
    path.write_text(head)
    assert ply.mesh_plan(path, ply._ply_header(path)) is None


# ---- bad data: one readable error naming the file and the face -----------------------------


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("case, message", [
    ("out_of_range", "corrupt PLY mesh: face 5 has vertex indices outside 0..9"),
    ("negative", "corrupt PLY mesh: face 5 has vertex indices outside 0..9"),
    ("two_corners", "corrupt PLY mesh: face 5 has 2 corners"),
    ("truncated", "truncated PLY"),
])
def test_bad_faces_are_clear_errors(tmp_path, rng, fmt, case, message):
    verts = rng.normal(size=(10, 3))
    polys = _polygons(rng, 10, [3] * 8)
    if case == "out_of_range":
        polys[5] = np.array([1, 2, 10])
    elif case == "negative":
        polys[5] = np.array([1, -1, 2])
    elif case == "two_corners":
        polys[5] = np.array([1, 2])
    path = tmp_path / "bad.ply"
    write_mesh(path, verts, polys, fmt=fmt)
    if case == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) - 7])
    with pytest.raises(FileFormatError) as err:
        load(path)
    text = str(err.value)
    assert str(path) in text and message in text and "\n" not in text


@pytest.mark.parametrize("line, message", [
    ("3 0 1 x", "face 2 holds a non-number"),
    ("3 0 1", "face 2 ends before its list items"),
    ("3 0 1 2 7", "face 2 has more values than its properties"),
    ("3 0 1 2.5", "face 2 has vertex indices outside"),
])
def test_bad_ascii_face_lines(tmp_path, line, message):
    path = tmp_path / "a.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                    "property float z\nelement face 4\nproperty list uchar int vertex_indices\n"
                    "end_header\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n"
                    f"{line}\n3 1 2 3\n")
    with pytest.raises(FileFormatError, match=message):
        load(path)


def test_a_face_count_beyond_the_file_is_refused_before_reading(tmp_path):
    path = tmp_path / "huge.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                     b"property float y\nproperty float z\nelement face 99999999999999999999\n"
                     b"property list uchar int vertex_indices\nend_header\n" + bytes(36))
    with pytest.raises(FileFormatError, match="truncated PLY: the header declares"):
        load(path)
