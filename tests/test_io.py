"""Tests of pointviz.io: real files from ../shared/data (oracle: its summary.json), synthetic
round trips written to tmp_path, registration of Stanford range scans, and bad input."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pointviz.cloud import PointCloud, vertex_normals
from pointviz.errors import FileFormatError, InputError
from pointviz.io import load, parse_conf, quaternion_matrix


def _o3d():
    """Open3D, for the tests that write files with it or use it as an oracle: only those skip
    when it is missing (the readers under test do not need it)."""
    return pytest.importorskip("open3d")


# ------------------------------------------------------------------------------------------
# real data, checked against summary.json (written by whoever fetched the data, not by us)

REAL_FILES = [
    "stanford_bunny/reconstruction/bun_zipper.ply",
    "stanford_bunny/data/bun000.ply",
    "stanford_armadillo/Armadillo.ply",
    "lidar/autzen_trim.laz",
    "lidar/simple.las",
    "photogrammetry/ggg_benchmarksfm/owl_decimated.vtp",
    "pcl_testdata/table_scene_mug_stereo_textured.pcd",
    "open3d_testdata/fragment.pcd",
    "misc_scans/horse_cyberware.ply",
    "photogrammetry/demosthenes/demosthenes-low-res.obj",
]


@pytest.fixture(scope="module")
def summary():
    from conftest import SHARED_DATA

    path = SHARED_DATA / "summary.json"
    if not path.is_file():
        pytest.skip(f"../shared/data is absent: {path} not found")
    return json.loads(path.read_text())


@pytest.mark.data
@pytest.mark.parametrize("rel", REAL_FILES)
def test_real_file_counts_and_bounds_match_summary(shared_data, summary, rel):
    expected = summary[rel]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the organised PCD warns about its NaN holes
        cloud = load(shared_data / rel, estimate=False)
    assert len(cloud) == expected["finite_points"]
    lo, hi = cloud.bounds
    (elo, ehi) = np.asarray(expected["bbox"], dtype=float)
    tol = 1e-3 * np.linalg.norm(ehi - elo)  # summary.json rounds to 4-5 significant digits
    np.testing.assert_allclose(lo, elo, atol=tol)
    np.testing.assert_allclose(hi, ehi, atol=tol)
    assert cloud.has_colors == expected["colors"]
    if expected.get("normals") or expected.get("faces", 0) > 0:
        assert cloud.has_normals  # from the file or from the mesh's faces
    assert cloud.name == rel.rsplit("/", 1)[-1]
    assert cloud.points.dtype == np.float64


@pytest.mark.data
def test_armadillo_loads_with_outward_normals(shared_data):
    cloud = load(shared_data / "stanford_armadillo/Armadillo.ply")  # estimate=True: radii too
    assert len(cloud) == 172_974 and cloud.has_normals
    assert np.all(cloud.radii > 0)
    # the face normals are outward (positive enclosed volume) and the estimator finds the same
    # orientation from the bare points: measured 99.9994% agreement
    ref = load(shared_data / "stanford_armadillo/Armadillo.ply", estimate=False)
    estimated = PointCloud(ref.points).normals
    agree = np.einsum("ij,ij->i", estimated, cloud.normals) > 0
    assert agree.mean() > 0.99


@pytest.mark.data
def test_lidar_attributes(shared_data):
    cloud = load(shared_data / "lidar/autzen_trim.laz", estimate=False)
    np.testing.assert_array_equal(cloud.up, [0, 0, 1])
    assert cloud.intensity.dtype == np.float32 and cloud.intensity.shape == (110_000,)
    assert cloud.colors.min() >= 0 and cloud.colors.max() <= 1 and cloud.colors.max() > 0.5
    assert cloud.points[:, 1].min() > 8e5  # georeferenced coordinates kept in float64
    # terrain seen from above: with the +Z hint the estimated normals face up (mostly)
    small = load(shared_data / "lidar/simple.las")
    assert np.mean(small.normals[:, 2] > 0) > 0.9


@pytest.mark.data
def test_organised_pcd_drops_nan_holes_with_a_note(shared_data):
    path = shared_data / "pcl_testdata/table_scene_mug_stereo_textured.pcd"
    with pytest.warns(UserWarning, match="dropped 97920 of 307200 points"):
        cloud = load(path, estimate=False)
    assert any("97920" in note for note in cloud.notes)
    assert np.isfinite(cloud.points).all() and len(cloud) == 209_280


@pytest.mark.data
@pytest.mark.filterwarnings("ignore:.*NaN/inf coordinates:UserWarning")
def test_compressed_pcl_frames_read_by_the_core_equal_open3ds_reading(shared_data):
    """PCL's binary_compressed frames (LZF, one block per field), expanded in the core: the same
    points, colours and pixel grid as Open3D's reader gives, without importing Open3D."""
    from pointviz.readers import pcd as pcd_reader

    for name in ("office1.pcd", "car6.pcd"):
        path = shared_data / "pcl_testdata" / name
        header = pcd_reader._check_pcd(path)
        assert header["mode"] == "binary_compressed"
        ours = pcd_reader.read_pcd(path, None, None)
        ref = pcd_reader.read_o3d_points(
            path, None, None,
            frame=lambda pts, normals, h=header, p=path: pcd_reader.depth_frame(p, h, pts, normals))
        np.testing.assert_array_equal(ours.points, ref.points)
        assert (ours.colors is None) == (ref.colors is None)
        if ours.colors is not None:
            np.testing.assert_allclose(ours.colors, ref.colors, atol=1e-7)
        np.testing.assert_array_equal(ours.scan_grid, ref.scan_grid)


@pytest.mark.data
def test_mesh_surface_sampling(shared_data):
    o3d = _o3d()
    path = shared_data / "stanford_bunny/reconstruction/bun_zipper.ply"
    cloud = load(path, sample=5000, rng=1, estimate=False)
    assert len(cloud) == 5000 and cloud.has_normals
    mesh = o3d.io.read_triangle_mesh(str(path))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    dist = scene.compute_distance(o3d.core.Tensor(cloud.points.astype(np.float32))).numpy()
    assert dist.max() < 1e-6


@pytest.mark.data
def test_point_file_random_subset(shared_data):
    cloud = load(shared_data / "open3d_testdata/fragment.pcd", sample=1000, rng=0, estimate=False)
    assert len(cloud) == 1000 and cloud.has_normals and cloud.has_colors
    assert "1000 of 113662" in cloud.notes[-1]


# ------------------------------------------------------------------------------------------
# Stanford .conf registration


def registration_residuals(points, scan_index, step=8):
    """Per scan: median distance from (every step-th of) its points to all other scans."""
    out = []
    for s in np.unique(scan_index):
        mine = scan_index == s
        dist, _ = cKDTree(points[~mine]).query(points[mine][::step], workers=-1)
        out.append(np.median(dist))
    return np.array(out)


def wrong_convention(conf):
    """The same scans placed with R(q) p + t (column-vector Hamilton matrix, no transpose)."""
    pts, idx = [], []
    for i, (scan, t, q, _) in enumerate(parse_conf(conf)):
        local = load(scan, estimate=False).points
        pts.append(local @ quaternion_matrix(q).T + t)
        idx.append(np.full(len(local), i))
    return np.concatenate(pts), np.concatenate(idx)


@pytest.mark.data
@pytest.mark.parametrize(
    "conf, nscans",
    [
        ("stanford_bunny/data/bun.conf", 10),
        ("stanford_dragon/dragon_stand/dragonStandRight.conf", 15),
    ],
)
def test_conf_scans_line_up(shared_data, summary, conf, nscans):
    """Measured median distances to the other scans: bunny 0.23-0.34 mm, dragon 0.22-0.24 mm
    (sample spacing ~0.5 mm); with R(q) p + t instead: median 11.7 mm (bunny), 4.3 mm (dragon)."""
    path = shared_data / conf
    cloud = load(path, estimate=False)
    scans = parse_conf(path)
    assert len(scans) == nscans
    folder = conf.rsplit("/", 1)[0]
    assert len(cloud) == sum(summary[f"{folder}/{s.name}"]["finite_points"] for s, *_ in scans)
    assert cloud.scan_index.dtype == np.int32 and set(cloud.scan_index) == set(range(nscans))
    assert cloud.viewpoints.shape == (len(cloud), 3)
    good = registration_residuals(cloud.points, cloud.scan_index)
    assert good.max() < 0.5e-3  # metres: sub-millimetre, about half the scan spacing
    bad = registration_residuals(*wrong_convention(path))
    assert np.median(bad) > 10 * np.median(good)


