"""Denoising: closer to a high-sample reference than the noisy frame, edges the tracer resolved
kept, the albedo guide against analytic scenes, and a clear error without the extra."""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np
import pytest

import pointviz
from pointviz.camera import Camera
from pointviz.errors import InputError, MissingDependencyError
from pointviz.images import linear_to_srgb, tonemap
from pointviz.scene import LOOKS, DirectionalLight, Material, Scene
from pointviz.shapes import plane, sphere

REFERENCE_SPP = 128


def _display(color, exposure):
    return linear_to_srgb(tonemap(color, exposure))


def _soft_shadow_scene():
    ball = sphere(20000, 0.5, (0.0, 0.7, 0.0), color=(0.9, 0.85, 0.8))
    sun = DirectionalLight(direction=(-0.6, 1.0, 0.4), intensity=1.2, angle_deg=6.0)
    scene = Scene([ball], lights=[sun], look="studio",
                  ground=Material.glossy((0.6, 0.6, 0.62), use_point_colors=False))
    cam = Camera.look_at((0.5, 2.0, 3.2), (0.0, 0.4, 0.0), width=160, height=120)
    return scene, cam


def test_denoised_frame_is_closer_to_the_reference_than_the_noisy_one():
    pytest.importorskip("pyoidn")
    scene, cam = _soft_shadow_scene()
    ref = pointviz.render(scene, cam, spp=REFERENCE_SPP, seed=99)
    f = pointviz.render(scene, cam, spp=4, denoise=True)
    target = _display(ref.color, ref.exposure)
    err_noisy = np.mean((_display(f.noisy_color, ref.exposure) - target) ** 2)
    err_denoised = np.mean((_display(f.color, ref.exposure) - target) ** 2)
    assert err_denoised < 0.5 * err_noisy
    assert f.stats["settings"]["denoise"] and f.stats["denoise_seconds"] > 0
    # the undenoised buffers stay available
    assert f.noisy_color.shape == f.color.shape and not np.array_equal(f.noisy_color, f.color)


def test_denoising_keeps_silhouettes_sharp():
    """A noise-free frame (flat look, no shadows) with hard silhouettes is left as it was."""
    pytest.importorskip("pyoidn")
    ball = sphere(20000, 0.5, (0.0, 0.0, 0.0), color=(0.9, 0.2, 0.1))
    scene = Scene([ball], look="flat", background=(0.05, 0.05, 0.05))
    cam = Camera.look_at((0.0, 0.0, 2.0), (0.0, 0.0, 0.0), width=64, height=64)
    f = pointviz.render(scene, cam, spp=1, denoise=True, shadows=False)
    edge = (f.alpha > 0) & (f.alpha < 1) | (np.abs(np.diff(f.alpha, axis=1, prepend=0)) > 0)
    assert edge.sum() > 50
    a, b = _display(f.color, 1.0), _display(f.noisy_color, 1.0)
    assert np.abs(a - b)[edge].mean() < 0.03
    # the silhouette's step stays one pixel wide: the brightest jump across it is kept
    row = f.height // 2
    step_before = np.abs(np.diff(b[row, :, 0])).max()
    step_after = np.abs(np.diff(a[row, :, 0])).max()
    assert step_after > 0.85 * step_before


def test_albedo_buffer_is_the_base_colour_and_follows_mirrors():
    ball = sphere(20000, 0.5, (0.0, 0.5, 0.0), color=(1.0, 1.0, 1.0))
    mat = Material(color=(0.2, 0.6, 0.3))
    mirror = Material(color=(0.9, 0.1, 0.1), mirror=1.0, specular=0.0, use_point_colors=False)
    scene = Scene([ball], materials=mat, ground=mirror, look="flat", background=(0.5, 0.5, 0.5))
    cam = Camera.look_at((0.0, 1.2, 3.0), (0.0, 0.3, 0.0), width=64, height=48)
    f = pointviz.render(scene, cam, spp=1, reflections=1)
    on_ball = f.object_alpha == 1
    np.testing.assert_allclose(f.albedo[on_ball], np.broadcast_to((0.2, 0.6, 0.3), f.albedo[on_ball].shape),
                               rtol=1e-6)
    # ground pixels: a perfect mirror shows the ball's albedo where it reflects the ball, the
    # sky (the flat look's is white) where it reflects the sky, never its own red
    ground = (f.alpha == 1) & (f.object_alpha == 0)
    assert ground.any()
    got = f.albedo[ground]
    is_ball = np.all(np.abs(got - (0.2, 0.6, 0.3)) < 1e-5, axis=1)
    is_bg = np.all(np.abs(got - 1.0) < 1e-5, axis=1)
    assert is_ball.any() and is_bg.any() and np.all(is_ball | is_bg)
    # misses: the background
    np.testing.assert_allclose(f.albedo[f.alpha == 0], 0.5, rtol=1e-6)


