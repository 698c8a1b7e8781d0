"""The conventional KD-tree (``variant="kdtree"``, ext/include/pointviz/kdtree.h).

Oracles: brute force over all surfels (nearest disk, any disk in an interval) and the hierarchy
(``variant="bvh"``), which blends the same disks around each hit.
"""

from __future__ import annotations

import numpy as np
import pytest

import pointviz
from pointviz import InputError, PointCloud, SurfelScene, shapes


def brute_disks(cloud, rays, tmin=0.0, cull=False):
    """Every ray against every disk, in float64.

    Returns
    -------
    t : (n_rays,) float64
        Parameter of the nearest disk hit in [tmin, inf) (inf on a miss).
    index : (n_rays,) int64
        Its surfel (-1 on a miss).
    """
    p = np.asarray(cloud.points, dtype=np.float64)
    nrm = np.asarray(cloud.normals, dtype=np.float64)
    r2 = np.asarray(cloud.radii, dtype=np.float64) ** 2
    o, d = rays[:, None, :3], rays[:, None, 3:]
    facing = np.einsum("rsk,sk->rs", np.broadcast_to(d, (len(rays), len(p), 3)), nrm)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("rsk,sk->rs", p[None] - o, nrm) / facing
        q = o + d * t[..., None] - p[None]
        ok = (np.abs(facing) > 1e-6) & (t >= tmin) & (np.einsum("rsk,rsk->rs", q, q) <= r2)
    if cull:
        ok &= facing <= 0
    t = np.where(ok, t, np.inf)
    index = np.argmin(t, axis=1)
    best = t[np.arange(len(rays)), index]
    return best, np.where(np.isfinite(best), index, -1)


def random_rays(rng, n, spread=2.0, dist=2.5):
    """Rays from random points around the unit cube toward random points inside it."""
    o = rng.normal(size=(n, 3))
    o *= dist / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform(-1, 1, (n, 3)) * spread / 2 - o
    return np.hstack([o, d / np.linalg.norm(d, axis=1, keepdims=True)])


@pytest.fixture(scope="module")
def soup():
    """3000 disks at random positions and orientations in the unit cube."""
    g = np.random.default_rng(11)
    return PointCloud(g.uniform(-1, 1, (3000, 3)), normals=g.normal(size=(3000, 3)),
                      radii=g.uniform(0.02, 0.08, 3000))


@pytest.mark.parametrize("cull", [False, True])
def test_nearest_disk_matches_brute_force(soup, rng, cull):
    rays = random_rays(rng, 600)
    t_bf, idx_bf = brute_disks(soup, rays, cull=cull)
    out = SurfelScene(soup, variant="kdtree", interpolation="none", cull=cull).cast_rays(rays)
    assert 0.2 < np.isfinite(t_bf).mean() < 0.95  # the case is not trivial either way
    np.testing.assert_allclose(out["t_hit"], t_bf, rtol=1e-4, atol=1e-5)
    # ties (two disks at the same t to float precision) may pick either
    assert np.mean(out["index"] == idx_bf) > 0.995
    hit = np.isfinite(t_bf)
    n_true = np.asarray(soup.normals)[idx_bf[hit]]
    n_true /= np.linalg.norm(n_true, axis=1, keepdims=True)
    same = out["index"][hit] == idx_bf[hit]
    np.testing.assert_allclose(out["normals"][hit][same], n_true[same], atol=1e-5)
    assert np.all(out["count"][hit] == 1)


def test_any_hit_matches_brute_force(soup, rng):
    rays = random_rays(rng, 600)
    t_max = rng.uniform(0.5, 4.0, len(rays))
    hit = SurfelScene(soup, variant="kdtree").occluded(rays, t_max, t_min=0.1)
    t_bf, _ = brute_disks(soup, rays, tmin=0.1)
    expect = t_bf <= t_max
    close = np.abs(t_bf - t_max) < 1e-5  # within float rounding of t_max: either way
    assert expect.any() and not expect.all()
    assert np.array_equal(hit[~close], expect[~close])


