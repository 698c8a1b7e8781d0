"""One side or two: ``SurfelScene(cull="auto")`` and ``Scene(two_sided="auto")`` cull back faces
where the surfels close a surface (:mod:`pointviz.sides`)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import pointviz
from pointviz import sides
from pointviz.cloud import PointCloud
from pointviz.errors import InputError
from pointviz.shapes import plane, sphere, torus

TORUS_R, TORUS_r = 1.0, 0.35


def torus_exact_hits(rays: np.ndarray) -> np.ndarray:
    """Which rays meet the exact torus of shapes.torus (axis y, radii TORUS_R, TORUS_r): the
    squared distance to the tube's core circle, G(t) = (hypot(x, z) - R)^2 + y^2, sampled at 400
    points across the bounding sphere and its least sample refined by a ternary search within a
    step either side; a hit when its minimum is below r^2."""
    o, d = rays[:, :3], rays[:, 3:]
    tc = -np.einsum("ij,ij->i", o, d)
    reach2 = (TORUS_R + TORUS_r) ** 2 - (np.einsum("ij,ij->i", o, o) - tc * tc)
    hit = np.zeros(len(rays), bool)
    idx = np.flatnonzero(reach2 > 0)
    h = np.sqrt(reach2[idx])

    def g(i, t):  # t: (len(i),) or (len(i), k)
        tt = t.reshape(len(i), -1)
        p = o[i][:, None, :] + d[i][:, None, :] * tt[..., None]
        return ((np.hypot(p[..., 0], p[..., 2]) - TORUS_R) ** 2 + p[..., 1] ** 2).reshape(t.shape)

    for b in range(0, len(idx), 2000):
        i, hb = idx[b:b + 2000], h[b:b + 2000]
        step = 2.0 * hb / 399.0
        ts = (tc[i] - hb)[:, None] + step[:, None] * np.arange(400)[None, :]
        k = np.argmin(g(i, ts), axis=1)
        lo, hi = ts[np.arange(len(i)), k] - step, ts[np.arange(len(i)), k] + step
        for _ in range(60):
            m1, m2 = lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0
            left = g(i, m1) < g(i, m2)
            hi = np.where(left, m2, hi)
            lo = np.where(left, lo, m1)
        hit[i] = g(i, 0.5 * (lo + hi)) < TORUS_r ** 2
    return hit


def back_faces(scene, rays) -> tuple[np.ndarray, np.ndarray]:
    """(hit, back): the rays that hit, and those whose hit is a disk's back face."""
    out = scene.cast_rays(rays, stats=False)
    hit = np.isfinite(out["t_hit"])
    back = hit & (np.einsum("ij,ij->i", out["normals"], rays[:, 3:]) > 0)
    return hit, back


def test_probe_rays_surround_the_sphere():
    c, r = np.array([1.0, -2.0, 0.5]), 0.7
    rays = sides.probe_rays(c, r, directions=32, grid=8)
    assert rays.shape == (32 * 64, 6)
    d = rays[:, 3:]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    # every origin lies outside the sphere, on the plane 2r behind its centre
    np.testing.assert_allclose(np.einsum("ij,ij->i", rays[:, :3] - c, d), -2.0 * r, atol=1e-9)
    # all around: the directions' mean is near zero, and both ends of every axis are seen
    dirs = d[::64]
    assert np.linalg.norm(dirs.mean(axis=0)) < 0.05
    assert (dirs.max(axis=0) > 0.9).all() and (dirs.min(axis=0) < -0.9).all()
    # the rays whose offset from the centre line is below r meet the sphere: pi/4 of a square
    off = np.linalg.norm(np.cross(c - rays[:, :3], d), axis=1)
    assert abs(np.mean(off < r) - np.pi / 4) < 0.05


@pytest.mark.parametrize("cloud", [sphere(6000), torus(12000)], ids=["sphere", "torus"])
def test_closed_surfaces_are_culled(cloud):
    s = pointviz.SurfelScene(cloud, cull="auto")
    assert s.back_face_share is not None and s.back_face_share < 0.02
    assert s.cull is True


