"""The automatic exposure is metered on a small full-detail pass of the view
(pointviz.rendering.metered_exposure), so that every frame of a view is exposed alike whatever
its level of detail, samples or resolution.

Oracles: pointviz.images.auto_exposure applied by hand to an independent render of the pass
(given an exposure, so that it meters nothing itself), and equality between frames of one view.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from pointviz import Camera, PointCloud, render
from pointviz.errors import CancelledError, InputError
from pointviz.images import EXPOSURE_COVERAGE, auto_exposure
from pointviz.rendering import (METER_CROP, METER_MAX_SCALE, METER_MIN_COVERED, METER_PIXELS,
                                meter_crop, meter_size, metered_exposure)
from pointviz.scene import Scene
from pointviz.shapes import sphere

SETTINGS = {"reflections": 1, "threads": 1}


@pytest.fixture(scope="module")
def scene():
    """A sphere white on one side and nearly black on the other over the default ground: its
    mean luminance depends on the view, so a wrong metering shows."""
    ball = sphere(20000, 0.6)
    colors = np.where(ball.points[:, :1] > 0, 0.9, 0.04) * np.ones((1, 3))
    return Scene([PointCloud(ball.points, ball.normals, colors=colors)], up=(0, 1, 0))


def view(scene, width=160, height=120, distance=1.0, aside=0.0):
    """A view of the sphere from the lit, white side's edge, ``distance`` x the near one;
    ``aside``: the target moved that far to the view's right (the sphere toward the left)."""
    eye = np.array([1.2, 0.5, 1.6]) * distance
    right = np.cross(-eye / np.linalg.norm(eye), (0.0, 1.0, 0.0))
    target = aside * right / np.linalg.norm(right)
    return Camera(eye=tuple(eye), target=tuple(target), width=width, height=height)


def own_exposure(scene, cam, **kw):
    """auto_exposure of the frame's own pixels at full detail, one sample per pixel."""
    f = render(scene, cam, spp=1, lod_pixels=0, exposure=1.0, **{**SETTINGS, **kw})
    return auto_exposure(f.color, f.object_alpha)


def pass_exposure(scene, cam, scale=1, **kw):
    """auto_exposure of an independent full-detail, 1-spp render of the pass at ``scale``, and
    how many of its pixels the objects cover."""
    frame = render(scene, cam.with_size(*meter_size(cam.width, cam.height, scale)),
                   spp=1, lod_pixels=0, exposure=1.0, **{**SETTINGS, **kw})
    covered = int(np.count_nonzero(frame.object_alpha >= EXPOSURE_COVERAGE))
    return auto_exposure(frame.color, frame.object_alpha), covered


def counting_core_renders(monkeypatch):
    """The sizes of the core's renders from here on (the frames' and the metering passes')."""
    from pointviz import _core, rendering

    sizes = []
    real = _core.render

    def counting(rs, cam, settings, poll, **kw):
        sizes.append((cam.width, cam.height))
        return real(rs, cam, settings, poll, **kw)

    monkeypatch.setattr(rendering._core, "render", counting)
    return sizes


@pytest.mark.parametrize("size", [(640, 480), (480, 360), (1920, 1080), (81, 60), (40, 30),
                                  (1, 1), (5000, 1), (7, 100000)])
def test_meter_size_keeps_the_aspect_at_about_the_pixel_count(size):
    w, h = size
    mw, mh = meter_size(w, h)
    assert mw >= 1 and mh >= 1
    if mw > 1 and mh > 1:  # not an extreme aspect: about METER_PIXELS, the frame's aspect
        assert 0.9 * METER_PIXELS <= mw * mh <= 1.1 * METER_PIXELS
        assert mw / mh == pytest.approx(w / h, rel=0.05)
    assert meter_size(w, h, 4) == (4 * mw, 4 * mh)
    assert meter_size(2 * w, 2 * h) == (mw, mh)  # the resolution does not enter


VARIANTS = [dict(lod_pixels=0, spp=4), dict(lod_pixels=0, spp=1), dict(lod_pixels=1.0, spp=2),
            dict(lod_pixels=8.0, spp=1), dict(lod_pixels="auto", max_error=0.02, spp=1)]


def test_every_frame_of_a_near_view_is_exposed_alike(scene):
    """Full detail at 4 spp and 1 spp, fixed thresholds and the error budget: one exposure, the
    metering pass's (640x480: a 40x30 pass), close to the frame's own pixels'."""
    cam = view(scene, 640, 480)
    assert meter_size(640, 480) == (40, 30) and meter_crop(cam, scene.bounds()) is None
    expected, covered = pass_exposure(scene, cam)
    assert covered >= METER_MIN_COVERED
    exposures = [render(scene, cam, **v, **SETTINGS).exposure for v in VARIANTS]
    assert exposures == [expected] * len(VARIANTS)
    assert metered_exposure(scene, cam, **SETTINGS) == expected
    assert own_exposure(scene, cam) == pytest.approx(expected, rel=0.03)