@pytest.mark.data
def test_conf_normals_face_the_scanner_and_agree_with_the_reconstruction(shared_data):
    """Estimated normals of the 10 registered bunny scans vs face normals of bun_zipper.ply.

    Measured: 99.5% agree in sign. Orienting toward each scan's local origin instead (inside
    the bunny) agrees on only 3-22% per scan.
    """
    o3d = _o3d()
    cloud = load(shared_data / "stanford_bunny/data/bun.conf")
    mesh = o3d.io.read_triangle_mesh(
        str(shared_data / "stanford_bunny/reconstruction/bun_zipper.ply")
    )
    verts, faces = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    ref = vertex_normals(verts, faces)
    used = np.linalg.norm(ref, axis=1) > 0
    dist, idx = cKDTree(verts[used]).query(cloud.points, workers=-1)
    near = dist < 2e-3
    assert near.mean() > 0.99
    agree = np.einsum("ij,ij->i", cloud.normals, ref[used][idx]) > 0
    assert agree[near].mean() > 0.98
    assert np.all(cloud.radii > 0) and np.median(cloud.radii) < 1e-3


def write_ply(path, points, **kw):
    o3d = _o3d()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    for key, value in kw.items():
        setattr(pcd, key, o3d.utility.Vector3dVector(value))
    assert o3d.io.write_point_cloud(str(path), pcd, write_ascii=False)
    return path


def test_conf_convention_on_synthetic_scans(tmp_path, rng):
    """p' = R(q)^T p + t: a known transform written to a .conf comes back exactly."""
    local = rng.random((200, 3))
    write_ply(tmp_path / "a.ply", local)
    (tmp_path / "sub").mkdir()
    write_ply(tmp_path / "sub" / "b.ply", local[:50])
    q = np.array([0.1, -0.3, 0.2, 0.9])
    q /= np.linalg.norm(q)
    t = np.array([1.0, 2.0, 3.0])
    conf = tmp_path / "scans.conf"
    conf.write_text(
        "camera 0 0 1 0 0 0 1\n\n"
        f"bmesh a.ply {' '.join(map(str, t))} {' '.join(map(str, q))}\n"
        "mesh whatever 0 0 0 0 0 0 1\n"
        "bmesh sub/b.ply 0 0 0 0 0 0 1\n"
    )
    cloud = load(conf, estimate=False)
    expected = local @ quaternion_matrix(q) + t  # rows: (R^T p)^T
    np.testing.assert_allclose(cloud.points[:200], expected, atol=1e-6)
    np.testing.assert_allclose(cloud.points[200:], local[:50], atol=1e-6)
    np.testing.assert_array_equal(cloud.scan_index, np.r_[np.zeros(200), np.ones(50)])
    # the scanner looks down -z of each scan's frame: its viewpoint lies along R^T z from the scan
    view_dir = cloud.viewpoints[0] - cloud.points[:200].mean(axis=0)
    view_dir /= np.linalg.norm(view_dir)
    np.testing.assert_allclose(view_dir, quaternion_matrix(q).T @ [0, 0, 1], atol=0.02)


def test_quaternion_matrix_is_a_rotation(rng):
    q = rng.normal(size=4)
    r = quaternion_matrix(q)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(
        quaternion_matrix([0, 0, np.sin(0.5), np.cos(0.5)]) @ [1, 0, 0],
        [np.cos(1.0), np.sin(1.0), 0],
        atol=1e-12,
    )


# ------------------------------------------------------------------------------------------
# synthetic round trips (no shared data needed)


