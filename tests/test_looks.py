"""Looks: sky visibility (ambient occlusion) against an analytic crevice, shadowless fills, the
studio backdrop, automatic exposure, and the look chosen from the data."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import pointviz
from pointviz.camera import Camera
from pointviz.errors import InputError
from pointviz.images import EXPOSURE_COVERAGE, EXPOSURE_KEY, auto_exposure
from pointviz.scene import LOOKS, DirectionalLight, Scene
from pointviz.shapes import plane, sphere

#: Occlusion ray length of the crevice test, in bounding radii: longer than the crevice.
LONG_OCCLUSION = 10.0
#: Directions per point of the analytic visibility oracle.
ORACLE_DIRECTIONS = 4096


def _crevice():
    """Two 2 x 4 faces meeting at a right angle along the z axis: A in y = 0 (x in [0, 2],
    normal +y) and B in x = 0 (y in [0, 2], normal +x)."""
    full = plane(40000, size=4.0)
    keep = full.points[:, 0] > 0
    pa = full.points[keep]
    pb = pa[:, [1, 0, 2]]
    na = np.tile([0.0, 1.0, 0.0], (len(pa), 1))
    nb = na[:, [1, 0, 2]]
    r = full.radii[keep]
    cloud = pointviz.PointCloud(np.vstack([pa, pb]), normals=np.vstack([na, nb]),
                                radii=np.concatenate([r, r]))
    return cloud


def _visibility_on_a(points, length, rng):
    """Cosine-weighted fraction of directions from points of face A that do not meet face B
    within ``length`` (brute force over ORACLE_DIRECTIONS directions per point)."""
    u1, u2 = rng.random(ORACLE_DIRECTIONS), rng.random(ORACLE_DIRECTIONS)
    rad, phi = np.sqrt(u1), 2 * np.pi * u2
    d = np.stack([rad * np.cos(phi), np.sqrt(1 - u1), rad * np.sin(phi)], axis=1)  # around +y
    out = []
    for p in points:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -p[0] / d[:, 0]
        y, z = t * d[:, 1], p[2] + t * d[:, 2]
        blocked = (d[:, 0] < 0) & (t <= length) & (y >= 0) & (y <= 2) & (z >= -2) & (z <= 2)
        out.append(1.0 - blocked.mean())
    return np.array(out)


def _ambient_only(occlusion):
    return replace(LOOKS["flat"], occlusion=occlusion)


def test_occlusion_darkens_a_crevice_as_the_brute_force_says(rng):
    cloud = _crevice()
    cam = Camera.look_at((2.6, 2.6, 1.2), (0.35, 0.35, 0.0), up=(0, 0, 1), width=64, height=48)
    frames = [pointviz.render(Scene([cloud], look=_ambient_only(occ), ground="none"), cam,
                              spp=64, shadows=True, reflections=0) for occ in (0.0, LONG_OCCLUSION)]
    plain, occluded = frames
    assert plain.exposure == occluded.exposure == 1.0
    # hit points on face A near the fold
    rays = cam.rays().astype(np.float64).reshape(cam.height, cam.width, 6)
    p = rays[..., :3] + rays[..., 3:] * plain.depth[..., None]
    on_a = ((plain.alpha == 1) & (plain.normal[..., 1] > 0.99) & (p[..., 0] > 0.15)
            & (p[..., 0] < 0.6) & (np.abs(p[..., 2]) < 1.0))
    assert on_a.sum() > 30
    ratio = occluded.color[..., 1][on_a] / plain.color[..., 1][on_a]
    lo, hi = Scene([cloud]).bounds()
    length = LONG_OCCLUSION * np.linalg.norm(hi - lo) / 2
    oracle = _visibility_on_a(p[on_a], length, rng)
    assert 0.45 < oracle.mean() < 0.7  # a right-angle crevice hides about half the sky
    assert ratio.mean() == pytest.approx(oracle.mean(), abs=0.03)


def test_occlusion_leaves_an_open_plane_untouched():
    cloud = plane(20000, size=2.0)
    cam = Camera.look_at((0.0, 2.0, 1.5), (0.0, 0.0, 0.0), width=48, height=36)
    plain, occluded = (pointviz.render(Scene([cloud], look=_ambient_only(occ), ground="none"), cam,
                                       spp=4, reflections=0) for occ in (0.0, LONG_OCCLUSION))
    inside = plain.alpha == 1
    assert inside.mean() > 0.3
    np.testing.assert_allclose(occluded.color[inside], plain.color[inside], rtol=1e-5)


def test_a_fill_light_casts_no_shadow():
    ball = sphere(6000, 0.4, (0.0, 0.8, 0.0))
    floor = plane(20000, size=3.0)
    cam = Camera.look_at((0.0, 3.0, 0.01), (0.0, 0.0, 0.0), width=40, height=40)
    flat = replace(LOOKS["flat"], ambient=0.0)

    def frame(light_shadows, trace_shadows):
        light = DirectionalLight(direction=(1, 1, 0), intensity=1.0, angle_deg=0.0,
                                 shadows=light_shadows)
        return pointviz.render(Scene([floor, ball], lights=[light], look=flat, ground="none"),
                               cam, spp=1, reflections=0, shadows=trace_shadows)

    keyed, fill, unshadowed = frame(True, True), frame(False, True), frame(True, False)
    floor_px = (keyed.alpha == 1) & (keyed.depth > 2.5)
    g = keyed.color[..., 1][floor_px]
    assert g.min() < 0.05 * g.max()  # the key casts the ball's shadow on the floor
    np.testing.assert_array_equal(fill.color, unshadowed.color)  # the fill casts none


def test_studio_backdrop_has_no_horizon():
    ball = sphere(8000, 0.5, (0.0, 0.5, 0.0), color=(0.9, 0.9, 0.9))
    scene = Scene([ball], look="studio")
    assert scene.ground is not None
    cam = Camera.look_at((0.0, 0.6, 4.0), (0.0, 0.4, 0.0), width=64, height=48)
    f = pointviz.render(scene, cam, spp=2, reflections=0)
    rs, _ = scene.to_core(cam, 1.0)
    bg = np.asarray(rs.sky.background, dtype=np.float32)
    assert not rs.sky.background_is_sky and rs.sky.ground_fade > 0
    # the top rows (sky) and the far ground at the horizon show the same plain background
    np.testing.assert_allclose(f.color[0], np.broadcast_to(bg, f.color[0].shape), rtol=1e-6)
    row = int(np.argmax(f.alpha[:, 0] > 0))  # first ground row in the left column
    assert f.color[row, 0] == pytest.approx(bg, rel=0.05)


def test_exposure_keys_white_and_dark_objects_alike():
    cam = Camera.look_at((0.0, 0.8, 3.0), (0.0, 0.5, 0.0), width=48, height=36)
    shown = []
    for albedo in (0.95, 0.25):  # sRGB: white plaster, dark ground
        ball = sphere(8000, 0.5, (0.0, 0.5, 0.0), color=(albedo, albedo, albedo))
        scene = Scene([ball], look="studio")
        f = pointviz.render(scene, cam, spp=4)
        # metered on a small full-detail pass of the view, as every frame of it is
        assert f.exposure == pointviz.render(scene, cam, spp=1, lod_pixels=0).exposure
        # the object keyed: its pixels that show nothing else (the rims' mix with the backdrop
        # is not the object's luminance), within the pass's sampling of the mean
        obj = f.object_alpha >= 1.0
        lum = f.color[obj] @ [0.2126, 0.7152, 0.0722]
        assert lum.mean() * f.exposure == pytest.approx(EXPOSURE_KEY, rel=0.06)
        srgb = f.to_srgb8()[obj].mean() / 255
        shown.append(srgb)
    # neither washed out nor black, and close to each other
    assert all(0.45 < s < 0.85 for s in shown)
    assert abs(shown[0] - shown[1]) < 0.12


def test_auto_exposure_edge_cases():
    assert auto_exposure(np.zeros((4, 4, 3))) == 1.0
    assert auto_exposure(np.full((4, 4, 3), np.nan)) == 1.0
    assert auto_exposure(np.full((4, 4, 3), 1e6)) == pytest.approx(1 / 8)
    assert auto_exposure(np.full((4, 4, 3), 1e-9)) == pytest.approx(8.0)


def test_auto_exposure_averages_exactly_the_covered_pixels(rng):
    """The covered pixels, gathered by a loop over the frame in row order, give the same
    exposure to the last bit (same values in the same order), for C- and Fortran-ordered
    frames, with non-finite pixels and with no pixel covered."""
    for k in range(40):
        h, w = rng.integers(1, 60, 2)
        c = (rng.random((h, w, 3)) * rng.choice([0.01, 1.0, 10.0])).astype(np.float32)
        c[rng.random((h, w)) < 0.05] = np.inf
        oa = (rng.random((h, w)) < rng.random()).astype(np.float32) * rng.random()
        if k % 2:
            c = np.asfortranarray(c)
        rows = [c[y, x] for y in range(h) for x in range(w) if oa[y, x] >= EXPOSURE_COVERAGE]
        sel = np.array(rows if rows else [c[y, x] for y in range(h) for x in range(w)],
                       dtype=np.float64)
        lum = 0.2126 * sel[:, 0] + 0.7152 * sel[:, 1] + 0.0722 * sel[:, 2]
        lum = lum[np.isfinite(lum)]
        mean = float(lum.mean()) if lum.size else 0.0
        want = float(np.clip(EXPOSURE_KEY / mean, 1 / 8, 8.0)) if mean > 0 else 1.0
        assert auto_exposure(c, oa) == want


def test_look_from_the_data_and_bad_names(rng):
    xy = rng.uniform(-50, 50, (20000, 2))
    terrain = pointviz.PointCloud(np.column_stack([xy, np.sin(xy[:, 0] / 9) * 2]), up=(0, 0, 1))
    assert Scene([terrain]).look.name == "outdoor"
    assert Scene([terrain]).ground is None
    assert Scene([sphere(2000)]).look.name == "studio"
    assert Scene([sphere(2000)], look="flat").look.name == "flat"
    with pytest.raises(InputError, match="look"):
        Scene([sphere(2000)], look="noir")
    with pytest.raises(InputError, match="look"):
        pointviz.render(sphere(2000), Camera.fit(sphere(2000), width=8, height=8), look="noir")


def test_a_scene_sent_to_workers_keeps_its_look():
    import pickle

    rebuilt = pickle.loads(pickle.dumps(Scene([sphere(2000)], look="flat")))
    assert rebuilt.build() == 1 and rebuilt.look == LOOKS["flat"]
    assert Scene([sphere(2000)], look="studio").key != rebuilt.key
