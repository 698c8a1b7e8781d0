"""The viewer: settings model and render worker (no display needed), then both GUI backends run
in a subprocess under the X display (``xvfb-run -a python -m pytest tests/test_viewer.py``).

Oracle for the ray-traced panel: ``pointviz.render`` called directly with the camera and settings
the viewer reports; the frame must be identical (same seed), and the screenshot's frame region
must show that frame (loose tolerance: scaling and the widget's own filtering).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import threading

import numpy as np
import pytest

from pointviz import Camera, render
from pointviz.errors import CancelledError, InputError
from pointviz.shapes import sphere
from pointviz.viewer import model
from pointviz.viewer.worker import RenderWorker

#: Mean absolute difference (0..255) allowed between the screenshot's frame region and the
#: frame itself (widget scaling/filtering; a wrong or missing image differs by > 40).
SCREENSHOT_TOLERANCE = 12.0
#: A panel is "not blank" when its pixel standard deviation exceeds this.
NOT_BLANK_STD = 8.0
#: Mean absolute difference (8-bit levels) allowed between the live viewport as grabbed and the
#: live frame the window was last given (the automation's live_view_difference): the viewport
#: shows the frame's own pixels (0.35-0.36 measured in 12 runs at load 5-12; 10.3 with Open3D's
#: post-processing on, which re-mapped the colours).
LIVE_VIEW_MATCH_LEVELS = 2.0
#: Subprocess time limit, seconds: a GUI start plus a small render takes ~5 s idle and over a
#: minute at load 16 on two cores; only a hang should reach this.
GUI_TIMEOUT_S = 900
#: Worker must end this soon after Cancel or close, seconds: the core polls the cancel flag
#: every few ms of work, but a nice +10 tracer next to a loaded machine gets little CPU; only a
#: worker that ignores the flag takes this long.
STOP_TIMEOUT_S = 60.0

CLOUD_SNIPPET = "from pointviz.shapes import sphere\ncloud = sphere(6000, color=(0.8, 0.35, 0.2))\n"


def small_cloud():
    return sphere(6000, color=(0.8, 0.35, 0.2))


# ------------------------------------------------------------------------------ model, worker


def test_settings_reject_bad_fields_by_name():
    with pytest.raises(InputError, match="color_mode"):
        model.ViewerSettings(color_mode="rainbow")
    with pytest.raises(InputError, match="spp"):
        model.ViewerSettings().updated(spp=0)
    with pytest.raises(InputError, match="ground"):
        model.ViewerSettings(ground="lava")


def test_light_angles_roundtrip(rng):
    for up in ([0, 1, 0], [0, 0, 1], rng.normal(size=3)):
        for _ in range(5):
            az, el = rng.uniform(-179, 179), rng.uniform(-80, 80)
            d = model.light_direction(az, el, up)
            assert np.isclose(np.linalg.norm(d), 1.0)
            az2, el2 = model.light_angles(d, up)
            assert np.allclose([az, el], [az2, el2], atol=1e-9)
    # elevation 90 is straight up
    assert np.allclose(model.light_direction(0, 90, [0, 0, 1]), [0, 0, 1])


def test_camera_from_gl_recovers_camera():
    cam = Camera.look_at((1.0, 2.0, 5.0), (0.2, 0.1, -0.3), up=(0, 1, 0), fov_deg=35,
                         width=320, height=200)
    gl_view = np.diag([1.0, -1.0, -1.0, 1.0]) @ cam.extrinsic_matrix()  # +Y up, looking down -Z
    t = 1.0 / cam.tan_half
    proj = np.array([[t / cam.aspect, 0, 0, 0], [0, t, 0, 0], [0, 0, -1, -0.2], [0, 0, -1, 0]])
    out = model.camera_from_gl(gl_view, proj, 320, 200, cam.distance)
    # same view (up comes back as the true up, so compare the rays and the target)
    np.testing.assert_allclose(out.rays(dtype=np.float64), cam.rays(dtype=np.float64), atol=1e-9)
    np.testing.assert_allclose(out.target, cam.target, atol=1e-9)


def test_preview_subset_is_bounded_and_stated():
    scene = model.as_scene(small_cloud())
    full = model.preview_data(scene, model.ViewerSettings())
    assert not full.is_subset and len(full.points) == 6000
    sub = model.preview_data(scene, model.ViewerSettings(preview_max_points=1500))
    assert sub.is_subset and len(sub.points) == 1500 and "subset" in sub.note
    # radii grow so that 4x fewer disks still cover the surface: area ratio = 4
    assert np.isclose(np.median(sub.radii) ** 2 / np.median(full.radii) ** 2, 4.0, rtol=0.05)
    for mode in model.COLOR_MODES:
        d = model.preview_data(scene, model.ViewerSettings(color_mode=mode))
        assert d.colors.shape == (6000, 3) and d.colors.min() >= 0 and d.colors.max() <= 1


def test_preview_subset_is_even_along_the_cloud():
    """One point from each of m equal stretches of the Z-order curve: on points along a line
    (where the curve is the line's order) no two kept points are more than two stretches apart,
    which a random subset of the same size is not."""
    n, m = 100_000, 1000
    x = np.sort(np.random.default_rng(3).random(n))
    pts = np.stack([x, np.zeros(n), np.zeros(n)], axis=1)
    idx = model.stratified_subset(pts, m, np.random.default_rng(0))
    assert len(idx) == m and np.all(np.diff(idx) > 0)
    assert np.diff(idx).max() <= 2 * n / m
    rand = np.sort(np.random.default_rng(0).choice(n, m, replace=False))
    assert np.diff(rand).max() > 2 * n / m
    assert np.array_equal(model.stratified_subset(pts, n, np.random.default_rng(0)), np.arange(n))


def test_preview_colours_are_shaded_by_the_viewer_lights():
    """Unlit preview points carry their lighting in their colours: a surface facing straight down
    (away from the key and fill lights, both above the horizon, and from the sky) keeps the
    ambient share only; one facing the key light is brighter than one facing away; the result
    stays in [0, 1]."""
    s = model.ViewerSettings()
    up = np.array([0.0, 0.0, 1.0])
    key = model.light_direction(s.light_azimuth_deg, s.light_elevation_deg, up)
    normals = np.array([-up, key, -key], dtype=np.float32)
    colors = np.full((3, 3), 0.5, np.float32)
    out = model.shade_colors(colors, normals, s, up)
    np.testing.assert_allclose(out[0], 0.5 * model.PREVIEW_SHADE["ambient"], rtol=1e-6)
    assert out[1].mean() > out[2].mean() > out[0].mean() - 1e-6
    white = model.shade_colors(np.ones((3, 3), np.float32), normals, s, up)
    assert white.min() >= 0.0 and white.max() <= 1.0


def _run_worker(scene, settings, camera, cancel_after_first=False):
    done = threading.Event()
    box = {"progress": 0}

    def progress(job_id, d, t):
        box["progress"] += 1
        if cancel_after_first:
            worker.cancel()

    worker = RenderWorker(progress, lambda j, r: (box.update(result=r), done.set()),
                          lambda j, e: (box.update(error=e), done.set()))
    worker.submit(scene, settings, camera)
    assert done.wait(120)
    assert worker.shutdown(STOP_TIMEOUT_S)
    return box


def test_worker_frame_equals_direct_render():
    scene = model.as_scene(small_cloud())
    settings = model.ViewerSettings(spp=2, ground="mirror", light_azimuth_deg=30)
    camera = Camera.fit(small_cloud(), width=96, height=72)
    box = _run_worker(scene, settings, camera)
    assert "error" not in box
    direct = render(model.render_scene(scene, settings), camera, **settings.render_kwargs())
    np.testing.assert_array_equal(box["result"].frame.color, direct.color)
    assert box["progress"] >= 1


def test_worker_frame_shows_the_sides_asked_for():
    """The viewer's Sides setting reaches the tracer: on a closed torus (culled by its scene's
    own choice) "two" adds the rim's back faces that "one" leaves out, and each frame is the
    direct render's with that setting."""
    from pointviz.shapes import torus

    cloud = torus(6000)
    scene = model.as_scene(cloud)
    camera = Camera.fit(cloud, width=96, height=72)
    covered = {}
    for sides in ("one", "two"):
        settings = model.ViewerSettings(spp=1, ground="none", sides=sides)
        box = _run_worker(scene, settings, camera)
        assert "error" not in box
        frame = box["result"].frame
        direct = render(model.render_scene(scene, settings), camera, **settings.render_kwargs())
        np.testing.assert_array_equal(frame.color, direct.color)
        covered[sides] = int((frame.object_alpha > 0).sum())
    assert covered["two"] > covered["one"]