@pytest.mark.parametrize("interpolation", ["none", "paper", "smooth"])
def test_interpolated_hits_equal_the_hierarchy(interpolation, rng):
    """The same disks are blended: the KD-tree's early exit waits until the depth window behind
    the nearest hit is covered."""
    cloud = shapes.sphere(20000, radius=1.0, color=(0.2, 0.6, 0.9))
    o = rng.normal(size=(4000, 3))
    o *= 3.0 / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform(-0.9, 0.9, (4000, 3)) - o
    rays = np.hstack([o, d])
    kd = SurfelScene(cloud, variant="kdtree", interpolation=interpolation).cast_rays(rays)
    bvh = SurfelScene(cloud, variant="bvh", interpolation=interpolation).cast_rays(rays)
    np.testing.assert_array_equal(np.isfinite(kd["t_hit"]), np.isfinite(bvh["t_hit"]))
    np.testing.assert_allclose(kd["t_hit"], bvh["t_hit"], rtol=1e-6)
    # Two disks at the same t to float precision may come first in either structure: with
    # "none" that decides the normal, so compare where the nearest surfel is the same one.
    same = kd["index"] == bvh["index"]
    assert same.mean() > 0.995
    np.testing.assert_allclose(kd["normals"][same], bvh["normals"][same], atol=1e-6)
    np.testing.assert_allclose(kd["colors"], bvh["colors"], atol=1e-6)
    np.testing.assert_array_equal(kd["count"], bvh["count"])
    assert kd["count"].max() > 1 or interpolation == "none"


def test_layers_within_the_window_are_all_blended(rng):
    """Two sheets closer than the depth window, on either side of many split planes: the KD-tree
    must keep searching past the nearest sheet's cell."""
    # Two square lattices (spacing s, the second shifted by s/2 and 0.3 radii up), radius 0.75 s:
    # every point of a sheet is covered by 1-4 disks, so all fit in the gather (8 disks).
    s = 2.0 / 60
    u = (np.arange(60) + 0.5) * s - 1.0
    gx, gy = np.meshgrid(u, u)
    lower = np.c_[gx.ravel(), gy.ravel(), np.zeros(gx.size)]
    upper = lower + [s / 2, s / 2, 0.3 * 0.75 * s]
    pts = np.vstack([lower, upper])
    cloud = PointCloud(pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1)),
                       radii=np.full(len(pts), 0.75 * s))
    o = np.c_[rng.uniform(-0.8, 0.8, (500, 2)), np.full(500, 2.0)]
    d = np.c_[rng.uniform(-0.05, 0.05, (500, 2)), -np.ones(500)]
    rays = np.hstack([o, d])
    kd = SurfelScene(cloud, variant="kdtree").cast_rays(rays)
    bvh = SurfelScene(cloud, variant="bvh").cast_rays(rays)
    assert np.isfinite(kd["t_hit"]).all()
    assert kd["count"].max() <= 8
    np.testing.assert_array_equal(kd["count"], bvh["count"])
    np.testing.assert_allclose(kd["t_hit"], bvh["t_hit"], rtol=1e-6)
    assert kd["count"].mean() > 2  # both sheets are blended


