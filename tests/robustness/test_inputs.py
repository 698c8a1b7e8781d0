"""Bad and strange input at the API and CLI boundaries.

Arrays of the wrong shape, dtype or layout; NaN/inf; empty, single, duplicate and degenerate
clouds; georeferenced coordinates; cameras that cannot see; broken camera and path JSON; and the
CLI, which must answer every bad input with one line on stderr and a non-zero exit code.
"""

from __future__ import annotations

import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from pointviz import Camera, CameraPath, PointCloud, SurfelScene
from pointviz.errors import InputError, PointvizError

from . import samples as S

rng0 = np.random.default_rng(5)
P = rng0.normal(size=(60, 3))
N = P / np.linalg.norm(P, axis=1, keepdims=True)

# -- arrays ------------------------------------------------------------------------------------

BAD_POINTS = [
    ("empty", np.zeros((0, 3)), "empty"),
    ("nan", np.where(np.arange(180).reshape(60, 3) == 7, np.nan, P), "NaN"),
    ("inf", np.where(np.arange(180).reshape(60, 3) == 7, np.inf, P), "NaN or inf"),
    ("shape-n2", P[:, :2], "shape"),
    ("shape-3d", P[None], "shape"),
    ("shape-flat", P.ravel(), "shape"),
    ("object", P.astype(object), "dtype object"),
    ("structured", np.zeros(5, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]), "dtype"),
    ("bool", P > 0, "dtype bool"),
    ("complex", P + 0j, "complex"),
    ("strings", np.array([["a", "b", "c"]]), "dtype"),
    ("ragged", [[0, 0, 0], [1, 0]], "points"),
]


@pytest.mark.parametrize("points, fragment", [c[1:] for c in BAD_POINTS],
                         ids=[c[0] for c in BAD_POINTS])
def test_bad_points_name_the_argument(points, fragment):
    with pytest.raises(InputError, match="points") as info:
        PointCloud(points)
    assert fragment in str(info.value)


@pytest.mark.parametrize("layout", ["int64", "int32", "float16", "float32", "fortran",
                                    "strided", "list", "readonly", "big-endian"])
def test_odd_layouts_are_converted_not_misread(layout):
    base = np.round(P * 8)  # exactly representable in every dtype below
    arr = {
        "int64": base.astype(np.int64), "int32": base.astype(np.int32),
        "float16": base.astype(np.float16), "float32": base.astype(np.float32),
        "fortran": np.asfortranarray(base), "strided": np.repeat(base, 2, axis=1)[:, ::2],
        "list": base.tolist(), "readonly": _readonly(base), "big-endian": base.astype(">f8"),
    }[layout]
    cloud = PointCloud(arr, normals=np.asfortranarray(N), radii=np.full(60, 0.5)[::1])
    assert cloud.points.dtype == np.float64 and cloud.points.flags.c_contiguous
    np.testing.assert_array_equal(cloud.points, base)
    # the core sees the same surfels whatever the layout was
    ray = [[0.0, 0.0, 50.0, 0.0, 0.0, -1.0]]
    ref = SurfelScene(PointCloud(base, normals=N, radii=0.5), interpolation="none", lod=False)
    got = SurfelScene(cloud, interpolation="none", lod=False)
    assert got.cast_rays(ray)["index"][0] == ref.cast_rays(ray)["index"][0]


def _readonly(a):
    a = a.copy()
    a.flags.writeable = False
    return a


@pytest.mark.parametrize("kw, fragment", [
    ({"normals": np.zeros((60, 3))}, "normals: 60 rows have zero length"),
    ({"normals": N[:59]}, "normals: has 59 rows"),
    ({"normals": np.where(P > 2, np.nan, N)}, "normals"),
    ({"radii": -1.0}, "radii: 60 values are zero or negative"),
    ({"radii": np.zeros(60)}, "zero or negative"),
    ({"radii": np.full(60, np.nan)}, "NaN"),
    ({"radii": np.ones(59)}, "radii: expected shape"),
    ({"radii": np.full(60, 1e-50)}, "underflow"),
    ({"colors": np.full((60, 3), 2.0)}, "outside [0, 1]"),
    ({"colors": np.full((60, 3), 300)}, "8-bit"),
    ({"colors": np.full((60, 3), np.nan)}, "NaN"),
], ids=["zero-normals", "normals-rows", "nan-normals", "negative-radii", "zero-radii",
        "nan-radii", "radii-shape", "radii-underflow", "colors-range", "colors-int-range",
        "colors-nan"])