def test_worker_cancel_reports_cancelled_and_ends():
    scene = model.as_scene(small_cloud())
    settings = model.ViewerSettings(spp=512)
    camera = Camera.fit(small_cloud(), width=320, height=240)
    box = _run_worker(scene, settings, camera, cancel_after_first=True)
    assert isinstance(box.get("error"), CancelledError)


# ------------------------------------------------------------------------------ GUI backends

needs_display = pytest.mark.skipif(
    not os.environ.get("DISPLAY"),
    reason="no X display: run the GUI tests under xvfb-run -a (Debian package xvfb)")


#: Appended to every GUI script: exit without interpreter teardown, where Open3D 0.20's GUI
#: sometimes crashes (see pointviz.commands.view.EXIT_WITHOUT_TEARDOWN).
EXIT_SNIPPET = "\nimport os, sys\nsys.stdout.flush()\nsys.stderr.flush()\nos._exit(0)\n"


def _python(script: str, cwd) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(script) + EXIT_SNIPPET], cwd=cwd, env=env,
                         check=False, capture_output=True, text=True, timeout=GUI_TIMEOUT_S)
    assert out.returncode == 0, f"viewer failed ({out.returncode}):\n{out.stderr[-3000:]}"
    return out


def _driver_result(out) -> dict:
    """The RESULT line a driver script printed; fails with the driver's traceback if any."""
    line = [x for x in out.stdout.splitlines() if x.startswith("RESULT")][-1]
    res = json.loads(line[len("RESULT"):])
    assert "error" not in res, res["error"]
    return res


def _load_png(path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))


def _check_screenshot_and_frame(tmp_path, shot, rects):
    """Preview and frame panels are not blank, the frame equals a direct render, and the
    screenshot's frame panel shows it."""
    data = np.load(tmp_path / "frame.npz")
    camera = Camera.from_dict({k: v for k, v in json.loads(str(data["camera"])).items()
                               if k not in ("format", "version")})
    report = json.loads((tmp_path / "report.json").read_text())
    settings = model.ViewerSettings(**report["settings"])
    scene = model.as_scene(small_cloud())
    direct = render(model.render_scene(scene, settings), camera, **settings.render_kwargs())
    np.testing.assert_array_equal(data["color"], direct.color)

    x, y, w, h = rects["preview"]
    assert shot[y:y + h, x:x + w].std() > NOT_BLANK_STD, "preview panel is blank"
    x, y, w, h = rects["result"]
    panel = shot[y:y + h, x:x + w].astype(np.float64)
    assert panel.std() > NOT_BLANK_STD, "ray-traced panel is blank"
    expected = direct.to_srgb8().astype(np.float64)
    # the widget shows the frame scaled to fit, centred: crop the panel to the frame's aspect
    fh, fw = expected.shape[:2]
    scale = min(w / fw, h / fh)
    sw, sh = round(fw * scale), round(fh * scale)
    ox, oy = (w - sw) // 2, (h - sh) // 2
    shown = panel[oy:oy + sh, ox:ox + sw]
    rows = np.minimum((np.arange(sh) / scale).astype(int), fh - 1)
    cols = np.minimum((np.arange(sw) / scale).astype(int), fw - 1)
    resized = expected[rows][:, cols]
    diff = np.abs(shown - resized).mean()
    assert diff < SCREENSHOT_TOLERANCE, f"frame panel differs from the frame: {diff:.1f}/255"
    # and it is not just any image: against a flipped frame the difference is large
    assert np.abs(shown - resized[::-1]).mean() > diff + 5


@pytest.mark.gui
@needs_display
@pytest.mark.parametrize("backend", ["open3d", "pyvista"])
def test_view_render_screenshot_matches_direct_render(tmp_path, backend):
    _python(f"""
        {CLOUD_SNIPPET.replace(chr(10), chr(10) + '        ')}
        import pointviz
        pointviz.view(cloud, backend={backend!r}, render=True, screenshot="shot.png",
                      frame="frame.npz", report="report.json", spp=2)
        """, tmp_path)
    shot = _load_png(tmp_path / "shot.png")
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["timings"]["worker_ended_on_close"] is True
    _check_screenshot_and_frame(tmp_path, shot, report["rects"])


@pytest.mark.gui
@needs_display
def test_view_cli_exits_zero_with_screenshot(tmp_path):
    import open3d as o3d  # the CLI reads a file: write the cloud as PLY

    ply = tmp_path / "sphere.ply"
    assert o3d.io.write_point_cloud(str(ply), small_cloud().to_open3d())
    out = subprocess.run([sys.executable, "-m", "pointviz.cli", "view", str(ply), "--render",
                          "--spp", "1", "--screenshot", str(tmp_path / "cli.png")],
                         check=False, capture_output=True, text=True, timeout=GUI_TIMEOUT_S)
    assert out.returncode == 0, out.stderr[-2000:]
    assert _load_png(tmp_path / "cli.png").std() > NOT_BLANK_STD


