"""Where point-based ray tracing fails, it must fail gracefully and visibly.

- Sparse sampling: where the disks do not cover the surface, rays miss (t inf, index -1, zero
  normal; alpha < 1 in a frame), exactly where an analytic coverage oracle says so.
- Thin structures: two sheets closer than a disk radius, facing opposite ways: a ray hits the
  sheet on its own side, with that sheet's normal; front and back are never blended.
- Grazing rays: no NaN, whatever the angle.
- Missing normals: estimated, unit, and oriented consistently (outward on closed surfaces).
"""

from __future__ import annotations

import numpy as np
import pytest

import pointviz
from pointviz import Camera, PointCloud, SurfelScene
from pointviz.shapes import torus

VARIANTS = ("full", "kdtree", "lod", "lod+cull")
INTERPOLATIONS = ("smooth", "paper", "none")

SPACING = 0.1
SPARSE_RADIUS = 0.03  # covers pi r^2 / s^2 = 28% of the plane


def _grid(n, spacing, z=0.0):
    g = (np.arange(n) - (n - 1) / 2) * spacing
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    return np.column_stack([xy, np.full(len(xy), z)])


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("interpolation", INTERPOLATIONS)
def test_sparse_sampling_reports_holes_as_holes(variant, interpolation):
    pts = _grid(21, SPACING)
    cloud = PointCloud(pts, normals=np.tile([0, 0, 1.0], (len(pts), 1)), radii=SPARSE_RADIUS)
    scene = SurfelScene(cloud, variant=variant, interpolation=interpolation)
    rng = np.random.default_rng(1)
    xy = rng.uniform(-0.9, 0.9, (3000, 2))
    tilt = rng.normal(scale=0.2, size=(3000, 2))
    rays = np.column_stack([xy - tilt, np.ones(3000), tilt, -np.ones(3000)])  # reach z=0 at xy
    out = scene.cast_rays(rays)
    # coverage oracle: distance from the crossing point to the nearest grid centre
    d = np.linalg.norm(xy - np.round(xy / SPACING) * SPACING, axis=1)
    inside, outside = d < SPARSE_RADIUS * 0.999, d > SPARSE_RADIUS * 1.001
    t = out["t_hit"]
    assert np.isfinite(t[inside]).all(), f"{(~np.isfinite(t[inside])).sum()} covered rays missed"
    assert np.isinf(t[outside]).all(), f"{np.isfinite(t[outside]).sum()} rays hit a hole"
    assert (out["index"][outside] == -1).all()
    assert (out["normals"][outside] == 0).all(), "a miss carries a normal"
    np.testing.assert_allclose(np.abs(out["normals"][inside, 2]), 1.0, atol=1e-4)
    np.testing.assert_allclose(t[inside], 1.0, atol=1e-5)  # on the plane z = 0
    assert 0.2 < inside.mean() < 0.35  # the oracle itself: about 28% covered


def test_sparse_frame_alpha_matches_coverage():
    pts = _grid(41, SPACING)
    cloud = PointCloud(pts, normals=np.tile([0, 0, 1.0], (len(pts), 1)), radii=SPARSE_RADIUS)
    cam = Camera.look_at((0, 0, 3), (0, 0, 0), up=(0, 1, 0), fov_deg=30, width=64, height=64)
    frame = pointviz.render(cloud, cam, spp=16, ground="none", reflections=0, lod_pixels=0)
    a = frame.alpha
    assert 0.2 < a.mean() < 0.36, f"coverage {a.mean():.3f}, analytic 0.283"
    empty = a == 0
    assert empty.any() and (a < 1).mean() > 0.5
    assert np.isinf(frame.depth[empty]).all() and (frame.normal[empty] == 0).all()
    hit = a > 0
    np.testing.assert_allclose(frame.normal[hit][:, 2], 1.0, atol=1e-3)  # faces the camera
    assert np.isfinite(frame.color).all()


SHEET = 0.01  # half the gap between the two sheets; disks are 5x wider than the gap


def _sheets():
    top = _grid(30, 0.05, +SHEET)
    bottom = _grid(30, 0.05, -SHEET)
    pts = np.vstack([top, bottom])
    normals = np.vstack([np.tile([0, 0, 1.0], (len(top), 1)), np.tile([0, 0, -1.0], (len(top), 1))])
    return PointCloud(pts, normals=normals, radii=0.05)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("interpolation", INTERPOLATIONS)
def test_thin_sheets_do_not_mix_front_and_back(variant, interpolation):
    scene = SurfelScene(_sheets(), variant=variant, interpolation=interpolation)
    rng = np.random.default_rng(2)
    m = 1000
    xy = rng.uniform(-0.6, 0.6, (m, 2))
    tilt = rng.normal(scale=0.3, size=(m, 2))
    for side in (+1.0, -1.0):
        o = np.column_stack([xy - side * tilt, np.full(m, side)])
        d = np.column_stack([side * tilt, np.full(m, -side)])
        out = scene.cast_rays(np.hstack([o, d]))
        t = out["t_hit"]
        assert np.isfinite(t).all()
        z = o[:, 2] + d[:, 2] * t
        np.testing.assert_allclose(z, side * SHEET, atol=1e-4, err_msg=f"side {side}")
        n = out["normals"]
        assert (np.einsum("ij,ij->i", n, d) < 0).all(), "a hit's normal faces away from the ray"
        np.testing.assert_allclose(n[:, 2], side, atol=1e-4)