def test_degenerate_clouds(rng):
    # every centre the same: no split separates them, one leaf holds them all
    n = 500
    same = PointCloud(np.tile([0.5, 0.5, 0.5], (n, 1)), normals=np.tile([0.0, 1.0, 0.0], (n, 1)),
                      radii=np.full(n, 0.25))
    # an axis-aligned plane: every disk box is flat and lies on the same coordinate
    plane = shapes.plane(5000, size=2.0)
    # one surfel
    one = PointCloud(np.array([[1.0, 2.0, 3.0]]), normals=np.array([[0.0, 0.0, 1.0]]),
                     radii=np.array([0.5]))
    for cloud in (same, plane, one):
        c = np.asarray(cloud.points).mean(axis=0)
        rays = random_rays(rng, 300, spread=1.0)
        rays[:, :3] += c
        # axis-parallel rays (zero direction components), some starting inside the bounds
        par = np.zeros((60, 6))
        par[:, :3] = c + rng.uniform(-1, 1, (60, 3))
        par[np.arange(60), 3 + np.arange(60) % 3] = np.where(np.arange(60) % 2, 1.0, -1.0)
        rays = np.vstack([rays, par])
        t_bf, _ = brute_disks(cloud, rays)
        out = SurfelScene(cloud, variant="kdtree", interpolation="none").cast_rays(rays)
        np.testing.assert_allclose(out["t_hit"], t_bf, rtol=1e-4, atol=1e-5)


def test_tree_shape_and_memory(soup):
    scene = SurfelScene(soup, variant="kdtree")
    tree = scene.tree
    assert tree.n_surfels == 3000
    # every surfel is referenced at least once; straddling disks more than once
    assert tree.n_references >= 3000
    assert tree.n_leaves >= 3000 / 8
    # pbrt's depth limit, 8 + 1.3 log2(n)
    assert scene.depth <= round(8 + 1.3 * np.log2(3000))
    assert scene.memory_bytes == 8 * tree.n_nodes + 36 * tree.n_references


def test_statistics_count_the_traversal(soup, rng):
    scene = SurfelScene(soup, variant="kdtree")
    rays = random_rays(rng, 500)
    scene.cast_rays(rays)
    st = scene.last_stats
    assert st["rays"] == 500
    assert st["nodes_visited"] >= 1 and st["disk_tests"] > 0
    assert 0 < st["max_depth"] <= st["deepest"] <= scene.depth
    # a ray that misses the scene's bounds visits nothing
    scene.cast_rays(np.array([[10.0, 10.0, 10.0, 1.0, 0.0, 0.0]]))
    assert scene.last_stats["nodes_visited"] == 0


def test_bad_input_is_reported(soup):
    scene = SurfelScene(soup, variant="kdtree")
    with pytest.raises(InputError, match="row 1"):
        scene.cast_rays(np.array([[0, 0, 5, 0, 0, -1], [0, 0, 5, np.nan, 0, -1]], dtype=float))
    with pytest.raises(InputError, match="row 0"):
        scene.occluded(np.array([[0, 0, 5, 0, 0, 0]], dtype=float), 1.0)
    out = scene.cast_rays(np.zeros((0, 6)))
    assert out["t_hit"].shape == (0,)


def test_render_equals_the_hierarchy():
    """Frames (shadows, a mirror bounce) through the KD-tree equal those through the hierarchy
    without level of detail: the renderer sees the same hits."""
    cloud = shapes.sphere(8000, radius=1.0, color=(0.8, 0.4, 0.2))
    cam = pointviz.Camera.fit(cloud, width=48, height=40)
    frames = {}
    for variant in ("kdtree", "bvh"):
        scene = pointviz.Scene([cloud], ground="mirror", variant=variant)
        frames[variant] = pointviz.render(scene, cam, spp=1, reflections=1, lod_pixels=0.0,
                                          threads=1)
    np.testing.assert_allclose(frames["kdtree"].color, frames["bvh"].color, atol=1e-5)
    np.testing.assert_allclose(frames["kdtree"].depth, frames["bvh"].depth, rtol=1e-5)


def test_pickled_scene_rebuilds_the_same_kdtree(soup, rng):
    import pickle

    scene = SurfelScene(soup, variant="kdtree")
    copy = pickle.loads(pickle.dumps(scene))
    assert copy.variant == "kdtree" and copy.tree.n_references == scene.tree.n_references
    rays = random_rays(rng, 300)
    a, b = scene.cast_rays(rays), copy.cast_rays(rays)
    for key in ("t_hit", "normals", "index", "count"):
        np.testing.assert_array_equal(a[key], b[key])
