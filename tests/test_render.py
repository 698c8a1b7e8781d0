"""Tests of final frames (pointviz.render, pointviz.scene, ext/ renderer).

Oracles: analytic shadows of a sphere over a plane, a mirrored copy of the scene for
reflections, analytic depth and normals of a sphere, and the renderer itself across thread
counts and seeds.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
from PIL import Image

import pointviz
from pointviz import Camera, DirectionalLight, Material, Scene, rendering, shapes
from pointviz.errors import CancelledError, InputError


def sphere_oracle(cam, center, radius):
    """Analytic depth (inf on a miss) and normals of a sphere for the camera's pixel centres."""
    rays = cam.rays(dtype=np.float64)
    o, d = rays[:, :3] - center, rays[:, 3:]
    b = np.einsum("ij,ij->i", o, d)
    c = np.einsum("ij,ij->i", o, o) - radius**2
    disc = b * b - c
    t = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    p = o + d * np.where(np.isfinite(t), t, 0)[:, None]
    n = p / radius
    return t.reshape(cam.height, cam.width), n.reshape(cam.height, cam.width, 3)


@pytest.fixture(scope="module")
def ball():
    return shapes.sphere(60_000, radius=1.0, center=(0.0, 1.5, 0.0), color=(0.8, 0.8, 0.8))


def test_depth_and_normal_buffers_match_analytic_sphere(ball):
    cam = Camera.look_at((0.3, 2.0, 5.0), (0, 1.5, 0), fov_deg=35, width=160, height=120)
    frame = pointviz.render(Scene(ball, ground="none"), cam, spp=1, lod_pixels=0, shadows=False,
                            reflections=0)
    t, n = sphere_oracle(cam, np.array([0, 1.5, 0]), 1.0)
    inside = np.isfinite(t)
    facing = np.abs(np.einsum("hwc,hwc->hw", n, cam.rays(dtype=np.float64)[:, 3:].reshape(n.shape))) > 0.3
    sel = inside & facing
    assert sel.sum() > 2000
    assert np.array_equal(frame.alpha[sel] > 0, np.ones(sel.sum(), bool))
    assert np.abs(frame.depth[sel] - t[sel]).max() < 0.01
    cosang = np.einsum("hwc,hwc->hw", frame.normal, n)[sel]
    assert np.degrees(np.arccos(np.clip(cosang, -1, 1))).mean() < 1.0
    assert (frame.alpha[~inside] == 0).mean() > 0.99  # misses are misses


def test_shadow_of_sphere_on_plane_matches_analytic(ball):
    # Light straight down, hard: the shadow is the disk under the sphere.
    cam = Camera.look_at((0.0, 6.0, 3.0), (0, 0, 0), fov_deg=40, width=160, height=120)
    light = DirectionalLight(direction=(0, 1, 0), intensity=1.0, angle_deg=0.0)
    scene = Scene(ball, lights=[light], ground=Material(color=(0.8, 0.8, 0.8), specular=0.0),
                  ambient=0.0)
    frame = pointviz.render(scene, cam, spp=1, reflections=0)
    h = scene.ground_point()[1]  # "auto" ground: just under the sphere
    assert 0.45 < h <= 0.5
    rays = cam.rays(dtype=np.float64)
    t_ground = (h - rays[:, 1]) / rays[:, 4]
    p = rays[:, :3] + rays[:, 3:] * t_ground[:, None]
    on_ground = (np.abs(frame.depth.ravel() - t_ground) < 1e-3 * t_ground)
    in_shadow = np.hypot(p[:, 0], p[:, 2]) < 1.0
    lum = frame.color.mean(axis=2).ravel()
    dark = lum < 0.05
    # compare away from the shadow's rim: one pixel's footprint on the ground
    rim = np.abs(np.hypot(p[:, 0], p[:, 2]) - 1.0) < 2.0 * cam.pixel_angle * t_ground
    sel = on_ground & ~rim
    assert sel.sum() > 5000 and (sel & in_shadow).sum() > 200
    assert np.array_equal(dark[sel], in_shadow[sel])