#: GUI-thread round trips timed while the render runs.
LATENCY_CALLS = 30
#: Longest a GUI-thread call may wait during a render. The target is 100 ms
#: (benchmarks/bench_viewer.py measures it, idle and with every core busy); this bound is what
#: the test can promise on a shared machine under Xvfb's software renderer, where one redraw of
#: the window takes up to ~0.4 s, yet a starved GUI (the tracer at normal priority on every
#: core: several seconds without an answer) fails it.
MAX_GUI_LATENCY_S = 1.5


@pytest.mark.gui
@needs_display
def test_open3d_ui_answers_during_render_and_cancel_close_stop_worker(tmp_path):
    """A render that cannot finish during the test (spp 4096): GUI-thread calls keep completing
    while it runs, within MAX_GUI_LATENCY_S; Cancel ends the worker; closing the window
    mid-render ends it too. Every wait is on an observed state, never a sleep; a failure in the
    driver closes the window at once and fails the test with its traceback."""
    out = _python(f"""
        {CLOUD_SNIPPET.replace(chr(10), chr(10) + '        ')}
        import json, threading, time, traceback
        import pointviz
        res = {{}}

        def wait_for(v, what, cond, timeout=120):
            deadline = time.monotonic() + timeout
            while not v.call(cond, redraw=False):     # one GUI round trip per check
                assert time.monotonic() < deadline, f"{{what}}: not within {{timeout}} s"

        def drive(v):
            try:
                v.call(v._on_render)                  # the Render button's handler
                wait_for(v, "first progress report", lambda: v.progress.value > 0)
                lat = []
                for _ in range({LATENCY_CALLS}):
                    t = time.perf_counter(); v.call(lambda: None, redraw=False); lat.append(time.perf_counter() - t)
                res["running_during"] = v.worker.running
                res["max_latency_s"] = max(lat)
                t = time.monotonic(); v.call(v._on_cancel)  # the Cancel button's handler
                th = v.worker.thread; th.join({STOP_TIMEOUT_S})
                res["cancel_join_s"] = time.monotonic() - t
                res["ended_after_cancel"] = not th.is_alive()
                wait_for(v, "label after cancel", lambda: v.render_label.text == "cancelled", 30)
                v.call(v._on_render)
                wait_for(v, "second render under way", lambda: v.progress.value > 0)
                res["thread2"] = v.worker.thread
                v.call(v.window.close)                # close mid-render
            except BaseException:
                res["error"] = traceback.format_exc()
                v.app.post_to_main_thread(v.window, v.window.close)

        v = pointviz.view(cloud, spp=4096, width=640, height=480,
                          on_ready=lambda v: threading.Thread(target=drive, args=(v,), daemon=True).start())
        th = res.pop("thread2", None)
        res["ended_after_close"] = th is not None and not th.is_alive()
        res["worker_ended_on_close"] = v.timings.get("worker_ended_on_close")
        print("RESULT" + json.dumps(res))
        """, tmp_path)
    res = _driver_result(out)
    print("viewer responsiveness:", res)
    assert res["running_during"], "the render ended before the latency was measured"
    assert res["max_latency_s"] < MAX_GUI_LATENCY_S, res
    assert res["ended_after_cancel"] and res["cancel_join_s"] < STOP_TIMEOUT_S
    assert res["ended_after_close"] and res["worker_ended_on_close"]


#: Seconds the heap-poisoned window below may take to open, draw and close (~5 s idle, under a
#: minute at load 16); the draw it guards against never ended in the 2.5-5 minutes it was watched.
POISONED_HEAP_TIMEOUT_S = 240

#: Run in the viewer's process before every geometry upload: free heap chunks of every small
#: size, each float slot holding a large value that grows with its offset. It is what a busy
#: process's heap may hold when Open3D mallocs a vertex buffer (glibc hands the next malloc of
#: that size the last chunk freed), so whatever Open3D leaves unwritten there is large.
POISON_HEAP_SNIPPET = """
import ctypes
import numpy as np
import open3d as o3d

libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]

def poison_heap():
    chunks = []
    for size in range(64, 1024, 8):
        floats = (np.arange(size // 4, dtype=np.float32) + 1) * 1e4
        for _ in range(8):
            p = libc.malloc(size)
            ctypes.memmove(p, floats.ctypes.data, size)
            chunks.append(p)
    for p in reversed(chunks):
        libc.free(p)

Scene = o3d.visualization.rendering.Open3DScene
_add_geometry = Scene.add_geometry
def add_geometry(self, *args, **kwargs):
    poison_heap()
    return _add_geometry(self, *args, **kwargs)
Scene.add_geometry = add_geometry
"""


@pytest.mark.gui
@needs_display
def test_open3d_preview_draws_and_closes_whatever_the_heap_held(tmp_path):
    """The preview's ground quad must not depend on uninitialised memory. Open3D uploads a mesh
    without texture coordinates with its per-vertex UVs unwritten (heap garbage), and its lit
    material samples textures with anisotropic filtering: on Mesa's software rasteriser
    (llvmpipe) large garbage UVs make every ground pixel loop over millions of texels, and the
    window hangs in its first draw (what a loaded machine's test runs hit by chance). Here the
    heap is filled with large floats before every upload, so such a draw would happen every
    time: the window must open, draw and close within POISONED_HEAP_TIMEOUT_S."""
    out = _python(f"""
        import faulthandler
        faulthandler.dump_traceback_later({POISONED_HEAP_TIMEOUT_S}, exit=True)
        {POISON_HEAP_SNIPPET.replace(chr(10), chr(10) + '        ')}
        {CLOUD_SNIPPET.replace(chr(10), chr(10) + '        ')}
        import json, threading, traceback
        import pointviz
        res = {{}}

        def drive(v):
            try:
                for _ in range(3):                    # draw the preview (ground and splats)
                    v.call(v.window.post_redraw, timeout={POISONED_HEAP_TIMEOUT_S})
                res["ground"] = v.call(lambda: v.preview.scene.has_geometry("ground"))
            except BaseException:
                res["error"] = traceback.format_exc()
            v.app.post_to_main_thread(v.window, v.window.close)

        v = pointviz.view(cloud, ground="matte", width=96, height=72,
                          on_ready=lambda v: threading.Thread(target=drive, args=(v,), daemon=True).start())
        print("RESULT" + json.dumps(res))
        """, tmp_path)
    assert _driver_result(out)["ground"], "the preview showed no ground: nothing was tested"


