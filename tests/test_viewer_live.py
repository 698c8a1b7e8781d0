"""The live viewport's worker (no display needed): progressive sampling against one render with
all the samples (the oracle), stale frames cancelled, shutdown mid-frame, the resolution
controller, the orbit. The window itself is tested in tests/test_viewer.py."""

from __future__ import annotations

import math
import queue
import threading

import numpy as np
import pytest

from pointviz import Camera, render
from pointviz.errors import CancelledError, InputError
from pointviz.scene import Scene
from pointviz.shapes import sphere
from pointviz.viewer import live

#: Waiting for a frame that must come, seconds (a generous bound, not a sleep: the wait ends as
#: soon as the frame arrives).
FRAME_TIMEOUT_S = 60.0
#: Float rounding between a sum of pass means and one render's sum (float32 colour buffers).
ACCUMULATION_RTOL = 1e-4


def small_scene():
    return Scene(sphere(6000, color=(0.8, 0.35, 0.2)), ground="mirror")


def camera(width=48, height=36):
    return Camera((0.3, 0.9, 3.2), (0, 0, 0), fov_deg=40, width=width, height=height)


OPTS = dict(shadows=True, reflections=1, lod_pixels=1.0, seed=3, threads=2)


# ------------------------------------------------------------------ progressive sampling (core)


@pytest.mark.parametrize("passes", [[1, 1, 1, 1, 1, 1, 1, 1], [1, 2, 4, 1], [8]])
def test_passes_average_to_one_render_with_all_samples(passes):
    scene, cam = small_scene(), camera()
    total = sum(passes)
    acc, off = 0.0, 0
    for n in passes:
        f = render(scene, cam, spp=n, sample_offset=off, sequence_spp=total, **OPTS)
        acc = acc + f.color.astype(np.float64) * n
        off += n
    whole = render(scene, cam, spp=total, **OPTS)
    np.testing.assert_allclose(acc / total, whole.color, rtol=ACCUMULATION_RTOL, atol=1e-5)


def test_one_sample_sequence_keeps_pixel_centres_and_longer_ones_jitter():
    scene, cam = small_scene(), camera()
    centre = render(scene, cam, spp=1, **OPTS)
    assert np.array_equal(render(scene, cam, spp=1, sequence_spp=1, **OPTS).color, centre.color)
    jittered = render(scene, cam, spp=1, sequence_spp=8, **OPTS)
    assert not np.array_equal(jittered.color, centre.color)
    # the first sample of a jittered sequence is the first sample of a render with more spp:
    # offsets shift the sequence (different frames), they do not reseed it
    assert not np.array_equal(render(scene, cam, spp=1, sample_offset=1, sequence_spp=8,
                                     **OPTS).color, jittered.color)


@pytest.mark.parametrize("kw", [dict(sample_offset=-1), dict(sample_offset=1.5),
                                dict(sequence_spp=0)])
def test_bad_progressive_options_are_named(kw):
    name = next(iter(kw))
    with pytest.raises(InputError, match=name):
        render(small_scene(), camera(), spp=1, **kw)


# ------------------------------------------------------------------ live renderer


def collect(scene, **kw):
    """A live renderer whose settings are render() options for ``scene``, and its outputs."""
    frames: queue.Queue = queue.Queue()
    errors: queue.Queue = queue.Queue()
    lr = live.LiveRenderer(frames.put, lambda opts: (scene, opts), errors.put, **kw)
    return lr, frames, errors


def next_frame(frames, pred=lambda f: True):
    while True:
        f = frames.get(timeout=FRAME_TIMEOUT_S)
        if pred(f):
            return f


def test_live_frames_match_direct_renders():
    scene, cam = small_scene(), camera(64, 48)
    lr, frames, errors = collect(scene, threads=2, denoise=False)
    try:
        lr.update(cam, dict(OPTS))
        moving = next_frame(frames)
        assert moving.moving and moving.spp == 1
        direct = render(scene, moving.camera, spp=1,
                        **dict(OPTS, lod_pixels=live.MOVING_LOD_PIXELS))
        np.testing.assert_array_equal(moving.frame.color, direct.color)
        assert moving.image.shape == (moving.camera.height, moving.camera.width, 3)
        still = next_frame(frames, lambda f: not f.moving and f.spp >= 4)
        assert (still.camera.width, still.camera.height) == (64, 48)
        assert still.fraction == 1.0 and not still.denoised
        whole = render(scene, cam, spp=still.spp, **OPTS)
        np.testing.assert_allclose(still.frame.color, whole.color, rtol=ACCUMULATION_RTOL,
                                   atol=1e-5)
        np.testing.assert_allclose(still.frame.alpha, whole.alpha, atol=1e-5)
        # metered alike whatever the samples, and at the moving frames' reduced size too
        assert still.frame.exposure == whole.exposure == moving.frame.exposure
    finally:
        assert lr.shutdown()
    assert errors.empty()