def test_no_shadow_acne_on_lit_curved_surface(ball):
    # Every front-facing point of the sphere lit at more than ~10 degrees must be lit.
    cam = Camera.look_at((0.0, 1.5, 5.0), (0, 1.5, 0), fov_deg=35, width=160, height=120)
    light = DirectionalLight(direction=(0.3, 0.8, 1.0), angle_deg=0.0)
    scene = Scene(ball, lights=[light], ground="none", ambient=0.0,
                  materials=Material(specular=0.0))
    frame = pointviz.render(scene, cam, spp=1, reflections=0)
    _, n = sphere_oracle(cam, np.array([0, 1.5, 0]), 1.0)
    ldir = np.array([0.3, 0.8, 1.0]) / np.linalg.norm([0.3, 0.8, 1.0])
    ndl = np.einsum("hwc,c->hw", n, ldir)
    lit = (frame.alpha == 1) & (ndl > 0.2)
    albedo = 0.7 * 0.6038  # base colour 0.7 x the sRGB-decoded point colour 0.8
    ratio = frame.color.mean(axis=2)[lit] / (albedo * ndl[lit])
    assert lit.sum() > 3000
    assert np.quantile(ratio, 0.001) > 0.8  # not one pixel in a thousand wrongly shadowed


def test_mirror_floor_shows_mirror_image():
    # Uniform sky and constant ambient light only: shading does not depend on orientation, so
    # the mirror's picture must equal the mirrored cloud rendered directly.
    ball = shapes.sphere(40_000, radius=0.8, center=(0.0, 1.2, 0.0))
    shade = np.clip(0.2 + 0.6 * (ball.points[:, 1:2] - 0.4) / 1.6, 0, 1)
    colors = np.repeat(shade, 3, axis=1) * [1.0, 0.6, 0.3]
    obj = pointviz.PointCloud(ball.points, ball.normals, ball.radii, colors)
    mirror = Material(color=(1, 1, 1), diffuse=0.0, specular=0.0, mirror=1.0, use_point_colors=False)
    mat = Material(specular=0.0)
    sky = (0.7, 0.75, 0.8)  # one colour: reflected and direct misses see the same
    a = Scene(obj, ground=mirror, materials=mat, lights=[], ambient=1.0, sky=sky)
    h = a.ground_point()[1]
    flipped = ball.points.copy()
    flipped[:, 1] = 2 * h - flipped[:, 1]
    normals = ball.normals * np.array([1.0, -1.0, 1.0], np.float32)
    mirrored = pointviz.PointCloud(flipped, normals, ball.radii, colors)
    b = Scene([obj, mirrored], ground="none", materials=[mat, mat], lights=[], ambient=1.0, sky=sky)
    cam = Camera.look_at((0.0, 1.5, 5.0), (0, 0.0, 0), fov_deg=45, width=160, height=120)
    fa = pointviz.render(a, cam, spp=1, reflections=1, lod_pixels=0, shadows=False)
    fb = pointviz.render(b, cam, spp=1, reflections=1, lod_pixels=0, shadows=False)
    rays = cam.rays(dtype=np.float64)
    down = rays[:, 4] < 0
    t_floor = np.where(down, (h - rays[:, 1]) / np.where(down, rays[:, 4], -1.0), np.inf)
    behind = (fb.depth.ravel() > t_floor) & np.isfinite(fb.depth.ravel())
    sel = behind.reshape(fb.depth.shape) & (fa.alpha == 1)
    assert sel.sum() > 1000
    diff = np.abs(fa.color - fb.color).mean(axis=2)[sel]
    assert np.median(diff) < 0.01 and np.quantile(diff, 0.95) < 0.05


def test_frames_identical_across_thread_counts(ball):
    scene, cam = shapes.demo_scene(detail=0.2)
    cam = cam.with_size(96, 64)
    f1 = pointviz.render(scene, cam, spp=4, threads=1, seed=7)
    f2 = pointviz.render(scene, cam, spp=4, threads=2, seed=7)
    f3 = pointviz.render(scene, cam, spp=4, threads=2, seed=8)
    for key in ("color", "depth", "normal", "alpha"):
        np.testing.assert_array_equal(getattr(f1, key), getattr(f2, key))
    assert not np.array_equal(f1.color, f3.color)  # the seed matters (soft light, antialiasing)