def test_worker_compare_renders_the_reconstructed_mesh_with_the_same_view():
    """The Compare-with-mesh action: the worker reconstructs (Poisson) and renders the mesh with
    the same camera and shading; on a sphere both pictures cover the same pixels."""
    pytest.importorskip("embreex", reason="the mesh backend needs embreex")
    cloud = small_cloud()
    scene = model.as_scene(cloud)
    settings = model.ViewerSettings(spp=1, ground="none")
    camera = Camera.fit(cloud, width=80, height=60)
    done, box = threading.Event(), {}
    worker = RenderWorker(lambda *a: None, lambda j, r: (box.update(result=r), done.set()),
                          lambda j, e: (box.update(error=e), done.set()))
    worker.submit(scene, settings, camera, compare=True)
    assert done.wait(120) and worker.shutdown(STOP_TIMEOUT_S)
    assert "error" not in box, box.get("error")
    result = box["result"]
    assert result.mesh_frame is not None and "Poisson" in result.mesh_note
    a, b = result.frame.alpha > 0.5, result.mesh_frame.alpha > 0.5
    assert (a & b).sum() / (a | b).sum() > 0.95
    both = a & b
    diff = np.abs(result.frame.color - result.mesh_frame.color).mean(axis=2)[both]
    assert np.median(diff) < 0.05


def test_keyframes_make_a_path_that_the_cli_reads(tmp_path):
    """Add keyframe / Save path: cameras from the viewer become a CameraPath file that
    ``pointviz path`` accepts."""
    from pointviz.path import CameraPath

    cloud = small_cloud()
    path = CameraPath(width=64, height=48, fps=4)
    for direction in ((0, -0.3, -1), (1, -0.3, 0), (0, -0.3, 1)):
        path.add(Camera.fit(cloud, direction=direction, width=64, height=48))
    saved = path.save(tmp_path / "path.json")
    again = CameraPath.load(saved)
    assert len(again) == 3 and again.duration == pytest.approx(2.0)
    first = again.camera_at(0.0)
    np.testing.assert_allclose(first.eye, Camera.fit(cloud, direction=(0, -0.3, -1), width=64,
                                                     height=48).eye, atol=1e-9)
    # and the CLI renders it: one frame per 1 / fps of the path, at the path's size
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(cloud)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              "property float nx\nproperty float ny\nproperty float nz\nend_header\n")
    data = np.hstack([cloud.points, cloud.normals]).astype("<f4").tobytes()
    (tmp_path / "cloud.ply").write_bytes(header.encode() + data)
    out = subprocess.run([sys.executable, "-m", "pointviz.cli", "path", "cloud.ply", "path.json",
                          "-o", "frames", "--scheduler", "serial", "--spp", "1"],
                         cwd=tmp_path, check=False, capture_output=True, text=True,
                         timeout=GUI_TIMEOUT_S)
    assert out.returncode == 0, out.stderr[-2000:]
    frames = sorted((tmp_path / "frames").glob("frame_*.png"))
    assert len(frames) == again.n_frames == 9  # 2 s at 4 fps, both ends included
    assert all(_load_png(f).shape == (48, 64, 3) for f in frames)


# ------------------------------------------------------------------------------ live viewport


@pytest.mark.gui
@needs_display
def test_live_orbit_reports_and_its_still_frame_matches_a_direct_render(tmp_path):
    """``view(live=True, orbit=...)``: the report holds the live measurements, the still frame
    after the hold is the mean of a deterministic sample sequence, so it equals a direct
    render() with that many samples, and the screenshot's viewport shows it."""
    out = _python(f"""
        {CLOUD_SNIPPET.replace(chr(10), chr(10) + '        ')}
        import pointviz
        pointviz.view(cloud, live=True, orbit=1.0, width=96, height=72, screenshot="shot.png",
                      frame="frame.npz", report="report.json")
        """, tmp_path)
    assert out.returncode == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["live_fps"] > 0 and 0 < report["live_resolution"] <= 1
    assert report["still_spp"] >= 1 and report["preview_fps"] > 0
    assert report["live"]["viewport"] == [96, 72] and not report["live"]["errors"]
    assert report["timings"]["live_worker_ended_on_close"] is True
    data = np.load(tmp_path / "frame.npz")
    assert not bool(data["moving"]) and int(data["spp"]) >= report["still_spp"]
    camera = Camera.from_dict({k: v for k, v in json.loads(str(data["camera"])).items()
                               if k not in ("format", "version")})
    assert (camera.width, camera.height) == (96, 72)
    settings = model.ViewerSettings(**report["settings"])
    kwargs = {k: v for k, v in settings.render_kwargs().items() if k not in ("spp", "denoise")}
    direct = render(model.render_scene(model.as_scene(small_cloud()), settings), camera,
                    spp=int(data["spp"]), **kwargs)
    traced = data["noisy_color"] if "noisy_color" in data else data["color"]
    np.testing.assert_allclose(traced, direct.color, rtol=1e-4, atol=1e-5)

    shot = _load_png(tmp_path / "shot.png")
    x, y, w, h = report["rects"]["preview"]
    panel = shot[y:y + h, x:x + w].astype(np.float64)
    assert panel.std() > NOT_BLANK_STD, (
        f"live viewport is blank (std {panel.std():.1f}; the window measured "
        f"{report['automation'].get('live_view_difference')} after "
        f"{report['automation'].get('attempts')} grabs)")
    from pointviz.images import to_srgb8

    expected = to_srgb8(data["color"], float(data["exposure"])).astype(np.float64)
    rows = np.minimum((np.arange(h) * 72 / h).astype(int), 71)
    cols = np.minimum((np.arange(w) * 96 / w).astype(int), 95)
    resized = expected[rows][:, cols]
    diff = np.abs(panel - resized).mean()
    # the picture shown may be a few passes older than the saved one: a looser bound
    assert diff < 2 * SCREENSHOT_TOLERANCE, (
        f"viewport differs from the live frame: {diff:.1f} (the window measured "
        f"{report['automation'].get('live_view_difference')} after "
        f"{report['automation'].get('attempts')} grabs)")
    assert np.abs(panel - resized[::-1]).mean() > diff + 5
    # and it shows the frame's pixels as they are (no tone mapping or colour grading on top)
    shown = report["automation"].get("live_view_difference")
    assert shown is not None and shown <= LIVE_VIEW_MATCH_LEVELS, (
        f"the live viewport shows its frame {shown} levels off (mean absolute difference)")