def test_a_far_object_is_metered_on_a_crop_of_its_sphere(scene):
    """Where the objects' bounding sphere lies inside the view and would be small in the pass,
    a square crop at the frame's eye sees it edge to edge: every frame of the view takes its
    exposure, which keys the object as the frame's own pixels would."""
    for distance in (3.0, 9.0):
        cam = view(scene, 640, 480, distance)
        crop = meter_crop(cam, scene.bounds())
        assert crop is not None and (crop.width, crop.height) == (METER_CROP, METER_CROP)
        np.testing.assert_allclose(crop.eye, cam.eye)
        lo, hi = scene.bounds()
        np.testing.assert_allclose(crop.target, 0.5 * (lo + hi))
        exposures = [render(scene, cam, **v, **SETTINGS).exposure for v in VARIANTS]
        assert len(set(exposures)) == 1
        assert own_exposure(scene, cam) == pytest.approx(exposures[0], rel=0.06)


def test_a_view_takes_one_exposure_at_any_resolution(scene):
    """The pass depends on the view and the frame's aspect, not its resolution: the viewer's
    reduced moving frames, its still frames and the final Render agree, near and far."""
    for distance in (1.0, 9.0):
        exposures = {render(scene, view(scene, w, h, distance), spp=1, lod_pixels=lod,
                            **SETTINGS).exposure
                     for w, h in ((640, 480), (452, 339), (64, 48), (8, 6)) for lod in (0, 1.0)}
        assert len(exposures) == 1


def test_a_far_object_at_the_edge_is_metered_on_larger_passes(scene, monkeypatch):
    """A far object that crosses the frame's edge gets no crop; where it covers fewer than
    METER_MIN_COVERED pixels of the pass, the pass is taken again at twice the size each way,
    up to METER_MAX_SCALE: the exposure is that of the first pass that sees enough of it."""
    cam = view(scene, 640, 480, 9.0, aside=8.25)
    assert meter_crop(cam, scene.bounds()) is None
    first, covered = pass_exposure(scene, cam)
    assert 0 < covered < METER_MIN_COVERED  # the case under test
    scale = 1
    while scale < METER_MAX_SCALE:
        scale *= 2
        expected, covered = pass_exposure(scene, cam, scale)
        if covered >= METER_MIN_COVERED:
            break
    assert covered >= METER_MIN_COVERED and expected != first
    sizes = counting_core_renders(monkeypatch)
    assert [render(scene, cam, **v, **SETTINGS).exposure for v in VARIANTS[1:3]] == [expected] * 2
    mw, mh = meter_size(640, 480, METER_MAX_SCALE)
    assert len(sizes) > 3 and all(w <= mw and h <= mh for w, h in sizes[1:-1])
    assert own_exposure(scene, cam) == pytest.approx(expected, rel=0.06)


def test_a_view_without_the_objects_is_metered_on_one_small_pass(scene, monkeypatch):
    """Looking away from every object: one pass keys the whole frame (no larger passes for
    objects that cannot show)."""
    away = Camera(eye=(3.0, 0.5, 4.0), target=(6.0, 0.5, 8.0), width=640, height=480)
    sizes = counting_core_renders(monkeypatch)
    exposure = render(scene, away, spp=1, **SETTINGS).exposure
    assert sizes == [(640, 480), meter_size(640, 480)]
    expected, covered = pass_exposure(scene, away)
    assert covered == 0 and exposure == expected


def test_a_view_is_metered_once(scene, monkeypatch):
    """The frames of one view (the viewer's passes, a benchmark's variants) meter it once: the
    exposure is kept with the view's full-detail RenderScene. A changed setting that changes
    the picture meters again."""
    cam = view(scene, 320, 240, 1.5)
    assert meter_crop(cam, scene.bounds()) is None
    sizes = counting_core_renders(monkeypatch)
    first = render(scene, cam, spp=2, **SETTINGS).exposure
    assert sizes == [(320, 240), meter_size(320, 240)]  # the frame, then its metering pass
    again = [render(scene, cam, **v, **SETTINGS).exposure for v in VARIANTS]
    assert again == [first] * len(VARIANTS) and len(sizes) == 2 + len(VARIANTS)
    other = render(scene, cam, spp=2, shadows=False, **SETTINGS).exposure
    assert len(sizes) == 2 + len(VARIANTS) + 2
    assert other == pass_exposure(scene, cam, shadows=False)[0]


def test_the_metering_follows_the_settings_that_change_the_picture(scene):
    """Shadows, reflections and the look enter the metering pass as they enter the frame."""
    cam = view(scene, 320, 240)
    for kw in (dict(shadows=False), dict(reflections=0), dict(look="outdoor")):
        expected, _ = pass_exposure(scene, cam, **kw)
        assert render(scene, cam, spp=2, **{**SETTINGS, **kw}).exposure == expected
        assert metered_exposure(scene, cam, **{**SETTINGS, **kw}) == expected
    assert metered_exposure(scene, cam, look="flat", **SETTINGS) == 1.0
    assert render(scene, cam, look="flat", **SETTINGS).exposure == 1.0


def test_metering_checks_its_camera_and_can_be_cancelled(scene):
    with pytest.raises(InputError, match="camera"):
        metered_exposure(scene, None)
    with pytest.raises(InputError, match="shadows"):
        metered_exposure(scene, view(scene), shadows="yes")
    stop = threading.Event()
    stop.set()
    with pytest.raises(CancelledError):
        metered_exposure(scene, view(scene, 64, 48, 1.2), cancel=stop)