def test_a_sheet_is_seen_from_both_sides():
    # a flat sheet shows its back to exactly the directions below it: half of a sphere's
    s = pointviz.SurfelScene(plane(4000), cull="auto")
    assert abs(s.back_face_share - 0.5) < 0.03
    assert s.cull is False


def test_an_open_shell_is_seen_from_both_sides():
    # the upper half of a sphere: from below, its inside faces the rays
    c = sphere(8000)
    keep = c.points[:, 1] > 0.0
    shell = PointCloud(c.points[keep], normals=c.normals[keep], radii=c.radii[keep])
    s = pointviz.SurfelScene(shell, cull="auto")
    assert s.back_face_share > 2 * sides.CLOSED_BACK_SHARE
    assert s.cull is False


def test_a_closed_surface_turned_inside_out_is_not_taken_for_closed():
    c = sphere(6000)
    s = pointviz.SurfelScene(PointCloud(c.points, normals=-c.normals, radii=c.radii), cull="auto")
    assert s.back_face_share > 0.95
    assert s.cull is False


def test_culling_drops_the_rim_back_faces_outside_the_silhouette_and_opens_no_hole():
    """Two-sided, a closed torus shows far-side disks from behind where they reach past the
    near side's rim; the exact torus says those pixels are background. One-sided they go, and
    no pixel of the exact torus is lost."""
    cloud = torus(20000)
    cam = pointviz.Camera.fit(cloud, width=240, height=180)
    rays = cam.rays()
    exact = torus_exact_hits(rays)
    hit2, back2 = back_faces(pointviz.SurfelScene(cloud, cull=False), rays)
    hit1, back1 = back_faces(pointviz.SurfelScene(cloud, cull="auto"), rays)
    assert back2.sum() >= 10  # the flecks exist two-sided
    assert (back2 & ~exact).sum() >= 0.75 * back2.sum()  # and lie outside the exact outline
    assert back1.sum() == 0
    holes2, holes1 = (exact & ~hit2).sum(), (exact & ~hit1).sum()
    assert holes1 <= holes2 + 1e-4 * exact.sum()
    assert (hit1 & ~exact).sum() < (hit2 & ~exact).sum()


def test_scene_default_is_auto():
    closed, sheet = sphere(3000), plane(3000)
    s = pointviz.Scene([closed, sheet])
    assert s.geometry(0).cull is True
    assert s.geometry(1).cull is False
    assert pointviz.Scene([closed], two_sided=True).geometry(0).cull is False
    assert pointviz.Scene([closed], two_sided=False).geometry(0).cull is True
    assert pointviz.Scene([sheet], two_sided=False).geometry(0).cull is True
    assert pointviz.Scene([closed], cull=False).geometry(0).cull is False  # explicit wins


def test_bad_values_are_named():
    with pytest.raises(InputError, match="two_sided"):
        pointviz.Scene([sphere(500)], two_sided="sometimes")
    with pytest.raises(InputError, match="cull"):
        pointviz.SurfelScene(sphere(500), cull="yes")


def test_the_decision_survives_pickling():
    s = pointviz.SurfelScene(sphere(3000), cull="auto")
    t = pickle.loads(pickle.dumps(s))
    assert t.cull is s.cull is True
    assert t.back_face_share == s.back_face_share


def test_the_cli_build_decides_too():
    from pointviz.commands.common import handed_over_scene

    scene = handed_over_scene(sphere(3000), None, "auto", "auto", {})
    assert scene.geometry(0).cull is True
    scene = handed_over_scene(plane(3000), None, "auto", "auto", {})
    assert scene.geometry(0).cull is False