def test_bad_attributes_name_the_argument(kw, fragment):
    with pytest.raises(InputError) as info:
        PointCloud(P, **kw)
    assert fragment in str(info.value)


@pytest.mark.filterwarnings("ignore:overflow encountered in cast:RuntimeWarning")
def test_radii_overflowing_float32_are_rejected():
    with pytest.raises(InputError, match="radii"):
        PointCloud(P, normals=N, radii=1e39)


def test_one_point_needs_normals_and_radii_then_traces_exactly():
    with pytest.raises(InputError, match="normals: cannot be estimated from 1 point"):
        PointCloud([[1.0, 2.0, 3.0]]).normals  # noqa: B018
    with pytest.raises(InputError, match="radii: cannot be estimated from a single point"):
        PointCloud([[1.0, 2.0, 3.0]]).radii  # noqa: B018
    scene = SurfelScene(PointCloud([[1.0, 2.0, 3.0]], normals=[[0, 0, 1]], radii=0.5))
    out = scene.cast_rays([[1.2, 2.0, 10.0, 0, 0, -1], [1.6, 2.0, 10.0, 0, 0, -1]])
    assert out["t_hit"][0] == pytest.approx(7.0, abs=1e-5) and out["index"][0] == 0
    assert np.isinf(out["t_hit"][1]) and out["index"][1] == -1


def test_duplicate_points():
    pts = np.repeat(P[:1], 500, axis=0)
    with pytest.raises(InputError, match="coincide"):
        PointCloud(pts).radii  # noqa: B018
    scene = SurfelScene(PointCloud(pts, normals=np.tile([0, 0, 1.0], (500, 1)), radii=0.1))
    out = scene.cast_rays([[*P[0, :2], P[0, 2] + 1, 0, 0, -1]])
    assert out["t_hit"][0] == pytest.approx(1.0, abs=1e-5)
    assert 0 <= out["index"][0] < 500 and np.isfinite(out["normals"]).all()


def test_empty_ray_batch_and_bad_rays():
    scene = SurfelScene(PointCloud(N, normals=N, radii=0.3))
    out = scene.cast_rays(np.zeros((0, 6)))
    assert out["t_hit"].shape == (0,) and out["normals"].shape == (0, 3)
    for rays, fragment in [([[0, 0, np.nan, 0, 0, 1]], "NaN"), ([[0, 0, 5, 0, 0, 0]], "zero direction"),
                           ([0, 0, 5, 0, 0, -1], "shape"), (np.zeros((3, 6), object), "dtype"),
                           (np.zeros((3, 7)), "shape")]:
        with pytest.raises(InputError, match="rays") as info:
            scene.cast_rays(rays)
        assert fragment in str(info.value)
    with pytest.raises(InputError, match="t_max"):
        scene.occluded([[0, 0, 5, 0, 0, -1]], np.nan)


def test_ray_layouts_agree():
    scene = SurfelScene(PointCloud(N, normals=N, radii=0.3), interpolation="none", lod=False)
    rng = np.random.default_rng(3)
    rays = np.hstack([rng.normal(size=(50, 3)) * 4, rng.normal(size=(50, 3))])
    ref = scene.cast_rays(rays)
    for variant in (np.asfortranarray(rays), np.repeat(rays, 2, axis=0)[::2],
                    np.repeat(rays, 2, axis=1)[:, ::2], rays.astype(np.float32),
                    rays.astype(">f8"), rays.tolist()):
        out = scene.cast_rays(variant)
        np.testing.assert_array_equal(out["index"], ref["index"])
        np.testing.assert_allclose(out["t_hit"], ref["t_hit"], rtol=1e-5)


@pytest.mark.parametrize("length", [1e-300, 1e300])
def test_extreme_direction_lengths_are_rejected(length):
    scene = SurfelScene(PointCloud(N, normals=N, radii=0.3))
    with pytest.raises(InputError, match="rays"):
        scene.cast_rays([[0, 0, 5, 0, 0, -length]])


