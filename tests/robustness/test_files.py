"""Broken files: every loader answers with a specific error naming the file and what is wrong.

Headers that lie (counts too large, too small, negative, 10^12 points) are caught by comparing
the header with the file size *before* any reader allocates for them; the message says so
("truncated", "counts are wrong"), which is how these tests know the check ran first.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

from pointviz.errors import InputError, PointvizError
from pointviz.io import load

from . import samples as S

PTS = S.sample_points(40)


def _las_patch(offset: int, fmt: str, value) -> bytes:
    raw = bytearray(S.las_bytes(PTS))
    struct.pack_into(fmt, raw, offset, value)
    return bytes(raw)


# (case id, file name, bytes, a fragment the message must contain)
BAD_FILES = [
    ("ply-truncated", "a.ply", S.ply_binary(PTS)[:-100], "truncated PLY"),
    ("ply-no-end-header", "a.ply", S.ply_header(40)[:-11] + PTS.tobytes(), "end_header"),
    ("ply-not-ply", "a.ply", b"plx\n" + PTS.tobytes(), "not a PLY file"),
    ("ply-1e12-binary", "a.ply", S.ply_header(10**12) + PTS.tobytes(), "truncated PLY"),
    ("ply-1e12-ascii", "a.ply", S.ply_header(10**12, "ascii") + S.ascii_rows(PTS), "truncated PLY"),
    ("ply-negative-count", "a.ply", S.ply_header(-5) + PTS.tobytes(), "negative element count"),
    ("ply-count-too-small", "a.ply", S.ply_header(10) + PTS.tobytes(), "counts are wrong"),
    ("ply-count-too-large", "a.ply", S.ply_header(41) + PTS.tobytes(), "truncated PLY"),
    ("ply-ascii-header-binary-body", "a.ply", S.ply_header(40, "ascii") + PTS.tobytes(), "PLY"),
    ("ply-binary-header-ascii-body", "a.ply", S.ply_header(40) + S.ascii_rows(PTS) * 2,
     "the data is ASCII text"),
    ("ply-ascii-non-number", "a.ply", S.ply_header(3, "ascii") + b"1 2 x\n3 4 5\n6 7 8\n",
     "non-number 'x'"),
    ("ply-ascii-short-row", "a.ply", S.ply_header(3, "ascii") + b"1 2\n3 4 5\n6 7 8\n",
     "row 0 has 2 values"),
    ("ply-unknown-format", "a.ply", S.ply_header(40, "binary_middle_endian") + PTS.tobytes(),
     "unknown PLY format"),
    ("ply-bad-face-index", "a.ply", S.ply_mesh(PTS[:3], [[0, 1, 99999]]),
     "face 0 has vertex indices outside 0..2"),
    ("ply-negative-face-index", "a.ply", S.ply_mesh(PTS[:4], [[0, 1, 2], [0, -7, 3]]),
     "face 1 has vertex indices"),
    ("ply-face-two-corners", "a.ply",
     S.ply_mesh(PTS[:4], [[0, 1, 2]]).replace(b"face 1", b"face 2") + bytes([2]) + bytes(12),
     "face 1 has 2 corners"),
    ("ply-face-count-garbage", "a.ply",
     S.ply_mesh(PTS[:4], [[0, 1, 2]])[:-13] + bytes([200]) + bytes(12), "truncated PLY"),
    ("ply-ascii-face-garbage", "a.ply",
     (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
     b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
     b"0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n"), "face 0 has vertex indices outside 0..2"),
    ("ply-duplicate-property", "a.ply",
     S.ply_header(40).replace(b"property float z", b"property float y\nproperty float z")
     + PTS.tobytes() + bytes(160), "declared twice"),
    ("ply-unknown-type", "a.ply",
     S.ply_header(40).replace(b"float x", b"float128 x") + PTS.tobytes(),
     "unknown property type 'float128'"),
    ("pcd-truncated", "a.pcd", S.pcd_binary(PTS)[:-50], "truncated PCD"),
    ("pcd-1e12-binary", "a.pcd", S.pcd_header(10**12) + PTS.tobytes(), "truncated PCD"),
    ("pcd-1e12-ascii", "a.pcd", S.pcd_header(10**12, "ascii") + S.ascii_rows(PTS), "truncated PCD"),
    ("pcd-width-lies", "a.pcd", S.pcd_header(40, width=7) + PTS.tobytes(), "WIDTH x HEIGHT"),
    ("pcd-no-data-line", "a.pcd", S.pcd_header(40).replace(b"DATA", b"DADA") + PTS.tobytes(),
     "not a PCD file"),
    ("pcd-missing-height", "a.pcd", S.pcd_header(40).replace(b"HEIGHT 1\n", b"") + PTS.tobytes(),
     "missing HEIGHT"),
    ("pcd-unknown-line", "a.pcd", S.pcd_header(40).replace(b"POINTS", b"POI\xcdNTS") + PTS.tobytes(),
     "unknown line"),
    ("pcd-unknown-mode", "a.pcd", S.pcd_header(40, "zipped") + PTS.tobytes(), "unknown DATA mode"),
    ("pcd-compressed-lies", "a.pcd",
     S.pcd_header(40, "binary_compressed") + struct.pack("<II", 100, 10**9) + PTS.tobytes(),
     "corrupt PCD"),
    ("pcd-compressed-garbage", "a.pcd",
     S.pcd_header(40, "binary_compressed") + struct.pack("<II", 200, 480) + bytes(range(200)),
     "corrupt PCD compressed block"),
    ("pcd-compressed-cannot-expand", "a.pcd",
     S.pcd_header(10**6, "binary_compressed") + struct.pack("<II", 100, 12 * 10**6) + bytes(100),
     "cannot expand"),
    ("pcd-negative", "a.pcd", S.pcd_header(40).replace(b"POINTS 40", b"POINTS -40"), "negative"),
    ("las-truncated", "a.las", S.las_bytes(PTS)[:-100], "truncated LAS"),
    ("las-count-4e9", "a.las", _las_patch(S.LAS_LEGACY_COUNT, "<I", 4_000_000_000), "4000000000"),
    ("las-count-too-small", "a.las", _las_patch(S.LAS_LEGACY_COUNT, "<I", 10), "wrong point count"),
    ("las-offset-past-end", "a.las", _las_patch(S.LAS_OFFSET_TO_POINTS, "<I", 10**9), "LAS"),
    ("las-million-vlrs", "a.las", _las_patch(S.LAS_N_VLRS, "<I", 10**6), "variable-length"),
    ("las-not-las", "a.las", b"LASX" + bytes(400), "LASF"),
    ("xyz-text-garbage", "a.xyz", b"hello world\nthis is not\na point cloud\n",
     "data row 0 holds a non-number 'hello'"),
    ("obj-garbage", "a.obj", b"v 1 2\nf 1 2 3\nvn x y z\n",
     "malformed OBJ: line 1: a vertex needs x, y and z"),
    ("conf-recursive", "a.conf", b"bmesh a.conf 0 0 0 0 0 0 1\n", "is a .conf file"),
    ("empty", "a.ply", b"", "empty"),
    ("one-point", "a.ply", S.ply_binary(PTS[:1]), "1 point"),
    ("duplicates", "a.ply", S.ply_binary(np.repeat(PTS[:1], 30, axis=0)), "coincide"),
    ("all-nan", "a.ply", S.ply_binary(np.full((10, 3), np.nan, np.float32)), "NaN"),
]


@pytest.mark.filterwarnings("ignore::UserWarning")  # the all-NaN case warns, then fails
@pytest.mark.parametrize("name, data, fragment", [c[1:] for c in BAD_FILES],
                         ids=[c[0] for c in BAD_FILES])
def test_bad_file_raises_a_specific_error(tmp_path, name, data, fragment):
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(PointvizError) as info:
        load(path)
    msg = str(info.value)
    assert fragment and fragment in msg
    assert name in msg  # names the file
    assert "\n" not in msg.strip()  # one line for the CLI


def test_valid_samples_load(tmp_path):
    """The builders' valid files load, so every failure above comes from the damage done."""
    for name, data in [("a.ply", S.ply_binary(PTS)), ("b.ply", S.ply_ascii(PTS)),
                       ("c.pcd", S.pcd_binary(PTS)), ("d.pcd", S.pcd_ascii(PTS)),
                       ("e.xyz", S.xyz_text(PTS)), ("f.las", S.las_bytes(PTS))]:
        (tmp_path / name).write_bytes(data)
        cloud = load(tmp_path / name)
        assert len(cloud) == len(PTS), name
        np.testing.assert_allclose(cloud.points, PTS, atol=1e-4)


