"""OBJ files read in the core (positions, vertex colours, faces) against two oracles: Open3D's
reader on the OBJ files of the shared data, and files written here whose triangles numpy builds
(every corner form, negative indices, polygons as fans)."""

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


@pytest.mark.parametrize("text, message", [
    ("v 0 0\n", "line 1: a vertex needs x, y and z"),
    ("v 0 0 x\n", "line 1: a vertex holds a non-number"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "line 4: a face has 2 corners"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", "line 4: a face corner's vertex index"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 1.5\n", "line 4: a face corner's vertex index"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 4\n", "line 5: a face names a vertex that is not"),
    ("v 0 0 0\nv 1 0 0\nf 1 2 -3\nv 0 1 0\n", "line 3: a face names a vertex that is not"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999\n", "line 4: a face names a vertex"),
    ("# nothing\n", "no vertices"),
])
def test_bad_obj_files_are_clear_errors(tmp_path, text, message):
    path = tmp_path / "bad.obj"
    path.write_text(text)
    with pytest.raises(FileFormatError) as err:
        load(path)
    assert str(path) in str(err.value) and message in str(err.value), str(err.value)
