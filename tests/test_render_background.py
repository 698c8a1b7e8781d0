"""Camera samples that see only background are shaded without a ray (``background_shortcut``).

Oracle: the same frame rendered with the shortcut off, where every camera sample is queued,
intersected with the objects and the ground and shaded by the general path. Every buffer must
be the same bits, on views chosen to put the decision's edges in the frame: objects at the
frame's edge (samples grazing their bounds), the ground's horizon, the fade's edge, mirror and
glossy grounds, point and area lights, jittered samples (spp > 1) and the budget's level of
detail.
"""

from __future__ import annotations

import numpy as np
import pytest

import pointviz
from pointviz import AreaLight, Camera, DirectionalLight, PointLight, Scene, rendering, shapes

BUFFERS = ("color", "depth", "normal", "alpha", "albedo", "object_alpha")


class _NoShortcut:
    """``pointviz._core`` whose RenderSettings come with the shortcut off."""

    def __init__(self, core):
        self._core = core

    def __getattr__(self, name):
        return getattr(self._core, name)

    def RenderSettings(self):  # noqa: N802 (the core's name)
        s = self._core.RenderSettings()
        s.background_shortcut = False
        return s


def render_both(monkeypatch, scene, cam, **kw):
    fast = pointviz.render(scene, cam, **kw)
    with monkeypatch.context() as m:
        m.setattr(rendering, "_core", _NoShortcut(rendering._core))
        slow = pointviz.render(scene, cam, **kw)
    return fast, slow


def assert_same_bits(fast, slow, what):
    for key in BUFFERS:
        a, b = getattr(fast, key), getattr(slow, key)
        assert a.shape == b.shape, (what, key)
        assert np.array_equal(a.view(np.uint32), b.view(np.uint32)), f"{what}: {key} differs"


def at(cam, factor, shift=(0.0, 0.0)):
    """The view from ``factor`` times farther, its target moved by ``shift`` (in units of the
    distance) along the camera's right and up: the object toward the frame's edge."""
    target = (np.asarray(cam.target) + np.asarray(cam.right) * shift[0] * cam.distance * factor
              + np.asarray(cam.true_up) * shift[1] * cam.distance * factor)
    eye = target - np.asarray(cam.forward) * cam.distance * factor
    return Camera.look_at(eye, target, up=cam.true_up, fov_deg=cam.fov_deg, width=cam.width,
                          height=cam.height)


@pytest.fixture(scope="module")
def ball():
    return shapes.sphere(20_000, radius=1.0, center=(0.0, 1.5, 0.0), color=(0.8, 0.6, 0.4))


# (factor, shift): the framing distance, farther, the object at the frame's right edge and in a
# corner (tiles that graze its bounds), and far enough that the fade's edge crosses the frame
VIEWS = [(1.0, (0, 0)), (2.5, (0, 0)), (7.5, (0, 0)), (7.5, (0.3, 0.0)), (4.0, (0.25, -0.2)),
         (20.0, (0, 0))]


@pytest.mark.parametrize("factor, shift", VIEWS)
def test_studio_frames_equal_the_general_path(monkeypatch, ball, factor, shift):
    scene = Scene(ball, look="studio")
    cam = at(Camera.fit(ball, width=128, height=96), factor, shift)
    fast, slow = render_both(monkeypatch, scene, cam, spp=1, threads=1)
    assert_same_bits(fast, slow, f"studio {factor}x {shift}")
    if factor >= 7.5:  # the far views are mostly background: most tiles took the shortcut
        assert fast.stats["primary_background"] > cam.width * cam.height // 2
    elif factor > 1.0:
        assert fast.stats["primary_background"] > 0
    assert slow.stats["primary_background"] == 0
    assert fast.stats["primary_rays"] == slow.stats["primary_rays"]


@pytest.mark.parametrize("spp, lod", [(3, 0.0), (2, "auto"), (1, 1.0)])
def test_jittered_and_lod_frames_equal_the_general_path(monkeypatch, ball, spp, lod):
    scene = Scene(ball, look="studio")
    cam = at(Camera.fit(ball, width=48, height=40), 6.0, (0.2, 0.1))
    fast, slow = render_both(monkeypatch, scene, cam, spp=spp, lod_pixels=lod, threads=1, seed=3)
    assert_same_bits(fast, slow, f"spp {spp} lod {lod}")
    assert fast.stats["primary_background"] > 0