# -- precision ---------------------------------------------------------------------------------


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (1e7, -2e7, 3e7), (5e7, 5e7, 0.0)])
def test_georeferenced_offsets_keep_hit_accuracy(offset):
    """A tilted planar patch 1e7 from the origin: hits agree with a float64 analytic oracle.

    The core stores positions in float32 relative to the bounding-box centre; without that,
    float32 spacing at 3e7 is 2 m and nothing here would be resolvable.
    """
    off = np.asarray(offset)
    normal = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    u = np.cross(normal, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    g = np.stack(np.meshgrid(np.linspace(-1, 1, 41), np.linspace(-1, 1, 41)), -1).reshape(-1, 2)
    pts = off + g[:, :1] * u + g[:, 1:] * v
    scene = SurfelScene(PointCloud(pts, normals=np.tile(normal, (len(pts), 1)), radii=0.04),
                        interpolation="none", lod=False)
    rng = np.random.default_rng(11)
    targets = off + rng.uniform(-0.8, 0.8, (300, 1)) * u + rng.uniform(-0.8, 0.8, (300, 1)) * v
    origins = off + rng.normal(size=(300, 3)) + 4 * normal
    d = targets - origins
    out = scene.cast_rays(np.hstack([origins, d]))
    t_exact = ((off - origins) @ normal) / (d @ normal)  # float64 plane intersection
    assert np.isfinite(out["t_hit"]).all()
    hit = origins + d * out["t_hit"][:, None].astype(np.float64)
    err = np.linalg.norm(hit - (origins + d * t_exact[:, None]), axis=1)
    assert err.max() < 2e-5, f"max position error {err.max():.2e} at offset {offset}"
    np.testing.assert_allclose(np.abs(out["normals"] @ normal), 1.0, atol=1e-4)


def _misaligned(a: np.ndarray) -> np.ndarray:
    """A C-contiguous copy of ``a`` one byte off its dtype's alignment (as arrays unpickled from
    out-of-band buffers can be)."""
    buf = bytearray(a.nbytes + 1)
    out = np.frombuffer(buf, dtype=a.dtype, count=a.size, offset=1).reshape(a.shape)
    out[...] = a
    assert not out.flags.aligned and out.flags.c_contiguous
    return out


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_misaligned_arrays_give_the_same_answers(dtype):
    """The core reads misaligned input through an aligned copy (a misaligned load is undefined
    behaviour; UBSan caught it on a Dask worker's unpickled scene)."""
    rng = np.random.default_rng(4)
    pts = S.sample_points(500, seed=4).astype(np.float64)
    cloud = PointCloud(pts, normals=pts, radii=0.1)
    scene = SurfelScene(cloud)
    o = rng.normal(size=(200, 3)) * 3
    rays = np.hstack([o, -o + rng.normal(size=(200, 3)) * 0.3]).astype(dtype)
    want = scene.cast_rays(rays)
    got = scene.cast_rays(_misaligned(rays))
    for key in ("t_hit", "index", "normals"):
        np.testing.assert_array_equal(got[key], want[key])
    t_max = np.full(len(rays), np.inf, np.float32)
    np.testing.assert_array_equal(scene.occluded(_misaligned(rays), _misaligned(t_max)),
                                  scene.occluded(rays, t_max))


@pytest.mark.parametrize("query", ["cast_rays", "cast_rays-camera", "occluded"])
def test_georeferenced_rays_keep_float64_with_a_pixel_angle(query):
    p = np.array([[1e7 + 0.05, -5e6 - 0.09, 2.5e6]])
    # the disk faces the ray (culling would skip its back)
    scene = SurfelScene(PointCloud(p, normals=[[0, 0, -1.0]], radii=0.033),
                        interpolation="none")
    o = p[0] + [0.0, 0.0, -0.24]
    rays = np.hstack([o, p[0] - o])[None]  # straight at the disk's centre
    cam = Camera.look_at(o, p[0], up=(0, 1, 0), width=64, height=48)
    if query == "occluded":
        assert scene.occluded(rays, 2.0, pixel_angle=1e-3)[0]
        return
    kw = {"camera": cam} if query == "cast_rays-camera" else {"pixel_angle": 1e-3}
    out = scene.cast_rays(rays, **kw)
    assert out["t_hit"][0] == pytest.approx(1.0, abs=1e-5)


@pytest.mark.parametrize("case", ["scale-1e38", "outlier-1e39"])
def test_coordinates_beyond_float32_are_rejected(case):
    # rejected when the cloud is made: no surfel tree could resolve such a cloud
    with pytest.raises(InputError, match="points: the cloud spans"):
        if case == "scale-1e38":
            PointCloud(N * 1e38, normals=N, radii=3e37)
        else:
            PointCloud(np.vstack([N, [[1e39, 0, 0]]]), normals=np.vstack([N, [[0, 0, 1]]]),
                       radii=0.3)


def test_huge_float64_coordinates_give_a_clear_error():
    with pytest.raises(InputError, match="points: the cloud spans"):
        PointCloud(np.vstack([P[:10], [[1e200, 0, 0]]]))


# -- cameras and JSON --------------------------------------------------------------------------


@pytest.mark.parametrize("kw, fragment", [
    ({"fov_deg": 0}, "fov_deg"), ({"fov_deg": 180}, "fov_deg"), ({"fov_deg": -5}, "fov_deg"),
    ({"fov_deg": np.nan}, "fov_deg"), ({"eye": (0, 0, 0)}, "eye and target coincide"),
    ({"eye": (0, 5, 0)}, "parallel"), ({"up": (0, 0, 0)}, "up"), ({"width": 0}, "width"),
    ({"height": 10**6}, "height"), ({"eye": (0, 0, np.inf)}, "eye"), ({"width": 2.5}, "width"),
])
def test_cameras_that_cannot_see(kw, fragment):
    args = {"eye": (0, 0, 5), "target": (0, 0, 0), **kw}
    eye, target = args.pop("eye"), args.pop("target")
    with pytest.raises(InputError) as info:
        Camera.look_at(eye, target, **args)
    assert fragment in str(info.value)


GOOD_CAMERA = {"eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 40,
               "width": 64, "height": 48}


@pytest.mark.parametrize("text", [
    "", "{", "not json", "[1, 2, 3]", "null", '"camera"',
    json.dumps({**GOOD_CAMERA, "eye": "far away"}),
    json.dumps({**GOOD_CAMERA, "fov_deg": 0}),
    json.dumps({k: v for k, v in GOOD_CAMERA.items() if k != "target"}),
    json.dumps({**GOOD_CAMERA, "target": GOOD_CAMERA["eye"]}),
    json.dumps({**GOOD_CAMERA, "width": -3}),
    json.dumps({**GOOD_CAMERA, "eye": [0, 0, float("nan")]}),  # Python's json writes NaN
    json.dumps({**GOOD_CAMERA, "eye": [0, 0]}),
    "\ufeff\x00\x01binary",
], ids=lambda t: t[:20] or "empty")
def test_invalid_camera_json(tmp_path, text):
    path = tmp_path / "cam.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(PointvizError) as info:
        Camera.from_json(path)
    assert "cam.json" in str(info.value)


def test_valid_camera_json_loads(tmp_path):
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(GOOD_CAMERA))
    cam = Camera.from_json(path)
    assert cam.width == 64 and np.allclose(cam.eye, [0, 0, 5])


