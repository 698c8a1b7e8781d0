"""Scene bounds and ground level: right against brute force, and computed once per geometry."""

from __future__ import annotations

import numpy as np
import pytest

import pointviz
from pointviz import extent as extent_mod
from pointviz.cloud import PointCloud
from pointviz.scene import GROUND_OUTLIER_FRACTION, Scene, cloud_extent


@pytest.fixture
def blob(rng):
    n = 5000
    p = rng.normal(size=(n, 3)) * [1.0, 2.0, 0.5] + [10.0, -3.0, 7.0]
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    radii = rng.uniform(0.01, 0.05, n).astype(np.float32)
    return PointCloud(p, normals, radii=radii)


def test_cloud_extent_against_brute_force(blob, rng):
    up = rng.normal(size=3)
    up /= np.linalg.norm(up)
    lo, hi, level = cloud_extent(blob.points, blob.radii, up)
    r = blob.radii.max()
    np.testing.assert_allclose(lo, blob.points.min(axis=0) - r)
    np.testing.assert_allclose(hi, blob.points.max(axis=0) + r)
    h = np.sort(blob.points @ up)
    # the ground ignores the lowest GROUND_OUTLIER_FRACTION of the heights, then sinks by the
    # 99th percentile radius: between the sorted heights around that rank
    k = GROUND_OUTLIER_FRACTION * (len(h) - 1)
    r99 = np.quantile(blob.radii, 0.99)
    assert h[int(np.floor(k))] - r99 - 1e-12 <= level <= h[int(np.ceil(k))] - r99 + 1e-12


def test_small_cloud_rests_on_its_lowest_point(blob):
    small = blob.subset(np.arange(100))
    _, _, level = cloud_extent(small.points, small.radii, (0.0, 1.0, 0.0))
    assert level == pytest.approx(small.points[:, 1].min() - np.quantile(small.radii, 0.99))


def test_render_of_a_surfel_scene_scans_its_points_once(blob, monkeypatch):
    """render(surfel_scene) wraps the scene in a new Scene per frame; bounds and ground must
    come from the SurfelScene's cache, not from a new pass over the points."""
    ss = pointviz.SurfelScene(blob)
    calls = []
    real = extent_mod.cloud_extent

    def counting(*args, **kw):
        calls.append(1)
        return real(*args, **kw)

    monkeypatch.setattr(extent_mod, "cloud_extent", counting)
    cam = pointviz.Camera.fit(blob, width=16, height=12)
    frames = [pointviz.render(ss, cam, spp=1) for _ in range(3)]
    assert len(calls) == 1
    for f in frames[1:]:
        np.testing.assert_array_equal(f.color, frames[0].color)
    # the cached extent is the one a fresh computation gives
    fresh = real(blob.points, blob.radii, Scene(ss).up)
    cached = ss.extent(Scene(ss).up)
    for a, b in zip(cached, fresh):
        np.testing.assert_array_equal(a, b)


def test_extent_is_kept_per_up_direction(blob):
    ss = pointviz.SurfelScene(blob)
    y = ss.extent((0.0, 1.0, 0.0))
    z = ss.extent((0.0, 0.0, 1.0))
    assert y[2] != z[2]
    assert Scene(ss, up=(0, 0, 1)).ground_point()[2] == pytest.approx(z[2])
    assert Scene(ss).ground_point()[1] == pytest.approx(y[2])


def test_a_cloud_scene_scans_its_points_once_across_the_tree_build(blob, monkeypatch):
    """Scene(cloud): bounds taken before the tree exists (Camera.fit) are reused once the cloud
    has become a SurfelScene inside render()."""
    calls = []
    real = extent_mod.cloud_extent
    monkeypatch.setattr(extent_mod, "cloud_extent",
                        lambda *a, **kw: calls.append(1) or real(*a, **kw))
    scene = Scene(blob)
    cam = pointviz.Camera.fit(scene, width=16, height=12)
    pointviz.render(scene, cam, spp=1)
    pointviz.render(scene, cam, spp=1)
    assert len(calls) == 1


def test_render_of_a_surfel_scene_decides_its_look_once(blob, monkeypatch):
    """The "auto" look's terrain/object test reads the points: render(surfel_scene) must take it
    from the SurfelScene's cache at every frame after the first."""
    from pointviz import camera as camera_mod

    ss = pointviz.SurfelScene(blob)
    cam = pointviz.Camera.fit(blob, width=16, height=12)
    calls = []
    real = camera_mod.shape_kind
    monkeypatch.setattr(camera_mod, "shape_kind",
                        lambda *a, **kw: calls.append(1) or real(*a, **kw))
    frames = [pointviz.render(ss, cam, spp=1) for _ in range(3)]
    assert len(calls) == 1
    for f in frames[1:]:
        np.testing.assert_array_equal(f.color, frames[0].color)
    # the cached answer is the one a fresh test gives, per up direction
    for up in ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)):
        assert ss.shape_kind(up) == real(blob.points, up)


def test_a_flat_surfel_scene_gets_the_outdoor_look_from_the_cache(rng):
    from pointviz import scene as scene_mod

    n = 4000
    p = np.column_stack([rng.uniform(-50, 50, n), rng.normal(scale=0.1, size=n),
                         rng.uniform(-50, 50, n)])
    tile = pointviz.SurfelScene(PointCloud(p, np.tile([0.0, 1.0, 0.0], (n, 1)), radii=1.0))
    assert tile.shape_kind((0.0, 1.0, 0.0)) == "terrain"
    assert Scene(tile).look is scene_mod.LOOKS["outdoor"]
    assert Scene(tile).look is scene_mod.LOOKS["outdoor"]  # second time from the cache