def test_header_beyond_memory_fails_before_allocation(tmp_path, monkeypatch):
    """An honest header whose points do not fit in memory: a clear error, not an OOM kill."""
    from pointviz import validate

    monkeypatch.setattr(validate, "available_memory_bytes", lambda: 1000)
    for name, data in [("a.ply", S.ply_binary(PTS)), ("b.pcd", S.pcd_binary(PTS)),
                       ("c.las", S.las_bytes(PTS))]:
        (tmp_path / name).write_bytes(data)
        with pytest.raises(InputError, match="GB of memory available") as info:
            load(tmp_path / name)
        assert name in str(info.value)


def test_mesh_sample_beyond_memory_fails_before_allocation(tmp_path):
    (tmp_path / "m.ply").write_bytes(S.ply_mesh(PTS[:3], [[0, 1, 2]]))
    with pytest.raises(PointvizError, match="sample: 1,000,000,000,000 points need"):
        load(tmp_path / "m.ply", sample=10**12)


def test_nan_rows_are_dropped_with_a_note(tmp_path):
    pts = PTS.copy()
    pts[[3, 7]] = [np.nan, 0, np.inf]
    (tmp_path / "n.ply").write_bytes(S.ply_binary(pts))
    with pytest.warns(UserWarning, match="dropped 2 of 40 points"):
        cloud = load(tmp_path / "n.ply")
    assert len(cloud) == 38 and np.isfinite(cloud.points).all()
    assert any("NaN/inf" in note for note in cloud.notes)