@pytest.mark.parametrize("mutate", ["not-json", "list", "no-keyframes", "keyframes-not-list",
                                    "bad-time", "duplicate-time", "nan-eye", "wrong-format",
                                    "eye-is-target",
                                    "empty-keyframes"])
def test_invalid_path_json(tmp_path, mutate):
    cloud = PointCloud(N, normals=N, radii=0.3)
    good = CameraPath.orbit(cloud, seconds=1, fps=4).to_dict()
    kfs = good["keyframes"]
    data = {
        "not-json": None, "list": [good],
        "no-keyframes": {k: v for k, v in good.items() if k != "keyframes"},
        "keyframes-not-list": {**good, "keyframes": {"0": kfs[0]}},
        "bad-time": {**good, "keyframes": [{**kfs[0], "time": "soon"}] + kfs[1:]},
        "duplicate-time": {**good, "keyframes": [kfs[0], {**kfs[1], "time": kfs[0]["time"]}]},
        "nan-eye": {**good, "keyframes": [{**kfs[0], "eye": [float("nan"), 0, 0]}] + kfs[1:]},
        "wrong-format": {**good, "format": "something.else"},
        "eye-is-target": {**good, "keyframes": [{**kfs[0], "eye": kfs[0]["target"]}] + kfs[1:]},
        "empty-keyframes": {**good, "keyframes": []},
    }[mutate]
    path = tmp_path / "path.json"
    path.write_text("{oops" if data is None else json.dumps(data))
    with pytest.raises(PointvizError) as info:
        CameraPath.load(path).camera_at(0.0)
    assert "path.json" in str(info.value)


