"""OBJ files read in the core (positions, vertex colours, faces), STL and OFF read with numpy,
against two oracles: Open3D's reader (the shared data's OBJ files; STL and OFF written by
trimesh) and
files written here whose triangles numpy builds (every OBJ corner form, negative indices,
polygons as fans)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pointviz import _core
from pointviz.errors import FileFormatError
from pointviz.io import load


def _rows_sorted(a, *others):
    order = np.lexsort(np.asarray(a).T[::-1])
    return [np.asarray(a)[order]] + [np.asarray(x)[order] for x in others]


def test_shared_obj_files_equal_open3ds_reading(shared_data):
    """The same surfels as through Open3D's reader (whose vertex order differs and whose
    positions are parsed as float32): positions within float32 rounding, normals within 0.1°."""
    o3d = pytest.importorskip("open3d")
    from pointviz.readers.common import mesh_from_o3d

    files = sorted(shared_data.rglob("*.obj"))
    assert len(files) >= 4
    for path in files:
        ours = load(path)
        mesh = o3d.io.read_triangle_mesh(str(path))
        theirs = mesh_from_o3d(path, mesh, None, None, merge=True)
        assert len(ours) == len(theirs), path
        pa, na = _rows_sorted(ours.points.astype(np.float64), ours.normals)
        pb, nb = _rows_sorted(theirs.points.astype(np.float64), theirs.normals)
        scale = np.abs(pb).max()
        assert np.abs(pa - pb).max() <= 1e-6 * scale, path
        cos = np.clip((na * nb).sum(axis=1), -1.0, 1.0)
        assert np.degrees(np.arccos(cos)).max() < 0.1, path


def test_loading_an_obj_does_not_import_open3d(tmp_path):
    path = tmp_path / "t.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    code = ("import sys; from pointviz.io import load; c = load(sys.argv[1]); "
            "print(len(c), 'open3d' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == ["3", "False"], out


def write_obj(path, verts, polys, rng, colors=None):
    """An OBJ with comments, groups, texture coordinates, normals, a line element, and each face
    corner in a random one of the four forms, its index positive or negative at random."""
    lines = ["# written by the test", "mtllib none.mtl", "o thing"]
    faces_at = {}  # faces after the k-th vertex line (negative indices count from there)
    per = max(1, len(polys) // 4)
    for i, p in enumerate(polys):
        faces_at.setdefault(min(len(verts), max(max(p) + 1, (i // per + 1) * len(verts) // 4)),
                            []).append(p)
    for k, v in enumerate(verts, start=1):
        rgb = "" if colors is None else " " + " ".join(repr(float(c)) for c in colors[k - 1])
        lines.append("v " + " ".join(repr(float(x)) for x in v) + rgb)
        lines.append(f"vt {k % 3 * 0.5} 0.25")
        lines.append("vn 0 0 1")
        for p in faces_at.get(k, []):
            corners = []
            for c in p:
                idx = str(c + 1) if rng.random() < 0.5 else str(c - k)  # 1-based or relative
                form = rng.integers(4)
                corners.append([idx, f"{idx}/1", f"{idx}//1", f"{idx}/1/1"][form])
            lines.append("f " + " ".join(corners))
        if k == 2:
            lines += ["g part", "usemtl red", "s 1", "l 1 2"]
    Path(path).write_text("\n".join(lines) + "\n")


def _fans(polys):
    return np.array([(p[0], p[k], p[k + 1]) for p in polys for k in range(1, len(p) - 1)],
                    dtype=np.int64).reshape(-1, 3)


def test_every_corner_form_and_negative_indices(tmp_path, rng):
    verts = rng.normal(size=(30, 3))
    polys = [rng.choice(30, size=int(n), replace=False) for n in rng.integers(3, 7, size=40)]
    path = tmp_path / "m.obj"
    write_obj(path, verts, polys, rng)
    mesh = _core.read_obj(str(path))
    np.testing.assert_array_equal(mesh["vertices"], verts)
    # the faces are written grouped by where they were placed: compare the fans as a multiset
    # (each triangle's corner order, which carries its winding, as written)
    assert sorted(map(tuple, mesh["triangles"])) == sorted(map(tuple, _fans(polys)))
    assert mesh["polygons"] == sum(len(p) > 3 for p in polys)
    assert mesh["colors"] is None


def test_vertex_colours_and_polygon_note(tmp_path, rng):
    verts = rng.normal(size=(12, 3))
    colors = rng.random((12, 3))
    path = tmp_path / "c.obj"
    write_obj(path, verts, [np.array([0, 1, 2, 3]), np.array([4, 5, 6])], rng, colors=colors)
    cloud = load(path)
    np.testing.assert_allclose(_core.read_obj(str(path))["colors"], colors, rtol=0, atol=0)
    assert cloud.colors is not None
    assert any("split 1 polygons" in note for note in cloud.notes), cloud.notes





# ---- STL ------------------------------------------------------------------------------------


@pytest.mark.parametrize("file_type", ["stl", "stl_ascii"])
def test_stl_equals_open3ds_reading(tmp_path, file_type):
    trimesh = pytest.importorskip("trimesh")
    o3d = pytest.importorskip("open3d")
    from pointviz.readers.common import mesh_from_o3d

    mesh = trimesh.creation.icosphere(subdivisions=3)
    path = tmp_path / "ico.stl"
    mesh.export(str(path), file_type=file_type)
    ours = load(path, estimate=False)
    theirs = mesh_from_o3d(path, o3d.io.read_triangle_mesh(str(path)), None, None, merge=True)
    assert len(ours) == len(theirs) == len(mesh.vertices)  # every facet's copies merged
    # pair the points by brute force (Open3D parses ASCII as float32: sorting would split ties)
    pa, pb = ours.points.astype(np.float64), theirs.points.astype(np.float64)
    d2 = ((pa[:, None, :] - pb[None, :, :]) ** 2).sum(-1)
    match = d2.argmin(axis=1)
    assert np.sqrt(d2[np.arange(len(pa)), match]).max() < 1e-6
    assert len(np.unique(match)) == len(pa)
    cos = np.clip(np.einsum("ij,ij->i", ours.normals, theirs.normals[match]), -1.0, 1.0)
    assert np.degrees(np.arccos(cos)).max() < 0.1


def test_loading_an_stl_does_not_import_open3d(tmp_path):
    path = tmp_path / "t.stl"
    path.write_text("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
                    "vertex 0 1 0\nendloop\nendfacet\nendsolid t\n")
    code = ("import sys; from pointviz.io import load; c = load(sys.argv[1]); "
            "print(len(c), 'open3d' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == ["3", "False"], out


def _binary_stl(n, extra=b""):
    rec = np.zeros(n, dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["v"] = np.arange(9 * n, dtype=np.float32).reshape(n, 3, 3) % 7
    return b"solid but binary".ljust(80, b" ") + np.uint32(n).tobytes() + rec.tobytes() + extra





def test_binary_stl_whose_header_says_solid(tmp_path):
    """A binary file is told by its size, whatever its 80-byte header says."""
    path = tmp_path / "b.stl"
    path.write_bytes(_binary_stl(5))
    from pointviz.readers.mesh import read_stl

    v, f = read_stl(path)
    assert v.shape == (15, 3) and f.shape == (5, 3)


# ---- OFF ------------------------------------------------------------------------------------


def test_off_equals_open3ds_reading(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    o3d = pytest.importorskip("open3d")
    from pointviz.readers.common import mesh_from_o3d

    mesh = trimesh.creation.icosphere(subdivisions=3)
    path = tmp_path / "ico.off"
    mesh.export(str(path))
    ours = load(path, estimate=False)
    theirs = mesh_from_o3d(path, o3d.io.read_triangle_mesh(str(path)), None, None)
    np.testing.assert_allclose(ours.points, theirs.points, rtol=0, atol=1e-6)  # same order
    cos = np.clip(np.einsum("ij,ij->i", ours.normals, theirs.normals), -1.0, 1.0)
    assert np.degrees(np.arccos(cos)).max() < 0.1


def test_off_variants_comments_colours_and_polygons(tmp_path):
    path = tmp_path / "c.off"
    path.write_text("COFF # coloured\n# a comment line\n5 2 0\n0 0 0 255 0 0 255\n"
                    "1 0 0 0 255 0 255\n1 1 0 0 0 255 255\n0 1 0 255 255 255 255\n"
                    "0 0 1 0 0 0 255\n4 0 1 2 3 200 0 0\n3 0 1 4\n")
    cloud = load(path, estimate=False)
    assert len(cloud) == 5
    np.testing.assert_allclose(cloud.colors[:3], np.eye(3), atol=1 / 255)
    assert any("split 1 polygons" in n for n in cloud.notes)
    from pointviz.readers.mesh import read_off

    _, tri, _, polygons = read_off(path)
    np.testing.assert_array_equal(tri, [[0, 1, 2], [0, 2, 3], [0, 1, 4]])
    assert polygons == 1
    inline = tmp_path / "i.off"  # the counts on the OFF line
    inline.write_text("OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    assert len(load(inline, estimate=False)) == 3

#: (suffix, file contents (str: text), what the one-line error must say)
BAD_FILES = [
    (".obj", "v 0 0\n", "line 1: a vertex needs x, y and z"),
    (".obj", "v 0 0 x\n", "line 1: a vertex holds a non-number"),
    (".obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "line 4: a face has 2 corners"),
    (".obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", "line 4: a face corner's vertex index"),
    (".obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 1.5\n", "line 4: a face corner's vertex index"),
    (".obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 4\n", "line 5: a face names a vertex that is not"),
    (".obj", "v 0 0 0\nv 1 0 0\nf 1 2 -3\nv 0 1 0\n", "line 3: a face names a vertex that is not"),
    (".obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999\n", "line 4: a face names a vertex"),
    (".obj", "# nothing\n", "no vertices"),
    (".stl", _binary_stl(4, b"xx"), "binary STL of 4 facets needs 284 bytes, the file has 286"),
    (".stl", _binary_stl(4)[:-10], "binary STL of 4 facets needs 284 bytes, the file has 274"),
    (".stl", b"\0" * 90, "binary STL of 0 facets needs 84 bytes, the file has 90"),
    (".stl", b"solid x\nfacet\nvertex 0 0 0\nvertex 1 0 0\nendfacet\n", "not three per facet"),
    (".stl", b"solid x\nvertex 0 0 0\nvertex 1 0 q\nvertex 0 1 0\n", "holds a non-number"),
    (".stl", b"solid x\nendsolid x\n", "no vertices"),
    (".off", "PLY\n", "not an OFF file"),
    (".off", "OFF\nthree 1 0\n", "the counts line"),
    (".off", "OFF\n3 1 0\n0 0 0\n1 0 0\n", "truncated OFF"),
    (".off", "OFF\n3 1 0\n0 0 0\n1 0 x\n0 1 0\n3 0 1 2\n", "a vertex holds a non-number"),
    (".off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n",
     "face 0 has vertex indices outside 0..2"),
    (".off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n", "face 0 declares 2 corners"),
    (".off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1\n", "face 0 declares 3 corners, has 2"),
]


@pytest.mark.parametrize("suffix, data, message", BAD_FILES,
                         ids=[f"{s[1:]}-{k}" for k, (s, _, _) in enumerate(BAD_FILES)])
def test_bad_mesh_files_are_clear_errors(tmp_path, suffix, data, message):
    path = tmp_path / f"bad{suffix}"
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    with pytest.raises(FileFormatError) as err:
        load(path)
    assert str(path) in str(err.value) and message in str(err.value), str(err.value)
