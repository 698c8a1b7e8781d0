"""The wide traversal (the default) against the binary one, brute force and analytic surfaces.

The wide tree tests two levels of the binary tree's bounds at once and takes the binary
traversal's decisions: any hits are identical, every ray finds the same nearest disk, and the
blended hit agrees except on the rare rays where disks reach the closest-hit policy in another
order (``ext/include/pointviz/wide_trace.h``). The C++ side (``tests/cpp/wide_tests.cpp``)
checks the collapse lane by lane and every instruction set.
"""

from __future__ import annotations

import numpy as np
import pytest

from pointviz import Camera, PointCloud, SurfelScene, shapes
from pointviz.errors import InputError

from test_surfels import brute_first_disk, rays_at_sphere, sphere_oracle


def _pair(cloud, **kw):
    """The same scene traversed wide and binary."""
    return SurfelScene(cloud, traversal="wide", **kw), SurfelScene(cloud, traversal="binary", **kw)


def _compare(wide, binary, rays, tmax, **cast_kw):
    """Closest and any hits of both traversals; returns the closest-hit outputs."""
    w, b = wide.cast_rays(rays, **cast_kw), binary.cast_rays(rays, **cast_kw)
    ws, bs = wide.last_stats, binary.last_stats
    np.testing.assert_array_equal(np.isfinite(w["t_hit"]), np.isfinite(b["t_hit"]))
    np.testing.assert_array_equal(w["index"], b["index"])  # the same nearest disk (or LoD node)
    hit = np.isfinite(b["t_hit"])
    tw, tb = w["t_hit"][hit], b["t_hit"][hit]
    same = np.abs(tw - tb) <= 1e-5 * (1 + np.abs(tb))
    same &= np.all(np.abs(w["normals"][hit] - b["normals"][hit]) <= 1e-4, axis=1)
    assert same.mean() >= 0.99, f"{(~same).sum()} of {hit.sum()} blended hits differ"
    assert ws["hits"] == bs["hits"]
    assert ws["nodes_visited"] == pytest.approx(bs["nodes_visited"], rel=0.1)
    assert ws["disk_tests"] == pytest.approx(bs["disk_tests"], rel=0.05)
    pixel_angle = cast_kw.get("pixel_angle")
    occ_w = wide.occluded(rays, tmax, pixel_angle=pixel_angle)
    occ_b = binary.occluded(rays, tmax, pixel_angle=pixel_angle)
    np.testing.assert_array_equal(occ_w, occ_b)
    return w, b


@pytest.mark.parametrize("variant", ["full", "lod+cull", "lod"])
@pytest.mark.parametrize("shape", ["sphere", "torus"])
def test_wide_equals_binary_on_analytic_shapes(shape, variant, rng):
    cloud = getattr(shapes, shape)(30000)
    wide, binary = _pair(cloud, variant=variant)
    rays = rays_at_sphere(rng, 4000, dist=3.5, spread=2.0)
    tmax = rng.uniform(1.0, 5.0, len(rays)).astype(np.float32)
    for pixel_angle in (None, 0.002, 0.02):  # without LoD, fine and coarse LoD
        _compare(wide, binary, rays, tmax, pixel_angle=pixel_angle)
    for lod_pixels in ("auto",):  # the error budget's stopping rule
        _compare(wide, binary, rays, tmax, pixel_angle=0.01, lod_pixels=lod_pixels,
                 max_error=0.05)


def test_wide_equals_binary_with_boxes_slabs_and_interpolation(rng):
    cloud = shapes.sphere(20000)
    rays = rays_at_sphere(rng, 3000)
    tmax = rng.uniform(1.0, 4.0, len(rays)).astype(np.float32)
    for kw in ({"box_depth": 0}, {"box_depth": 5}, {"slabs": False}, {"interpolation": "none"},
               {"interpolation": "paper"}, {"leaf_size": 1}, {"leaf_size": 31}):
        wide, binary = _pair(cloud, **kw)
        _compare(wide, binary, rays, tmax)
        _compare(wide, binary, rays, tmax, pixel_angle=0.01)


def test_wide_equals_binary_on_random_disks(rng):
    # Disks at every orientation: cone culling skips and un-culls subtrees everywhere.
    n = 6000
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    cloud = PointCloud(p, normals=normals, radii=rng.uniform(0.02, 0.08, n),
                       colors=rng.uniform(0, 1, (n, 3)))
    wide, binary = _pair(cloud)
    rays = rays_at_sphere(rng, 3000)
    tmax = rng.uniform(1.0, 4.0, len(rays)).astype(np.float32)
    _compare(wide, binary, rays, tmax)
    _compare(wide, binary, rays, tmax, pixel_angle=0.02)


def test_wide_matches_brute_force_and_the_analytic_sphere(rng):
    cloud = shapes.sphere(8000)
    scene = SurfelScene(cloud, variant="bvh", box_depth=4, interpolation="none")
    assert scene.trace_options().wide
    rays = rays_at_sphere(rng, 400)
    out = scene.cast_rays(rays)
    t_brute, _ = brute_first_disk(cloud, rays)
    hit = np.isfinite(t_brute)
    np.testing.assert_array_equal(np.isfinite(out["t_hit"]), hit)
    np.testing.assert_allclose(out["t_hit"][hit], t_brute[hit], rtol=1e-4, atol=1e-5)
    occ = scene.occluded(rays, np.full(len(rays), 1e30, np.float32))
    np.testing.assert_array_equal(occ, hit)
    # and the surface it samples
    smooth = SurfelScene(cloud).cast_rays(rays)
    t_true = sphere_oracle(rays, (0, 0, 0), 1.0)
    both = np.isfinite(t_true) & np.isfinite(smooth["t_hit"])
    spacing = np.sqrt(4 * np.pi / 8000)
    assert np.abs(smooth["t_hit"][both] - t_true[both]).mean() < 0.02 * spacing