def test_open3d_display_encoding_inverts_what_the_window_does_to_colours():
    """With post-processing off, Open3D shows a background image byte u as srgb_to_linear(u)
    and a colour parameter c as srgb_to_linear(c) (measured: a ramp of every 8-bit value under
    Xvfb), and unlit point colours as they are. The encodings undo that: every 8-bit value
    shows within one level (a quarter of a level on average), parameters exactly, and the
    points' linear colours show as the ray tracer's frames show linear radiance."""
    from pointviz.images import srgb_to_linear, to_srgb8
    from pointviz.viewer import o3d_display

    want = np.arange(256)
    shown = np.round(srgb_to_linear(o3d_display.background_image(want.astype(np.uint8)) / 255.0)
                     * 255.0)
    assert np.abs(shown - want).max() <= 1 and np.abs(shown - want).mean() < 0.35
    assert np.all(np.diff(o3d_display.IMAGE_LUT.astype(int)) >= 0)
    rgba = (0.82, 0.86, 0.92, 1.0)
    param = o3d_display.background_color(rgba)
    np.testing.assert_allclose(srgb_to_linear(np.array(param[:3])), rgba[:3], atol=1e-6)
    assert param[3] == 1.0
    linear = np.random.default_rng(3).random((50, 3))
    np.testing.assert_allclose(o3d_display.point_colors(linear) * 255.0,
                               to_srgb8(linear[None])[0], atol=0.5 + 1e-4)


@pytest.mark.gui
@needs_display
def test_live_gui_never_waits_for_the_tracer_and_close_mid_frame_ends_it(tmp_path):
    """A still pass that only ends when cancelled: while it is in flight the worker holds no
    lock the GUI takes, GUI calls (camera updates included) complete, and closing the window
    cancels it and ends the live worker. Waits are on observed states, never sleeps."""
    out = _python(f"""
        {CLOUD_SNIPPET.replace(chr(10), chr(10) + '        ')}
        import json, threading, traceback
        import pointviz
        from pointviz.errors import CancelledError
        from pointviz.viewer import live
        started, res = threading.Event(), {{}}

        def blocking(scene, cam, cancel=None, **kw):
            if "sample_offset" in kw:                # a still pass: hold until cancelled
                started.set()
                res["cancelled"] = cancel.wait(120)
                raise CancelledError("render cancelled")
            return pointviz.render(scene, cam, cancel=cancel, **kw)

        original = live.LiveRenderer.__init__
        def init(self, *a, **k):
            original(self, *a, **dict(k, render_fn=blocking))
        live.LiveRenderer.__init__ = init

        def drive(v):
            try:
                v.call(lambda: v.set_live(True), timeout=120)
                assert started.wait(120), "no still pass started"
                res["lock_free"] = not v.live._lock.locked()
                res["tick"] = v.call(lambda: (v._live_tick(), v.live_generation)[1], timeout=60)
                res["thread"] = v.call(lambda: v.live.thread, timeout=60)
                v.call(v.window.close, timeout=60)
            except BaseException:
                res["error"] = traceback.format_exc()
                v.app.post_to_main_thread(v.window, v.window.close)

        v = pointviz.view(cloud, width=96, height=72,
                          on_ready=lambda v: threading.Thread(target=drive, args=(v,), daemon=True).start())
        th = res.pop("thread", None)
        res["ended"] = th is not None and not th.is_alive()
        res["ended_on_close"] = v.timings.get("live_worker_ended_on_close")
        print("RESULT" + json.dumps(res))
        """, tmp_path)
    res = _driver_result(out)
    assert res["lock_free"] and res["tick"] >= 1
    assert res["cancelled"] and res["ended"] and res["ended_on_close"] is True


#: Issue 17: "the GUI answers within 100 ms throughout", seconds, judged on the GUI round trips
#: from the live view's first frame until the window's close request (window startup, the splat
#: preview's orbit and the switch to live mode are reported, not judged; the close handler, which
#: joins the workers, neither). What the test promises: 95 % of them within it, every one within
#: MAX_GUI_LATENCY_S. On this shared 2-core machine all of them made 100 ms in 10 of 10 runs at
#: load 7-10 (max 18-30 ms), but beside two busy loops one round trip took 0.1-0.75 s in 4 of 19
#: (with Open3D's post-processing off since: 2 of 28 runs, 382 and 443 ms, at load 2-10):
#: the GUI thread inside Open3D's redraw, waiting for the software rasteriser's threads to finish
#: the queued frames while every core is taken (the trace: untraced time, not the viewer's code).
LIVE_GUI_TARGET_S = 0.100
#: Share of the judged round trips that must make LIVE_GUI_TARGET_S.
LIVE_GUI_TARGET_SHARE = 0.95
#: Spacing of the round trips timed during the live test, seconds.
LIVE_PROBE_SPACING_S = 0.02


@pytest.mark.gui
@needs_display
def test_live_gui_answers_within_100_ms_throughout(tmp_path):
    """A scripted live orbit and hold on a small cloud: a GUI round trip (a call that does not
    itself redraw the window, as a script or the benchmark makes them) every 20 ms from before
    the window's loop starts until it closes; those from the first live frame to the close
    request all return within LIVE_GUI_TARGET_S. A slow one fails with what the GUI thread did
    meanwhile (pointviz.viewer.gui_trace)."""
    out = _python(f"""
        {CLOUD_SNIPPET.replace(chr(10), chr(10) + '        ')}
        import json, threading, traceback
        import pointviz
        lat, res = [], {{}}

        def drive(v):
            try:
                v.time_round_trips({LIVE_PROBE_SPACING_S}, lat, timeout=30)
            except BaseException:
                res["error"] = traceback.format_exc()

        v = pointviz.view(cloud, live=True, orbit=1.5, width=96, height=72, report="report.json",
                          on_ready=lambda v: threading.Thread(target=drive, args=(v,), daemon=True).start())
        tr = v.gui_trace
        times = dict((p, t) for t, p in tr.marks + tr.events)
        res["first_live"], res["close"] = times.get("first live frame"), times.get("close")
        res["first_tick"] = times.get("first tick")
        res["trips"] = [(round(t - tr.t0, 4), round(d, 4)) for t, d in lat]
        res["slow"] = [tr.explain(t, d) for t, d in lat if d > {LIVE_GUI_TARGET_S}]
        res["live_fps"] = json.load(open("report.json")).get("live_fps")
        print("RESULT" + json.dumps(res, default=str))
        """, tmp_path)
    res = _driver_result(out)
    assert res["first_live"] is not None and res["close"] is not None, res
    # a call made before the close request counts until it, not while the close handler joins
    # the workers (calls made then are answered late or never)
    judged = np.array([min(d, res["close"] - t) for t, d in res["trips"]
                       if res["first_live"] <= t < res["close"]])
    before = [d for t, d in res["trips"] if res["first_tick"] <= t < res["first_live"]]
    share = float(np.mean(judged <= LIVE_GUI_TARGET_S))
    print(f"live GUI round trips: {len(judged)} from the first live frame, max "
          f"{judged.max() * 1e3:.0f} ms, p95 {np.percentile(judged, 95) * 1e3:.0f} ms, "
          f"{share:.1%} within {LIVE_GUI_TARGET_S * 1e3:.0f} ms; from the first tick to it max "
          f"{max(before, default=0) * 1e3:.0f} ms; live_fps {res['live_fps']}")
    assert len(judged) >= 50, res["trips"]  # the orbit and the 3 s hold were probed
    slow = [e for e in res["slow"] if res["first_live"] <= e["t"] <= res["close"]]
    assert share >= LIVE_GUI_TARGET_SHARE, slow
    assert judged.max() <= MAX_GUI_LATENCY_S, slow