def test_lod_changes_the_image_little_at_one_pixel():
    """Objects standing on a mirror ground: at 1 px the frame stays within 38 dB of full detail.
    Rays leaving the (exact) ground keep full detail's clearance: with a footprint-sized one
    they passed the objects' feet (the mirror showed the background through them: 24.9 dB with
    the objects culled, 30.7 two-sided)."""
    scene, cam = shapes.demo_scene(detail=0.5)
    cam = cam.with_size(200, 125)
    full = pointviz.render(scene, cam, spp=1, lod_pixels=0, seed=0)
    lod = pointviz.render(scene, cam, spp=1, lod_pixels=1.0, seed=0)
    a = full.to_srgb8().astype(float)
    b = lod.to_srgb8().astype(float)
    mse = np.mean((a - b) ** 2)
    psnr = 10 * np.log10(255.0**2 / max(mse, 1e-12))
    assert psnr > 38.0


def test_cancel_stops_and_raises(ball):
    cam = Camera.look_at((0.3, 2.0, 5.0), (0, 1.5, 0), width=320, height=240)
    stop = threading.Event()
    seen = []

    def progress(done, total):
        seen.append((done, total))
        stop.set()

    with pytest.raises(CancelledError):
        pointviz.render(ball, cam, spp=64, progress=progress, cancel=stop)
    assert seen and seen[-1][0] < seen[-1][1]

    with pytest.raises(CancelledError):
        pointviz.render(ball, cam, spp=64, progress=lambda d, t: False)


def test_progress_reaches_total(ball):
    cam = Camera.look_at((0.3, 2.0, 5.0), (0, 1.5, 0), width=64, height=48)
    seen = []
    pointviz.render(ball, cam, spp=1, progress=lambda d, t: seen.append((d, t)))
    assert seen[-1][0] == seen[-1][1] > 0


def test_save_png_8_and_16_bit_and_refuse_overwrite(ball, tmp_path):
    cam = Camera.look_at((0.3, 2.0, 5.0), (0, 1.5, 0), width=48, height=32)
    frame = pointviz.render(ball, cam, spp=1)
    p8 = frame.save(tmp_path / "a.png")
    assert np.array_equal(np.asarray(Image.open(p8)), frame.to_srgb8())
    p16 = frame.save(tmp_path / "b.png", bits=16)
    img16 = _read_png16(p16)
    assert img16.dtype == np.uint16 and img16.shape == (32, 48, 3)
    # the same picture as the 8-bit file, with 257 times finer steps (65535 = 255 * 257)
    assert np.abs(img16 / 257.0 - frame.to_srgb8()).max() <= 0.5 + 1e-6
    assert len(np.unique(img16 % 257)) > 1  # not 8-bit values scaled up
    before = p8.read_bytes()
    with pytest.raises(FileExistsError):
        frame.save(p8)
    assert p8.read_bytes() == before
    assert not list(tmp_path.glob("*.part"))


def _read_png16(path) -> np.ndarray:
    """(h, w, c) pixels of a PNG read by VTK's reader, the independent 16-bit decoder (Pillow
    reads 48-bit RGB as 8-bit)."""
    vtk = pytest.importorskip("vtk", reason="VTK's PNG reader is the independent 16-bit decoder")
    from vtk.util.numpy_support import vtk_to_numpy

    reader = vtk.vtkPNGReader()
    reader.SetFileName(str(path))
    reader.Update()
    img = reader.GetOutput()
    w, h, _ = img.GetDimensions()
    arr = vtk_to_numpy(img.GetPointData().GetScalars())
    return arr.reshape(h, w, -1)[::-1]  # VTK is bottom-up


def test_sixteen_bit_png_round_trip(tmp_path):
    from pointviz.images import encode_png

    px = (np.arange(4 * 5 * 3, dtype=np.uint16).reshape(4, 5, 3) * 1000)
    (tmp_path / "x.png").write_bytes(encode_png(px))
    arr = _read_png16(tmp_path / "x.png")
    assert arr.dtype == np.uint16
    assert np.array_equal(arr, px)


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_png_pixels_round_trip_through_other_decoders(tmp_path, channels):
    """Row filtering and the deflate level change the bytes, never the pixels: random pixels (the
    row differences wrap around modulo 256) read back by Pillow (8 bits) and VTK (16 bits)."""
    from pointviz.images import encode_png

    rng = np.random.default_rng(channels)
    px8 = rng.integers(0, 256, size=(7, 11, channels), dtype=np.uint8)
    (tmp_path / "x8.png").write_bytes(encode_png(px8))
    assert np.array_equal(np.array(Image.open(tmp_path / "x8.png")).reshape(px8.shape), px8)
    if channels == 3:
        px16 = rng.integers(0, 65536, size=(6, 9, 3), dtype=np.uint16)
        (tmp_path / "x16.png").write_bytes(encode_png(px16))
        assert np.array_equal(_read_png16(tmp_path / "x16.png"), px16)