@pytest.mark.data
@pytest.mark.slow
def test_real_scans(shared_data):
    """The dragon's 15 registered scans close a surface (its base unscanned: ~11 % back faces),
    and so does the Cyberware horse, a mesh saved inside out that loading turns; one of the
    bunny's range scans and a LiDAR tile do not."""
    dragon = pointviz.load(shared_data / "stanford_dragon/dragon_stand/dragonStandRight.conf")
    assert pointviz.SurfelScene(dragon, cull="auto").cull is True
    horse = pointviz.load(shared_data / "misc_scans/horse_cyberware.ply")
    assert any("inside out" in n for n in horse.notes)
    assert pointviz.SurfelScene(horse, cull="auto").back_face_share < 0.02
    one_scan = pointviz.load(shared_data / "stanford_bunny/data/bun000.ply")
    assert pointviz.SurfelScene(one_scan, cull="auto").cull is False
    tile = pointviz.load(shared_data / "lidar/simple.las")
    assert pointviz.SurfelScene(tile, cull="auto").cull is False


@pytest.mark.parametrize("points, radius", [
    (np.zeros((1, 3)), 0.1),                                            # one disk
    (np.zeros((50, 3)), 0.01),                                          # all in one place
    (np.c_[np.linspace(0, 1, 100), np.zeros(100), np.zeros(100)], 0.01),  # a line seen edge-on
    (np.random.default_rng(0).normal(size=(200, 3)), 1e-30),            # disks too small to hit
], ids=["one", "coincident", "line", "tiny"])
def test_degenerate_clouds_keep_both_sides(points, radius):
    n = len(points)
    cloud = PointCloud(points, normals=np.tile([0.0, 1.0, 0.0], (n, 1)), radii=np.full(n, radius))
    s = pointviz.SurfelScene(cloud, cull="auto")
    assert s.cull is False
    assert s.back_face_share is None or abs(s.back_face_share - 0.5) < 0.1
    cam = pointviz.Camera.fit(cloud, width=32, height=24)
    frame = pointviz.render(pointviz.Scene([cloud]), cam, spp=1)
    assert np.isfinite(frame.color).all()


def test_a_frame_asks_for_its_sides():
    """``render(..., sides=...)`` overrides each tree's own choice for that frame: "two" draws
    what a two-sided scene draws, bit for bit, and "one" what a culled one does."""
    cloud = torus(8000)
    cam = pointviz.Camera.fit(cloud, width=96, height=72)
    auto, both = pointviz.Scene([cloud]), pointviz.Scene([cloud], two_sided=True)
    assert auto.geometry(0).cull is True and both.geometry(0).cull is False
    kw = dict(spp=1, seed=3)

    def same(a, b):
        return all(np.array_equal(getattr(a, k), getattr(b, k))
                   for k in ("color", "depth", "normal", "alpha"))

    assert same(pointviz.render(auto, cam, sides="two", **kw), pointviz.render(both, cam, **kw))
    assert same(pointviz.render(both, cam, sides="one", **kw), pointviz.render(auto, cam, **kw))
    assert same(pointviz.render(both, cam, sides="auto", **kw), pointviz.render(auto, cam, **kw))
    two = pointviz.render(auto, cam, sides="two", **kw)
    one = pointviz.render(auto, cam, **kw)
    assert (two.object_alpha > 0).sum() > (one.object_alpha > 0).sum()  # the rim's back faces
    with pytest.raises(InputError, match="sides"):
        pointviz.render(auto, cam, sides="three", **kw)


def test_culls():
    closed = pointviz.SurfelScene(sphere(3000), cull=False)
    assert closed.back_face_share is None
    assert closed.culls() is False and closed.culls("one") is True
    assert closed.culls("auto") is True  # probed on first use
    assert closed.back_face_share < 0.02
    sheet = pointviz.SurfelScene(plane(3000), cull=True)
    assert sheet.culls() is True and sheet.culls("auto") is False and sheet.culls("two") is False


def test_the_sides_option():
    from pointviz.cli import build_parser
    from pointviz.commands.common import render_kwargs
    from pointviz.viewer.model import ViewerSettings

    def parsed(*opts):
        return render_kwargs(build_parser().parse_args(["render", "x.ply", "-o", "x.png", *opts]))

    assert parsed()["sides"] is None
    assert parsed("--sides", "two")["sides"] == "two"
    with pytest.raises(SystemExit):
        parsed("--sides", "three")
    assert ViewerSettings(sides="one").render_kwargs()["sides"] == "one"
    with pytest.raises(InputError, match="sides"):
        ViewerSettings(sides="both")