def test_a_given_exposure_is_kept_by_moving_and_accumulated_frames():
    """An exposure the settings give is the user's: every live frame keeps it, moving and
    accumulated."""
    scene, cam = small_scene(), camera(64, 48)
    lr, frames, errors = collect(scene, threads=2, denoise=False)
    try:
        lr.update(cam, dict(OPTS, exposure=0.8))
        assert next_frame(frames).frame.exposure == 0.8
        still = next_frame(frames, lambda f: not f.moving and f.spp >= 4)
        assert still.frame.exposure == 0.8
        assert render(scene, cam, spp=still.spp, **OPTS).exposure != 0.8  # not the automatic one
    finally:
        assert lr.shutdown()
    assert errors.empty()


class BlockingRender:
    """render() that, for the cameras it is told to block, holds until cancelled (no sleeps:
    the test knows the frame is in flight through ``started``)."""

    def __init__(self, block):
        self.block = block
        self.started = threading.Event()
        self.cancelled = threading.Event()

    def __call__(self, scene, cam, cancel=None, **kw):
        if self.block(cam, kw):
            self.started.set()
            if not cancel.wait(FRAME_TIMEOUT_S):
                raise AssertionError("the blocked frame was never cancelled")
            self.cancelled.set()
            raise CancelledError("render cancelled")
        return render(scene, cam, cancel=cancel, **kw)


def test_a_new_camera_cancels_the_stale_frame():
    scene = small_scene()
    a = camera(64, 48)
    b = live.orbit_camera(a, (0, 0, 0), (0, 1, 0), 0.5)
    fake = BlockingRender(lambda cam, kw: np.array_equal(cam.eye, a.eye))
    lr, frames, errors = collect(scene, render_fn=fake, threads=2, denoise=False)
    try:
        lr.update(a, dict(OPTS))
        assert fake.started.wait(FRAME_TIMEOUT_S)
        gen_b = lr.update(b, dict(OPTS))
        assert fake.cancelled.wait(FRAME_TIMEOUT_S)
        f = next_frame(frames)
        assert f.generation == gen_b and np.array_equal(f.camera.eye, b.eye)
        assert lr.cancelled_frames >= 1
    finally:
        assert lr.shutdown()
    assert errors.empty()


def test_a_new_camera_cancels_a_still_pass_and_shows_a_moving_frame():
    scene = small_scene()
    a = camera(64, 48)
    b = live.orbit_camera(a, (0, 0, 0), (0, 1, 0), 0.5)
    fake = BlockingRender(lambda cam, kw: "sample_offset" in kw)  # every still pass blocks
    lr, frames, errors = collect(scene, render_fn=fake, threads=2, denoise=False)
    try:
        lr.update(a, dict(OPTS))
        assert next_frame(frames).moving
        assert fake.started.wait(FRAME_TIMEOUT_S)  # a's still pass is in flight
        gen_b = lr.update(b, dict(OPTS))
        assert fake.cancelled.wait(FRAME_TIMEOUT_S)
        f = next_frame(frames)
        assert f.moving and f.generation == gen_b
    finally:
        assert lr.shutdown()
    assert errors.empty()


def test_shutdown_mid_frame_ends_the_worker():
    fake = BlockingRender(lambda cam, kw: True)
    lr, frames, errors = collect(small_scene(), render_fn=fake, threads=2)
    lr.update(camera(), dict(OPTS))
    assert fake.started.wait(FRAME_TIMEOUT_S)
    assert lr.thread.is_alive()
    assert lr.shutdown(timeout=FRAME_TIMEOUT_S)
    assert fake.cancelled.is_set() and not lr.thread.is_alive()
    assert frames.empty() and errors.empty()