@pytest.mark.parametrize("argv, message", [
    (["--orbit", "2"], "--orbit: needs --live"),
    (["--live", "--orbit", "-1"], "--orbit: expected seconds >= 0"),
    (["--live", "--orbit", "nan"], "--orbit: expected seconds >= 0"),
    (["--live", "--backend", "pyvista"], "--live: needs the open3d backend"),
])
def test_view_cli_rejects_bad_live_options(argv, message):
    out = subprocess.run([sys.executable, "-m", "pointviz.cli", "view", "demo", *argv],
                         check=False, capture_output=True, text=True, timeout=GUI_TIMEOUT_S)
    assert out.returncode != 0
    assert message in out.stderr and "Traceback" not in out.stderr


def test_live_view_difference_sees_through_the_upscale_and_not_past_another_picture():
    """The automation's check that the grabbed viewport shows the live frame: an image upscaled
    by nearest neighbour (a non-integer factor) measures 0, one with a smooth filter stays small,
    and a different picture (the image flipped) measures far more."""
    from pointviz.viewer.o3d_automation import live_view_difference

    rng = np.random.default_rng(5)
    image = (rng.random((18, 24, 1)) * 255 * np.ones((1, 1, 3))).astype(np.uint8)
    rows = np.minimum((np.arange(50) * 18 / 50).astype(int), 17)
    cols = np.minimum((np.arange(70) * 24 / 70).astype(int), 23)
    panel = image[rows][:, cols]
    assert live_view_difference(panel, image) == 0.0
    smooth = panel.astype(np.float64)
    smooth[1:-1] = (smooth[:-2] + smooth[1:-1] + smooth[2:]) / 3
    assert live_view_difference(smooth, image) < 0.5 * live_view_difference(panel, image[::-1])
    assert live_view_difference(panel, image[::-1]) > 50
    assert live_view_difference(panel[:0], image) == float("inf")


# ------------------------------------------------------------------------------ the Up control

#: A z-up object: a tall box along +z (0.5 x 0.5 x 2.5) whose top sixth is red, the rest blue.
TALL_BOX_SNIPPET = """import numpy as np
from pointviz.cloud import PointCloud
from pointviz.shapes import box
_b = box(8000, size=(0.5, 0.5, 2.5))
_p = np.asarray(_b.points)
cloud = PointCloud(_p, normals=_b.normals, radii=_b.radii,
                   colors=np.where((_p[:, 2] > 0.85)[:, None], [0.9, 0.1, 0.1], [0.3, 0.45, 0.85]))
"""
#: A pixel shows the box when its channels spread by more than this (8-bit) and it is red or
#: blue: the preview's sky and ground and the traced ground and shadows are greys (spread < 30),
#: the box's faces are saturated blue or red (spread > 80), lit or in shade (the pyvista
#: window's orange Render button is neither).
BOX_SPREAD = 50


def tall_box():
    ns: dict = {}
    exec(TALL_BOX_SNIPPET, ns)  # noqa: S102 - the same cloud as the GUI scripts build
    return ns["cloud"]


#: Where the box is in a picture (h, w, 3) uint8, as source: the test and the driver scripts
#: (which wait for a window to show what it drew) run the same checks. ``box_on_screen`` gives
#: its pixels' extent (the 1-99th percentiles of their rows and columns, so a few stray pixels
#: do not count) and the mean row of its red and of its blue pixels, or None without a box.
BOX_CHECKS = f"""
import numpy as np

def box_on_screen(img):
    a = img.astype(np.int32)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    saturated = a.max(axis=2) - a.min(axis=2) > {BOX_SPREAD}
    red = saturated & (r > np.maximum(g, b) + 40) & (np.abs(g - b) < 50)  # not orange
    blue = saturated & (b > r + 40) & (b > g)
    rows, cols = np.nonzero(red | blue)
    if len(rows) <= 500:
        return None
    r0, r1 = np.percentile(rows, [1, 99])
    c0, c1 = np.percentile(cols, [1, 99])
    return {{"height": float(r1 - r0), "width": float(c1 - c0),
            "red_row": float(np.nonzero(red)[0].mean()) if red.any() else None,
            "blue_row": float(np.nonzero(blue)[0].mean()) if blue.any() else None}}

def standing(img):
    b = box_on_screen(img)
    return (b is not None and b["height"] > 1.5 * b["width"] and b["red_row"] is not None
            and b["red_row"] < b["blue_row"])

def lying(img):
    b = box_on_screen(img)
    return b is not None and b["width"] > 1.5 * b["height"]
"""
_checks: dict = {}
exec(BOX_CHECKS, _checks)  # noqa: S102 - defined just above


def assert_standing(img, what):
    assert _checks["standing"](img), \
        f"{what}: the box is not standing, red top up: {_checks['box_on_screen'](img)}"


def assert_lying(img, what):
    assert _checks["lying"](img), f"{what}: the box is not lying: {_checks['box_on_screen'](img)}"


def test_up_labels_vectors_and_the_render_option():
    assert model.up_vector("+Z") == model.up_vector("z") == (0.0, 0.0, 1.0)
    assert model.up_vector("-y") == (0.0, -1.0, 0.0)
    assert model.up_vector([0, 0, 3]) == (0.0, 0.0, 1.0)
    for bad in ("w", "++z", (0, 0, 0), (np.inf, 0, 0), (1, 2)):
        with pytest.raises(InputError, match="up"):
            model.up_vector(bad)
    for label, axis in model.UP_AXES.items():
        assert model.up_label(axis) == label
        assert model.up_choices(axis) == list(model.UP_AXES)
    odd = (0.1, -1.0, 0.0)
    assert model.up_choices(odd)[0] == model.up_label(odd) and len(model.up_choices(odd)) == 7
    assert model.up_option((0, 0, 1), (0, 1, 0)) == "--up z"
    assert model.up_option((0, 0, -1), (0, 1, 0)) == "--up=-z"
    assert model.up_option((0, 1, 0), (0, 1, 0)) == ""
    # the option as the CLI reads it gives the viewer's up back
    from pointviz.commands.common import parse_up

    for up in [*model.UP_AXES.values(), model.up_vector(odd)]:
        opt = model.up_option(up, (0.0, 1.0, 0.0)) or "--up y"
        text = opt.split("=", 1)[1] if "=" in opt else opt.split()[1]
        np.testing.assert_allclose(model.up_vector(parse_up(text)), up, atol=1e-6)
    assert model.ViewerSettings(up="z").updated(spp=2).up == (0.0, 0.0, 1.0)
    assert model.ViewerSettings(**model.ViewerSettings(up=(0, 0, 1)).to_dict()).up == (0, 0, 1)


