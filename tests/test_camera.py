"""Tests of pointviz.camera against independent oracles (geometry, Open3D's own projection)."""

from __future__ import annotations

import json
import math
import os
import pickle
from types import SimpleNamespace

import numpy as np
import pytest

from pointviz.camera import Camera, bounding_sphere, fit_distance
from pointviz.errors import FileFormatError, InputError

ATOL = 1e-9


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture
def camera():
    return Camera((1.0, 2.0, 3.0), (-0.5, 0.25, -1.0), up=(0.1, 1.0, 0.2), fov_deg=50.0,
                  width=33, height=21)


def random_points_in_view(cam, rng, n=200, depth=(0.5, 20.0)):
    """World points whose pixels are uniform in the image (an oracle built from the basis)."""
    col = rng.uniform(0, cam.width, n)
    row = rng.uniform(0, cam.height, n)
    z = rng.uniform(*depth, n)
    x = (2 * col / cam.width - 1) * cam.tan_half * cam.aspect * z
    y = (1 - 2 * row / cam.height) * cam.tan_half * z
    pts = cam.eye + z[:, None] * cam.forward + x[:, None] * cam.right + y[:, None] * cam.true_up
    return pts, np.stack([col, row], 1), z


# ------------------------------------------------------------------------------------ basis