def test_zero_length_normals_in_a_file_are_replaced_by_estimates(tmp_path):
    normals = PTS.copy()
    normals[5] = 0.0
    (tmp_path / "z.ply").write_bytes(S.ply_binary(PTS, normals))
    cloud = load(tmp_path / "z.ply")
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-5)
    assert any("normals are estimated" in note for note in cloud.notes)
    # estimated on a sphere: radial, and oriented consistently (all outward or all inward)
    cos = np.sum(cloud.normals * PTS, axis=1)
    assert (np.abs(cos) > 0.9).mean() > 0.9
    assert (cos > 0).all() or (cos < 0).all()


def test_line_and_plane_files_load_with_unit_normals(tmp_path):
    t = np.linspace(0, 1, 30, dtype=np.float32)
    line = np.column_stack([t, 2 * t, -t])
    g = np.stack(np.meshgrid(t, t), -1).reshape(-1, 2)
    plane = np.column_stack([g, np.full(len(g), 3.0, np.float32)])
    for name, pts in [("line.ply", line), ("plane.ply", plane)]:
        (tmp_path / name).write_bytes(S.ply_binary(pts))
        cloud = load(tmp_path / name)
        n = cloud.normals
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
        assert (cloud.radii > 0).all() and np.isfinite(cloud.radii).all()
        if name == "line.ply":  # any direction across the line will do
            assert np.abs(n @ np.array([1, 2, -1]) / np.sqrt(6)).max() < 1e-3
    # the plane's normals are its normal, one orientation for all
    assert np.abs(n[:, 2]).min() > 0.999 and len(np.unique(np.sign(n[:, 2]))) == 1
