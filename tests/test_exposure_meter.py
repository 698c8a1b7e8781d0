"""The automatic exposure is metered on a small full-detail pass of the view
(pointviz.rendering.metered_exposure), so that every frame of a view is exposed alike whatever
its level of detail or samples.

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
from pointviz.rendering import (METER_MIN_COVERED, METER_PIXELS, meter_divisor, meter_size,
                                metered_exposure)
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


def view(scene, width=160, height=120, distance=1.0):
    """A view of the sphere from the lit, white side's edge, ``distance`` x the near one."""
    return Camera(eye=(1.2 * distance, 0.5 * distance, 1.6 * distance), target=(0.0, 0.0, 0.0),
                  width=width, height=height)


def pass_exposure(scene, cam, divisor, **kw):
    """auto_exposure of an independent full-detail, 1-spp render of the pass at ``divisor``,
    and how many of its pixels the objects cover."""
    frame = render(scene, cam.with_size(*meter_size(cam.width, cam.height, divisor)),
                   spp=1, lod_pixels=0, exposure=1.0, **{**SETTINGS, **kw})
    covered = int(np.count_nonzero(frame.object_alpha >= EXPOSURE_COVERAGE))
    return auto_exposure(frame.color, frame.object_alpha), covered


@pytest.mark.parametrize("size", [(640, 480), (480, 360), (1920, 1080), (81, 60), (64, 48),
                                  (1, 1), (5000, 1), (7, 100000)])
def test_meter_size_is_the_smallest_divisor_within_the_pixel_count(size):
    w, h = size
    s = meter_divisor(w, h)
    mw, mh = meter_size(w, h)
    assert (mw, mh) == (-(-w // s), -(-h // s)) and mw * mh <= METER_PIXELS
    assert s == 1 or -(-w // (s - 1)) * -(-h // (s - 1)) > METER_PIXELS
    if w * h <= METER_PIXELS:
        assert (mw, mh) == (w, h)


def test_every_frame_of_a_view_is_exposed_alike(scene):
    """Full detail at 4 spp and 1 spp, fixed thresholds and the error budget: one exposure, the
    metering pass's (640x480: an 80x60 pass)."""
    cam = view(scene, 640, 480)
    assert meter_size(640, 480) == (80, 60)
    expected, covered = pass_exposure(scene, cam, meter_divisor(640, 480))
    assert covered >= METER_MIN_COVERED
    variants = [dict(lod_pixels=0, spp=4), dict(lod_pixels=0, spp=1), dict(lod_pixels=1.0, spp=2),
                dict(lod_pixels=8.0, spp=1), dict(lod_pixels="auto", max_error=0.02, spp=1)]
    exposures = [render(scene, cam, **v, **SETTINGS).exposure for v in variants]
    assert exposures == [expected] * len(variants)
    assert metered_exposure(scene, cam, **SETTINGS) == expected
    # and it keys the frame as its own pixels would, within the pass's sampling of the mean
    full = render(scene, cam, lod_pixels=0, spp=4, **SETTINGS)
    assert auto_exposure(full.color, full.object_alpha) == pytest.approx(expected, rel=0.03)


def test_the_metering_follows_the_settings_that_change_the_picture(scene):
    """Shadows, reflections and the look enter the metering pass as they enter the frame."""
    cam = view(scene, 320, 240)
    s = meter_divisor(320, 240)
    for kw in (dict(shadows=False), dict(reflections=0), dict(look="outdoor")):
        expected, _ = pass_exposure(scene, cam, s, **kw)
        assert render(scene, cam, spp=2, **{**SETTINGS, **kw}).exposure == expected
        assert metered_exposure(scene, cam, **{**SETTINGS, **kw}) == expected
    assert metered_exposure(scene, cam, look="flat", **SETTINGS) == 1.0
    assert render(scene, cam, look="flat", **SETTINGS).exposure == 1.0


def test_a_small_full_detail_frame_is_metered_on_its_own_pixels(scene):
    cam = view(scene, 64, 48)
    frame = render(scene, cam, spp=1, lod_pixels=0, **SETTINGS)
    assert frame.exposure == auto_exposure(frame.color, frame.object_alpha)
    # the same view with level of detail or more samples meters a pass of the same size
    assert render(scene, cam, spp=3, **SETTINGS).exposure == frame.exposure


def test_a_far_object_is_metered_on_a_larger_pass(scene):
    """Where the objects cover fewer than METER_MIN_COVERED pixels of the pass, it is taken
    again at twice the size each way: the exposure is that of the first pass that sees enough
    of them."""
    cam = view(scene, 640, 480, distance=9.0)
    s = meter_divisor(640, 480)
    first, covered = pass_exposure(scene, cam, s)
    assert 0 < covered < METER_MIN_COVERED  # the case under test
    while s > 1:
        s //= 2
        expected, covered = pass_exposure(scene, cam, s)
        if covered >= METER_MIN_COVERED:
            break
    assert covered >= METER_MIN_COVERED and expected != first
    assert render(scene, cam, spp=1, **SETTINGS).exposure == expected
    full = render(scene, cam, lod_pixels=0, spp=1, exposure=1.0, **SETTINGS)
    assert auto_exposure(full.color, full.object_alpha) == pytest.approx(expected, rel=0.05)


def test_metering_checks_its_camera_and_can_be_cancelled(scene):
    with pytest.raises(InputError, match="camera"):
        metered_exposure(scene, None)
    with pytest.raises(InputError, match="shadows"):
        metered_exposure(scene, view(scene), shadows="yes")
    stop = threading.Event()
    stop.set()
    with pytest.raises(CancelledError):
        metered_exposure(scene, view(scene), cancel=stop)