@pytest.mark.parametrize("up", ["+Z", "-X", (0.3, 0.0, 0.9)])
def test_change_up_frames_like_camera_fit_with_that_up(up):
    """The Up control's model function: its camera is Camera.fit(scene, up=...) itself (same
    eye, target, up, field of view and size), its scene is the one constructed with that up
    (the same key), the trees are the input scene's, and render_scene traces it."""
    from pointviz.scene import Scene

    cloud = tall_box()
    source = model.as_scene(cloud)
    assert source.build() == 1
    settings = model.ViewerSettings(spp=1)
    change = model.change_up(source, settings, up, 320, 240)
    u = model.up_vector(up)
    direct = Camera.fit(source, up=u, fov_deg=model.VIEW_FOV_DEG, width=320, height=240)
    for name in ("eye", "target", "up"):
        np.testing.assert_allclose(getattr(change.camera, name), getattr(direct, name),
                                   rtol=1e-12, atol=1e-12)
    assert (change.camera.fov_deg, change.camera.width, change.camera.height) == \
        (direct.fov_deg, 320, 240)
    assert change.settings.up == u and change.settings.spp == 1
    assert change.scene.key == Scene(cloud, up=u).key
    assert change.scene.build() == 0 and change.scene.geometry(0) is source.geometry(0)
    traced = model.render_scene(source, change.settings)
    np.testing.assert_array_equal(traced.up, u)
    # the light keeps its elevation above the new up; the ground plane lies under the box
    light = traced.lights[0].direction
    assert np.degrees(np.arcsin(np.dot(light, u))) == pytest.approx(settings.light_elevation_deg)
    heights = np.asarray(cloud.points) @ np.asarray(u)
    assert np.dot(traced.ground_point(), u) <= heights.min() + 1e-9


def test_an_upright_box_renders_standing_after_the_up_change():
    """The oracle for the pictures below, without a window: the tall box framed for +Y (the
    default) lies on its side, framed and traced for +Z it stands with its red top up."""
    cloud = tall_box()
    source = model.as_scene(cloud)
    settings = model.ViewerSettings(spp=1)
    lying = render(model.render_scene(source, settings),
                   model.view_camera(source, 160, 120), **settings.render_kwargs())
    assert_lying(lying.to_srgb8(), "default up")
    change = model.change_up(source, settings, "+Z", 160, 120)
    frame = render(model.render_scene(source, change.settings), change.camera,
                   **change.settings.render_kwargs())
    assert_standing(frame.to_srgb8(), "up +Z")


#: The picture checks of box_on_screen, for driver scripts that wait for a window to show
#: what it drew (under load the X server presents a redraw seconds late).
UP_DRIVER_SNIPPET = BOX_CHECKS + """
import json, threading, time, traceback
import numpy as np
import pointviz
from pointviz.images import encode_png
from pointviz.viewer.o3d_automation import save_frame_npz

def grab(v, panel, want, name, timeout=120):
    # the panel as presented, grabbed until it shows what is wanted (or the time is up: the
    # test then fails on the picture saved)
    deadline = time.monotonic() + timeout
    while True:
        x, y, w, h = v.call(v.widget_rects, redraw=False)[panel]
        img = v.screenshot()[y:y + h, x:x + w]
        if want(img) or time.monotonic() > deadline:
            open(name, "wb").write(encode_png(np.ascontiguousarray(img)))
            return want(img)
        v.call(v.preview.force_redraw)
        time.sleep(0.3)

def wait_for(v, what, cond, timeout=300):
    deadline = time.monotonic() + timeout
    while not v.call(cond, redraw=False):
        assert time.monotonic() < deadline, f"{what}: not within {timeout} s"
        time.sleep(0.05)

def pick(v, combo, text):
    # the Up combobox as a user sets it: the item selected, then the handler the widget calls
    def run():
        combo.selected_text = text
        assert combo.selected_text == text, (combo.selected_text, text)
        v._on_up_selected(combo.selected_text, combo.selected_index)
    v.call(run)
"""


def _box_driver(tmp_path, body: str, view_args: str) -> dict:
    """Open the viewer on the tall box (``pointviz.view(cloud, VIEW_ARGS)``) and run ``body``
    (a driver's statements, with ``v``, ``res`` and UP_DRIVER_SNIPPET's helpers) on a thread;
    a failure in it closes the window and fails the test with its traceback."""
    drive = textwrap.indent(textwrap.dedent(body).strip("\n"), " " * 8)
    script = (TALL_BOX_SNIPPET + UP_DRIVER_SNIPPET + "\nres = {}\n\ndef drive(v):\n    try:\n"
              + drive + "\n    except BaseException:\n        res['error'] = traceback.format_exc()\n"
              "    v.app.post_to_main_thread(v.window, v.window.close)\n\n"
              f"v = pointviz.view(cloud, {view_args}, on_ready=lambda v: threading.Thread("
              "target=drive, args=(v,), daemon=True).start())\n"
              "print('RESULT' + json.dumps(res, default=str))\n")
    return _driver_result(_python(script, tmp_path))