def test_denoise_without_pyoidn_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyoidn", None)  # import fails as if not installed
    cloud = sphere(500)
    cam = Camera.fit(cloud, width=8, height=8)
    with pytest.raises(MissingDependencyError, match=r"pointviz\[denoise\]"):
        pointviz.render(cloud, cam, denoise=True)
    # without denoising nothing changes
    assert pointviz.render(cloud, cam, spp=1).noisy_color is None


def test_denoise_image_rejects_bad_buffers():
    pytest.importorskip("pyoidn")
    from pointviz.denoise import denoise_image

    good = np.ones((4, 4, 3), np.float32)
    with pytest.raises(InputError, match="color"):
        denoise_image(np.ones((4, 4)))
    with pytest.raises(InputError, match="NaN"):
        denoise_image(np.full((4, 4, 3), np.nan, np.float32))
    with pytest.raises(InputError, match="albedo"):
        denoise_image(good, np.ones((2, 2, 3)))
    with pytest.raises(InputError, match="albedo too"):
        denoise_image(good, None, good)
    out = denoise_image(good, good, good * 0)
    assert out.shape == good.shape and np.isfinite(out).all()


def test_cli_render_look_and_denoise(tmp_path, capsys):
    from pointviz.cli import main

    out = tmp_path / "f.png"
    args = ["render", "demo", "-o", str(out), "--width", "48", "--height", "32", "--spp", "1",
            "--look", "flat", "--no-denoise"]
    assert main(args) == 0 and out.exists()
    with pytest.raises(SystemExit) as exc:  # argparse: one line naming the option
        main(["render", "demo", "-o", str(tmp_path / "g.png"), "--look", "noir"])
    assert exc.value.code != 0 and "--look" in capsys.readouterr().err


@pytest.mark.parametrize("quality", ["fast", "high"])
def test_denoising_keeps_a_hard_shadow_edge(quality):
    """A noise-free frame (hard sun, matte ground, no sky occlusion): the shadow's edge on the
    ground keeps its step, and the lit and shadowed ground keep their levels."""
    pytest.importorskip("pyoidn")
    from scipy.ndimage import gaussian_filter

    ball = sphere(20000, 0.5, (0.0, 0.8, 0.0), color=(0.9, 0.9, 0.9))
    sun = DirectionalLight(direction=(0.8, 1.0, 0.3), intensity=1.0, angle_deg=0.0)
    dim = replace(LOOKS["flat"], ambient=0.3)  # even sky light, dimmer: the shadow shows
    scene = Scene([ball], lights=[sun], look=dim, ground=Material(color=(0.7, 0.7, 0.7)))
    cam = Camera.look_at((0.0, 3.0, 0.01), (0.0, 0.0, 0.0), width=96, height=96)  # from above
    f = pointviz.render(scene, cam, spp=4, denoise=quality, reflections=0)
    a, b = _display(f.color, f.exposure), _display(f.noisy_color, f.exposure)
    ground = (f.alpha == 1) & (f.object_alpha == 0)
    lum = b[..., 1]
    lit, dark = ground & (lum > np.percentile(lum[ground], 90) - 0.01), ground & (lum < lum[ground].min() + 0.01)
    assert lit.sum() > 200 and dark.sum() > 50  # both sides of the edge are in the frame
    np.testing.assert_allclose(a[lit].mean(axis=0), b[lit].mean(axis=0), atol=0.02)
    np.testing.assert_allclose(a[dark].mean(axis=0), b[dark].mean(axis=0), atol=0.02)

    def row_steps(img):  # each row's steepest step between neighbouring ground pixels
        g = np.abs(np.diff(np.where(ground, img[..., 1], np.nan), axis=1))
        return np.nanmax(np.where(np.isnan(g), -1.0, g), axis=1)

    before = row_steps(b)
    rows = before > 0.1  # the rows that cross the shadow's edge
    assert rows.sum() > 15
    kept = np.median(row_steps(a)[rows] / before[rows])
    # the oracle of a blur: a Gaussian of 0.5 pixels keeps 0.74 of the step (the tracer's
    # antialiased edge), Open Image Denoise "fast" 0.87, "high" 0.94
    blurred = np.median(row_steps(gaussian_filter(b, (0.5, 0.5, 0)))[rows] / before[rows])
    assert blurred < 0.8 < kept