def test_basis_is_orthonormal_and_right_handed(camera):
    basis = np.stack([camera.right, camera.true_up, -camera.forward])
    np.testing.assert_allclose(basis @ basis.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(basis) == pytest.approx(1.0)
    np.testing.assert_allclose(
        camera.forward, (camera.target - camera.eye) / np.linalg.norm(camera.target - camera.eye))
    assert camera.true_up @ camera.up > 0  # true up on the same side as the hint


def test_derived_quantities(camera):
    assert camera.aspect == 33 / 21
    assert camera.tan_half == pytest.approx(math.tan(math.radians(25.0)))
    assert camera.pixel_angle == pytest.approx(2 * math.atan(camera.tan_half / 21))


# ------------------------------------------------------------------------------------- rays


def test_rays_shape_dtype_origin_unit(camera):
    rays = camera.rays()
    assert rays.shape == (33 * 21, 6) and rays.dtype == np.float32
    np.testing.assert_allclose(rays[:, :3], np.broadcast_to(camera.eye, (33 * 21, 3)), rtol=1e-7)
    np.testing.assert_allclose(np.linalg.norm(rays[:, 3:], axis=1), 1.0, atol=1e-6)
    rays64 = camera.rays(dtype=np.float64)
    assert rays64.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(rays64[:, 3:], axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(rays, rays64, atol=1e-6)


def test_centre_ray_of_odd_image_is_forward(camera):
    rays = camera.rays(dtype=np.float64)
    centre = (camera.height // 2) * camera.width + camera.width // 2
    np.testing.assert_allclose(rays[centre, 3:], camera.forward, atol=1e-14)


def test_rays_run_row_by_row_from_top_left(camera):
    d = camera.rays(dtype=np.float64)[:, 3:].reshape(camera.height, camera.width, 3)
    assert np.all(np.diff(d @ camera.right, axis=1) > 0)  # columns go right
    assert np.all(np.diff(d @ camera.true_up, axis=0) < 0)  # rows go down


def test_corner_rays_make_analytic_angles():
    """With offsets (0, 0) / (1-, 1-) pixel corners are the image corners: the horizontal angle
    from forward is atan(tan_half * aspect) and the vertical one atan(tan_half)."""
    cam = Camera((0, 0, 0), (0, 0, -1), fov_deg=60.0, width=40, height=30)
    rays = cam.rays(samples=(0.0, 0.0), dtype=np.float64)
    d = rays[0, 3:]  # top-left corner of the image
    x, y, z = d @ cam.right, d @ cam.true_up, d @ cam.forward
    assert math.atan2(-x, z) == pytest.approx(math.atan(cam.tan_half * cam.aspect), rel=1e-12)
    assert math.atan2(y, z) == pytest.approx(math.radians(30.0), rel=1e-12)
    # the centre ray of the top row of pixel centres: vertical angle of its centre
    d = cam.rays(dtype=np.float64)[0 * 40 + 20, 3:]
    expected = math.atan((1 - 1 / 30) * cam.tan_half)
    assert math.atan2(d @ cam.true_up, d @ cam.forward) == pytest.approx(expected, rel=1e-12)


def test_pixel_angle_matches_adjacent_centre_rays():
    cam = Camera((0, 0, 0), (0, 0, -1), fov_deg=45.0, width=9, height=9)
    d = cam.rays(dtype=np.float64)[:, 3:].reshape(9, 9, 3)
    # centre pixel straddles the axis; its top and bottom edges are +-half a pixel
    top = cam.rays(samples=(0.5, 0.0), dtype=np.float64)[4 * 9 + 4, 3:]
    bottom_edge = np.array([0.0, -cam.tan_half / 9, -1.0])
    bottom_edge /= np.linalg.norm(bottom_edge)
    assert math.acos(np.clip(top @ bottom_edge, -1, 1)) == pytest.approx(cam.pixel_angle)
    assert d.shape == (9, 9, 3)


def test_samples_per_pixel_and_validation(camera, rng):
    offsets = rng.uniform(0, 1, (camera.height, camera.width, 2))
    rays = camera.rays(samples=offsets, dtype=np.float64)
    pixels, _ = camera.project(rays[:, :3] + rays[:, 3:])
    rows, cols = np.mgrid[0:camera.height, 0:camera.width]
    expected = np.stack([cols + offsets[..., 0], rows + offsets[..., 1]], -1).reshape(-1, 2)
    np.testing.assert_allclose(pixels, expected, atol=1e-9)
    np.testing.assert_allclose(camera.rays(samples=offsets.reshape(-1, 2)), camera.rays(offsets))
    for bad in ([0.5, 1.0], [-0.1, 0.5], [np.nan, 0.5], np.zeros((3, 2))):
        with pytest.raises(InputError, match="samples"):
            camera.rays(samples=bad)


# --------------------------------------------------------------------------------- project


def test_project_is_inverse_of_rays(camera):
    rays = camera.rays(dtype=np.float64)
    depth_along_ray = np.linspace(0.1, 100.0, len(rays))
    pts = rays[:, :3] + depth_along_ray[:, None] * rays[:, 3:]
    pixels, depth = camera.project(pts)
    rows, cols = np.mgrid[0:camera.height, 0:camera.width]
    centres = np.stack([cols + 0.5, rows + 0.5], -1).reshape(-1, 2)
    np.testing.assert_allclose(pixels, centres, atol=1e-9)
    np.testing.assert_allclose(depth, depth_along_ray * (rays[:, 3:] @ camera.forward))


def test_project_independent_oracle(camera, rng):
    pts, pixels_expected, z = random_points_in_view(camera, rng)
    pixels, depth = camera.project(pts)
    np.testing.assert_allclose(pixels, pixels_expected, atol=1e-9)
    np.testing.assert_allclose(depth, z)


def test_project_behind_camera_is_nan(camera):
    pixels, depth = camera.project(np.array([camera.eye - camera.forward, camera.eye]))
    assert np.all(np.isnan(pixels)) and depth[0] == pytest.approx(-1.0) and depth[1] == 0


def test_float64_rays_keep_precision_far_from_origin():
    far = np.array([1e7 + 0.123, -3e6 - 0.456, 2e7 + 0.789])
    cam = Camera(far, far + (0.0, 0.0, -1.0), width=5, height=5)
    rays = cam.rays(dtype=np.float64)
    assert np.array_equal(rays[:, :3], np.broadcast_to(far, (25, 3)))
    assert not np.array_equal(cam.rays()[:, :3].astype(np.float64), rays[:, :3])


# ------------------------------------------------------------------------------------- fit


@pytest.mark.parametrize("width,height", [(640, 480), (300, 600), (101, 101)])
def test_fit_frames_cloud_and_sphere_touches_margin(rng, width, height):
    pts = rng.normal(size=(2000, 3)) * [5.0, 1.0, 2.0] + [100.0, -20.0, 3.0]
    cloud = SimpleNamespace(points=pts)
    margin = 1.1
    # an explicit direction frames the bounding sphere
    cam = Camera.fit(cloud, direction=(0.0, -0.3, -1.0), fov_deg=35.0, width=width,
                     height=height, margin=margin, outliers=0.0)
    centre, radius = bounding_sphere(pts)
    np.testing.assert_allclose(cam.target, centre)
    pixels, depth = cam.project(pts)
    assert np.all(depth > 0)
    assert np.all((pixels >= 0) & (pixels <= [width, height]))
    # silhouette of the bounding sphere: project many points of the sphere; the farthest one
    # from the image centre lies on a circle of radius min(w, h) / (2 margin)
    dirs = rng.normal(size=(200000, 3))
    sphere = centre + radius * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    sp, _ = cam.project(sphere)
    reach = np.max(np.linalg.norm(sp - [width / 2, height / 2], axis=1))
    assert reach == pytest.approx(min(width, height) / (2 * margin), rel=2e-3)
    assert reach <= min(width, height) / (2 * margin) * (1 + 1e-12)


def test_fit_ignores_a_few_stray_points(rng):
    body = rng.normal(size=(20000, 3))
    strays = rng.normal(size=(10, 3)) * 0.1 + [40.0, 0.0, 0.0]
    cloud = SimpleNamespace(points=np.vstack([body, strays]))
    robust = Camera.fit(cloud, width=200, height=200)
    whole = Camera.fit(cloud, width=200, height=200, outliers=0.0)
    px, _ = robust.project(body)
    inside = np.all((px >= 0) & (px <= 200), axis=1).mean()
    assert inside > 0.995
    # the body fills the robust frame: its spread in pixels is many times the whole-cloud one
    spread = lambda cam: np.ptp(cam.project(body)[0], axis=0).max()  # noqa: E731
    assert spread(robust) > 5 * spread(whole)
    with pytest.raises(InputError, match="outliers"):
        Camera.fit(cloud, outliers=0.5)


def test_fit_default_direction_follows_up(rng):
    pts = rng.uniform(-1, 1, (500, 3))
    z_up = Camera.fit(SimpleNamespace(points=pts, up=np.array([0.0, 0.0, 1.0])))
    y_up = Camera.fit(SimpleNamespace(points=pts))
    # the same elevation above the ground plane in both frames
    assert z_up.forward @ [0, 0, 1] == pytest.approx(y_up.forward @ [0, 1, 0])


def test_fit_direction_and_up(rng):
    pts = rng.uniform(-1, 1, (100, 3))
    cloud = SimpleNamespace(points=pts, up=np.array([0.0, 0.0, 1.0]))
    cam = Camera.fit(cloud, direction=(1.0, 0.0, 0.0))
    np.testing.assert_allclose(cam.forward, [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(cam.up, [0, 0, 1])
    cam = Camera.fit(cloud, direction=(1.0, 0.0, 0.0), up=(0, 1, 0))
    np.testing.assert_allclose(cam.up, [0, 1, 0])
    cam = Camera.fit(pts)  # bare arrays work too; default up +Y
    np.testing.assert_allclose(cam.up, [0, 1, 0])
    with pytest.raises(InputError, match="up"):
        Camera.fit(cloud, direction=(0.0, 0.0, -1.0))


def test_fit_degenerate_and_bad_clouds():
    cam = Camera.fit(np.ones((5, 3)))
    np.testing.assert_allclose(cam.target, [1, 1, 1])
    assert cam.distance == pytest.approx(fit_distance(1.0, 40.0, 640, 480))
    with pytest.raises(InputError, match="empty"):
        Camera.fit(np.zeros((0, 3)))
    with pytest.raises(InputError, match="NaN"):
        Camera.fit(np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0]]))
    with pytest.raises(InputError, match="margin"):
        Camera.fit(np.eye(3), margin=0.0)
    with pytest.raises(InputError, match="direction"):
        Camera.fit(np.eye(3), direction=(0, 0, 0))


# ------------------------------------------------------------------------------ validation


@pytest.mark.parametrize("kwargs,match", [
    (dict(fov_deg=0.0), "fov_deg"),
    (dict(fov_deg=180.0), "fov_deg"),
    (dict(fov_deg=float("nan")), "fov_deg"),
    (dict(width=0), "width"),
    (dict(height=16385), "height"),
    (dict(width=64.0), "width"),
    (dict(width=True), "width"),
    (dict(eye=(0, 0, -1)), "eye and target coincide"),
    (dict(up=(0, 0, 2)), "up"),
    (dict(up=(0, 0, 0)), "up"),
    (dict(eye=(0, np.inf, 0)), "eye"),
    (dict(target=(0, 0, np.nan)), "target"),
    (dict(up=(np.nan, 1, 0)), "up"),
    (dict(eye=(0, 0)), "eye"),
])
def test_validation(kwargs, match):
    args = dict(eye=(0, 0, 0), target=(0, 0, -1), up=(0, 1, 0), fov_deg=40.0, width=8, height=8)
    args.update(kwargs)
    with pytest.raises(InputError, match=match):
        Camera(**args)


def test_limits_accepted():
    Camera((0, 0, 0), (0, 0, -1), fov_deg=179.9, width=16384, height=1)
    Camera((0, 0, 0), (0, 0, -1), width=np.int64(3), height=np.int32(2))


# ------------------------------------------------------------------ copies, equality, repr


def test_replace_with_size_equality_repr(camera):
    assert camera == Camera(camera.eye, camera.target, camera.up, 50.0, 33, 21)
    assert hash(camera) == hash(camera.replace())
    other = camera.with_size(64, 48)
    assert (other.width, other.height, other.fov_deg) == (64, 48, camera.fov_deg)
    assert other != camera
    assert camera.replace(fov_deg=20.0).fov_deg == 20.0
    with pytest.raises(TypeError):
        camera.replace(zoom=2)
    text = repr(camera)
    assert text.startswith("Camera(eye=(1, 2, 3)") and "width=33" in text
    assert pickle.loads(pickle.dumps(camera)) == camera
    with pytest.raises(ValueError):
        camera.eye[0] = 5.0  # read-only


# ------------------------------------------------------------------------------------- JSON


def test_dict_and_json_round_trip(camera, tmp_path):
    assert Camera.from_dict(json.loads(json.dumps(camera.to_dict()))) == camera
    path = tmp_path / "cam.json"
    camera.to_json(path)
    assert Camera.from_json(path) == camera
    assert json.loads(path.read_text())["format"] == "pointviz.camera"
    assert [p.name for p in tmp_path.iterdir()] == ["cam.json"]  # no temp files left


def test_json_overwrite_refused(camera, tmp_path):
    path = tmp_path / "cam.json"
    path.write_text("precious")
    with pytest.raises(FileExistsError, match="cam.json"):
        camera.to_json(path)
    assert path.read_text() == "precious"
    camera.to_json(str(path), overwrite=True)
    assert Camera.from_json(path) == camera
    assert sorted(os.listdir(tmp_path)) == ["cam.json"]


@pytest.mark.parametrize("content,match", [
    ("{not json", "invalid JSON"),
    ("[1, 2]", "object"),
    (lambda d: {k: v for k, v in d.items() if k != "target"}, "target"),
    (lambda d: {**d, "fov_deg": float("nan")}, "fov_deg"),
    (lambda d: {**d, "eye": [0, "1", 2]}, "eye"),
    (lambda d: {**d, "eye": [0, 1]}, "eye"),
    (lambda d: {**d, "width": "640"}, "width"),
    (lambda d: {**d, "width": 2.5}, "width"),
    (lambda d: {**d, "format": "other"}, "format"),
])
def test_json_errors_name_file_and_field(camera, tmp_path, content, match):
    path = tmp_path / "bad.json"
    if callable(content):
        content = json.dumps(content({"format": "pointviz.camera", **camera.to_dict()}))
    path.write_text(content)
    with pytest.raises(FileFormatError, match=match) as info:
        Camera.from_json(path)
    assert "bad.json" in str(info.value)


def test_json_missing_file(tmp_path):
    with pytest.raises(FileFormatError, match="nope.json"):
        Camera.from_json(tmp_path / "nope.json")


# ----------------------------------------------------------------------------------- Open3D


@pytest.fixture(scope="module")
def o3d():
    return pytest.importorskip("open3d")


def test_open3d_projection_matches(o3d, camera, rng):
    """Apply Open3D's own K and extrinsic to points: same pixel as ours, up to Open3D's integer
    pixel-centre convention (ours minus 0.5)."""
    params = camera.to_open3d()
    k = np.asarray(params.intrinsic.intrinsic_matrix)
    ext = np.asarray(params.extrinsic)
    assert (params.intrinsic.width, params.intrinsic.height) == (camera.width, camera.height)
    pts, pixels, z = random_points_in_view(camera, rng)
    cam_pts = (ext[:3, :3] @ pts.T).T + ext[:3, 3]
    assert np.all(cam_pts[:, 2] > 0)
    np.testing.assert_allclose(cam_pts[:, 2], z)
    uvw = (k @ cam_pts.T).T
    o3d_pixels = uvw[:, :2] / uvw[:, 2:]
    np.testing.assert_allclose(o3d_pixels + 0.5, pixels, atol=1e-8)
    np.testing.assert_array_equal(np.floor(o3d_pixels + 0.5), np.floor(pixels))


def test_open3d_round_trip(o3d, camera):
    back = Camera.from_open3d(camera.to_open3d(), target_distance=camera.distance)
    assert (back.width, back.height) == (camera.width, camera.height)
    assert back.fov_deg == pytest.approx(camera.fov_deg, abs=1e-12)
    for name in ("eye", "target", "forward", "right", "true_up"):
        np.testing.assert_allclose(getattr(back, name), getattr(camera, name), atol=1e-12)
    np.testing.assert_allclose(back.rays(dtype=np.float64), camera.rays(dtype=np.float64),
                               atol=1e-12)


def test_open3d_unrepresentable(o3d, camera):
    params = camera.to_open3d()
    params.intrinsic = o3d.camera.PinholeCameraIntrinsic(33, 21, 30.0, 31.0, 16.0, 10.0)
    with pytest.raises(InputError, match="fx == fy"):
        Camera.from_open3d(params)
    params.intrinsic = o3d.camera.PinholeCameraIntrinsic(33, 21, 30.0, 30.0, 10.0, 10.0)
    with pytest.raises(InputError, match="principal point"):
        Camera.from_open3d(params)


# ------------------------------------------------------------------------ automatic views


def _coverage(cloud, cam):
    """Fraction of the frame's primary rays that hit the cloud, and the fractions of columns
    and rows they span (ray casting through the surfel tree, the renderer's own query)."""
    import pointviz

    hit = np.isfinite(pointviz.SurfelScene(cloud, cull=False).cast_rays(cam.rays())["t_hit"])
    hit = hit.reshape(cam.height, cam.width)
    return hit.mean(), hit.any(axis=0).mean(), hit.any(axis=1).mean()


def test_fit_views_a_terrain_tile_from_above_and_fills_the_frame(rng):
    import pointviz
    from pointviz.camera import TERRAIN_ELEVATIONS_DEG, shape_kind

    # a 300 x 120 m tile, z up, with hills and a few stray points far above and below
    xy = rng.uniform([0, 0], [300, 120], (60000, 2)) + [5e5, 4e6]
    z = 8 * np.sin(xy[:, 0] / 40) * np.cos(xy[:, 1] / 30) + 100
    pts = np.column_stack([xy, z])
    pts[:20, 2] += rng.choice([-400, 400], 20)
    cloud = pointviz.PointCloud(pts, up=(0, 0, 1))
    assert shape_kind(pts, (0, 0, 1)) == "terrain"
    cam = Camera.fit(cloud, width=160, height=120)
    elevation = np.degrees(np.arcsin(-cam.forward @ [0, 0, 1]))
    assert min(TERRAIN_ELEVATIONS_DEG) - 1e-6 <= elevation <= max(TERRAIN_ELEVATIONS_DEG) + 1e-6
    cover, width_span, height_span = _coverage(cloud, cam)
    assert cover >= 0.35 and max(width_span, height_span) >= 0.8
    old = Camera.fit(cloud, direction=(0.0, -0.3, -1.0), width=160, height=120)
    assert _coverage(cloud, old)[0] < cover


def test_fit_views_an_object_from_three_quarters_and_fills_the_frame(rng):
    from pointviz.camera import OBJECT_AZIMUTH_DEG, OBJECT_ELEVATION_DEG, shape_kind
    from pointviz.shapes import torus

    cloud = torus(30000, 1.0, 0.35)  # y up
    assert shape_kind(cloud.points, (0, 1, 0)) == "object"
    margin = 1.05
    cam = Camera.fit(cloud, width=160, height=120, margin=margin, outliers=0.0)
    elevation = np.degrees(np.arcsin(-cam.forward @ [0, 1, 0]))
    assert elevation == pytest.approx(OBJECT_ELEVATION_DEG, abs=1e-6)
    # the horizontal view is OBJECT_AZIMUTH_DEG off one of the principal horizontal axes
    h = cam.forward - np.array([0, 1, 0]) * cam.forward[1]
    h /= np.linalg.norm(h)
    from pointviz.camera import _horizontal_axes

    _, major, minor = _horizontal_axes(cloud.points, np.array([0.0, 1.0, 0.0]))
    assert np.degrees(np.arccos(abs(h @ minor))) == pytest.approx(OBJECT_AZIMUTH_DEG, abs=1e-6)
    # every point inside, and the projection fills the width or the height (shrunk by margin)
    px, depth = cam.project(cloud.points)
    assert np.all(depth > 0) and np.all((px >= 0) & (px <= [160, 120]))
    span = np.ptp(px, axis=0) / [160, 120]
    assert span.max() == pytest.approx(1 / margin, rel=1e-3)
    centre = (px.min(axis=0) + px.max(axis=0)) / 2
    np.testing.assert_allclose(centre, [80, 60], atol=0.5)


def _depth_frame(rng, eye, forward, up, n=20000):
    """Points a camera at ``eye`` sees: a wall 3 units ahead and a box on the floor below its
    line of sight (a depth frame's scene), all within 30 degrees of ``forward``."""
    forward, up = np.asarray(forward, float), np.asarray(up, float)
    right = np.cross(forward, up)
    a, b = rng.uniform(-1, 1, (2, n // 2, 1))
    wall = eye + 3 * forward + a * right + b * up
    floor = eye + rng.uniform(1, 3, (n // 2, 1)) * forward + b * right - up
    return np.vstack([wall, floor])


def test_fit_views_a_single_viewpoint_cloud_from_its_viewpoint(rng):
    import pointviz
    from pointviz.framing import VIEWPOINT_ELEVATION_DEG

    eye = np.array([1.0, 2.0, 3.0])
    forward, up = np.array([0.0, 0.0, 1.0]), np.array([0.0, -1.0, 0.0])  # PCL's camera frame
    pts = _depth_frame(rng, eye, forward, up)
    cloud = pointviz.PointCloud(pts, viewpoints=eye, up=up)
    cam = Camera.fit(cloud, width=160, height=120, outliers=0.0)
    # oracle: the line of sight from the viewpoint to the centre of the points' bounding box
    # (what outliers=0 frames), raised by the elevation
    sight = (pts.min(axis=0) + pts.max(axis=0)) / 2 - eye
    sight /= np.linalg.norm(sight)
    dip = np.degrees(np.arcsin(-(sight @ up)))
    elevation = np.degrees(np.arcsin(-(cam.forward @ up)))
    assert elevation == pytest.approx(dip + VIEWPOINT_ELEVATION_DEG, abs=1e-6)
    # the same vertical plane: the horizontal parts of the two directions agree
    h = lambda v: (v - up * (v @ up)) / np.linalg.norm(v - up * (v @ up))  # noqa: E731
    assert h(cam.forward) @ h(sight) == pytest.approx(1.0, abs=1e-9)
    px, depth = cam.project(pts)
    assert np.all(depth > 0) and np.all((px >= 0) & (px <= [160, 120]))
    # what the CLI's background fit and a scene of the cloud see: the same view
    from pointviz.commands.common import _camera_in_background

    background = _camera_in_background(cloud, cam.fov_deg)().with_size(160, 120)
    np.testing.assert_allclose(background.forward, Camera.fit(cloud, fov_deg=cam.fov_deg).forward,
                               atol=1e-12)
    scene_cam = Camera.fit(pointviz.Scene([cloud]), width=160, height=120)
    assert np.degrees(np.arccos(np.clip(scene_cam.forward @ cam.forward, -1, 1))) < 5.0


def test_fit_ignores_a_viewpoint_inside_its_scene(rng):
    import pointviz

    # a scanner in the middle of a room: no direction sees it all, so the shape decides
    pts = rng.normal(size=(20000, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    pts *= [4.0, 1.5, 3.0]
    inside = pointviz.PointCloud(pts, viewpoints=[0.0, 0.0, 0.0])
    assert Camera.fit(inside) == Camera.fit(pointviz.PointCloud(pts))
    # per-point viewpoints (registered scans) are several positions: the shape decides too
    many = pointviz.PointCloud(pts, viewpoints=np.tile([0.0, 0.0, 10.0], (len(pts), 1)))
    assert Camera.fit(many) == Camera.fit(pointviz.PointCloud(pts))


# ------------------------------------------------------------- against the renderer's ray model


@pytest.mark.parametrize("seed", range(4))
def test_rays_match_the_core_camera_model(seed):
    """Camera.rays and the C++ CameraModel::direction (what the renderer traces) give the same
    ray through every pixel, at pixel centres and at random in-pixel offsets; the core sees
    the eye relative to the scene's origin."""
    from pointviz.rendering import camera_model

    rng = np.random.default_rng(seed)
    cam = Camera(rng.normal(size=3) * 10, rng.normal(size=3), up=rng.normal(size=3),
                 fov_deg=rng.uniform(10, 120), width=int(rng.integers(1, 23)),
                 height=int(rng.integers(1, 17)))
    origin = rng.normal(size=3) * 5
    core = camera_model(cam, origin)
    np.testing.assert_allclose(core.eye, cam.eye - origin, rtol=0, atol=1e-5)
    offsets = rng.random((cam.height, cam.width, 2))
    for samples in (None, offsets):
        rays = cam.rays(samples, dtype=np.float64)
        uv = np.full((cam.height, cam.width, 2), 0.5) if samples is None else offsets
        expected = np.array([core.direction(j + uv[i, j, 0], i + uv[i, j, 1])
                             for i in range(cam.height) for j in range(cam.width)])
        np.testing.assert_allclose(rays[:, 3:], expected, rtol=0, atol=2e-6)
        np.testing.assert_allclose(rays[:, :3], np.broadcast_to(cam.eye, rays[:, :3].shape))


def test_bounding_sphere_of_a_large_cloud_is_the_whole_array_formula():
    """Computed block by block (bounded temporaries), it equals the one-expression formula."""
    from pointviz.framing import SPHERE_BLOCK

    rng = np.random.default_rng(11)
    pts = rng.normal(size=(2 * SPHERE_BLOCK + 7, 3)) * [1e3, 2.0, 0.5] + [4e6, -3.0, 1.0]
    pts[SPHERE_BLOCK + 3] = [4e6 + 9e3, 0.0, 0.0]  # the farthest point in the second block
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = float(np.sqrt(np.max(np.einsum("ij,ij->i", pts - centre, pts - centre))))
    c, r = bounding_sphere(pts)
    np.testing.assert_array_equal(c, centre)
    assert r == radius
    pts[-1, 2] = np.nan
    with pytest.raises(InputError, match="NaN or inf"):
        bounding_sphere(pts)


@pytest.mark.parametrize("q", [0.001, 0.01, 0.05, 0.3, 0.4999])
def test_tail_quantiles_equal_numpy_over_a_changing_sequence(rng, q):
    """The camera fit's quantiles of the points' projections, searched among the entries that
    were in the tails at the previous call, are np.quantile's bit for bit: with ties, sign
    changes, a reordering of every value and arrays of any length."""
    from pointviz.framing import TailQuantiles

    for n in (4, 5, 97, 2000, 20001):
        tails = TailQuantiles(n, q)
        base = rng.normal(size=n)
        if n > 97:
            base[: n // 3] = np.round(base[: n // 3], 1)  # many ties
        for step in range(12):
            v = base * (0.5 + step / 8) + (step % 3 - 1) * 0.2
            if step == 7:
                v = rng.permutation(v)
            if step == 9:
                v = -v
            want = tuple(float(x) for x in np.quantile(v, (q, 1 - q)))
            assert tails(v) == want, (n, step)
        if n >= 2000 and q <= 0.05:
            # what makes it worth having: calls after one whose order barely changed partition a
            # few values, not both sides' n (the reordered and negated steps search widely)
            assert tails.searched < 0.5 * 12 * 2 * n


def test_fit_camera_is_unchanged_by_the_tail_search(rng, monkeypatch):
    """Camera.fit with the remembered-tails search equals the fit with np.quantile at every
    call (the formula the search replaces)."""
    import pointviz.framing as framing

    pts = rng.normal(size=(30000, 3)) * [2.0, 1.0, 0.5]
    pts[:40] += 30.0  # stray points the robust fit leaves out
    fast = Camera.fit(pts, width=320, height=200)

    class Plain:
        def __init__(self, n, q):
            self.q = (q, 1 - q)

        def __call__(self, v):
            return tuple(float(x) for x in np.quantile(v, self.q))

    monkeypatch.setattr(framing, "TailQuantiles", Plain)
    plain = Camera.fit(pts, width=320, height=200)
    assert fast.to_dict() == plain.to_dict()
