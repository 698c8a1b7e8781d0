"""Tests of pointviz.path.CameraPath: keyframe fidelity, smoothness, slerp, generators, I/O."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from pointviz.camera import Camera, bounding_sphere
from pointviz.errors import FileFormatError, InputError
from pointviz.path import CameraPath, Keyframe

EASINGS = ("ease-in-out", "linear")


@pytest.fixture
def rng():
    return np.random.default_rng(99)


def make_path(rng, n=6, easing="ease-in-out"):
    """Random keyframes with non-uniform times, positions and orientations."""
    times = np.concatenate([[0.25], 0.25 + np.cumsum(rng.uniform(0.4, 2.0, n - 1))])
    path = CameraPath(width=64, height=48, fps=24.0, easing=easing)
    for t in times:
        eye = rng.normal(size=3) * 4.0
        target = eye + rng.normal(size=3)
        up = rng.normal(size=3)
        path.add(Keyframe(eye, target, up, rng.uniform(20, 80), t))
    return path


def eyes_at(path, t):
    return np.array([c.eye for c in path.cameras_at(t)])


# --------------------------------------------------------------------------- keyframes


def test_add_times_and_frames():
    path = CameraPath(fps=10.0)
    assert len(path) == 0 and path.n_frames == 0 and path.cameras() == []
    with pytest.raises(InputError, match="no keyframes"):
        path.camera_at(0.0)
    cam = Camera((0, 0, 5), (0, 0, 0))
    assert path.add(cam).time == 0.0
    assert path.add(cam.replace(eye=(1, 0, 5))).time == 1.0
    path.add(cam.replace(eye=(2, 0, 5)), time=0.5)  # inserted in time order
    assert [k.time for k in path.keyframes] == [0.0, 0.5, 1.0]
    assert path.add(Keyframe((3, 0, 5), (0, 0, 0), time=2.7)).time == 2.7
    assert len(path) == 4 and path.duration == 2.7
    assert path.n_frames == 28  # floor(2.7 * 10) + 1, despite 2.7 * 10 = 27.000000000000004
    np.testing.assert_allclose(path.times(), np.arange(28) / 10.0)
    assert len(path.cameras()) == 28 and len(list(path)) == 28
    assert all(c.width == 640 and c.height == 480 for c in path)
    with pytest.raises(InputError, match="already used"):
        path.add(cam, time=1.0)
    with pytest.raises(InputError, match="camera_or_keyframe"):
        path.add("camera")


def test_constructor_validation():
    for kwargs, match in [(dict(fps=0.0), "fps"), (dict(easing="bounce"), "easing"),
                          (dict(width=0), "width"), (dict(keyframes=[1]), "keyframes")]:
        with pytest.raises(InputError, match=match):
            CameraPath(**kwargs)
    with pytest.raises(InputError, match="eye and target coincide"):
        Keyframe((1, 1, 1), (1, 1, 1))
    with pytest.raises(InputError, match="time"):
        Keyframe((0, 0, 1), (0, 0, 0), time=float("nan"))


def test_single_keyframe_and_clamping():
    path = CameraPath([Keyframe((0, 0, 5), (0, 0, 0), fov_deg=30.0, time=2.0)])
    assert path.duration == 0 and path.n_frames == 1
    cam = path.camera_at(-10.0)
    np.testing.assert_array_equal(cam.eye, [0, 0, 5])
    assert cam.fov_deg == 30.0


@pytest.mark.parametrize("easing", EASINGS)
def test_passes_through_every_keyframe(rng, easing):
    path = make_path(rng, n=7, easing=easing)
    for kf in path.keyframes:
        cam = path.camera_at(kf.time)
        ref = kf.to_camera(path.width, path.height)
        np.testing.assert_array_equal(cam.eye, kf.eye)
        np.testing.assert_array_equal(cam.target, kf.target)
        assert cam.fov_deg == kf.fov_deg
        for name in ("forward", "right", "true_up"):
            np.testing.assert_allclose(getattr(cam, name), getattr(ref, name), atol=1e-13)


@pytest.mark.parametrize("easing", EASINGS)
def test_between_keyframes_stays_bounded(rng, easing):
    """Centripetal Catmull-Rom does not overshoot wildly: the eye stays near the keyframes'
    bounding box and the fov inside the keyframe range (monotone time maps)."""
    path = make_path(rng, easing=easing)
    cams = path.cameras_at(np.linspace(path.start, path.start + path.duration, 500))
    eyes = np.array([c.eye for c in cams])
    keys = np.array([k.eye for k in path.keyframes])
    span = keys.max(0) - keys.min(0)
    assert np.all(eyes >= keys.min(0) - 0.5 * span) and np.all(eyes <= keys.max(0) + 0.5 * span)
    fovs = np.array([c.fov_deg for c in cams])
    key_fovs = [k.fov_deg for k in path.keyframes]
    assert fovs.min() >= min(key_fovs) - 1e-9 and fovs.max() <= max(key_fovs) + 1e-9


def test_repeated_positions_and_rotation_in_place():
    """Coincident consecutive eyes (a pause, or turning on the spot) give no NaN and the eye
    stays put between them."""
    path = CameraPath([Keyframe((0, 0, 5), (0, 0, 0), time=0.0),
                       Keyframe((1, 0, 5), (0, 0, 0), time=1.0),
                       Keyframe((1, 0, 5), (0, 1, 0), time=2.0),
                       Keyframe((3, 0, 5), (0, 1, 0), time=3.0)])
    cams = path.cameras_at(np.linspace(0.0, 3.0, 301))
    eyes = np.array([c.eye for c in cams])
    assert np.all(np.isfinite(eyes))
    np.testing.assert_allclose(eyes[100:201], np.broadcast_to([1, 0, 5], (101, 3)), atol=1e-9)
    spin = CameraPath([Keyframe((0, 0, 0), (0, 0, -1), time=0.0),
                       Keyframe((0, 0, 0), (1, 0, 0), time=1.0),
                       Keyframe((0, 0, 0), (0, 0, 1), time=2.0)])
    fwd = np.array([c.forward for c in spin.cameras_at(np.linspace(0.0, 2.0, 81))])
    assert np.all(np.sum(fwd[1:] * fwd[:-1], 1) > math.cos(math.radians(10)))
    np.testing.assert_array_equal([c.eye for c in spin.cameras()], np.zeros((61, 3)))


# --------------------------------------------------------------------------- smoothness


def velocity_jumps(sample, knots, h):
    """|one-sided finite-difference velocity difference| at interior knots, shape (k,)."""
    t = np.concatenate([[tk - h, tk, tk + h] for tk in knots])
    p = sample(t).reshape(len(knots), 3, 3)
    left = (p[:, 1] - p[:, 0]) / h
    right = (p[:, 2] - p[:, 1]) / h
    return np.linalg.norm(right - left, axis=1)


def max_acceleration(sample, t0, t1, h):
    t = np.arange(t0, t1, h)
    p = sample(t)
    return np.max(np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=1)) / h**2


def test_ease_in_out_velocity_continuous_and_acceleration_bounded(rng):
    """The eye is C1 in time: finite-difference velocity jumps at keyframes vanish with h (they
    are O(h * acceleration)) and the acceleration estimate does not grow as h shrinks. A
    piecewise-linear path through the same keyframes (the oracle for 'not smooth') keeps
    O(1) velocity jumps and its acceleration estimate grows like 1 / h."""
    path = make_path(rng, n=6)
    times = np.array([k.time for k in path.keyframes])
    keys = np.array([k.eye for k in path.keyframes])
    interior = times[1:-1]

    def ours(t):
        return eyes_at(path, t)

    def linear(t):
        return np.stack([np.interp(t, times, keys[:, i]) for i in range(3)], 1)

    speed = np.max(np.linalg.norm(np.diff(keys, axis=0), axis=1) / np.diff(times))
    jumps_coarse = velocity_jumps(ours, interior, 1e-3)
    jumps_fine = velocity_jumps(ours, interior, 1e-4)
    assert np.max(jumps_fine) < 1e-2 * speed
    assert np.max(jumps_fine) < 0.2 * np.max(jumps_coarse)  # shrinks ~10x with h
    lin_coarse = velocity_jumps(linear, interior, 1e-3)
    lin_fine = velocity_jumps(linear, interior, 1e-4)
    assert np.min(lin_fine) > 0.5 * np.min(lin_coarse) and np.min(lin_fine) > 1e-2 * speed

    t0, t1 = times[0], times[-1]
    acc_coarse = max_acceleration(ours, t0, t1, 4e-3)
    acc_fine = max_acceleration(ours, t0, t1, 1e-3)
    assert acc_fine < 1.5 * acc_coarse
    lin_acc_coarse = max_acceleration(linear, t0, t1, 4e-3)
    lin_acc_fine = max_acceleration(linear, t0, t1, 1e-3)
    assert lin_acc_fine > 2.5 * lin_acc_coarse
    assert acc_fine < lin_acc_fine


def test_linear_easing_is_only_direction_continuous(rng):
    """With linear easing the direction of motion is continuous but the speed may jump."""
    path = make_path(rng, n=5, easing="linear")
    interior = np.array([k.time for k in path.keyframes])[1:-1]
    h = 1e-5
    t = np.concatenate([[tk - h, tk, tk + h] for tk in interior])
    p = eyes_at(path, t).reshape(-1, 3, 3)
    left, right = p[:, 1] - p[:, 0], p[:, 2] - p[:, 1]
    cos = np.sum(left * right, 1) / np.linalg.norm(left, axis=1) / np.linalg.norm(right, axis=1)
    assert np.all(cos > 1 - 1e-6)


def test_two_keyframes_are_smoothstep_on_a_line():
    """Reflected phantom points make a two-keyframe spline the straight segment; ease-in-out
    is then exactly smoothstep (analytic oracle), linear is a uniform lerp."""
    a, b = np.array([1.0, 2.0, 3.0]), np.array([4.0, -2.0, 3.5])
    t = np.linspace(1.0, 3.0, 41)
    u = (t - 1.0) / 2.0
    for easing, w in (("ease-in-out", u * u * (3 - 2 * u)), ("linear", u)):
        path = CameraPath([Keyframe(a, a + (0, 0, -1), time=1.0),
                           Keyframe(b, b + (0, 0, -1), time=3.0)], easing=easing)
        np.testing.assert_allclose(eyes_at(path, t), a + w[:, None] * (b - a), atol=1e-12)


def test_ease_in_out_starts_and_ends_at_rest(rng):
    path = make_path(rng)
    t0, t1, h = path.start, path.start + path.duration, 1e-4
    p = eyes_at(path, [t0, t0 + h, t1 - h, t1])
    assert np.linalg.norm(p[1] - p[0]) / h < 1e-2
    assert np.linalg.norm(p[3] - p[2]) / h < 1e-2


# --------------------------------------------------------------------------------- slerp


def roll_up(angle_deg):
    """Up vector of a camera looking down -Z rolled by angle_deg (right-hand rule about +Z)."""
    a = math.radians(angle_deg)
    return np.array([-math.sin(a), math.cos(a), 0.0])


@pytest.mark.parametrize("end_roll,mid_roll", [(200.0, -80.0), (160.0, 80.0), (300.0, -30.0),
                                               (-170.0, -85.0)])
def test_slerp_takes_the_short_arc(end_roll, mid_roll):
    eye, target = np.zeros(3), np.array([0.0, 0.0, -1.0])
    path = CameraPath([Keyframe(eye, target, roll_up(0.0), time=0.0),
                       Keyframe(eye, target, roll_up(end_roll), time=2.0)])
    cam = path.camera_at(1.0)
    np.testing.assert_allclose(cam.true_up, roll_up(mid_roll), atol=1e-12)
    # the roll angle moves monotonically along the short arc
    rolls = [math.degrees(math.atan2(-c.true_up[0], c.true_up[1]))
             for c in path.cameras_at(np.linspace(0, 2, 21))]
    steps = np.diff(np.unwrap(np.radians(rolls)))
    assert np.all(np.sign(steps) == np.sign(mid_roll)) or np.allclose(steps, 0)
    assert abs(np.sum(steps)) == pytest.approx(math.radians(2 * abs(mid_roll)))


def test_orientation_changes_continuously(rng):
    """No flips: consecutive frames of a random path differ by small rotations."""
    path = make_path(rng, n=6)
    cams = path.cameras_at(np.linspace(path.start, path.start + path.duration, 2000))
    ups = np.array([c.true_up for c in cams])
    fwd = np.array([c.forward for c in cams])
    assert np.min(np.sum(ups[1:] * ups[:-1], 1)) > math.cos(math.radians(5))
    assert np.min(np.sum(fwd[1:] * fwd[:-1], 1)) > math.cos(math.radians(5))


# ---------------------------------------------------------------------------- generators


@pytest.fixture
def cloud(rng):
    pts = rng.normal(size=(500, 3)) * [3.0, 1.0, 2.0] + [10.0, 0.0, -4.0]
    return SimpleNamespace(points=pts)


@pytest.mark.parametrize("easing", EASINGS)
def test_orbit_is_closed_constant_distance_and_frames_cloud(cloud, easing):
    path = CameraPath.orbit(cloud, seconds=4.0, fps=12.0, elevation_deg=20.0, width=80,
                            height=60, easing=easing)
    centre, _ = bounding_sphere(cloud.points)
    cams = path.cameras()
    assert len(cams) == 4 * 12 + 1
    np.testing.assert_array_equal(cams[0].eye, cams[-1].eye)  # first and last frames coincide
    fine = path.cameras_at(np.linspace(0, 4, 2001))
    dist = np.array([np.linalg.norm(c.eye - centre) for c in fine])
    assert np.max(np.abs(dist / dist[0] - 1)) < 5e-4  # between frames (measured 2.8e-4)
    frame_dist = np.array([np.linalg.norm(c.eye - centre) for c in cams])
    np.testing.assert_allclose(frame_dist, dist[0], rtol=1e-12)  # frames are on keyframes
    for c in fine:
        np.testing.assert_allclose(c.target, centre, atol=1e-12)
    up = np.array([0.0, 1.0, 0.0])
    elev = np.degrees(np.arcsin([(c.eye - centre) @ up / np.linalg.norm(c.eye - centre)
                                 for c in fine]))
    np.testing.assert_allclose(elev, 20.0, atol=0.02)
    angles = np.unwrap([math.atan2(*(c.eye - centre)[[0, 2]]) for c in cams])
    assert angles[-1] - angles[0] == pytest.approx(2 * math.pi)  # one full turn
    for c in cams[:: len(cams) // 6]:
        pixels, depth = c.project(cloud.points)
        assert np.all(depth > 0) and np.all((pixels >= 0) & (pixels <= [80, 60]))


def test_turntable_linear_level_constant_speed(cloud):
    path = CameraPath.turntable(cloud, seconds=3.0, fps=20.0)
    assert path.easing == "linear"
    centre, _ = bounding_sphere(cloud.points)
    rel = np.array([c.eye - centre for c in path.cameras()])
    np.testing.assert_allclose(rel[:, 1], 0.0, atol=1e-9)
    steps = np.diff(np.unwrap(np.arctan2(rel[:, 0], rel[:, 2])))
    np.testing.assert_allclose(steps, 2 * math.pi / 60, rtol=1e-3)
    cams = path.cameras()
    np.testing.assert_allclose([c.true_up for c in cams], [[0, 1, 0]] * len(cams), atol=1e-9)


def test_orbit_uses_cloud_up(cloud):
    cloud.up = np.array([0.0, 0.0, 1.0])
    path = CameraPath.orbit(cloud, seconds=2.0, fps=5.0, elevation_deg=0.0)
    centre, _ = bounding_sphere(cloud.points)
    for c in path.cameras():
        assert abs((c.eye - centre)[2]) < 1e-9
        np.testing.assert_allclose(c.true_up, [0, 0, 1], atol=1e-9)
    with pytest.raises(InputError, match="elevation_deg"):
        CameraPath.orbit(cloud, elevation_deg=90.0)


def test_fly_through_follows_polyline_and_looks_ahead():
    pts = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 0.0, -10.0], [20.0, 1.0, -10.0]])
    path = CameraPath.fly_through(pts, look_ahead=2.0, seconds=6.0, fps=10.0)
    # the eye passes through every vertex, at times proportional to arc length
    arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    for p, s in zip(pts, arc):
        np.testing.assert_allclose(path.camera_at(6.0 * s / arc[-1]).eye, p, atol=1e-12)
    # on the straight parts the camera looks along the polyline
    cam = path.camera_at(6.0 * 5.0 / arc[-1])
    np.testing.assert_allclose(cam.eye, [5, 0, 0], atol=1e-9)
    np.testing.assert_allclose(cam.forward, [1, 0, 0], atol=1e-9)
    # every frame's eye stays close to the polyline (corners are rounded within a sample)
    eyes = np.array([c.eye for c in path.cameras()])
    seg_a, seg_b = pts[:-1], pts[1:]
    d = seg_b - seg_a
    w = np.clip(np.einsum("ksj,sj->ks", eyes[:, None] - seg_a, d) / np.sum(d * d, 1), 0, 1)
    nearest = seg_a + w[..., None] * d
    assert np.max(np.min(np.linalg.norm(eyes[:, None] - nearest, axis=2), axis=1)) < 0.5
    with pytest.raises(InputError, match="parallel"):
        CameraPath.fly_through([[0, 0, 0], [0, 5, 0]])
    with pytest.raises(InputError, match="points"):
        CameraPath.fly_through([[0, 0, 0]])


# ------------------------------------------------------------------------------------ I/O


def test_save_load_round_trip(rng, tmp_path):
    path = make_path(rng, easing="linear")
    file = tmp_path / "path.json"
    path.save(file)
    data = json.loads(file.read_text())
    assert data["format"] == "pointviz.camera_path" and data["version"] == 1
    assert set(data["keyframes"][0]) == {"eye", "target", "up", "fov_deg", "time"}
    back = CameraPath.load(file)
    assert back == path and back.keyframes == path.keyframes
    assert back.camera_at(1.3) == path.camera_at(1.3)
    with pytest.raises(FileExistsError, match="path.json"):
        path.save(file)
    make_path(rng).save(file, overwrite=True)
    assert CameraPath.load(file) != path
    assert [p.name for p in tmp_path.iterdir()] == ["path.json"]


def _corrupt(data, field, value):
    data = json.loads(json.dumps(data))
    if field.startswith("keyframes[1]."):
        data["keyframes"][1][field.split(".")[1]] = value
    else:
        data[field] = value
    return data


@pytest.mark.parametrize("field,value,match", [
    ("keyframes[1].eye", float("nan"), r"keyframes\[1\]\.eye"),
    ("keyframes[1].eye", [0, 1], r"keyframes\[1\]\.eye"),
    ("keyframes[1].fov_deg", "wide", r"keyframes\[1\]\.fov_deg"),
    ("keyframes[1].time", 0.25, r"keyframes\[1\]\.time"),
    ("keyframes[1].up", [0.0, 0.0, 0.0], r"keyframes\[1\].*up"),
    ("fps", -1, "fps"),
    ("easing", "bounce", "easing"),
    ("format", "something", "format"),
    ("version", 2, "version"),
    ("keyframes", {}, "keyframes"),
])
def test_load_errors_name_file_and_field(rng, tmp_path, field, value, match):
    data = _corrupt(make_path(rng).to_dict(), field, value)
    file = tmp_path / "broken.json"
    file.write_text(json.dumps(data))  # json writes NaN as the (non-standard) literal NaN
    with pytest.raises(FileFormatError, match=match) as info:
        CameraPath.load(file)
    assert "broken.json" in str(info.value)


def test_load_bad_json_and_missing_key(rng, tmp_path):
    file = tmp_path / "p.json"
    file.write_text('{"format": "pointviz.camera_path", ')
    with pytest.raises(FileFormatError, match="p.json.*invalid JSON"):
        CameraPath.load(file)
    data = make_path(rng).to_dict()
    del data["keyframes"][0]["target"]
    file.write_text(json.dumps(data))
    with pytest.raises(FileFormatError, match=r"p.json.*keyframes\[0\].*target"):
        CameraPath.load(file)
    del data["fps"]
    file.write_text(json.dumps(data))
    with pytest.raises(FileFormatError, match="fps"):
        CameraPath.load(file)


def test_from_viewer_keyframes():
    cams = [Camera((0, 0, 5), (0, 0, 0), width=320, height=200),
            Camera((5, 0, 0), (0, 0, 0), width=320, height=200),
            Camera((0, 5, 1), (0, 0, 0), width=320, height=200)]
    dicts = [c.to_dict() for c in cams]
    dicts[2]["time"] = 4.0
    path = CameraPath.from_viewer_keyframes(dicts, fps=10.0)
    assert (path.width, path.height) == (320, 200)
    assert [k.time for k in path.keyframes] == [0.0, 1.0, 4.0]
    for kf, cam in zip(path.keyframes, cams):
        frame = path.camera_at(kf.time)
        assert frame.with_size(320, 200) == frame and frame.fov_deg == cam.fov_deg
        np.testing.assert_array_equal(frame.eye, cam.eye)
        np.testing.assert_allclose(frame.true_up, cam.true_up, atol=1e-13)
    no_time = [{k: v for k, v in d.items() if k != "time"} for d in dicts]
    assert [k.time for k in CameraPath.from_viewer_keyframes(no_time).keyframes] == [0, 1, 2]
    dicts[1]["eye"] = [0, "x", 0]
    with pytest.raises(InputError, match=r"keyframes\[1\]\.eye"):
        CameraPath.from_viewer_keyframes(dicts)


# --------------------------------------------------------------------------------- Open3D


def test_from_open3d_trajectory(tmp_path, rng):
    o3d = pytest.importorskip("open3d")
    cams = [Camera(rng.normal(size=3) * 3, rng.normal(size=3), up=(0, 1, 0), fov_deg=45.0,
                   width=64, height=48) for _ in range(5)]
    traj = o3d.camera.PinholeCameraTrajectory()
    traj.parameters = [c.to_open3d() for c in cams]
    file = tmp_path / "traj.json"
    assert o3d.io.write_pinhole_camera_trajectory(str(file), traj)
    fps = 4.0
    for source in (file, str(file), traj):
        path = CameraPath.from_open3d_trajectory(source, fps=fps)
        assert len(path) == 5 and (path.width, path.height) == (64, 48)
        np.testing.assert_allclose([k.time for k in path.keyframes], np.arange(5) / fps)
        frames = path.cameras()
        assert len(frames) == 5  # keyframes 1 / fps apart: one frame per pose
        for cam, frame in zip(cams, frames):
            assert frame.fov_deg == pytest.approx(45.0, abs=1e-9)
            for name in ("eye", "forward", "true_up"):
                np.testing.assert_allclose(getattr(frame, name), getattr(cam, name), atol=1e-9)
    with pytest.raises(FileFormatError, match="missing.json"):
        CameraPath.from_open3d_trajectory(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    with pytest.raises(FileFormatError, match="bad.json"):
        CameraPath.from_open3d_trajectory(bad)