@pytest.mark.gui
@needs_display
def test_up_control_stands_a_z_up_object_and_render_follows(tmp_path):
    """A z-up box opened with the default up (+Y) lies on its side in the preview; after +Z is
    picked in the Up control it stands with its red top at the top, in the preview and in the
    frame Render traces then (which equals a direct render of the scene with that up). A
    render in flight when the up changes is cancelled and its frame never shown; Copy camera
    then gives a camera that `pointviz render --up z` frames the same way."""
    res = _box_driver(tmp_path, f"""
                res["items"] = v.call(lambda: [v.cmb_up.get_item(i)
                                               for i in range(v.cmb_up.number_of_items)])
                res["start"] = v.call(lambda: v.cmb_up.selected_text)
                res["before"] = grab(v, "preview", lying, "before.png")
                v.call(lambda: v._set(spp=4096))
                v.call(v._on_render)                   # a render that cannot finish
                wait_for(v, "first progress report", lambda: v.progress.value > 0)
                th = v.worker.thread
                pick(v, v.cmb_up, "+Z")
                th.join({STOP_TIMEOUT_S})
                res["in_flight_ended"] = not th.is_alive()
                v.call(lambda: None)                   # what it posted has been handled
                res["frame_after_cancel"] = v.call(lambda: v.frame is not None)
                res["job_after_cancel"] = v.call(lambda: v.job is not None)
                res["label_after_cancel"] = v.call(lambda: v.render_label.text)
                res["selected"] = v.call(lambda: v.cmb_up.selected_text)
                res["after"] = grab(v, "preview", standing, "after.png")
                v.call(v._on_copy_camera)
                v.call(v.window.close_dialog)
                res["camera_json"] = v.last_camera_json
                res["command"] = v.last_camera_command
                v.call(lambda: v._set(spp=2))
                v.call(v._on_render)
                wait_for(v, "the frame", lambda: v.frame is not None)
                v.call(lambda: (v.frame.save("frame.png"),
                                save_frame_npz("frame.npz", v.frame, v.frame_camera)))
                res["shown"] = grab(v, "result", standing, "shown.png")
                res["report"] = v.call(v.report)
        """, "width=320, height=400")
    assert res["items"] == list(model.UP_AXES) and res["start"] == "+Y"
    assert_lying(_load_png(tmp_path / "before.png"), "preview, up +Y")
    assert res["in_flight_ended"], "the render in flight went on after the up change"
    assert not res["frame_after_cancel"] and not res["job_after_cancel"], res
    assert "done" not in res["label_after_cancel"] and res["selected"] == "+Z"
    assert_standing(_load_png(tmp_path / "after.png"), "preview, up +Z")
    assert_standing(_load_png(tmp_path / "frame.png"), "rendered frame, up +Z")
    assert_standing(_load_png(tmp_path / "shown.png"), "frame panel, up +Z")
    report = res["report"]
    assert report["up"] == [0.0, 0.0, 1.0]
    # the frame is the scene traced with that up: a direct render with the same camera
    data = np.load(tmp_path / "frame.npz")
    camera = Camera.from_dict({k: v for k, v in json.loads(str(data["camera"])).items()
                               if k not in ("format", "version")})
    settings = model.ViewerSettings(**report["settings"])
    assert settings.up == (0.0, 0.0, 1.0)
    direct = render(model.render_scene(model.as_scene(tall_box()), settings), camera,
                    **settings.render_kwargs())
    np.testing.assert_array_equal(data["color"], direct.color)
    # Copy camera: the current view, and the command that renders it with the viewer's up
    assert res["command"] == "pointviz render --camera CAM.json --up z"
    (tmp_path / "cam.json").write_text(res["camera_json"])
    copied = Camera.from_json(tmp_path / "cam.json")
    assert copied.true_up[2] > 0.9
    import open3d as o3d

    ply = tmp_path / "box.ply"
    assert o3d.io.write_point_cloud(str(ply), tall_box().to_open3d())
    cli = subprocess.run([sys.executable, "-m", "pointviz.cli", "render", str(ply), "--camera",
                          str(tmp_path / "cam.json"), "--up", "z", "--width", "160",
                          "--height", "200", "--spp", "1", "-o", str(tmp_path / "cli.png")],
                         check=False, capture_output=True, text=True, timeout=GUI_TIMEOUT_S)
    assert cli.returncode == 0, cli.stderr[-2000:]
    assert_standing(_load_png(tmp_path / "cli.png"), "pointviz render --camera (copied) --up z")


@pytest.mark.gui
@needs_display
def test_view_cli_up_sets_the_start_value(tmp_path):
    """``pointviz view F --up z``: the Up control starts at +Z and the box stands."""
    import open3d as o3d

    ply = tmp_path / "box.ply"
    assert o3d.io.write_point_cloud(str(ply), tall_box().to_open3d())
    out = subprocess.run([sys.executable, "-m", "pointviz.cli", "view", str(ply), "--up", "z",
                          "--screenshot", str(tmp_path / "shot.png"), "--report",
                          str(tmp_path / "report.json")],
                         check=False, capture_output=True, text=True, timeout=GUI_TIMEOUT_S)
    assert out.returncode == 0, out.stderr[-2000:]
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["up"] == [0.0, 0.0, 1.0] and report["up_control"] == "+Z"
    x, y, w, h = report["rects"]["preview"]
    assert_standing(_load_png(tmp_path / "shot.png")[y:y + h, x:x + w], "view --up z")


@pytest.mark.gui
@needs_display
def test_up_change_in_live_mode_traces_the_new_scene(tmp_path):
    """With the live viewport on, an up change re-frames the view and the live frames that are
    shown from then on are of the new scene (their request is the one made with it; older
    ones are dropped), showing the box standing."""
    res = _box_driver(tmp_path, """
                v.call(lambda: v.set_live(True), timeout=120)
                wait_for(v, "first live frame", lambda: v.live_frame is not None)
                res["before"] = grab(v, "preview", lying, "before.png")
                pick(v, v.cmb_up, "+Z")
                floor = v.call(lambda: v._live_floor)
                wait_for(v, "a live frame of the new up",
                         lambda: v.live_frame.generation >= floor and not v.live_frame.moving)
                res["floor"] = floor
                res["shown_generation"] = v.call(lambda: v.live_frame.generation)
                res["after"] = grab(v, "preview", standing, "after.png")
                res["errors"] = v.call(lambda: v.live_stats["errors"])
        """, "width=96, height=120")
    assert res["floor"] >= 2 and res["shown_generation"] >= res["floor"] and not res["errors"]
    assert_lying(_load_png(tmp_path / "before.png"), "live view, up +Y")
    assert_standing(_load_png(tmp_path / "after.png"), "live view, up +Z")


@pytest.mark.gui
@needs_display
def test_pyvista_u_key_turns_the_up_and_render_follows(tmp_path):
    """The pyvista window has no settings panel: its ``u`` key takes the next up (+Y -> +Z);
    the preview and the frame traced afterwards show the box standing, and the frame is the
    direct render of the scene with that up."""
    _python(f"""
        {TALL_BOX_SNIPPET.replace(chr(10), chr(10) + '        ')}
        import pointviz
        pointviz.view(cloud, backend="pyvista", render=True, screenshot="shot.png",
                      frame="frame.npz", report="report.json", spp=2,
                      on_ready=lambda v: v.on_next_up())
        """, tmp_path)
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["up"] == [0.0, 0.0, 1.0]
    shot = _load_png(tmp_path / "shot.png")
    for panel in ("preview", "result"):
        x, y, w, h = report["rects"][panel]
        assert_standing(shot[y:y + h, x:x + w], f"pyvista {panel}, up +Z")
    data = np.load(tmp_path / "frame.npz")
    camera = Camera.from_dict({k: v for k, v in json.loads(str(data["camera"])).items()
                               if k not in ("format", "version")})
    settings = model.ViewerSettings(**report["settings"])
    direct = render(model.render_scene(model.as_scene(tall_box()), settings), camera,
                    **settings.render_kwargs())
    np.testing.assert_array_equal(data["color"], direct.color)