def test_a_reused_denoiser_gives_the_same_frame_as_a_new_one():
    pytest.importorskip("pyoidn")
    from pointviz.denoise import Denoiser

    scene, cam = _soft_shadow_scene()
    f = pointviz.render(scene, cam, spp=2, seed=3)
    g = pointviz.render(scene, cam.with_size(80, 60), spp=2, seed=3)
    with Denoiser("fast", threads=2) as reused:
        first = reused(f.color, f.albedo, f.normal, exposure=f.exposure)
        other = reused(g.color, g.albedo, g.normal, exposure=g.exposure)  # another size between
        unguided = reused(f.color)  # the guides unbound, then bound again
        again = reused(f.color, f.albedo, f.normal, exposure=f.exposure)
    with Denoiser("fast", threads=2) as new:
        fresh = new(f.color, f.albedo, f.normal, exposure=f.exposure)
    assert other.shape == g.color.shape and unguided.shape == f.color.shape
    assert not np.array_equal(unguided, first)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(first, fresh)
    with pytest.raises(InputError, match="close"):
        reused(f.color)


def test_exposure_is_the_filters_input_scale():
    """The exposure scales the filter's input, not its output: radiance k times brighter seen at
    an exposure k times lower denoises to k times the image."""
    pytest.importorskip("pyoidn")
    from pointviz.denoise import Denoiser

    scene, cam = _soft_shadow_scene()
    f = pointviz.render(scene, cam, spp=2)
    k = 8.0
    with Denoiser("fast") as d:
        base = d(f.color, f.albedo, f.normal, exposure=f.exposure)
        bright = d(f.color * k, f.albedo, f.normal, exposure=f.exposure / k)
        other = d(f.color, f.albedo, f.normal, exposure=4 * f.exposure)
    np.testing.assert_allclose(bright, k * base, rtol=1e-3, atol=1e-5 * k * base.max())
    assert np.abs(other - base).max() > 1e-3 * base.max()  # the scale is used at all
    # render(denoise=...) denoises at the frame's own exposure, with the denoiser it is given
    with Denoiser("fast") as d:
        g = pointviz.render(scene, cam, spp=2, denoise=d)
        np.testing.assert_array_equal(g.color, d(g.noisy_color, g.albedo, g.normal, exposure=g.exposure))
    assert g.stats["settings"]["denoise"] == "fast"


def test_denoiser_rejects_bad_options():
    pytest.importorskip("pyoidn")
    from pointviz.denoise import Denoiser

    with pytest.raises(InputError, match="denoise"):
        Denoiser("best")
    with pytest.raises(InputError, match="threads"):
        Denoiser("fast", threads=-1)
    with Denoiser("fast") as d:
        for bad in (0.0, -1.0, float("nan"), float("inf")):
            with pytest.raises(InputError, match="exposure"):
                d(np.ones((4, 4, 3), np.float32), exposure=bad)
    with pytest.raises(InputError, match="Denoiser"):
        pointviz.render(sphere(500), Camera.fit(sphere(500), width=8, height=8), denoise="best")


@pytest.mark.parametrize("quality", ["fast", "high"])
def test_denoiser_gives_what_pyoidn_gives(quality):
    """The library is called through ctypes: pyoidn's own wrapper, given the same buffers and
    settings, gives the same image, bit for bit (a second caller of the same C API)."""
    pyoidn = pytest.importorskip("pyoidn")
    from pointviz.denoise import Denoiser

    scene, cam = _soft_shadow_scene()
    f = pointviz.render(scene, cam, spp=2, seed=5)
    color = np.maximum(np.ascontiguousarray(f.color, np.float32), np.float32(0.0))
    albedo = np.ascontiguousarray(f.albedo, np.float32)
    normal = np.ascontiguousarray(f.normal, np.float32)
    want = np.empty_like(color)
    device = pyoidn.Device()
    device.set_int("numThreads", 2)
    device.commit()
    flt = pyoidn.Filter(device, "RT")
    for name, img in (("color", color), ("albedo", albedo), ("normal", normal), ("output", want)):
        flt.set_image(name, img, pyoidn.OIDN_FORMAT_FLOAT3)
    flt.set_bool("hdr", True)
    flt.set_bool("cleanAux", False)
    flt.set_quality({"fast": pyoidn.OIDN_QUALITY_FAST, "high": pyoidn.OIDN_QUALITY_HIGH}[quality])
    flt.set_float("inputScale", float(f.exposure))
    flt.commit()
    flt.execute()
    assert device.get_error() is None
    flt.release()
    device.release()
    with Denoiser(quality, threads=2) as d:
        got = d(f.color, f.albedo, f.normal, exposure=f.exposure)
    np.testing.assert_array_equal(got, np.maximum(want, np.float32(0.0)))