def _fine_sheets():
    """Two 1 x 1 sheets 0.004 apart, 0.01 spacing, disks of radius 0.012 (3x the gap)."""
    top, bottom = _grid(100, 0.01, 0.002), _grid(100, 0.01, -0.002)
    normals = np.vstack([np.tile([0, 0, 1.0], (len(top), 1)), np.tile([0, 0, -1.0], (len(top), 1))])
    return PointCloud(np.vstack([top, bottom]), normals=normals, radii=0.012)


def _down_up_rays(side, m=2000, seed=3):
    xy = np.random.default_rng(seed).uniform(-0.4, 0.4, (m, 2))
    o = np.column_stack([xy, np.full(m, 3.0 * side)])
    d = np.column_stack([np.zeros((m, 2)), np.full(m, -side)])
    return np.hstack([o, d])


@pytest.mark.parametrize("pixel_angle", [0.003, 0.02, 0.05])
def test_thin_sheets_with_lod_never_face_away(pixel_angle):
    """LoD disks may stand for nodes holding both sheets; a hit must still face the ray."""
    scene = SurfelScene(_fine_sheets(), variant="full")
    for side in (+1.0, -1.0):
        rays = _down_up_rays(side)
        out = scene.cast_rays(rays, pixel_angle=pixel_angle)
        hit = np.isfinite(out["t_hit"])
        assert (out["normals"][hit] @ np.array([0, 0, -side]) < 0).all()
        z = rays[hit, 2] + rays[hit, 5] * out["t_hit"][hit]
        # the depth stays within the gap's half (the LoD disk sits between the sheets at worst)
        np.testing.assert_allclose(z, side * 0.002, atol=0.0021)


def test_thin_sheets_with_coarse_lod_keep_their_coverage():
    scene = SurfelScene(_fine_sheets(), variant="full")
    for side in (+1.0, -1.0):
        out = scene.cast_rays(_down_up_rays(side), pixel_angle=0.05)
        assert np.isfinite(out["t_hit"]).all(), f"side {side}: {np.isinf(out['t_hit']).mean():.0%} missed"


@pytest.mark.parametrize("variant", VARIANTS)
def test_grazing_rays_produce_no_nan(variant):
    plane = _grid(30, 0.05)
    sphere = np.random.default_rng(4).normal(size=(2000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    pts = np.vstack([plane, sphere * 0.3 + [0, 0, 0.3]])
    normals = np.vstack([np.tile([0, 0, 1.0], (len(plane), 1)), sphere])
    scene = SurfelScene(PointCloud(pts, normals=normals, radii=0.04), variant=variant)
    elev = 10.0 ** -np.arange(0, 10)  # slopes 1 down to 1e-9 ...
    rays = []
    for e in np.concatenate([elev, -elev, [0.0]]):
        for y in np.linspace(-0.7, 0.7, 15):
            rays.append([-1.0, y, e * 0.5 + 1e-7, 1.0, 0.0, -e])  # ... crossing z=0 mid-plane
            rays.append([-1.0, y, 0.3 + 0.3 * np.sign(e) * (1 - abs(e)), 1.0, 0.0, 0.0])  # sphere
    rays = np.array(rays)
    for pa in (None, 1e-3):
        out = scene.cast_rays(rays, pixel_angle=pa)
        t = out["t_hit"]
        assert not np.isnan(t).any() and (t >= 0).all()
        for key in ("normals", "colors", "radii", "positions"):
            assert not np.isnan(out[key]).any(), key
        hit = np.isfinite(t)
        np.testing.assert_allclose(np.linalg.norm(out["normals"][hit], axis=1), 1.0, atol=1e-3)
        occ = scene.occluded(rays, 10.0, pixel_angle=pa)
        assert occ.dtype == bool
    # a camera with its eye in the plane, looking along it
    cam = Camera.look_at((-2, 0, 0), (0, 0, 0), up=(0, 0, 1), width=32, height=24)
    frame = pointviz.render(scene, cam, spp=2)
    assert np.isfinite(frame.color).all() and np.isfinite(frame.normal).all()


def test_missing_normals_are_estimated_and_oriented():
    rng = np.random.default_rng(5)
    s = rng.normal(size=(3000, 3))
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    # two separate spheres: each component is oriented on its own
    pts = np.vstack([s, s * 0.5 + [3, 0, 0]])
    outward = np.vstack([s, s])
    cloud = PointCloud(pts)
    n = cloud.normals
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    cos = np.einsum("ij,ij->i", n, outward)
    assert (cos > 0.9).mean() > 0.99, f"outward: {(cos > 0).mean():.3f}"
    # a torus: closed but not convex
    t = torus(4000)
    est = PointCloud(t.points).normals
    cos = np.einsum("ij,ij->i", est, t.normals)
    assert (cos > 0.9).mean() > 0.97, f"torus outward: {(cos > 0).mean():.3f}"
    # an open plane with an up hint faces up
    plane = _grid(30, 0.05) + rng.normal(scale=1e-3, size=(900, 3))
    up = PointCloud(plane, up=(0, 0, 1)).normals
    assert (up[:, 2] > 0.99).all()
    # and such a cloud renders: no NaN, the sphere seen from outside is lit from outside
    cam = Camera.look_at((0, 0, 4), (0, 0, 0), width=32, height=24)
    frame = pointviz.render(PointCloud(s), cam, spp=1, ground="none")
    hit = frame.alpha > 0
    assert hit.mean() > 0.1 and np.isfinite(frame.color).all()
    assert (frame.normal[hit][:, 2] > 0).mean() > 0.99
