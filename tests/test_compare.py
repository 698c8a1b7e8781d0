"""pointviz.compare: the embreex mesh backend against surfels, metrics against numpy formulas,
determinism, the report (schema, images, headless Chromium) and the CLI."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from pointviz import Camera, InputError, render, shapes 
from pointviz.comparison import analytic, metrics 
from pointviz.meshes import MeshGeometry 
from pointviz.comparison.run import Settings, render_geometry 
from pointviz.comparison.schema import SCHEMA, builtin_errors, validate 
from pointviz.scene import Scene 
from pointviz.surfels import SurfelScene 

#: The mesh backend needs embreex; report scores need flip_evaluator (the 'compare' extra).
#: Tests of the metrics' numpy formulas need neither and always run.
needs_embreex = pytest.mark.skipif(importlib.util.find_spec("embreex") is None,
                                   reason="embreex is not installed: pip install 'pointviz[compare]'")
needs_flip = pytest.mark.skipif(importlib.util.find_spec("flip_evaluator") is None,
                                reason="flip_evaluator is not installed: pip install 'pointviz[compare]'")

TIMES = ("times",)


def _frames(width=120, height=90):
    cam = Camera.look_at((0.0, 0.7, 3.5), (0, 0, 0), width=width, height=height)
    v, f = analytic.sphere_mesh(1.0, res=256)
    mesh = render(Scene([MeshGeometry(v, f)], ground="none"), cam, spp=1)
    surf = render(Scene([SurfelScene(shapes.sphere(120_000), interpolation="smooth")],
                        ground="none"), cam, spp=1, lod_pixels=0)
    return mesh, surf


@needs_embreex
def test_mesh_backend_agrees_with_surfels_on_exact_sphere():
    mesh, surf = _frames()
    mm, sm = metrics.hit_mask(mesh.alpha), metrics.hit_mask(surf.alpha)
    assert metrics.iou(mm, sm) > 0.98
    # interior: away from the silhouette, where a pixel's samples all hit
    from scipy.ndimage import binary_erosion

    inner = binary_erosion(mm & sm, iterations=2)
    assert inner.sum() > 1000
    assert np.abs(mesh.depth[inner] - surf.depth[inner]).max() < 0.01  # radius 1
    assert metrics.normal_error_deg(mesh.normal, surf.normal, inner) < 2.0
    ang = np.degrees(np.arccos(np.clip((mesh.normal[inner] * surf.normal[inner]).sum(-1), -1, 1)))
    assert np.percentile(ang, 99) < 5.0


@needs_embreex
def test_mesh_queries_honour_tmin_tmax():
    v, f = analytic.sphere_mesh(1.0, res=64)
    g = MeshGeometry(v, f).local(np.zeros(3))  # the mesh in the frame centred on the origin
    rays = np.zeros((4, 8), np.float32)
    rays[:, 2] = 5.0
    rays[:, 5] = -1.0
    rays[:, 7] = np.inf
    rays[1, 7] = 3.5      # stops before the sphere
    rays[2, 6] = 4.5      # starts inside: the back of the sphere at t ~ 6
    rays[3, :3] = (3.0, 0, 5)  # misses
    t, n, c, r = g.intersect(rays)
    assert t[0] == pytest.approx(4.0, abs=1e-3) and np.isinf(t[1]) and np.isinf(t[3])
    assert t[2] == pytest.approx(6.0, abs=1e-3)
    assert np.allclose(np.linalg.norm(n[[0, 2]], axis=1), 1, atol=1e-5)
    assert (r[[0, 2]] > 0).all() and all(a.flags.c_contiguous for a in (t, n, c, r))
    occ = g.occluded(rays)
    assert occ.dtype == bool and occ.tolist() == [True, False, True, False]
    rays[0, 7] = 3.99
    assert not g.occluded(rays[:1])[0]


@needs_embreex
def test_mesh_geometry_rejects_bad_input():
    with pytest.raises(InputError, match="faces"):
        MeshGeometry(np.zeros((3, 3)), np.array([[0, 1, 3]]))
    with pytest.raises(InputError, match="vertices"):
        MeshGeometry(np.zeros((3, 2)), np.array([[0, 1, 2]]))


def test_psnr_of_known_noise(rng):
    a = rng.random((40, 50, 3))
    b = a + rng.choice([-0.05, 0.05], size=a.shape)  # mse = 0.0025 exactly
    assert metrics.psnr(a, b) == pytest.approx(10 * np.log10(1 / 0.0025), abs=1e-9)
    assert metrics.psnr(a, a) == np.inf
    assert metrics.ssim(a, a) == pytest.approx(1.0)
    assert metrics.ssim(a, b) < 1.0


def test_iou_holes_depth_of_known_masks():
    a = np.zeros((10, 10), bool)
    b = np.zeros((10, 10), bool)
    a[:, :6] = True   # 60 pixels
    b[:, 4:] = True   # 60 pixels, 20 shared
    assert metrics.iou(a, b) == pytest.approx(20 / 100)
    assert metrics.holes(a, b) == pytest.approx(40 / 60)
    d1, d2 = np.full((10, 10), 2.0), np.full((10, 10), 2.5)
    assert metrics.depth_error(d1, d2, a & b, diagonal=5.0) == pytest.approx(0.1)


def test_normal_error_of_known_rotations(rng):
    n = rng.normal(size=(8, 8, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    angles = rng.uniform(0, 60, size=(8, 8))
    axis = np.cross(n, rng.normal(size=3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    th = np.radians(angles)[..., None]
    # Rodrigues with the axis perpendicular to n: rotates n by exactly the angle
    rot = n * np.cos(th) + np.cross(axis, n) * np.sin(th)
    mask = np.ones((8, 8), bool)
    assert metrics.normal_error_deg(n, rot, mask) == pytest.approx(angles.mean(), abs=1e-6)


@needs_flip
def test_flip_is_zero_for_identical_and_grows_with_error(rng):
    a = rng.random((32, 32, 3))
    f0, m0 = metrics.flip(a, a)
    f1, m1 = metrics.flip(a, np.clip(a + 0.2, 0, 1))
    assert f0 == 0 and f1 > 0.05 and m1.shape == (32, 32, 3)


def test_pareto_front():
    from pointviz.comparison.report import pareto

    pts = [(1, 5), (2, 3), (3, 4), (4, 1), (0.5, 9)]
    assert pareto(pts) == [4, 0, 1, 3]


def test_builtin_validator_catches_violations():
    doc = {"schema": "pointviz.compare/1", "input": "x", "reference": {"kind": "mesh"},
           "image": {"width": 4, "height": 4, "spp": 1}, "entries": []}
    errs = builtin_errors(doc)
    assert any("fewer than 1" in e for e in errs)
    doc["image"]["width"] = "4"
    assert any("/image/width" in e for e in builtin_errors(doc))
    with pytest.raises(InputError, match="schema"):
        validate(doc)


@needs_embreex
@needs_flip
def test_identical_settings_give_identical_metrics(tmp_path):
    from pointviz.comparison import compare

    def run(d):
        doc = compare("sphere", out_dir=tmp_path / d, methods=["surfels-smooth", "poisson"],
                      quick=True, log=lambda *_: None)
        return [(e["label"], e["metrics"]) for e in doc["entries"]]

    assert run("a") == run("b")


def test_unknown_method_is_an_input_error(tmp_path):
    from pointviz.comparison import compare

    with pytest.raises(InputError, match="methods"):
        compare("sphere", out_dir=tmp_path, methods=["nerf"], quick=True)


@needs_embreex
@needs_flip
def test_report_states_exactly_the_render_settings_used(tmp_path, monkeypatch):
    import html
    import re

    import pointviz.rendering
    from pointviz.comparison import compare
    from pointviz.settings import RenderSettings

    used = []
    real = pointviz.rendering.render

    def spy(scene, camera, **kw):  # what the comparison really passes to render()
        used.append(RenderSettings(**kw).to_json())
        return real(scene, camera, **kw)

    monkeypatch.setattr(pointviz.rendering, "render", spy)
    doc = compare("sphere", out_dir=tmp_path, methods=["surfels-smooth"], quick=True,
                  log=lambda *_: None)
    data = json.loads((tmp_path / "metrics.json").read_text())
    validate(data)
    assert used and list(data["render"]) == list(RenderSettings.names())
    # every frame used the stated settings, but for its level of detail and (the surfel
    # reference) its samples
    for u in used:
        assert {k: v for k, v in u.items() if k not in ("lod_pixels", "spp")} == \
            {k: v for k, v in data["render"].items() if k not in ("lod_pixels", "spp")}
    assert {u["lod_pixels"] for u in used} == {0.0} | {e["settings"]["lod_pixels"]
                                                       for e in doc["entries"]}
    page = (tmp_path / "index.html").read_text()
    table = re.search(r'<table id="render-settings">(.*?)</table>', page, re.S).group(1)
    rows = re.findall(r"<tr><td>(.*?)</td><td>(.*?)</td><td>(.*?)</td><td>(.*?)</td>"
                      r"<td>(.*?)</td></tr>", table)
    assert [r[0] for r in rows] == list(RenderSettings.names())
    defaults, meta = RenderSettings(), RenderSettings.__dataclass_fields__
    for name, value, default, _accepts, meaning in rows:
        assert value == html.escape(str(data["render"][name]))
        assert default == html.escape(str(getattr(defaults, name)))
        assert meaning == html.escape(meta[name].metadata["help"])


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory):
    """One quick report with every method and the stability sweeps (shared by the tests)."""
    import pointviz

    out = tmp_path_factory.mktemp("report")
    doc = pointviz.compare("demo", out_dir=out, quick=True, stability=True, log=lambda *_: None)
    return out, doc


@needs_embreex
@needs_flip
@pytest.mark.slow
def test_report_files_schema_and_images(quick_report):
    out, doc = quick_report
    methods = {e["method"] for e in doc["entries"]}
    assert {"discs", "surfels-paper", "surfels-smooth", "poisson", "ball-pivoting"} <= methods
    data = json.loads((out / "metrics.json").read_text())
    validate(data)
    assert builtin_errors(data) == []
    assert json.loads((out / "metrics.schema.json").read_text()) == json.loads(json.dumps(SCHEMA))
    for e in data["entries"]:
        t = e["times"]
        assert t["first_image"] == pytest.approx(t["preprocess"] + t["render"])
    import re

    import imageio.v3 as iio

    page = (out / "index.html").read_text()
    srcs = re.findall(r'<img src="([^"]+)"', page)
    assert "speed_accuracy.png" in srcs and "side_by_side.png" in srcs and "stability.png" in srcs
    for s in srcs:
        assert "/" not in s and (out / s).is_file()
        assert iio.imread(out / s).size > 0
    assert len(doc["stability"]["summary"]) == 6
    assert all("trust" in s for s in doc["stability"]["summary"])


@needs_embreex
@needs_flip
@pytest.mark.slow
def test_report_renders_in_headless_chromium(quick_report, tmp_path):
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("chromium is not installed")
    out, _ = quick_report
    shot = tmp_path / "shot.png"
    url = (out / "index.html").as_uri()
    base = [exe, "--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
            f"--user-data-dir={tmp_path / 'profile'}"]
    r = subprocess.run(base + [f"--screenshot={shot}", "--window-size=1300,2400",
                               "--enable-logging=stderr", "--v=0", url],
                       capture_output=True, text=True, timeout=120)
    assert shot.is_file() and shot.stat().st_size > 10_000, r.stderr[-2000:]
    console = [ln for ln in r.stderr.splitlines() if "CONSOLE" in ln or "Uncaught" in ln]
    assert console == []
    dom = subprocess.run(base + ["--dump-dom", url], capture_output=True, text=True, timeout=120)
    assert "speed_accuracy.png" in dom.stdout and "Where methods fail" in dom.stdout


@needs_embreex
@needs_flip
def test_cli_compare_quick(tmp_path, capsys):
    from pointviz.cli import main

    rc = main(["compare", "sphere", "-o", str(tmp_path / "r"), "--quick", "--methods",
               "discs,ball-pivoting"])
    assert rc == 0
    assert (tmp_path / "r" / "index.html").is_file()
    assert "wrote" in capsys.readouterr().out
    assert main(["compare", "sphere", "-o", str(tmp_path / "s"), "--quick", "--methods",
                 "nope"]) == 2
    # --up frames the view (and places the ground) about the given axis
    assert main(["compare", "sphere", "-o", str(tmp_path / "z"), "--quick", "--methods",
                 "discs", "--up", "z"]) == 0
    camera = json.loads((tmp_path / "z" / "metrics.json").read_text())["camera"]
    assert camera["up"] == [0.0, 0.0, 1.0]
    assert main(["compare", "sphere", "-o", str(tmp_path / "w"), "--quick", "--up", "w"]) == 2


@needs_embreex
@needs_flip
@pytest.mark.data
@pytest.mark.slow
def test_armadillo_mesh_is_its_own_reference(shared_data, tmp_path):
    from pointviz.comparison import compare

    s = Settings.quick()
    doc = compare(shared_data / "stanford_armadillo" / "Armadillo.ply", out_dir=tmp_path,
                  methods=["surfels-smooth"], settings=s, log=lambda *_: None)
    assert doc["reference"]["kind"] == "mesh"
    assert doc["entries"][0]["metrics"]["iou"] > 0.9


@needs_embreex
def test_mesh_backend_renders_from_several_threads_at_once():
    """Two Python threads render the same embreex mesh scene concurrently (each render calls
    back into Python from its own C++ thread, taking the GIL): frames equal the serial one."""
    import threading

    from pointviz import Camera, Scene, render
    from pointviz.comparison import analytic

    v, f = analytic.sphere_mesh(1.0, res=48)
    scene = Scene([MeshGeometry(v, f)], ground="matte")
    cam = Camera.look_at((0.0, 0.5, 4.0), (0, 0, 0), width=64, height=48)
    serial = render(scene, cam, spp=2, seed=3)
    frames, errors = [None, None], []

    def work(i):
        try:
            frames[i] = render(scene, cam, spp=2, seed=3)
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not errors, errors
    for fr in frames:
        np.testing.assert_array_equal(fr.color, serial.color)



def test_a_coarse_reference_mesh_is_flagged_in_the_report(tmp_path):
    """The dragon's case: a 23k-vertex reference for 469k scanned points favours smooth
    reconstructions, and the report must say so; a fine one, or an analytic one, gets no note."""
    from pointviz.comparison.run import COARSE_REFERENCE_FRACTION, reference_note

    note = reference_note("mesh", 22_998, 469_193)
    assert "coarse" in note and "22,998" in note and "favours smooth reconstructions" in note
    assert reference_note("mesh", 172_974, 172_974) is None
    assert reference_note("analytic", 10, 469_193) is None
    n = 1000
    assert reference_note("mesh", int(COARSE_REFERENCE_FRACTION * n) - 1, n) is not None
    assert reference_note("mesh", int(COARSE_REFERENCE_FRACTION * n), n) is None

    import pointviz
    from pointviz.cloud import PointCloud

    trimesh = pytest.importorskip("trimesh")
    ref = trimesh.creation.icosphere(subdivisions=1)  # 42 vertices
    ref_path = tmp_path / "coarse.ply"
    ref.export(str(ref_path))
    rng = np.random.default_rng(3)
    p = rng.normal(size=(3000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    pts_path = tmp_path / "points.xyzn"
    np.savetxt(pts_path, np.hstack([p, p]), fmt="%.7f")
    assert isinstance(pointviz.load(pts_path), PointCloud)
    out = tmp_path / "report"
    doc = pointviz.compare(pts_path, reference=ref_path, out_dir=out, quick=True,
                           methods=["surfels-smooth"], log=lambda *_: None)
    assert doc["reference"]["vertices"] == 42 and "coarse" in doc["reference"]["note"]
    assert doc["load_seconds"] > 0
    page = (out / "index.html").read_text()
    assert "Note on the reference" in page and "42 vertices for 3,000 input points" in page
    for e in doc["entries"]:
        assert e["times"]["render"] >= e["times"]["render_in_core"] > 0


@needs_embreex
@needs_flip
@pytest.mark.slow
def test_raw_scans_surfels_are_those_of_render_and_pay_their_own_normals(tmp_path):
    """On registered raw scans the surfels are fitted as `pointviz render` fits them (from the
    raw points, normals estimated by the fit), and their times hold the fit instead of the
    shared normals, which are the meshes'."""
    import pointviz
    from pointviz.comparison.scans import virtual_scans

    raw, _ = virtual_scans("torus", scans=4, resolution=40, noise=0.002, seed=3)
    assert raw.is_raw_scan and len(raw) < Settings.quick().max_points
    expected = pointviz.PointCloud(raw.points, viewpoints=raw.viewpoints,
                                   scan_index=raw.scan_index).fitted()
    doc = pointviz.compare(raw, out_dir=tmp_path, methods=["surfels-smooth", "poisson"],
                           quick=True, log=lambda *_: None)
    surfels = [e for e in doc["entries"] if e["method"] == "surfels-smooth"]
    meshes = [e for e in doc["entries"] if e["method"] == "poisson"]
    assert surfels and meshes
    for e in surfels:
        assert e["geometry"]["surfels"] == len(expected)
        assert set(e["times"]["steps"]) == {"fit", "radii", "tree"}
    for e in meshes:
        assert "normals" in e["times"]["steps"]


@needs_embreex
@needs_flip
def test_a_meshs_bvh_counts_once_in_its_first_image(tmp_path, monkeypatch):
    """The mesh's Embree BVH is built inside its first render() call: its time is the "bvh"
    step and not also part of the "render" time (the first image counts it once), as the
    surfels' tree is the "tree" step only. A BVH build made 1 s slower shows where it goes."""
    import time

    import pointviz
    from pointviz import meshes

    build = meshes.LocalMesh.__init__

    def slow_build(self, *a, **kw):
        build(self, *a, **kw)
        time.sleep(1.0)
        self.build_seconds += 1.0

    monkeypatch.setattr(meshes.LocalMesh, "__init__", slow_build)
    doc = pointviz.compare("sphere", out_dir=tmp_path, methods=["poisson"], quick=True,
                           log=lambda *_: None)
    for e in doc["entries"]:
        t = e["times"]
        assert t["steps"]["bvh"] >= 1.0
        assert t["render"] < 1.0  # (the render alone: a 160x120 frame of a small mesh)
        assert t["first_image"] == pytest.approx(t["preprocess"] + t["render"])