# -- CLI ---------------------------------------------------------------------------------------


def _cli(args, cwd):
    proc = subprocess.run([sys.executable, "-m", "pointviz.cli", *args], cwd=cwd, check=False,
                          capture_output=True, text=True, timeout=120)
    return proc.returncode, proc.stdout, proc.stderr


def _cli_files(tmp_path):
    (tmp_path / "good.ply").write_bytes(S.ply_binary(S.sample_points(40)))
    (tmp_path / "trunc.ply").write_bytes(S.ply_binary(S.sample_points(40))[:-50])
    (tmp_path / "lie.pcd").write_bytes(S.pcd_header(10**12) + b"\0" * 100)
    (tmp_path / "garbage.las").write_bytes(b"LASF" + bytes(300))
    (tmp_path / "self.conf").write_text("bmesh self.conf 0 0 0 0 0 0 1\n")
    (tmp_path / "cam.json").write_text("{not json")
    (tmp_path / "badcam.json").write_text(json.dumps({**GOOD_CAMERA, "fov_deg": 0}))
    (tmp_path / "path.json").write_text("[]")
    (tmp_path / "exists.png").write_bytes(b"precious")


CLI_CASES = [
    ("missing-input", ["render", "nope.ply", "-o", "o.png"]),
    ("truncated-ply", ["render", "trunc.ply", "-o", "o.png"]),
    ("pcd-1e12", ["render", "lie.pcd", "-o", "o.png"]),
    ("garbage-las", ["render", "garbage.las", "-o", "o.png"]),
    ("recursive-conf", ["render", "self.conf", "-o", "o.png"]),
    ("camera-not-json", ["render", "demo", "-o", "o.png", "--camera", "cam.json"]),
    ("camera-fov-0", ["render", "demo", "-o", "o.png", "--camera", "badcam.json"]),
    ("camera-missing", ["render", "demo", "-o", "o.png", "--camera", "nocam.json"]),
    ("output-exists", ["render", "demo", "-o", "exists.png"]),
    ("output-folder-is-a-file", ["render", "demo", "-o", "exists.png/o.png"]),
    ("width-negative", ["render", "demo", "-o", "o.png", "--width", "-5"]),
    ("spp-zero", ["render", "demo", "-o", "o.png", "--spp", "0"]),
    ("lod-nan", ["render", "demo", "-o", "o.png", "--lod", "nan"]),
    ("threads-zero", ["render", "demo", "-o", "o.png", "--threads", "0"]),
    ("light-zero", ["render", "demo", "-o", "o.png", "--light", "0,0,0"]),
    ("light-garbage", ["render", "demo", "-o", "o.png", "--light", "up"]),
    ("fov-zero-on-a-file", ["render", "good.ply", "-o", "o.png", "--fov", "0"]),
    ("sample-negative", ["render", "trunc.ply", "-o", "o.png", "--sample", "-3"]),
    ("path-not-a-path", ["path", "demo", "path.json", "-o", "frames", "--scheduler", "serial"]),
    ("up-zero", ["render", "good.ply", "-o", "o.png", "--up", "0,0,0"]),
    ("up-garbage", ["render", "good.ply", "-o", "o.png", "--up", "sideways"]),
    ("up-nan", ["render", "good.ply", "-o", "o.png", "--up", "nan,1,0"]),
    ("up-on-the-demo", ["render", "demo", "-o", "o.png", "--up", "z"]),
]

#: argparse's own errors print a usage block before the message (several lines).
ARGPARSE_CASES = [
    ("unknown-command", ["bogus"]),
    ("width-not-int", ["render", "demo", "-o", "o.png", "--width", "abc"]),
    ("missing-output", ["render", "demo"]),
]