def test_ply_roundtrip_with_normals_and_colors(tmp_path, rng):
    pts = rng.random((300, 3)) + 1e5
    nrm = rng.normal(size=(300, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    col = rng.random((300, 3))
    path = write_ply(tmp_path / "c.ply", pts, normals=nrm, colors=col)
    cloud = load(path, estimate=False)
    np.testing.assert_allclose(cloud.points, pts, rtol=1e-12)
    np.testing.assert_allclose(cloud.normals, nrm, atol=1e-6)
    np.testing.assert_allclose(cloud.colors, col, atol=1 / 255)
    assert cloud.has_normals and cloud.name == "c.ply"


@pytest.mark.parametrize("ext", [".xyz", ".xyzn", ".pcd", ".pts"])
def test_open3d_point_formats(tmp_path, rng, ext):
    o3d = _o3d()
    pts = rng.random((100, 3))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.normals = o3d.utility.Vector3dVector(np.tile([0.0, 0.0, 1.0], (100, 1)))
    path = tmp_path / f"p{ext}"
    assert o3d.io.write_point_cloud(str(path), pcd)
    cloud = load(path)
    assert len(cloud) == 100
    np.testing.assert_allclose(cloud.points, pts, atol=1e-5)
    assert np.all(cloud.radii > 0)


def test_pcd_with_nan_rows_warns(tmp_path, rng):
    o3d = _o3d()
    pts = rng.random((50, 3))
    pts[[3, 7]] = np.nan
    path = tmp_path / "holes.pcd"
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    assert o3d.io.write_point_cloud(str(path), pcd)
    with pytest.warns(UserWarning, match="dropped 2 of 50 points"):
        cloud = load(path, estimate=False)
    assert len(cloud) == 48 and "dropped 2 of 50" in cloud.notes[0]


# ------------------------------------------------------------------------------------------
# organised PCD clouds: one depth-camera frame each, in the camera's coordinates


def depth_frame_of_sphere(w=64, h=48, centre=(0.1, 0.2, 2.0), radius=0.8, origin=(0.0, 0.0, 0.0),
                          noise=0.0, rng=None):
    """Pixels (row, col) of a pinhole camera at ``origin`` looking along +z (x right, y down)
    and the first hits of their rays on a sphere: (h * w, 3) points in row-major order, NaN
    where a ray misses (the holes of an organised cloud)."""
    f = 0.9 * w
    rows, cols = np.mgrid[0:h, 0:w]
    d = np.column_stack([(cols.ravel() - w / 2 + 0.5) / f, (rows.ravel() - h / 2 + 0.5) / f,
                         np.ones(w * h)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.asarray(origin, float)
    oc = o - np.asarray(centre, float)
    b = d @ oc
    disc = b * b - (oc @ oc - radius * radius)
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(disc)
    if noise:
        t = t + noise * (rng.standard_normal(len(t)))
    pts = o + t[:, None] * d
    pts[~(disc > 0)] = np.nan
    return pts


def write_pcd(path, pts, w, h, mode="binary", viewpoint="0 0 0 1 0 0 0"):
    header = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
              f"WIDTH {w}\nHEIGHT {h}\nVIEWPOINT {viewpoint}\nPOINTS {w * h}\nDATA {mode}\n")
    with open(path, "wb") as fh:
        fh.write(header.encode())
        if mode == "ascii":
            fh.write("".join(" ".join("nan" if not np.isfinite(v) else f"{v:.9g}" for v in row)
                             + "\n" for row in pts).encode())
        else:
            fh.write(np.ascontiguousarray(pts, dtype="<f4").tobytes())


@pytest.mark.parametrize("mode", ["ascii", "binary", "binary_compressed"])
def test_organised_pcd_is_a_depth_frame_fitted_as_a_raw_scan(tmp_path, rng, mode):
    w, h, centre, radius = 64, 48, np.array([0.1, 0.2, 2.0]), 0.8
    pts = depth_frame_of_sphere(w, h, centre, radius, noise=0.002, rng=rng)
    finite = np.isfinite(pts).all(axis=1)
    assert 0.3 < finite.mean() < 0.95  # the frame has holes around the sphere
    path = tmp_path / f"frame_{mode}.pcd"
    if mode == "binary_compressed":  # Open3D writes it unorganised: make the header say w x h
        o3d = _o3d()
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        assert o3d.io.write_point_cloud(str(path), pcd, compressed=True)
        raw = path.read_bytes()
        cut = raw.index(b"DATA")
        head = raw[:cut].replace(f"WIDTH {w * h}\nHEIGHT 1".encode(),
                                 f"WIDTH {w}\nHEIGHT {h}".encode())
        assert f"HEIGHT {h}".encode() in head
        path.write_bytes(head + raw[cut:])
    else:
        write_pcd(path, pts, w, h, mode)
    with pytest.warns(UserWarning, match="NaN/inf"):
        bare = load(path, estimate=False)
    # the rows kept are the frame's finite pixels, each with its row and column
    index = np.flatnonzero(finite)
    np.testing.assert_allclose(bare.points, pts[finite], atol=1e-6)
    np.testing.assert_array_equal(bare.scan_grid, np.column_stack([index // w, index % w]))
    np.testing.assert_array_equal(bare.up, [0, -1, 0])  # y down in a camera's frame
    assert bare.is_raw_scan and any("depth-camera frame" in n for n in bare.notes)
    with pytest.warns(UserWarning, match="NaN/inf"):
        cloud = load(path)  # fitted on load, as raw scans are
    assert cloud.fit_report is not None and cloud.fit_report["points_kept"] > 0.8 * finite.sum()
    # oracle: the sphere. The fit moves the points onto it (closer than the noisy ones), and the
    # normals are its outward normals, which face the camera
    dist = np.abs(np.linalg.norm(cloud.points - centre, axis=1) - radius)
    noisy = np.abs(np.linalg.norm(bare.points - centre, axis=1) - radius)
    assert dist.mean() < 0.7 * noisy.mean()
    exact = (cloud.points - centre) / np.linalg.norm(cloud.points - centre, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", cloud.normals, exact)
    assert np.median(cos) > np.cos(np.radians(3)) and np.mean(cos > 0) > 0.99
    assert np.all(cloud.radii > 0)


def kinect_frame(w=320, h=240, f=290.0, baseline=0.075, subpixel=8, noise=0.0, quantise=True,
                 rng=None, mixed=False):
    """A depth camera's frame of an analytic scene: a wall through (0, 0, 3) turned 40 degrees
    about the vertical, a sphere of radius 0.35 in front. With ``quantise``, as a Kinect-class
    camera measures it: the disparity f b / z (plus Gaussian ``noise`` in pixels) rounded to
    1/``subpixel`` pixel, then converted back to depth (steps of z^2 / (subpixel f b): 4-5
    pixels' spacing at 3 m, as on PCL's Kinect frames). With ``mixed``, the sphere's outermost
    ring of pixels (those with a row or column neighbour on the wall) are mixed pixels, as real
    sensors return them: a depth drawn uniformly between the sphere's and the wall's along the
    ray. Returns the (h * w, 3) points (NaN past 6 m) and the scene: (wall normal, wall point,
    sphere centre, radius)."""
    rows, cols = np.mgrid[0:h, 0:w]
    d = np.column_stack([(cols.ravel() - w / 2 + 0.5) / f, (rows.ravel() - h / 2 + 0.5) / f,
                         np.ones(w * h)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    wall_n = np.array([np.sin(np.radians(40)), 0.1, -np.cos(np.radians(40))])
    wall_n /= np.linalg.norm(wall_n)
    wall_p = np.array([0.0, 0.0, 3.0])
    centre, radius = np.array([-0.3, 0.1, 2.2]), 0.35
    b = -(d @ centre)
    disc = b * b - (centre @ centre - radius * radius)
    with np.errstate(invalid="ignore"):
        t_sphere = -b - np.sqrt(disc)
    on_sphere = (disc > 0) & (t_sphere > 0)
    t_wall = (wall_p @ wall_n) / (d @ wall_n)
    t = np.where(on_sphere, t_sphere, t_wall)
    if mixed:
        img = on_sphere.reshape(h, w)
        ring = img.copy()
        ring[1:-1, 1:-1] &= ~(img[:-2, 1:-1] & img[2:, 1:-1] & img[1:-1, :-2] & img[1:-1, 2:])
        ring = ring.ravel()
        u = rng.random(ring.sum())
        t[ring] = t_sphere[ring] + u * (t_wall[ring] - t_sphere[ring])
    pts = t[:, None] * d
    if quantise:
        z = pts[:, 2]
        disparity = f * baseline / z + (noise * rng.standard_normal(len(z)) if noise else 0.0)
        pts *= (f * baseline / (np.round(disparity * subpixel) / subpixel) / z)[:, None]
    pts[t > 6] = np.nan
    return pts, (wall_n, wall_p, centre, radius)


def scene_errors(cloud, scene):
    """Mean angle (degrees) of the normals against the scene's surface nearest each point, and
    the points' mean distance to it."""
    wall_n, wall_p, centre, radius = scene
    p = cloud.points.astype(np.float64)
    to_wall = np.abs((p - wall_p) @ wall_n)
    off = p - centre
    to_sphere = np.abs(np.linalg.norm(off, axis=1) - radius)
    exact = np.where((to_sphere < to_wall)[:, None],
                     off / np.linalg.norm(off, axis=1, keepdims=True), -wall_n)
    cos = np.abs(np.einsum("ij,ij->i", cloud.normals, exact))
    return float(np.degrees(np.arccos(np.clip(cos, 0, 1))).mean()), float(
        np.minimum(to_wall, to_sphere).mean())


@pytest.mark.parametrize("noise", [0.05, 0.0])
def test_depth_steps_the_fit_follows_the_surface_through_kinect_quantisation(tmp_path, noise):
    # oracle: the analytic scene. Its Kinect-like frame (disparity in 1/8 pixel, with and
    # without disparity noise) is a staircase whose steps are wider than 16-32 points: fitted
    # from those (steps=False, as before) the normals followed the terraces
    rng = np.random.default_rng(7)
    pts, scene = kinect_frame(noise=noise, rng=rng)
    path = tmp_path / "kinect.pcd"
    write_pcd(path, pts, 320, 240)
    with pytest.warns(UserWarning, match="NaN/inf"):
        raw = load(path, estimate=False, fit=False)
    assert len(np.unique(raw.points[:, 2])) < 100  # the frame's depths come in steps
    plain = raw.fitted(steps=False)
    before = scene_errors(plain, scene)
    fitted = raw.fitted()
    after = scene_errors(fitted, scene)
    assert before[0] > 20.0  # the terraces' normals
    assert after[0] < 3.0 and after[0] < 0.15 * before[0], (before, after)
    assert after[1] < 0.3 * before[1], (before, after)
    assert any("depths in steps of" in n for n in fitted.notes)
    # facing away from the camera: no more than before (a few of the sphere's rim points)
    away = np.mean(np.einsum("ij,ij->i", fitted.normals, fitted.points) >= 0)
    assert away <= np.mean(np.einsum("ij,ij->i", plain.normals, plain.points) >= 0) + 1e-4
    assert away < 0.002
    # the same through load(), the default
    with pytest.warns(UserWarning, match="NaN/inf"):
        loaded = load(path)
    np.testing.assert_allclose(loaded.points, fitted.points)
    # invalid pixels written as zeros (the camera's position), not NaN: in no patch
    zeros = np.where(np.isfinite(pts), pts, 0.0)
    write_pcd(path, zeros, 320, 240)
    cloud = load(path)
    seen = np.linalg.norm(cloud.points, axis=1) > 0
    assert seen.sum() >= 0.99 * len(fitted)
    assert scene_errors(cloud.subset(seen), scene)[0] < 3.0


@pytest.mark.parametrize("noise", [0.05, 0.0])
def test_depth_edges_flying_pixels_dropped_and_patches_stop_at_edges(tmp_path, noise):
    # oracle: the analytic scene again, now with mixed pixels along the sphere's silhouette
    # (depths between the sphere's and the wall's, as real sensors return them). Fitted with
    # square patches across the edge (edges=False, as before) some stay in mid-air and the
    # normals next to the edge follow patches straddling it
    from scipy import ndimage

    pts, scene = kinect_frame(noise=noise, rng=np.random.default_rng(7), mixed=True)
    wall_n, wall_p, centre, radius = scene
    path = tmp_path / "mixed.pcd"
    write_pcd(path, pts, 320, 240)
    with pytest.warns(UserWarning, match="NaN/inf"):
        raw = load(path, estimate=False, fit=False)
    exact, _ = kinect_frame(quantise=False)
    sphere = (np.abs(np.linalg.norm(exact - centre, axis=1) - radius) < 1e-6).reshape(240, 320)
    to_edge = np.where(sphere, ndimage.distance_transform_edt(sphere),
                       ndimage.distance_transform_edt(~sphere))  # pixels to the silhouette

    def measure(cloud):
        """Fraction of points farther than 3 steps from both surfaces, points within 3 steps
        of one, mean normal angle of those within 3 pixels of the silhouette."""
        p = cloud.points.astype(np.float64)
        to_wall = np.abs((p - wall_p) @ wall_n)
        off = p - centre
        to_sphere = np.abs(np.linalg.norm(off, axis=1) - radius)
        step = p[:, 2] ** 2 / (290.0 * 0.075 * 8)
        on = np.minimum(to_wall, to_sphere) <= 3 * step
        truth = np.where((to_sphere < to_wall)[:, None],
                         off / np.linalg.norm(off, axis=1, keepdims=True), -wall_n)
        cos = np.abs(np.einsum("ij,ij->i", cloud.normals, truth))
        angle = np.degrees(np.arccos(np.clip(cos, 0, 1)))
        near = on & (to_edge[cloud.scan_grid[:, 0], cloud.scan_grid[:, 1]] <= 3)
        return np.mean(~on), on.sum(), angle[near].mean()

    before = measure(raw.fitted(edges=False))
    fitted = raw.fitted()
    after = measure(fitted)
    assert before[0] > 3e-4 and after[0] < 1e-4, (before, after)  # the flying ones gone
    assert after[1] >= 0.995 * before[1], (before, after)  # no surface lost
    assert after[2] < 0.7 * before[2], (before, after)  # normals next to the edge
    assert scene_errors(fitted, scene)[0] < 2.0
    note = [n for n in fitted.notes if "flying pixels" in n]
    assert note and int(note[0].split("dropped ")[1].split()[0]) > 100


def test_depth_steps_leave_frames_without_steps_alone(tmp_path, rng):
    # noise-free depths (floats): no steps, the fit as before, to the bit
    pts, scene = kinect_frame(quantise=False)
    path = tmp_path / "exact.pcd"
    write_pcd(path, pts, 320, 240)
    with pytest.warns(UserWarning, match="NaN/inf"):
        raw = load(path, estimate=False, fit=False)
    plain, stepped = raw.fitted(steps=False), raw.fitted()
    np.testing.assert_array_equal(plain.points, stepped.points)
    np.testing.assert_array_equal(plain.normals, stepped.normals)
    assert scene_errors(stepped, scene)[0] < 0.2
    # nor noisy floats (range noise without quantisation)
    from pointviz.depth_steps import depth_steps

    assert depth_steps(pts[np.isfinite(pts[:, 2]), 2] + rng.normal(0, 1e-3, np.isfinite(
        pts[:, 2]).sum())) is None


def test_depth_steps_leave_few_surfaces_at_distinct_depths_alone(tmp_path):
    """Two walls facing the camera, 0.5 m apart: two distinct depths among 3072 points, as few
    as a quantised frame has, but their gap is a depth edge, not a step: no patch may smooth it
    into a ramp (the fit leaves both walls where they are)."""
    from pointviz.depth_steps import depth_steps

    w, h = 64, 48
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    z = np.where(u < w // 2, 2.0, 2.5)
    pts = np.c_[((u - w / 2) / 500 * z).ravel(), ((v - h / 2) / 500 * z).ravel(), z.ravel()]
    assert depth_steps(pts[:, 2]) is None
    path = tmp_path / "walls.pcd"
    write_pcd(path, pts, w, h)
    cloud = load(path)
    near = cloud.points[:, 2] < 2.25
    np.testing.assert_allclose(cloud.points[near, 2], 2.0, atol=1e-6)
    np.testing.assert_allclose(cloud.points[~near, 2], 2.5, atol=1e-6)
    assert not any("depths in steps" in note for note in cloud.notes)


def test_organised_pcd_viewpoint_and_frames_that_are_not_the_cameras(tmp_path, rng):
    # the VIEWPOINT's origin is the camera: a frame taken from (1, 2, 3)
    origin = np.array([1.0, 2.0, 3.0])
    pts = depth_frame_of_sphere(origin=origin, centre=origin + [0.1, 0.2, 2.0])
    path = tmp_path / "moved.pcd"
    write_pcd(path, pts, 64, 48, viewpoint="1 2 3 1 0 0 0")
    with pytest.warns(UserWarning, match="NaN/inf"):
        cloud = load(path)
    np.testing.assert_array_equal(cloud.viewpoints, origin)
    assert np.all(np.einsum("ij,ij->i", cloud.normals, origin - cloud.points) > 0)
    # most points behind the camera's +z: not the camera's frame, so no up is assumed
    behind = pts.copy()
    behind[:, 2] = -behind[:, 2]
    path = tmp_path / "behind.pcd"
    write_pcd(path, behind, 64, 48)
    with pytest.warns(UserWarning, match="NaN/inf"):
        cloud = load(path, estimate=False)
    assert cloud.up is None and cloud.is_raw_scan
    # a spinning LiDAR's organised frame (beams x azimuths, z up, all around the sensor): its
    # grid and viewpoint hold, but it is no camera's frame
    elev, azim = np.meshgrid(np.radians(np.linspace(-15, 15, 16)), np.linspace(0, 2 * np.pi, 128,
                                                                               endpoint=False),
                             indexing="ij")
    dirs = np.stack([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)],
                    axis=-1).reshape(-1, 3)
    lidar = dirs * (10.0 + rng.uniform(0, 1, (len(dirs), 1)))
    path = tmp_path / "lidar.pcd"
    write_pcd(path, lidar, 128, 16)
    cloud = load(path, estimate=False)
    assert cloud.up is None and cloud.is_raw_scan and cloud.scan_grid.shape == (16 * 128, 2)
    # an unorganised cloud (HEIGHT 1) stays as it was
    flat = tmp_path / "flat.pcd"
    write_pcd(flat, pts[np.isfinite(pts).all(axis=1)], int(np.isfinite(pts).all(axis=1).sum()), 1)
    cloud = load(flat, estimate=False)
    assert cloud.viewpoints is None and cloud.up is None and not cloud.is_raw_scan
    # an organised one with normals keeps them (no fit), and is still the camera's frame
    o3d = _o3d()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.normals = o3d.utility.Vector3dVector(np.tile([0.0, 0.0, -1.0], (len(pts), 1)))
    with_normals = tmp_path / "with_normals.pcd"
    assert o3d.io.write_point_cloud(str(with_normals), pcd, compressed=True)
    raw = with_normals.read_bytes()
    cut = raw.index(b"DATA")
    with_normals.write_bytes(raw[:cut].replace(b"WIDTH 3072\nHEIGHT 1", b"WIDTH 64\nHEIGHT 48")
                             + raw[cut:])
    with pytest.warns(UserWarning, match="NaN/inf"):
        cloud = load(with_normals)
    finite = int(np.isfinite(pts).all(axis=1).sum())
    assert cloud.fit_report is None and not cloud.is_raw_scan and len(cloud) == finite
    np.testing.assert_array_equal(cloud.normals, np.tile([0.0, 0.0, -1.0], (finite, 1)))
    np.testing.assert_array_equal(cloud.up, [0, -1, 0])
    np.testing.assert_array_equal(cloud.viewpoints, [0, 0, 0])


@pytest.mark.parametrize("viewpoint", ["0 0 0 1 0 0", "0 0 x 1 0 0 0", "0 nan 0 1 0 0 0"])
def test_pcd_bad_viewpoint_is_a_clear_error(tmp_path, viewpoint):
    path = tmp_path / "bad_viewpoint.pcd"
    write_pcd(path, np.zeros((4, 3)), 2, 2, viewpoint=viewpoint)
    with pytest.raises(FileFormatError, match="bad_viewpoint.pcd: PCD header: VIEWPOINT"):
        load(path)


@pytest.mark.data
@pytest.mark.parametrize("name", ["table_scene_mug_stereo_textured",
                                  "milk_cartoon_all_small_clorox"])
def test_real_depth_frames_load_upright(shared_data, name):
    """PCL's organised test frames are in the camera's coordinates (y down): loaded, their up is
    -y, which the scene confirms — the largest plane (Open3D's RANSAC, an independent oracle)
    is the table, and its side facing the camera faces up."""
    o3d = _o3d()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # NaN holes
        cloud = load(shared_data / f"pcl_testdata/{name}.pcd", estimate=False)
    assert cloud.is_raw_scan
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(cloud.points)))
    o3d.utility.random.seed(1)
    (a, b, c, d), inliers = pcd.segment_plane(0.01, 3, 1000)
    assert len(inliers) > 0.5 * len(cloud)  # the table
    normal = np.array([a, b, c]) * np.sign(d)  # the side facing the camera at the origin
    assert normal @ cloud.up > 0.7


@pytest.mark.parametrize("ext", [".obj", ".off", ".stl", ".glb", ".ply"])
def test_mesh_formats(tmp_path, ext):
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    path = tmp_path / f"ico{ext}"
    mesh.export(str(path))
    cloud = load(path)
    assert len(cloud) == len(mesh.vertices)  # STL/OBJ duplicates are merged back
    np.testing.assert_allclose(np.linalg.norm(cloud.points, axis=1), 1.0, atol=1e-5)
    cos = np.einsum("ij,ij->i", cloud.normals, cloud.points)
    assert cos.min() > 0.98  # outward, from the faces
    sampled = load(path, sample=300, rng=0)
    assert len(sampled) == 300 and sampled.has_normals


def _coarse_and_fine_spheres(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    coarse = trimesh.creation.icosphere(subdivisions=1, radius=1.0)  # 42 vertices
    fine = trimesh.creation.icosphere(subdivisions=7, radius=1.0)    # 163842 vertices
    paths = tmp_path / "coarse.ply", tmp_path / "fine.ply"
    coarse.export(str(paths[0]))
    fine.export(str(paths[1]))
    return coarse, fine, paths


def test_sparse_meshes_are_sampled_densely_by_default_in_the_cli_path(tmp_path):
    """``sample="auto"`` (what render, view and path load with): a 42-vertex icosphere's vertex
    disks would be ~150 px facets, so its faces are sampled at ~1.5 px spacing of a 480 px frame
    (the count follows from its area: 4 pi r^2 / (1.5 * 2 r / 480)^2 ~ 1.3e5, the icosphere's
    area a little less); a 164k-vertex one (edges ~2 px) keeps its vertices. The sampling is seeded: the
    same points every time."""
    from pointviz.readers.common import DENSE_FRAME_PIXELS, DENSE_SPACING_PIXELS

    coarse, fine, (pc, pf) = _coarse_and_fine_spheres(tmp_path)
    auto = load(pc, sample="auto", estimate=False)
    want = coarse.area / (DENSE_SPACING_PIXELS * 2.0 / DENSE_FRAME_PIXELS) ** 2
    assert len(auto) == pytest.approx(want, rel=0.02)
    assert any("sparse for the picture" in n for n in auto.notes)
    np.testing.assert_array_equal(auto.points, load(pc, sample="auto", estimate=False).points)
    # the samples' normals follow the sphere (blended), not the 80 flat faces (up to ~20 deg)
    unit = auto.points / np.linalg.norm(auto.points, axis=1)[:, None]
    cos = np.einsum("ij,ij->i", auto.normals, unit)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).mean() < 6.0
    assert len(load(pf, sample="auto", estimate=False)) == len(fine.vertices)
    assert len(load(pc, estimate=False)) == len(coarse.vertices)  # the API's default: vertices
    # point files are never sampled by "auto"
    pts = tmp_path / "p.xyz"
    np.savetxt(pts, np.random.default_rng(0).normal(size=(50, 3)))
    assert len(load(pts, sample="auto", estimate=False)) == 50


def test_cli_sample_option(tmp_path):
    _, _, (pc, _) = _coarse_and_fine_spheres(tmp_path)
    from pointviz.cli import main

    def points(*extra):
        import contextlib
        import io as _io

        buf = _io.StringIO()
        with contextlib.redirect_stdout(buf):
            assert main(["info", str(pc), *extra]) == 0
        line = next(x for x in buf.getvalue().splitlines() if x.startswith("points"))
        return int(line.split()[1])

    assert points() > 100_000
    import contextlib
    import io as _io

    buf = _io.StringIO()
    with contextlib.redirect_stdout(buf):
        main(["info", str(pc)])
    assert "42 vertices are sparse for the picture" in buf.getvalue()  # the note is shown
    assert points("--sample", "vertices") == 42
    assert points("--sample", "500") == 500
    for bad in ("0", "-3", "many"):
        with pytest.raises(SystemExit):
            main(["info", str(pc), "--sample", bad])


def test_sampled_mesh_colours_are_blended_from_the_vertices(rng):
    """Samples of a coloured triangle take the barycentric blend of its corners' colours."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    col = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    cloud = PointCloud.from_mesh(v, [[0, 1, 2]], sample=2000, rng=rng, colors=col)
    p = cloud.points
    want = np.c_[1 - p[:, 0] - p[:, 1], p[:, 0], p[:, 1]]  # barycentric weights = colours
    np.testing.assert_allclose(cloud.colors, want, atol=2e-3)  # colours are stored as 8 bits


def test_las_roundtrip(tmp_path, rng):
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [0.001, 0.001, 0.001]
    header.offsets = [637000.0, 849000.0, 0.0]
    las = laspy.LasData(header)
    n = 400
    las.x = 637000 + rng.uniform(0, 20, n)
    las.y = 849000 + rng.uniform(0, 20, n)
    las.z = rng.uniform(400, 400.05, n)
    las.red = np.full(n, 65535, np.uint16)
    las.green = np.full(n, 32768, np.uint16)
    las.blue = np.zeros(n, np.uint16)
    las.intensity = np.arange(n, dtype=np.uint16)
    for ext in (".las", ".laz"):
        path = tmp_path / f"t{ext}"
        las.write(str(path))
        cloud = load(path)
        np.testing.assert_allclose(cloud.points[:, 0], np.asarray(las.x), atol=1e-9)
        np.testing.assert_allclose(cloud.colors[0], [1, 32768 / 65535, 0], atol=1e-6)
        np.testing.assert_array_equal(cloud.intensity, np.arange(n, dtype=np.float32))
        np.testing.assert_array_equal(cloud.up, [0, 0, 1])
        assert cloud.seen_from_above  # aerial/terrestrial LiDAR: oriented from above
        assert np.mean(cloud.normals[:, 2] > 0.9) > 0.95  # flat ground, facing up


def test_vtp_roundtrip(tmp_path):
    pv = pytest.importorskip("pyvista")
    sphere = pv.Sphere(radius=3.0)
    sphere.point_data["RGB"] = np.full((sphere.n_points, 3), 128, np.uint8)
    path = tmp_path / "s.vtp"
    sphere.save(str(path))
    cloud = load(path)
    assert len(cloud) == sphere.n_points and cloud.has_normals and cloud.has_colors
    np.testing.assert_allclose(cloud.colors, 128 / 255, atol=1e-6)


def test_load_overrides_and_keyword_checks(tmp_path, rng):
    path = write_ply(tmp_path / "k.ply", rng.random((20, 3)))
    cloud = load(path, up=(0, 2, 0), name="mine", estimate=False)
    np.testing.assert_array_equal(cloud.up, [0, 1, 0])
    assert cloud.name == "mine"
    with pytest.raises(InputError, match="unknown keyword argument"):
        load(path, colour=True)
    with pytest.raises(InputError, match="sample: expected a positive integer"):
        load(path, sample=-3)


def test_estimate_flag(tmp_path, rng):
    path = write_ply(tmp_path / "e.ply", rng.random((50, 3)))
    lazy = load(path, estimate=False)
    assert lazy._normals is None and lazy._radii is None
    eager = load(path)
    assert eager._normals is not None and eager._radii is not None
    tiny = write_ply(tmp_path / "tiny.ply", rng.random((2, 3)))
    with pytest.raises(FileFormatError, match=r"tiny\.ply: normals: cannot be estimated"):
        load(tiny)


# ------------------------------------------------------------------------------------------
# bad input


def test_missing_file(tmp_path):
    with pytest.raises(FileFormatError, match=r"nope\.ply: no such file"):
        load(tmp_path / "nope.ply")


def test_unknown_extension(tmp_path):
    path = tmp_path / "cloud.foo"
    path.write_text("1 2 3\n")
    with pytest.raises(FileFormatError, match=r"cloud\.foo: unsupported extension '\.foo'"):
        load(path)


@pytest.mark.parametrize("ext", [".ply", ".xyz", ".pcd", ".obj", ".las", ".vtp", ".conf"])
def test_empty_file(tmp_path, ext):
    path = tmp_path / f"empty{ext}"
    path.write_bytes(b"")
    with pytest.raises(FileFormatError, match=rf"empty\{ext}: the file is empty"):
        load(path)


@pytest.mark.filterwarnings("ignore:The VTK reader")
@pytest.mark.parametrize(
    "ext", [".ply", ".xyz", ".pcd", ".obj", ".off", ".las", ".laz", ".vtp", ".vtk", ".glb", ".conf"]
)
def test_garbage_file(tmp_path, ext):
    path = tmp_path / f"garbage{ext}"
    path.write_text("this is not a point cloud\nat all, really\n")
    with pytest.raises(FileFormatError, match=rf"garbage\{ext}"):
        load(path)


def test_truncated_binary_ply(tmp_path, rng):
    path = write_ply(tmp_path / "full.ply", rng.random((1000, 3)))
    data = path.read_bytes()
    cut = tmp_path / "cut.ply"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(FileFormatError, match=r"cut\.ply: truncated PLY"):
        load(cut)
    headless = tmp_path / "headless.ply"
    headless.write_bytes(data[:100])
    with pytest.raises(FileFormatError, match=r"headless\.ply: PLY header has no 'end_header'"):
        load(headless)


def test_truncated_binary_ply_mesh(tmp_path):
    o3d = _o3d()
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=20)
    path = tmp_path / "mesh.ply"
    assert o3d.io.write_triangle_mesh(str(path), mesh, write_ascii=False)
    data = path.read_bytes()
    cut = tmp_path / "cutmesh.ply"
    cut.write_bytes(data[: len(data) - 200])  # loses the last faces only
    with pytest.raises(FileFormatError, match=r"cutmesh\.ply: truncated PLY"):
        load(cut)


def test_truncated_ascii_ply(tmp_path, rng):
    o3d = _o3d()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(rng.random((100, 3))))
    path = tmp_path / "a.ply"
    assert o3d.io.write_point_cloud(str(path), pcd, write_ascii=True)
    lines = path.read_text().splitlines(keepends=True)
    cut = tmp_path / "acut.ply"
    cut.write_text("".join(lines[:-30]))
    with pytest.raises(FileFormatError, match=r"acut\.ply: truncated PLY"):
        load(cut)


def test_conf_missing_scan_names_both_files(tmp_path):
    conf = tmp_path / "reg.conf"
    conf.write_text("bmesh absent_scan.ply 0 0 0 0 0 0 1\n")
    with pytest.raises(
        FileFormatError, match=r"reg\.conf: line 1: scan .*absent_scan\.ply does not exist"
    ):
        load(conf)


@pytest.mark.parametrize(
    "line, detail",
    [
        ("bmesh a.ply 0 0 0 0 0 1", "got 7 fields"),
        ("bmesh a.ply 0 0 zero 0 0 0 1", "got non-numbers"),
        ("bmesh a.ply 0 0 0 0 0 0 0", "zero quaternion"),
    ],
)
def test_conf_malformed_bmesh_line(tmp_path, rng, line, detail):
    write_ply(tmp_path / "a.ply", rng.random((10, 3)))
    conf = tmp_path / "bad.conf"
    conf.write_text(f"camera 0 0 0 0 0 0 1\nbmesh a.ply 0 0 0 0 0 0 1\n\n{line}\n")
    with pytest.raises(
        FileFormatError, match=rf"bad\.conf: line 4: malformed bmesh line.*{detail}"
    ):
        load(conf)


def test_conf_with_a_broken_scan_names_both(tmp_path):
    (tmp_path / "broken.ply").write_text("garbage\n")
    conf = tmp_path / "r.conf"
    conf.write_text("bmesh broken.ply 0 0 0 0 0 0 1\n")
    with pytest.raises(FileFormatError, match=r"r\.conf: line 1: .*broken\.ply"):
        load(conf)


def test_directory_is_rejected(tmp_path):
    folder = tmp_path / "dir.ply"
    folder.mkdir()
    with pytest.raises(FileFormatError, match="is a directory"):
        load(folder)


def test_point_cloud_from_loaded_file_is_a_pointcloud(tmp_path, rng):
    cloud = load(write_ply(tmp_path / "x.ply", rng.random((30, 3))))
    assert isinstance(cloud, PointCloud)


# ------------------------------------------------------------------------------------------
# the core's table reader (PLY, PCD, XYZ rows): against what was written and against Open3D


def _ply_bytes(fmt, pts, normals=None, colors=None, extra_element=None):
    """A PLY file of float32 points (+ normals, uchar colours, and an element after them)."""
    props = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    dt = [(p, ">f4" if fmt == "binary_big_endian" else "<f4") for p in props]
    if colors is not None:
        dt += [(c, "u1") for c in ("red", "green", "blue")]
    head = f"ply\nformat {fmt} 1.0\ncomment core reader test\nelement vertex {len(pts)}\n"
    head += "".join(f"property {'uchar' if t == 'u1' else 'float'} {n}\n" for n, t in dt)
    if extra_element is not None:
        head += f"element range_grid {len(extra_element)}\nproperty list uchar int vertex_indices\n"
    head += "end_header\n"
    rows = np.zeros(len(pts), dtype=dt)
    for k, name in enumerate("xyz"):
        rows[name] = pts[:, k]
    if normals is not None:
        for k, name in enumerate(("nx", "ny", "nz")):
            rows[name] = normals[:, k]
    if colors is not None:
        for k, name in enumerate(("red", "green", "blue")):
            rows[name] = colors[:, k]
    if fmt == "ascii":
        body = "".join(" ".join(repr(v.item()) for v in row) + "\n" for row in rows).encode()
        if extra_element is not None:
            body += "".join(f"{len(r)} {' '.join(map(str, r))}\n" for r in extra_element).encode()
    else:
        body = rows.tobytes()
        if extra_element is not None:
            for r in extra_element:
                body += bytes([len(r)]) + np.asarray(r, dtype="<i4" if fmt != "binary_big_endian"
                                                     else ">i4").tobytes()
    return head.encode() + body


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_points_read_by_the_core_match_what_was_written_and_open3d(tmp_path, rng, fmt):
    n = 2000
    pts = (rng.normal(size=(n, 3)) * 10).astype(np.float32)
    nrm = rng.normal(size=(n, 3)).astype(np.float32)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    col = rng.integers(0, 256, size=(n, 3), dtype=np.uint8)
    grid = [[i] if i % 3 else [] for i in range(50)]  # a range_grid-like list element after them
    path = tmp_path / f"s_{fmt}.ply"
    path.write_bytes(_ply_bytes(fmt, pts, nrm, col, grid))
    cloud = load(path, estimate=False)
    np.testing.assert_array_equal(cloud.points, pts.astype(np.float64))  # exact: float32 values
    np.testing.assert_allclose(cloud.normals, nrm, atol=1e-7)
    np.testing.assert_allclose(cloud.colors, col / 255.0, atol=1e-6)
    ref = _o3d().io.read_point_cloud(str(path))  # the second reader, where installed
    np.testing.assert_array_equal(cloud.points, np.asarray(ref.points))
    np.testing.assert_allclose(cloud.colors, np.asarray(ref.colors), atol=1e-6)


def test_ascii_ply_errors_name_the_row_and_the_missing_lines(tmp_path, rng):
    pts = rng.random((20, 3)).astype(np.float32)
    good = _ply_bytes("ascii", pts, extra_element=[[1, 2]] * 5)
    (tmp_path / "short.ply").write_bytes(good[: good.rindex(b"2 1 2\n")])  # last line lost
    with pytest.raises(FileFormatError, match=r"short\.ply: truncated PLY: .*25 data lines.*24"):
        load(tmp_path / "short.ply")
    bad = good.replace(good.split(b"end_header\n")[1].split(b"\n")[7], b"0.5 nope 0.5", 1)
    (tmp_path / "word.ply").write_bytes(bad)
    with pytest.raises(FileFormatError, match=r"word\.ply: malformed ASCII PLY: vertex row 7 "
                                              r"holds a non-number 'nope'"):
        load(tmp_path / "word.ply")


def test_pcd_read_by_the_core_matches_open3d(tmp_path, rng):
    n = 500
    o3d = _o3d()
    pts = rng.random((n, 3))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    nrm = rng.normal(size=(n, 3))
    pcd.normals = o3d.utility.Vector3dVector(nrm / np.linalg.norm(nrm, axis=1, keepdims=True))
    pcd.colors = o3d.utility.Vector3dVector(rng.integers(0, 256, (n, 3)) / 255.0)
    for ascii_, compressed in ((True, False), (False, False), (False, True)):
        path = tmp_path / f"c{int(ascii_)}{int(compressed)}.pcd"
        assert o3d.io.write_point_cloud(str(path), pcd, write_ascii=ascii_, compressed=compressed)
        assert (b"binary_compressed" in path.read_bytes()[:400]) == compressed
        ref = o3d.io.read_point_cloud(str(path))
        cloud = load(path, estimate=False)
        np.testing.assert_allclose(cloud.points, np.asarray(ref.points), rtol=1e-7)
        np.testing.assert_allclose(cloud.normals, np.asarray(ref.normals), atol=1e-6)
        np.testing.assert_allclose(cloud.colors, np.asarray(ref.colors), atol=1e-6)


def test_xyz_text_variants(tmp_path):
    (tmp_path / "a.xyz").write_text("# x y z\n1 2 3\n\n4,5,6,99\n  7;8;9\n// end\n")
    np.testing.assert_array_equal(load(tmp_path / "a.xyz", estimate=False).points,
                                  [[1, 2, 3], [4, 5, 6], [7, 8, 9]])
    (tmp_path / "b.xyzn").write_text("0 0 0 0 0 2\n1 0 0 0 0 1\n0 1 0 0 0 1\n")
    np.testing.assert_allclose(load(tmp_path / "b.xyzn", estimate=False).normals[:, 2], 1.0)
    (tmp_path / "c.xyzrgb").write_text("0 0 0 255 0 0\n1 0 0 0 255 0\n0 1 0 0 0 255\n")
    np.testing.assert_allclose(load(tmp_path / "c.xyzrgb", estimate=False).colors, np.eye(3))
    (tmp_path / "d.xyz").write_text("1 2 3\n4 5\n")
    with pytest.raises(FileFormatError, match=r"d\.xyz: malformed \.xyz text: data row 1 has 2 "
                                              r"values, expected 3"):
        load(tmp_path / "d.xyz")
    (tmp_path / "e.xyz").write_text("# only a comment\n\n")
    with pytest.raises(FileFormatError, match=r"e\.xyz: no points"):
        load(tmp_path / "e.xyz")


def test_conf_scans_read_in_one_call_equal_each_scan_read_alone(tmp_path, rng):
    """The parallel read of a registration gives, scan by scan, what loading each file gives;
    a broken scan among them is named with its line."""
    lines = []
    for k in range(6):
        pts = rng.random((300 + 50 * k, 3))
        fmt = "ascii" if k % 2 else "binary_little_endian"
        (tmp_path / f"s{k}.ply").write_bytes(_ply_bytes(fmt, pts.astype(np.float32)))
        lines.append(f"bmesh s{k}.ply 0 0 0 0 0 0 1")
    (tmp_path / "all.conf").write_text("\n".join(lines) + "\n")
    cloud = load(tmp_path / "all.conf", estimate=False)
    alone = np.concatenate([load(tmp_path / f"s{k}.ply", estimate=False).points for k in range(6)])
    np.testing.assert_array_equal(cloud.points, alone)
    np.testing.assert_array_equal(np.bincount(cloud.scan_index), [300 + 50 * k for k in range(6)])
    data = (tmp_path / "s3.ply").read_bytes()
    (tmp_path / "s3.ply").write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(FileFormatError, match=r"all\.conf: line 4: .*s3\.ply: truncated PLY"):
        load(tmp_path / "all.conf")


def test_core_reader_gives_the_same_rows_for_any_thread_count(tmp_path, rng):
    from pointviz.readers import table

    pts = rng.normal(size=(60000, 3))
    path = tmp_path / "big.xyz"
    np.savetxt(path, pts, fmt="%.17g")
    spec = table.spec(path, offset=0, encoding="ascii", columns=["f64"] * 3, rows=-1,
                      wanted=[0, 1, 2])
    outs = [table.read([spec], threads=t)[0].values for t in (1, 2, 4)]
    np.testing.assert_array_equal(outs[0], pts)  # %.17g round trips exactly
    for out in outs[1:]:
        np.testing.assert_array_equal(out, outs[0])


def test_conf_scan_with_nan_rows_drops_them_with_a_note(tmp_path, rng):
    pts = rng.random((200, 3)).astype(np.float32)
    pts[[5, 17]] = np.nan
    (tmp_path / "a.ply").write_bytes(_ply_bytes("binary_little_endian", pts))
    (tmp_path / "b.ply").write_bytes(_ply_bytes("ascii", pts[20:]))
    (tmp_path / "r.conf").write_text("bmesh a.ply 1 2 3 0 0 0 1\nbmesh b.ply 0 0 0 0 0 0 1\n")
    with pytest.warns(UserWarning, match="dropped 2 of 380 points"):
        cloud = load(tmp_path / "r.conf", estimate=False)
    keep = np.isfinite(pts).all(axis=1)
    np.testing.assert_array_equal(cloud.points[:198], pts[keep].astype(np.float64) + [1, 2, 3])
    np.testing.assert_array_equal(np.bincount(cloud.scan_index), [198, 180])
    # the viewpoint comes from the finite points only
    assert np.isfinite(cloud.viewpoints).all()


def _range_scan_bytes(pts, cells, rows, cols, fmt="ascii"):
    """A range scan as Stanford's scans are stored (ASCII, or ``fmt``): its vertices, then a
    ``range_grid`` of rows x cols cells (row-major), each listing the vertex it holds (or none)."""
    grid = [[] for _ in range(rows * cols)]
    for v, c in enumerate(cells):
        if c >= 0:
            grid[c] = [v]
    body = _ply_bytes(fmt, pts.astype(np.float32), extra_element=grid)
    head, data = body.split(b"end_header\n", 1)
    head = head.replace(b"element vertex",
                        f"obj_info num_cols {cols}\nobj_info num_rows {rows}\nelement vertex"
                        .encode(), 1)
    return head + b"end_header\n" + data


def test_conf_range_grid_gives_each_point_its_cell(tmp_path, rng):
    """Each scan's range_grid becomes the row and column of its points (-1: in no cell), in
    the order of the points; a grid the header does not size is not used."""
    rows, cols, want = 5, 7, []
    for k in range(2):
        n = 20 + 3 * k
        cells = rng.permutation(rows * cols)[:n]
        cells[4] = -1  # a vertex in no cell
        (tmp_path / f"s{k}.ply").write_bytes(_range_scan_bytes(rng.random((n, 3)), cells, rows,
                                                               cols))
        want.append(np.where(cells[:, None] >= 0, np.stack([cells // cols, cells % cols], 1), -1))
    (tmp_path / "g.conf").write_text("bmesh s0.ply 0 0 0 0 0 0 1\nbmesh s1.ply 1 0 0 0 0 0 1\n")
    cloud = load(tmp_path / "g.conf", estimate=False)
    np.testing.assert_array_equal(cloud.scan_grid, np.concatenate(want))
    assert cloud.scan_grid.dtype == np.int32
    assert cloud.subset(np.arange(5, 30)).scan_grid.shape == (25, 2)
    # a vertex index beyond the vertices: named, with the grid's row
    data = (tmp_path / "s1.ply").read_bytes()
    head, body = data.split(b"end_header\n", 1)
    lines = body.split(b"\n")
    first = next(i for i, line in enumerate(lines) if i >= 23 and line.startswith(b"1 "))
    lines[first] = b"1 999"
    (tmp_path / "s1.ply").write_bytes(head + b"end_header\n" + b"\n".join(lines))
    with pytest.raises(FileFormatError, match=r"line 2: .*s1\.ply: malformed ASCII PLY: "
                                              r"range_grid row \d+ lists a vertex index"):
        load(tmp_path / "g.conf")
    # cells that do not match the header's num_cols x num_rows: no grid, points as before
    (tmp_path / "s1.ply").write_bytes(data.replace(b"obj_info num_rows 5", b"obj_info num_rows 6"))
    cloud2 = load(tmp_path / "g.conf", estimate=False)
    assert cloud2.scan_grid is None
    np.testing.assert_array_equal(cloud2.points, cloud.points)


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian"])
def test_binary_range_grid_reads_as_the_ascii_one(tmp_path, rng, fmt):
    """A binary scan's range_grid gives the cells its ASCII writing gives; a record that lists
    a vertex beyond the vertices, or a grid cut short, is named."""
    rows, cols, n = 6, 9, 40
    cells = rng.permutation(rows * cols)[:n]
    cells[7] = -1
    pts = rng.random((n, 3))
    (tmp_path / "a.ply").write_bytes(_range_scan_bytes(pts, cells, rows, cols))
    (tmp_path / "b.ply").write_bytes(_range_scan_bytes(pts, cells, rows, cols, fmt))
    (tmp_path / "a.conf").write_text("bmesh a.ply 0 0 0 0 0 0 1\n")
    (tmp_path / "b.conf").write_text("bmesh b.ply 0 0 0 0 0 0 1\n")
    a = load(tmp_path / "a.conf", estimate=False)
    b = load(tmp_path / "b.conf", estimate=False)
    assert b.scan_grid is not None
    np.testing.assert_array_equal(b.scan_grid, a.scan_grid)
    np.testing.assert_array_equal(b.points, a.points)
    data = (tmp_path / "b.ply").read_bytes()
    head, body = data.split(b"end_header\n", 1)
    grid_at = 12 * n  # the first record that lists a vertex
    first = next(c for c in range(rows * cols) if cells.tolist().count(c))
    at = grid_at + first  # one count byte per empty record before it
    assert body[at] == 1
    order = "<" if fmt == "binary_little_endian" else ">"
    bad = body[:at + 1] + np.array([999], dtype=order + "i4").tobytes() + body[at + 5:]
    (tmp_path / "b.ply").write_bytes(head + b"end_header\n" + bad)
    with pytest.raises(FileFormatError, match=r"malformed PLY: range_grid row \d+ lists a "
                                              r"vertex index"):
        load(tmp_path / "b.conf")
    (tmp_path / "b.ply").write_bytes(head + b"end_header\n" + body[:-6])
    with pytest.raises(FileFormatError, match=r"truncated PLY"):
        load(tmp_path / "b.conf")


def test_scan_grid_normals_equal_the_scan_trees_on_virtual_scans():
    """Normals from grid neighbours match those from each scan's KD-tree (the same neighbours
    on a smooth surface; a ring search may end differently where noise reorders them)."""
    from pointviz.comparison.scans import virtual_scans
    from pointviz.estimation import estimate_normals

    raw, _ = virtual_scans("torus", scans=4, resolution=80, noise=0.001)
    assert raw.scan_grid is not None and raw.scan_grid.shape == (len(raw), 2)
    kw = dict(viewpoints=raw.viewpoints, scan_index=raw.scan_index)
    tree = estimate_normals(raw.points, **kw)
    grid = estimate_normals(raw.points, scan_grid=raw.scan_grid, **kw)
    same = (tree == grid).all(axis=1)
    assert same.mean() > 0.99, same.mean()
    with pytest.raises(InputError, match="scan_grid: needs scan_index"):
        estimate_normals(raw.points, scan_grid=raw.scan_grid)
    with pytest.raises(InputError, match=r"scan_grid: expected shape"):
        estimate_normals(raw.points, scan_grid=raw.scan_grid[:5], **kw)
    with pytest.raises(InputError, match="scan_grid: needs scan_index"):
        PointCloud(raw.points, scan_grid=raw.scan_grid)
    with pytest.raises(InputError, match="scan_grid: rows and columns must fit in 32 bits"):
        PointCloud(raw.points, scan_index=raw.scan_index,
                   scan_grid=raw.scan_grid.astype(np.int64) + 2**31)


@pytest.mark.data
@pytest.mark.parametrize("conf", ["stanford_bunny/data/bun.conf",
                                  "stanford_dragon/dragon_stand/dragonStandRight.conf"])
def test_real_range_grids_are_row_major_grids_of_the_scans(shared_data, conf):
    """Every point of the Stanford scans has a cell, one point per cell, and the cells read
    row-major (num_cols per row) are the scanner's grid: grid-adjacent samples lie about one
    spacing apart (dragon 0.56 / 0.79 mm along a row / a column)."""
    cloud = load(shared_data / conf, estimate=False)
    grid, scan = cloud.scan_grid, cloud.scan_index
    assert grid is not None and (grid >= 0).all()
    key = (scan.astype(np.int64) << 40) | (grid[:, 0].astype(np.int64) << 20) | grid[:, 1]
    assert len(np.unique(key)) == len(cloud)  # one point per cell
    order = np.argsort(key)
    right = np.searchsorted(key[order], key + 1)  # the next cell along the row, where present
    right = np.minimum(right, len(key) - 1)
    has = key[order][right] == key + 1
    step = np.linalg.norm(cloud.points[order[right[has]]] - cloud.points[has], axis=1)
    own = cloud.points[scan == 0]  # the sample spacing within a scan (the layers lie closer)
    spacing = np.median(cKDTree(own).query(own, k=2)[0][:, 1])
    assert has.mean() > 0.5
    assert np.median(step) < 2.0 * spacing


def _reference_depth_steps():
    """The patch planes as first written (tests/depth_steps_reference.py), the oracle of the
    restructured ones."""
    import importlib.util
    import pathlib

    path = pathlib.Path(__file__).with_name("depth_steps_reference.py")
    spec = importlib.util.spec_from_file_location("depth_steps_reference", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _assert_patch_planes_equal(points, grid, step, viewpoint=(0.0, 0.0, 0.0)):
    """The numpy patch planes equal the first implementation bit for bit; the core's equal it
    within the rounding of arccos / cos (libm's against numpy's): points within 1e-12 (relative
    to the frame's extent; PCL's frames: at most 2e-15 m), normals (float32) within 1e-6, radii
    and flying pixels the same (a different radius would need a patch residual within ~1e-15
    of its limit)."""
    from pointviz.depth_steps import patch_planes, patch_planes_numpy

    ref = _reference_depth_steps()
    scale = max(1.0, float(np.abs(points).max()))
    for edges in (True, False):
        want = ref.patch_planes(points, grid, viewpoint, step, edges=edges)
        now = patch_planes_numpy(points, grid, viewpoint, step, edges=edges)
        core = patch_planes(points, grid, viewpoint, step, edges=edges)
        for name, a, b, c in zip(("points", "normals", "radius", "flying"), want, now, core):
            assert a.dtype == b.dtype == c.dtype and a.shape == b.shape == c.shape, name
            np.testing.assert_array_equal(b, a, err_msg=f"{name}, edges={edges}, numpy")
            if name == "points":
                np.testing.assert_allclose(c, a, rtol=0, atol=1e-12 * scale,
                                           err_msg=f"{name}, edges={edges}, core")
            elif name == "normals":
                np.testing.assert_allclose(c, a, rtol=0, atol=1e-6,
                                           err_msg=f"{name}, edges={edges}, core")
            else:
                np.testing.assert_array_equal(c, a, err_msg=f"{name}, edges={edges}, core")


@pytest.mark.parametrize("noise,mixed", [(0.05, True), (0.0, True), (0.05, False), (0.15, True)])
def test_patch_planes_equal_the_reference_on_kinect_frames(noise, mixed):
    # oracle: the first implementation (tests/depth_steps_reference.py); the numpy version bit
    # for bit, the core within a float tolerance (_assert_patch_planes_equal)
    from pointviz.depth_steps import depth_steps

    rng = np.random.default_rng(7)
    pts, _ = kinect_frame(noise=noise, rng=rng, mixed=mixed)
    rows, cols = np.divmod(np.arange(len(pts)), 320)
    keep = np.isfinite(pts).all(axis=1)
    pts, grid = pts[keep], np.column_stack([rows, cols])[keep].astype(np.int32)
    step = depth_steps(pts[:, 2])
    assert step is not None
    _assert_patch_planes_equal(pts, grid, step)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_patch_planes_equal_the_reference_on_random_grids(seed):
    # random organised frames: a few slanted planes at different depths (depth edges between
    # them), quantised to steps that grow as z^2, with NaN holes (points left out of the grid)
    # and zero-coded pixels (points at the camera); random noise levels and a shifted camera
    rng = np.random.default_rng(seed)
    h, w = rng.integers(40, 120), rng.integers(40, 160)
    rows, cols = np.mgrid[0:h, 0:w]
    f = rng.uniform(100, 300)
    x, y = (cols - w / 2) / f, (rows - h / 2) / f
    z = np.full((h, w), 3.0)
    for _ in range(4):
        r0, c0 = rng.integers(0, h), rng.integers(0, w)
        box = (rows >= r0) & (rows < r0 + rng.integers(5, h)) & (cols >= c0) & (
            cols < c0 + rng.integers(5, w))
        z[box] = rng.uniform(1.0, 5.0) + rng.uniform(-0.5, 0.5) * x[box] + rng.uniform(
            -0.5, 0.5) * y[box]
    z += rng.normal(0, rng.uniform(0, 0.01), z.shape)
    q = 0.003 * z * z
    z = np.round(z / q) * q
    pts = np.stack([x * z, y * z, z], axis=-1).reshape(-1, 3)
    grid = np.column_stack([rows.ravel(), cols.ravel()]).astype(np.int32)
    zero = rng.random(len(pts)) < 0.03
    pts[zero] = 0.0
    keep = rng.random(len(pts)) > 0.1
    keep[-1] = True  # the frame's last row and column stay in the grid
    pts, grid = pts[keep], grid[keep]
    step = np.maximum(0.003 * pts[:, 2] ** 2, 1e-4)
    viewpoint = rng.normal(0, 0.01, 3) * (seed > 1)
    _assert_patch_planes_equal(pts + viewpoint, grid, step, viewpoint)


def _bad_frames():
    """Organised frames the core must handle as the numpy version does: one row, one column,
    zero-coded pixels (points at the camera), depths beyond the doubles' squares, two depth
    levels only, two points on one pixel, a frame of NaN-free points whose patches are all
    degenerate (every point on one ray's line)."""
    rng = np.random.default_rng(11)
    frames = {}

    def grid_frame(h, w, z):
        rows, cols = np.mgrid[0:h, 0:w]
        pts = np.stack([(cols - w / 2) / 200 * z, (rows - h / 2) / 200 * z, z], -1).reshape(-1, 3)
        return pts, np.column_stack([rows.ravel(), cols.ravel()]).astype(np.int32)

    z = np.round(rng.uniform(2, 3, (1, 300)) / 0.01) * 0.01
    frames["one row"] = grid_frame(1, 300, z)
    frames["one column"] = grid_frame(300, 1, np.round(rng.uniform(2, 3, (300, 1)) / 0.01) * 0.01)
    pts, grid = grid_frame(40, 50, np.round(rng.uniform(2, 3, (40, 50)) / 0.01) * 0.01)
    pts[rng.random(len(pts)) < 0.3] = 0.0
    frames["zero-coded"] = pts, grid
    pts, grid = grid_frame(30, 40, np.full((30, 40), 2.0))
    pts[::7] *= 1e160  # squares overflow: these are no measurement
    frames["huge"] = pts, grid
    zz = np.where(np.arange(60)[None, :] < 30, 1.0, 1.5) * np.ones((40, 1))
    frames["two levels"] = grid_frame(40, 60, zz)
    pts, grid = grid_frame(30, 30, np.round(rng.uniform(2, 3, (30, 30)) / 0.01) * 0.01)
    grid[5] = grid[6]  # two points on one pixel
    frames["shared pixel"] = pts, grid
    ray = np.array([0.1, 0.2, 1.0])
    pts = np.outer(np.round(rng.uniform(1, 3, 400) / 0.01) * 0.01, ray)
    frames["one line"] = pts, np.column_stack(np.divmod(np.arange(400), 20)).astype(np.int32)
    return frames


@pytest.mark.parametrize("name", ["one row", "one column", "zero-coded", "huge", "two levels",
                                  "shared pixel", "one line"])
def test_patch_planes_core_handles_bad_frames_as_numpy_does(name):
    # oracle: the numpy version (patch_planes_numpy), the same tolerance as on the frames above
    from pointviz.depth_steps import patch_planes, patch_planes_numpy

    pts, grid = _bad_frames()[name]
    step = np.maximum(0.01 * np.abs(pts[:, 2]), 1e-3)
    for edges in (True, False):
        with np.errstate(all="ignore"):
            want = patch_planes_numpy(pts, grid, (0.0, 0.0, 0.0), step, edges=edges)
        got = patch_planes(pts, grid, (0.0, 0.0, 0.0), step, edges=edges)
        finite = np.isfinite(pts).all(axis=1) & (np.abs(pts).max(axis=1) < 1e100)
        scale = max(1.0, float(np.abs(pts[finite]).max()))
        np.testing.assert_allclose(got[0], want[0], rtol=1e-12, atol=1e-12 * scale)
        # a plane that holds the point's ray (one column: every point on one plane through
        # the camera) faces neither way: its normal's sign is rounding in both versions
        with np.errstate(all="ignore"):
            ray = pts / np.linalg.norm(pts, axis=1, keepdims=True)
        edge_on = np.abs(np.einsum("ij,ij->i", want[1].astype(np.float64), ray)) < 1e-9
        flip = np.where(edge_on & (np.einsum("ij,ij->i", got[1], want[1]) < 0), -1.0, 1.0)
        np.testing.assert_allclose(got[1] * flip[:, None], want[1], rtol=0, atol=1e-6)
        np.testing.assert_array_equal(got[2], want[2])
        np.testing.assert_array_equal(got[3], want[3])