@pytest.mark.parametrize("kwargs, message", [
    ({"spp": 0}, "spp"),
    ({"reflections": -1}, "reflections"),
    ({"lod_pixels": float("nan")}, "lod_pixels"),
    ({"threads": 0}, "threads"),
    ({"cancel": 3}, "cancel"),
])
def test_bad_render_arguments_are_named(ball, kwargs, message):
    cam = Camera.look_at((0.3, 2.0, 5.0), (0, 1.5, 0), width=8, height=8)
    with pytest.raises(InputError, match=message):
        pointviz.render(ball, cam, **kwargs)


def test_bad_scene_arguments_are_named(ball):
    with pytest.raises(InputError, match="ground"):
        Scene(ball, ground="lava")
    with pytest.raises(InputError, match="material.mirror"):
        Material(mirror=2.0)
    with pytest.raises(InputError, match="materials"):
        Scene([ball, ball], materials=[Material()])
    with pytest.raises(InputError, match="camera"):
        pointviz.render(ball, None)


def test_cli_render_and_errors(tmp_path, capsys):
    from pointviz.cli import main

    out = tmp_path / "demo.png"
    assert main(["render", "demo", "-o", str(out), "--width", "64", "--spp", "1"]) == 0
    assert Image.open(out).size == (64, 40)
    assert main(["render", "demo", "-o", str(out), "--width", "64"]) == 2  # exists
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0]
    assert main(["render", str(tmp_path / "missing.ply"), "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.ply" in err[0]
    assert main(["render", "demo", "-o", str(tmp_path / "y.png"), "--light", "0,0,0"]) == 2


def test_saved_files_get_normal_permissions_and_exr_round_trips(ball, tmp_path):
    import os

    from pointviz.files import default_file_mode

    cam = Camera.look_at((0.3, 2.0, 5.0), (0, 1.5, 0), width=24, height=16)
    frame = pointviz.render(ball, cam, spp=1)
    png = frame.save(tmp_path / "a.png")
    assert os.stat(png).st_mode & 0o777 == default_file_mode()
    exr_mod = pytest.importorskip("OpenEXR", reason="EXR output needs the OpenEXR package")
    exr = frame.save(tmp_path / "a.exr")
    with exr_mod.File(str(exr)) as f:
        rgb = f.channels()["RGB"].pixels
    np.testing.assert_array_equal(rgb, frame.color)


def test_silhouette_coverage_matches_analytic_sphere(ball):
    """Antialiased edges: alpha equals the fraction of the pixel the exact sphere covers
    (16x16 supersampled analytic oracle), so disks do not make the outline ragged."""
    cam = Camera.look_at((0.0, 1.5, 4.0), (0, 1.5, 0), fov_deg=40, width=64, height=48)
    frame = pointviz.render(Scene(ball, ground="none"), cam, spp=64, shadows=False,
                            reflections=0, lod_pixels=0)
    k = 16
    fine = cam.with_size(64 * k, 48 * k)
    t, _ = sphere_oracle(fine, np.array([0, 1.5, 0]), 1.0)
    cover = np.isfinite(t).reshape(48, k, 64, k).mean(axis=(1, 3))
    edge = (cover > 0.02) & (cover < 0.98)
    assert edge.sum() > 60
    err = np.abs(frame.alpha - cover)
    assert err[edge].mean() < 0.08
    assert err[~edge].max() < 0.1


def test_open_surface_seen_from_behind_is_visible_by_default():
    """A one-sided scan (normals toward the scanner) seen from the back: the default two-sided
    scene shows it; the paper's culling (two_sided=False) hides it."""
    sheet = shapes.plane(20_000, size=2.0, center=(0.0, 1.0, 0.0))  # normals +y
    cam = Camera.look_at((0.0, -2.0, 0.3), (0.0, 1.0, 0.0), width=48, height=48)  # from below
    seen = pointviz.render(Scene(sheet, ground="none"), cam, spp=1)
    hidden = pointviz.render(Scene(sheet, ground="none", two_sided=False), cam, spp=1)
    rays = cam.rays(dtype=np.float64)
    t = (1.0 - rays[:, 1]) / rays[:, 4]
    p = rays[:, :3] + rays[:, 3:] * t[:, None]
    inside = ((np.abs(p[:, 0]) < 1.0) & (np.abs(p[:, 2]) < 1.0)).reshape(48, 48)
    assert inside.mean() > 0.5
    assert np.mean((seen.alpha > 0) == inside) > 0.98
    assert hidden.alpha.max() == 0


def test_save_creates_missing_folders_but_not_over_a_file(ball, tmp_path):
    cam = Camera.look_at((0.3, 2.0, 5.0), (0, 1.5, 0), width=8, height=8)
    frame = pointviz.render(ball, cam, spp=1)
    out = frame.save(tmp_path / "a" / "b" / "x.png")
    assert out.exists()
    (tmp_path / "file").write_text("keep")
    with pytest.raises(InputError, match="not a folder"):
        frame.save(tmp_path / "file" / "x.png")
    assert (tmp_path / "file").read_text() == "keep"


def test_cli_render_hands_the_cloud_over_to_the_build(tmp_path, rng):
    """``pointviz render`` gives the loaded cloud to its tree's build (consume_cloud=True): the
    tree is the one a kept cloud builds, bit for bit, and the frame the same to float32 rounding
    of the bounds and ground (which come from the tree's surfels)."""
    from pointviz.cli import build_parser, main
    from pointviz.commands.common import make_scene_and_camera

    n = 4000
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    path = tmp_path / "ball.xyzn"
    np.savetxt(path, np.hstack([p * 2.0 + [3.0, 1.0, -2.0], p]), fmt="%.9f")
    argv = ["render", str(path), "-o", str(tmp_path / "f.png"), "--width", "64", "--height",
            "48", "--spp", "1", "--no-denoise"]
    args = build_parser().parse_args(argv)
    kept, cam_kept = make_scene_and_camera(args)
    given, cam_given = make_scene_and_camera(args, hand_over=True)
    assert cam_given.eye == pytest.approx(cam_kept.eye) and cam_given.width == 64
    tree = given.geometry(0)
    assert isinstance(tree, pointviz.SurfelScene) and tree.cloud is None
    np.testing.assert_array_equal(tree.tree.surfel_view(), kept.geometry(0).tree.surfel_view())
    assert tree.trace_options().cull == kept.geometry(0).trace_options().cull
    assert given.look == kept.look and given.ground == kept.ground
    np.testing.assert_allclose(given.up, kept.up)
    for a, b in zip(given.bounds(), kept.bounds()):
        np.testing.assert_allclose(a, b, atol=1e-6)
    a = pointviz.render(given, cam_given, spp=1, denoise=False)
    b = pointviz.render(kept, cam_kept, spp=1, denoise=False)
    np.testing.assert_array_equal(a.alpha, b.alpha)
    assert np.abs(a.color - b.color).max() < 1e-3
    assert main(argv) == 0 and (tmp_path / "f.png").exists()


def _fresh(scene_or_cloud):
    """The same scene with no kept RenderScene (rendering._core_scene's memo dropped)."""
    holder = scene_or_cloud._memo if isinstance(scene_or_cloud, Scene) else scene_or_cloud.__dict__
    holder.pop(rendering._CORE_MEMO, None)
    return scene_or_cloud


def _same_frame(a, b):
    return all(np.array_equal(getattr(a, k).view(np.uint32), getattr(b, k).view(np.uint32))
               for k in ("color", "depth", "normal", "alpha", "albedo", "object_alpha")) \
        and a.exposure == b.exposure


def test_a_kept_render_scene_gives_the_frame_a_new_one_gives():
    # render() keeps the last RenderScene with the SurfelScene or Scene it was asked of, keyed
    # by the camera, lod_pixels / max_error, the ground and look asked for and the trees'
    # options. Oracle: the same frame with nothing kept. Each change of a key must be seen.
    cloud = shapes.torus(30_000, color=(0.8, 0.5, 0.3))
    ss = pointviz.SurfelScene(cloud, threads=1)
    base = Camera.fit(cloud, width=64, height=48)
    far = Camera.look_at(np.asarray(base.target) - np.asarray(base.forward) * base.distance * 5,
                         base.target, up=base.true_up, width=64, height=48)
    turned = Camera.look_at(np.asarray(base.target) + np.asarray(base.right) * base.distance * 5,
                            base.target, up=base.true_up, width=64, height=48)
    kw = dict(spp=1, threads=1, shadows=True)
    frames = [
        (ss, far, dict(lod_pixels="auto", max_error=0.005)),
        (ss, far, dict(lod_pixels="auto", max_error=0.005)),   # kept
        (ss, far, dict(lod_pixels="auto", max_error=0.02)),
        (ss, far, dict(lod_pixels=1.0)),
        (ss, base, dict(lod_pixels="auto", max_error=0.005)),
        (ss, turned, dict(lod_pixels="auto", max_error=0.005)),   # the look's lights turn too
        (ss, turned, dict(lod_pixels="auto", max_error=0.005, look="outdoor")),
        (ss, turned, dict(lod_pixels="auto", max_error=0.005, ground="glossy")),
        (ss, turned, dict(lod_pixels=0.0)),
    ]
    for scene, cam, v in frames:
        kept = pointviz.render(scene, cam, **kw, **v)
        assert rendering._CORE_MEMO in ss.__dict__
        fresh = pointviz.render(_fresh(scene), cam, **kw, **v)
        assert _same_frame(kept, fresh), (cam.eye, v)
    # several are kept (a benchmark's interleaved variants of one view), the oldest dropped
    first = rendering._core_scene(_fresh(ss), {}, far, "auto", 0.005)
    rendering._core_scene(ss, {}, far, 1.0, None)
    trees, entries = ss.__dict__[rendering._CORE_MEMO]
    assert trees is None and len(entries) == 2
    assert rendering._core_scene(ss, {}, far, "auto", 0.005)[0] is first[0]
    for k in range(rendering.CORE_SCENES_KEPT):
        rendering._core_scene(ss, {}, far, float(k + 2), None)
    assert len(entries) == rendering.CORE_SCENES_KEPT
    assert rendering._core_scene(ss, {}, far, "auto", 0.005)[0] is not first[0]
    # a Scene keeps its own; the SurfelScene inside it is not the key
    sc = Scene(ss, ground="mirror")
    for cam in (far, turned, far):
        kept = pointviz.render(sc, cam, **kw, lod_pixels="auto", max_error=0.005)
        assert rendering._CORE_MEMO in sc._memo
        assert _same_frame(kept, pointviz.render(_fresh(sc), cam, **kw, lod_pixels="auto",
                                                 max_error=0.005))
    # the trees' options are settable in place: a frame after a change sees it
    v = dict(lod_pixels=4.0)
    before = pointviz.render(ss, far, **kw, **v)
    ss._options.lod = False
    try:
        after = pointviz.render(ss, far, **kw, **v)
        assert _same_frame(after, pointviz.render(_fresh(ss), far, **kw, **v))
        assert not _same_frame(after, before)  # (the change is visible: the test can fail)
    finally:
        ss._options.lod = True
    assert _same_frame(before, pointviz.render(ss, far, **kw, **v))


def test_a_kept_render_scene_keeps_no_cycle_on_the_surfel_scene():
    # the SurfelScene keeps its last RenderScene in its __dict__, which must not refer back to
    # it: a dropped cloud's tree is freed by reference counting, not by a later garbage cycle
    import gc
    import weakref

    cloud = shapes.sphere(5_000)
    ss = pointviz.SurfelScene(cloud, threads=1)
    pointviz.render(ss, Camera.fit(cloud, width=32, height=24), spp=1, threads=1,
                    lod_pixels="auto", max_error=0.005)
    assert rendering._CORE_MEMO in ss.__dict__
    ref = weakref.ref(ss)
    gc.disable()
    try:
        del ss
        assert ref() is None
    finally:
        gc.enable()