def test_render_errors_are_reported_and_the_loop_goes_on():
    scene = small_scene()
    bad = camera(64, 48)

    def failing(sc, cam, **kw):
        if np.array_equal(cam.eye, bad.eye):
            raise ValueError("boom")
        return render(sc, cam, **kw)

    lr, frames, errors = collect(scene, render_fn=failing, threads=2, denoise=False)
    try:
        lr.update(bad, dict(OPTS))
        assert "boom" in str(errors.get(timeout=FRAME_TIMEOUT_S))
        good = live.orbit_camera(bad, (0, 0, 0), (0, 1, 0), 1.0)
        lr.update(good, dict(OPTS))
        assert np.array_equal(next_frame(frames).camera.eye, good.eye)
    finally:
        assert lr.shutdown()


def test_update_with_the_same_request_does_not_restart():
    scene, cam = small_scene(), camera()
    fake = BlockingRender(lambda cam, kw: True)
    lr, _, _ = collect(scene, render_fn=fake, threads=2)
    try:
        g = lr.update(cam, dict(OPTS))
        same = Camera(cam.eye.copy(), cam.target.copy(), cam.up.copy(), cam.fov_deg,
                      cam.width, cam.height)
        assert lr.update(same, dict(OPTS)) == g
        assert lr.update(cam, dict(OPTS, shadows=False)) == g + 1
    finally:
        assert lr.shutdown()


# ------------------------------------------------------------------ pure helpers


def test_resolution_controller_inverts_a_proportional_cost():
    c = live.ResolutionController(target_fps=10, lo=1 / 16, hi=1)
    for _ in range(40):  # a frame of the whole viewport costs 0.4 s: 1/4 of it meets 10 fps
        c.observe(c.fraction, 0.4 * c.fraction)
    assert c.fraction == pytest.approx(0.25, rel=1e-3)
    for _ in range(40):  # very cheap frames: capped at the whole viewport
        c.observe(c.fraction, 0.001 * c.fraction)
    assert c.fraction == 1.0
    for _ in range(40):  # very slow ones: floored
        c.observe(c.fraction, 100 * c.fraction)
    assert c.fraction == pytest.approx(1 / 16)


def test_resolution_controller_keeps_a_quarter_of_the_pixels_while_it_makes_min_fps():
    c = live.ResolutionController(target_fps=10, lo=1 / 16, hi=1, min_fps=8, preferred=0.25)
    assert c.fraction == 0.25  # before any measurement
    for _ in range(40):  # 1/4 of the pixels costs 0.12 s: 8.3 fps, short of 10 but above 8
        c.observe(c.fraction, 0.48 * c.fraction)
    assert c.fraction == 0.25
    for _ in range(40):  # 1/4 costs 0.2 s (5 fps): pixels traded for 8 fps, 0.125 s / 0.8 s
        c.observe(c.fraction, 0.8 * c.fraction)
    assert c.fraction == pytest.approx(0.125 / 0.8, rel=1e-3)
    for _ in range(40):  # 1/4 costs 0.05 s: more pixels for 10 fps, 0.1 s / 0.2 s
        c.observe(c.fraction, 0.2 * c.fraction)
    assert c.fraction == pytest.approx(0.5, rel=1e-3)


@pytest.mark.skipif(not live._denoise_available(), reason="needs the denoise extra")
def test_a_still_pass_is_shown_before_it_is_denoised(monkeypatch):
    monkeypatch.setattr(live, "DENOISE_FIRST_SPP", 2)
    scene, cam = small_scene(), camera(64, 48)
    lr, frames, errors = collect(scene, threads=2, denoise=True)
    try:
        lr.update(cam, dict(OPTS))
        first = next_frame(frames, lambda f: not f.moving and f.spp >= 2)
        assert not first.denoised
        whole = render(scene, cam, spp=first.spp, **OPTS)  # the pass keeps the tracer's mean
        np.testing.assert_allclose(first.frame.color, whole.color, rtol=ACCUMULATION_RTOL,
                                   atol=1e-5)
        den = frames.get(timeout=FRAME_TIMEOUT_S)  # next: the same samples, denoised
        assert den.denoised and den.spp == first.spp and den.generation == first.generation
        np.testing.assert_array_equal(den.frame.noisy_color, first.frame.color)
        assert not np.array_equal(den.frame.color, first.frame.color)
        later = frames.get(timeout=FRAME_TIMEOUT_S)  # passes after it show the denoised picture
        assert later.spp > den.spp and later.denoised
        assert np.array_equal(later.image, den.image)
    finally:
        assert lr.shutdown()
    assert errors.empty()