def test_cli_bad_inputs_print_one_line(tmp_path):
    """Every bad input: exit code 2, exactly one line on stderr, no traceback, no output file."""
    _cli_files(tmp_path)
    with ThreadPoolExecutor(max_workers=4) as pool:  # the interpreters start in parallel
        results = list(pool.map(lambda c: _cli(c[1], tmp_path), CLI_CASES))
    problems = []
    for (name, _), (code, _out, err) in zip(CLI_CASES, results):
        lines = err.strip().splitlines()
        if (code != 2 or "Traceback" in err or len(lines) != 1 or "error" not in err
                or "[Errno" in err):
            problems.append(f"{name}: exit {code}, stderr {err.strip()[-300:]!r}")
    assert not problems, "\n".join(problems)
    exists_err = results[[n for n, _ in CLI_CASES].index("output-exists")][2]
    assert exists_err.count("exists.png") == 1 and "--overwrite" in exists_err, exists_err
    assert (tmp_path / "exists.png").read_bytes() == b"precious"
    assert not (tmp_path / "o.png").exists() and not list(tmp_path.glob("*.part"))


def test_cli_argparse_errors_print_one_line(tmp_path):
    with ThreadPoolExecutor(max_workers=3) as pool:
        results = list(pool.map(lambda c: _cli(c[1], tmp_path), ARGPARSE_CASES))
    for (name, _), (code, _out, err) in zip(ARGPARSE_CASES, results):
        assert code == 2 and "Traceback" not in err, name
        assert len(err.strip().splitlines()) == 1, f"{name}: {err!r}"


def test_cli_up_option_sets_the_clouds_up(tmp_path):
    from pointviz.commands.common import parse_up

    assert parse_up("z") == (0, 0, 1) and parse_up("-Y") == (0, -1, 0)
    assert parse_up("+x") == (1, 0, 0) and parse_up("0, 0.5 ,2") == (0, 0.5, 2)
    assert parse_up(None) is None
    _cli_files(tmp_path)
    code, out, err = _cli(["info", "good.ply", "--json", "--up=-z"], tmp_path)
    assert code == 0, err
    assert json.loads(out)["up"] == [0.0, 0.0, -1.0]


def test_cli_reader_gone_ends_quietly(tmp_path):
    """`pointviz info F | head`: standard output's reader gone before the first line, the run
    ends without a traceback or an error line (a broken pipe is not the user's mistake)."""
    import os

    _cli_files(tmp_path)
    read_end, write_end = os.pipe()
    os.close(read_end)  # no reader from the start: the first write fails, deterministically
    try:
        proc = subprocess.run([sys.executable, "-m", "pointviz.cli", "info", "good.ply"],
                              cwd=tmp_path, stdout=write_end, stderr=subprocess.PIPE, text=True,
                              timeout=120, check=False)
    finally:
        os.close(write_end)
    assert proc.returncode == 141, proc.stderr
    assert proc.stderr == "", proc.stderr


def test_cli_bad_output_extension_fails_before_rendering(tmp_path):
    code, _, err = _cli(["render", "demo", "-o", "o.bmp", "--progress", "--width", "8",
                         "--height", "6", "--spp", "1"], tmp_path)
    assert code == 2 and "unsupported image format" in err
    assert "render [" not in err and "render:" not in err, "progress shows it rendered first"


def test_cli_fov_zero_on_demo_is_rejected(tmp_path):
    code, _, err = _cli(["render", "demo", "-o", "o.png", "--fov", "0", "--width", "8"], tmp_path)
    assert code == 2 and "fov" in err


def test_cli_warnings_print_one_line_each(tmp_path):
    """A warning raised while a command runs (here the reader's, for rows with NaN coordinates)
    is one line ``pointviz: FILE: what`` on stderr, not Python's module path and source echo;
    the command still succeeds. Oracle: the reader's own warning, caught in-process."""
    import warnings

    from pointviz.io import load

    rows = [f"{x:.3f} {y:.3f} {0.1 * x * y:.3f}" for x in range(8) for y in range(8)]
    rows[5] = "nan 1.0 2.0"
    rows[17] = "1.0 inf 2.0"
    (tmp_path / "holes.xyz").write_text("\n".join(rows) + "\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load(tmp_path / "holes.xyz", estimate=False)
    expected = " ".join(str(caught[0].message).split())
    assert "holes.xyz" in expected and "dropped 2 of 64" in expected, expected
    code, out, err = _cli(["info", "holes.xyz"], tmp_path)
    assert code == 0, err
    assert err.strip().splitlines() == [f"pointviz: {expected}"], err
    points = [line.split()[1] for line in out.splitlines() if line.split()[:1] == ["points"]]
    assert points == ["62"], out