@pytest.mark.parametrize("ground", ["mirror", "glossy"])
def test_reflecting_grounds_and_soft_lights_equal_the_general_path(monkeypatch, ball, ground):
    lights = [DirectionalLight(direction=(0.3, 1.0, 0.2), angle_deg=3.0),
              PointLight(position=(0.0, 4.0, 3.0), radius=0.3, intensity=8.0),
              AreaLight(corner=(-1.0, 4.0, -1.0), edge_u=(2.0, 0.0, 0.0), edge_v=(0.0, 0.0, 2.0))]
    scene = Scene(ball, look="studio", ground=ground, lights=lights)
    for factor, shift in [(1.0, (0, 0)), (5.0, (0.2, 0.0))]:
        cam = at(Camera.fit(ball, width=48, height=40), factor, shift)
        fast, slow = render_both(monkeypatch, scene, cam, spp=2, reflections=2, threads=1)
        assert_same_bits(fast, slow, f"{ground} {factor}x")


def test_horizon_and_sky_background_equal_the_general_path(monkeypatch, ball):
    # a low camera looking along the ground: the horizon crosses the frame; the studio fade
    # and, outdoors, the sky (no fade: only samples above the horizon are background)
    eye, target = (0.0, 0.3, 12.0), (0.0, 0.5, 0.0)
    cam = Camera.look_at(eye, target, width=64, height=48, fov_deg=50.0)
    for look in ("studio", "outdoor"):
        scene = Scene(ball, look=look, ground="matte")
        fast, slow = render_both(monkeypatch, scene, cam, spp=2, threads=1)
        assert_same_bits(fast, slow, look)
        assert fast.stats["primary_background"] > 0


def test_thread_counts_give_the_same_frame(ball):
    scene = Scene(ball, look="studio")
    cam = at(Camera.fit(ball, width=80, height=60), 7.5, (0.1, 0.0))
    frames = [pointviz.render(scene, cam, spp=2, threads=t) for t in (1, 2, 3)]
    for f in frames[1:]:
        assert_same_bits(f, frames[0], "threads")


def test_random_views_equal_the_general_path(monkeypatch, ball):
    # views from every side, near and far, wide and narrow, under the ground too: every tile
    # the proof takes must be the general path's bits
    rng = np.random.default_rng(5)
    lights = [DirectionalLight(direction=(0.3, 1.0, 0.2), angle_deg=2.0),
              AreaLight(corner=(-1.0, 4.0, -1.0), edge_u=(2.0, 0.0, 0.0), edge_v=(0.0, 0.0, 2.0))]
    scenes = [Scene(ball, look="studio", lights=lights), Scene(ball, look="outdoor", ground="matte")]
    taken = 0
    for k in range(16):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        eye = np.array([0.0, 1.5, 0.0]) + direction * rng.uniform(2.5, 60.0)
        target = np.array([0.0, 1.5, 0.0]) + rng.normal(size=3) * rng.uniform(0.0, 4.0)
        cam = Camera.look_at(eye, target, up=(0.0, 1.0, 0.0), fov_deg=float(rng.uniform(10, 80)),
                             width=40, height=32)
        fast, slow = render_both(monkeypatch, scenes[k % 2], cam, spp=1 + k % 2, threads=1, seed=k)
        assert_same_bits(fast, slow, f"view {k}: eye {eye}, target {target}")
        taken += fast.stats["primary_background"]
    assert taken > 0


def test_progressive_samples_equal_the_general_path(monkeypatch, ball):
    # a later slice of a longer jittered sequence (sample_offset, sequence_spp), sky background
    import dataclasses

    from pointviz.looks import LOOKS

    sky_look = dataclasses.replace(LOOKS["studio"], backdrop=False, background=None)
    scene = Scene(ball, look=sky_look)
    rs, _ = scene.to_core(Camera.fit(ball), 0.0)
    assert rs.sky.background_is_sky  # the sky's colour per sample
    cam = Camera.look_at((0.0, 2.0, 30.0), (0.0, 6.0, 0.0), width=64, height=48)
    fast, slow = render_both(monkeypatch, scene, cam, spp=2, sample_offset=4, sequence_spp=8,
                             threads=1, seed=9)
    assert_same_bits(fast, slow, "progressive")
    assert fast.stats["primary_background"] > 0


@pytest.mark.parametrize("width, height", [(53, 37), (61, 45), (7, 5)])
def test_widths_off_the_vector_step_equal_the_general_path(monkeypatch, ball, width, height):
    # the faded ground's distances go four pixels a step (render.cpp, ground_distances_row):
    # tiles whose width leaves a remainder (the frame's last column of tiles) take the scalar
    # tail; every width of it, far views where most tiles are faded ground
    scene = Scene(ball, look="studio")
    for factor, shift in ((7.5, (0.0, 0.0)), (20.0, (0.1, 0.05)), (4.0, (0.25, -0.2))):
        cam = at(Camera.fit(ball, width=width, height=height), factor, shift)
        fast, slow = render_both(monkeypatch, scene, cam, spp=1, threads=1)
        assert_same_bits(fast, slow, f"{width}x{height} at {factor}x")
        if factor >= 7.5 and width > 16:
            assert fast.stats["primary_background"] > 0