def test_scaled_camera_keeps_the_view():
    cam = camera(640, 480)
    s = live.scaled_camera(cam, 0.25)
    assert (s.width, s.height) == (320, 240)
    assert s.fov_deg == cam.fov_deg and np.array_equal(s.eye, cam.eye)
    assert live.scaled_camera(cam, 1.0) is cam


def test_orbit_keeps_distance_and_closes_the_circle(rng):
    cam = camera()
    center, up = rng.normal(size=3) * 0.1, np.array([0.0, 1.0, 0.0])
    for angle in rng.uniform(-math.pi, math.pi, 5):
        o = live.orbit_camera(cam, center, up, angle)
        for p, q in ((o.eye, cam.eye), (o.target, cam.target)):
            r0, r1 = p - center, q - center
            assert np.linalg.norm(r0) == pytest.approx(np.linalg.norm(r1))
            assert r0 @ up == pytest.approx(r1 @ up)
    full = live.orbit_camera(cam, center, up, 2 * math.pi)
    np.testing.assert_allclose(full.eye, cam.eye, atol=1e-12)


def test_the_flat_look_gets_no_key_light():
    from pointviz.viewer import model

    cloud = sphere(2000)
    flat = Scene(cloud, look="flat")
    out = model.render_scene(flat, model.initial_settings(flat))
    assert out.lights is None  # the look's own (no) lights, no viewer key light
    studio = Scene(cloud, look="studio")
    lit = model.render_scene(studio, model.initial_settings(studio))
    assert lit.lights and lit.lights[0].intensity > 0


# ------------------------------------------------------------------ GUI thread side (no window)


def test_live_frames_are_converted_on_the_worker_and_coalesced():
    """The worker thread makes the Open3D image (the O(pixels) step) and posts one handler at a
    time: frames that arrive while it waits replace the waiting one, which shows the newest."""
    o3d = pytest.importorskip("open3d")
    from types import SimpleNamespace

    from pointviz.viewer.o3d_display import background_image
    from pointviz.viewer.o3d_live import LiveMixin

    class Viewer(LiveMixin):
        def __init__(self):
            self.o3d = o3d
            self._init_live()
            self.posted, self.shown = [], []

        def _post(self, fn, what="posted"):
            self.posted.append(fn)

        def _show_live(self, lf, image):
            self.shown.append((lf, image))

    v = Viewer()
    frames = [SimpleNamespace(image=np.full((4, 6, 3), 10 * i, np.uint8)) for i in range(3)]
    for f in frames:
        v._post_live_frame(f)
    assert len(v.posted) == 1 and v.live_stats["frames_coalesced"] == 2
    v.posted[0]()  # the GUI thread runs the handler
    [(lf, image)] = v.shown
    assert lf is frames[-1] and isinstance(image, o3d.geometry.Image)
    # its bytes encoded for Open3D's display of a background image (viewer.o3d_display)
    assert np.array_equal(np.asarray(image), background_image(frames[-1].image))
    v._post_live_frame(frames[0])  # nothing waits any more: a new handler is posted
    assert len(v.posted) == 2


def test_gui_trace_explains_a_round_trip():
    from pointviz.viewer.gui_trace import GuiTrace

    tr = GuiTrace(t0=100.0)
    tr.marks.extend([(1.0, "first tick"), (5.0, "orbit")])
    tr.add("tick", 105.0, 0.01)
    tr.add("show live frame", 105.02, 0.005)
    tr.add("tick", 105.3, 0.01)
    e = tr.explain(104.99, 0.33)  # a round trip from 4.99 s to 5.32 s
    assert e["phase"] == "first tick" and tr.phase_at(5.0) == "orbit"
    assert e["untraced_s"] == pytest.approx(0.275, abs=1e-9)  # 5.025 .. 5.3: inside Open3D
    assert [s[1] for s in e["spans"]] == ["tick", "tick", "show live frame"]
    tr.event("first live frame")
    tr.event("first live frame")  # events are recorded once
    d = tr.to_dict()
    assert d["kinds"]["tick"]["count"] == 2 and d["phases"][1] == [5.0, "orbit"]
    assert [n for _, n in d["events"]] == ["first live frame"]