def test_wide_nodes_memory_and_option(rng):
    cloud = shapes.sphere(20000)
    wide, binary = _pair(cloud)
    n = wide.n_surfels
    extra = (wide.memory_bytes - binary.memory_bytes) / n
    assert 0 < extra <= 17.0, extra  # wide.h: 12-17 bytes per surfel
    assert wide.trace_options().wide and not binary.trace_options().wide
    with pytest.raises(InputError, match="traversal: expected one of"):
        SurfelScene(cloud, traversal="quad")


def _packets_and_single(scene, rays, **cast_kw):
    """Closest hits without statistics (the path packets take), packets on and off."""
    scene._options.packets = True
    p = scene.cast_rays(rays, stats=False, **cast_kw)
    scene._options.packets = False
    s = scene.cast_rays(rays, stats=False, **cast_kw)
    scene._options.packets = True
    return p, s


def _any_packets_and_single(scene, rays, t_max, **kw):
    """Any hits without statistics (the path packets take), packets on and off."""
    scene._options.packets = True
    p = scene.occluded(rays, t_max, stats=False, **kw)
    scene._options.packets = False
    s = scene.occluded(rays, t_max, stats=False, **kw)
    scene._options.packets = True
    return p, s


def _t_max_around(t, seed):
    """tmax per ray: before or beyond the closest hit, far or infinite on misses."""
    rng = np.random.default_rng(seed)
    far = np.where(rng.random(len(t)) < 0.5, np.inf, 10.0)
    return np.where(np.isfinite(t), t * rng.uniform(0.5, 1.5, len(t)), far).astype(np.float32)


@pytest.mark.parametrize("shape", ["sphere", "torus"])
def test_packets_equal_single_rays_on_camera_grids(shape):
    """Camera rays in raster order traverse in packets (packet_trace.h): every output equals
    one ray at a time's, bit for bit, over silhouettes, holes and rays from inside."""
    cloud = getattr(shapes, shape)(30000)
    views = [((2.5, -1.5, 1.0), (0.0, 0.0, 0.0), 30.0),    # the whole shape: silhouettes
             ((0.0, 0.0, 3.0), (0.95, 0.0, 0.0), 4.0),     # the rim up close
             ((0.0, 0.0, 0.3), (0.0, 1.0, 0.0), 20.0)]     # from inside (the sphere) / the hole
    for variant, cull in (("full", True), ("full", False), ("lod", False), ("bvh", False)):
        scene = SurfelScene(cloud, variant=variant, cull=cull)
        hits, mixed = [], 0
        for eye, target, fov in views:
            cam = Camera.look_at(eye, target, fov_deg=fov, width=96, height=64)
            rays = cam.rays()
            # rows in raster order (blocks of 2x4 pixels), float64 rays, one row alone (groups of
            # eight consecutive rays), rows of eight, a width not a multiple of 4
            odd = Camera.look_at(eye, target, fov_deg=fov, width=37, height=23).rays()
            for name, r in (("raster", rays), ("float64", rays.astype(np.float64)),
                            ("row", rays[:96]), ("narrow", rays.reshape(64, 96, 6)[:, :8].reshape(-1, 6)),
                            ("odd", odd)):
                p, s = _packets_and_single(scene, r)
                for k in s:
                    np.testing.assert_array_equal(p[k], s[k], err_msg=f"{variant} {eye} {name} {k}")
                # any hits of the same rays, tmax per ray, with and without t_min
                t_max = _t_max_around(s["t_hit"], len(r))
                for t_min in (0.0, 0.05):
                    pa, sa = _any_packets_and_single(scene, r, t_max, t_min=t_min)
                    np.testing.assert_array_equal(pa, sa, err_msg=f"{variant} {eye} {name} any")
                    mixed += bool(0 < sa.sum() < len(sa))
            hits.append(np.isfinite(s["t_hit"]).mean())
        assert 0.05 < hits[0] < 0.95 and max(hits[1:]) > 0.05, hits
        assert mixed >= 10, mixed  # any hits and misses in most ray sets


def test_packets_leave_lod_and_incoherent_rays_alone(rng):
    """Level of detail, statistics and scattered rays take the single-ray path: the same
    answers either way."""
    cloud = shapes.sphere(20000)
    scene = SurfelScene(cloud)
    cam = Camera.look_at((2.0, 1.0, 1.5), (0.0, 0.0, 0.0), fov_deg=40.0, width=64, height=48)
    rays = cam.rays()
    p, s = _packets_and_single(scene, rays, pixel_angle=0.01)
    for k in s:
        np.testing.assert_array_equal(p[k], s[k])
    scattered = rays_at_sphere(rng, 2000, dist=3.0)
    p, s = _packets_and_single(scene, scattered)
    for k in s:
        np.testing.assert_array_equal(p[k], s[k])
    for r in (rays, scattered):
        t_max = _t_max_around(scene.cast_rays(r)["t_hit"], 7)
        pa, sa = _any_packets_and_single(scene, r, t_max, pixel_angle=0.01)
        np.testing.assert_array_equal(pa, sa)
        pa, sa = _any_packets_and_single(scene, r, t_max)
        np.testing.assert_array_equal(pa, sa)
    assert scene.trace_options().packets
