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


# -- the frozen value: replace(), pickling without trees --------------------------------------

def value_scene(rng, two_sided=True):
    """Three kinds of object: a bare cloud without normals or radii (estimated on first use),
    a SurfelScene with non-default options, and (when embreex is there) a mesh."""
    from pointviz.scene import DirectionalLight, Material, PointLight
    from pointviz.shapes import sphere
    from pointviz.surfels import SurfelScene

    raw = PointCloud(rng.normal(size=(3000, 3)) * [0.6, 0.3, 0.6] + [0.0, 0.3, 0.0])
    objs = [raw, SurfelScene(sphere(4000, 0.4, (1.0, 0.5, 0.0)), interpolation="paper",
                             leaf_size=6)]
    mats = [Material.matte((0.8, 0.3, 0.2)), Material.glossy()]
    try:
        import embreex  # noqa: F401
    except ImportError:
        pass
    else:
        from pointviz.meshes import MeshGeometry

        v = np.array([[-1.0, 0.0, -1.0], [-0.2, 0.0, -1.0], [-0.6, 0.8, -0.6], [-0.6, 0.0, -0.2]])
        objs.append(MeshGeometry(v, [[0, 1, 2], [0, 2, 3], [1, 3, 2], [0, 3, 1]]))
        mats.append(Material.reflective())
    lights = [DirectionalLight(direction=(0.3, 1.0, 0.2), angle_deg=3.0),
              PointLight(position=(0.0, 2.0, 1.0), intensity=2.0, radius=0.1)]
    return Scene(objs, materials=mats, lights=lights, ground="mirror", look="studio",
                 sky=(0.5, 0.6, 0.7), two_sided=two_sided)


def test_pickled_scene_renders_identically_and_builds_once(rng):
    import pickle

    scene = value_scene(rng)
    cam = pointviz.Camera.fit(scene, width=48, height=36)
    before = pointviz.render(scene, cam, spp=2, seed=7)
    copy = pickle.loads(pickle.dumps(scene))
    assert type(copy) is Scene and copy.key == scene.key
    assert [o.material for o in copy.objects] == [o.material for o in scene.objects]
    assert (copy.lights, copy.ground, copy.look, dict(copy.sky), copy.ambient) == \
        (scene.lights, scene.ground, scene.look, dict(scene.sky), scene.ambient)
    assert copy.build() == 2  # both surfel objects, lazily, on first use
    assert copy.build() == 0  # then never again in this process
    after = pointviz.render(copy, cam, spp=2, seed=7)
    np.testing.assert_array_equal(after.color, before.color)
    np.testing.assert_array_equal(after.depth, before.depth)


def test_pickle_carries_the_arrays_not_the_trees(rng):
    import pickle

    from pointviz.shapes import sphere

    cloud = sphere(20000)
    scene = Scene(cloud)
    tree_bytes = scene.surfel_scene(0).memory_bytes  # built before pickling
    arrays = sum(a.nbytes for a in (cloud.points, cloud.normals, cloud.radii))
    size = len(pickle.dumps(scene))
    assert arrays <= size < arrays + 0.25 * tree_bytes
    # a pickled SurfelScene alone carries no tree either (it is rebuilt on load), and the
    # scene's pickle is no larger than it
    assert size <= len(pickle.dumps(scene.surfel_scene(0))) + 4096


def test_a_scene_cannot_be_changed_after_construction(rng):
    from dataclasses import FrozenInstanceError

    from pointviz.scene import DirectionalLight

    scene = value_scene(rng)
    for name, value in (("lights", []), ("ground", None), ("objects", ()), ("up", (0, 0, 1)),
                        ("look", "flat"), ("new_attribute", 1)):
        with pytest.raises(FrozenInstanceError, match=name):
            setattr(scene, name, value)
    with pytest.raises(FrozenInstanceError):
        del scene.sky
    assert isinstance(scene.objects, tuple) and isinstance(scene.lights, tuple)
    with pytest.raises(AttributeError):  # a tuple
        scene.lights.append(DirectionalLight())
    with pytest.raises(TypeError):
        scene.sky["zenith"] = (1.0, 1.0, 1.0)
    with pytest.raises(ValueError):
        scene.up[0] = 1.0
    with pytest.raises(FrozenInstanceError):
        scene.objects[0].geometry = None


def test_replace_validates_like_the_constructor(blob):
    from pointviz.errors import InputError
    from pointviz.scene import Material

    scene = Scene(blob)
    for field_, value in (("ground", "lava"), ("look", "noir"), ("ambient", -1.0),
                          ("background", "black"), ("sky", {"zenith": (1, 1, 1), "top": (0, 0, 0)}),
                          ("materials", [Material(), Material()]), ("clouds", [])):
        with pytest.raises(InputError) as fresh:
            Scene(**{"clouds": blob, field_: value})
        with pytest.raises(InputError) as copied:
            scene.replace(**{field_: value})
        assert str(copied.value) == str(fresh.value)
    with pytest.raises(TypeError, match="with_up"):
        scene.replace(up=(0, 0, 1))
    with pytest.raises(TypeError, match="interpolation"):
        scene.replace(interpolation="none")


def test_replace_changes_only_what_it_is_given(rng):
    from pointviz.scene import GROUND_MATERIALS, LOOKS

    scene = value_scene(rng, two_sided=False)
    mirror = scene.replace(ground="glossy")
    assert mirror.ground == GROUND_MATERIALS["glossy"] and scene.ground == GROUND_MATERIALS["mirror"]
    assert (mirror.lights, mirror.look, dict(mirror.sky), mirror.ambient) == \
        (scene.lights, scene.look, dict(scene.sky), scene.ambient)
    flat = scene.replace(look="flat")  # a new look brings its sky light; the ground stays
    assert flat.look == LOOKS["flat"] and flat.ambient == LOOKS["flat"].ambient
    assert dict(flat.sky) == LOOKS["flat"].sky and flat.ground == scene.ground
    # the surfel options stay the scene's (two_sided=False: the normal cones cull)
    assert mirror.geometry(0).cull == scene.geometry(0).cull
    assert mirror.key != scene.key and scene.replace().key == scene.key


def test_copies_share_the_trees_whichever_builds_first(blob):
    scene = Scene(blob)
    copy = scene.replace(ground="mirror").with_look("outdoor")
    assert copy.build() == 1 and scene.build() == 0
    assert copy.geometry(0) is scene.geometry(0)
    other = scene.replace(clouds=[blob])  # new objects: their own trees
    assert other.build() == 1


def test_concurrent_first_use_builds_each_tree_once(rng):
    import threading

    from pointviz.shapes import sphere, torus

    scene = Scene([sphere(3000), torus(3000)])
    copies = [scene, scene.with_ground("mirror"), scene.replace(lights=[]), scene]
    start = threading.Barrier(len(copies))
    built = []

    def first_use(s):
        start.wait()
        built.append(s.build())

    threads = [threading.Thread(target=first_use, args=(s,)) for s in copies]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(built) in ([0, 0, 0, 2], [0, 0, 1, 1])
    assert sum(built) == 2
    assert len({id(c.geometry(0)) for c in copies}) == 1


def test_an_unpickled_surfel_object_keeps_its_options_through_replace(rng):
    import pickle

    from pointviz.shapes import sphere
    from pointviz.surfels import SurfelScene

    ss = SurfelScene(sphere(2000), interpolation="paper", leaf_size=5)
    copy = pickle.loads(pickle.dumps(Scene([ss, sphere(1000)])))
    again = copy.replace(clouds=[o.geometry for o in copy.objects][::-1])
    assert again.geometry(1).interpolation == "paper"
    assert again.geometry(1).settings["leaf_size"] == 5
    assert again.geometry(0).interpolation != "paper"


def test_blocked_quantile_is_numpy_quantile(rng):
    """The blocked quantile keeps only the extreme values and interpolates like numpy: the same
    number (bit for bit, same dtype) as np.quantile over the whole array, ties included."""
    for trial in range(600):
        n = int(rng.integers(1, 3000))
        x = (rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3)).astype(
            (np.float32, np.float64)[trial % 2])
        if trial % 5 == 0:
            x = np.round(x)
        q = float((0.0, GROUND_OUTLIER_FRACTION, 0.01, 0.5, 0.99, 1.0, rng.uniform())[trial % 7])
        size = int(rng.integers(1, 400))
        got = extent_mod.blocked_quantile((x[b:b + size] for b in range(0, n, size)), n, q)
        want = np.quantile(x, q)
        assert got == want and got.dtype == want.dtype, (n, x.dtype, q, size)


@pytest.mark.parametrize("block", [1, 37, 4096, 1 << 18])
def test_cloud_extent_in_blocks_is_the_whole_array_formula(blob, rng, monkeypatch, block):
    """Whatever the block size, bounds and ground level equal the whole-array formula's exactly
    (for the cloud's float64 points and for the tree's float32 view)."""
    monkeypatch.setattr(extent_mod, "EXTENT_BLOCK", block)
    up = rng.normal(size=3)
    up /= np.linalg.norm(up)
    view = pointviz.SurfelScene(blob).tree.surfel_view()
    for points, radii in ((blob.points, blob.radii), (view[:, :3], view[:, 3])):
        lo, hi, level = cloud_extent(points, radii, up)
        r = float(np.max(radii))
        h = points[:, 0] * up[0] + points[:, 1] * up[1] + points[:, 2] * up[2]
        want = float(np.quantile(h, GROUND_OUTLIER_FRACTION)) - float(np.quantile(radii, 0.99))
        np.testing.assert_array_equal(lo, points.min(axis=0).astype(np.float64) - r)
        np.testing.assert_array_equal(hi, points.max(axis=0).astype(np.float64) + r)
        assert level == want


def test_shape_kind_of_a_scene_without_its_cloud_reads_only_the_sample(rng):
    """keep_cloud=False decides the look from the tree's surfels: the same answer as the whole
    view moved to world coordinates, for a flat tile and an object, without moving all of it."""
    from pointviz.framing import FIT_SAMPLE, fit_sample, shape_kind

    n = 2 * FIT_SAMPLE + 123
    for scale, kind in (((50.0, 1.0, 40.0), "terrain"), ((1.0, 1.0, 1.0), "object")):
        p = rng.uniform(-1, 1, (n, 3)) * scale + [1e3, 20.0, -5e2]
        cloud = PointCloud(p, np.tile(np.float32([0, 1, 0]), (n, 1)), radii=np.full(n, 0.01))
        ss = pointviz.SurfelScene(cloud, keep_cloud=False)
        view = ss.tree.surfel_view()
        assert shape_kind(view[:, :3] + ss.origin, (0.0, 1.0, 0.0)) == kind
        assert ss.shape_kind((0.0, 1.0, 0.0)) == kind
        sample = fit_sample(view)
        assert len(sample) < 2 * FIT_SAMPLE
        np.testing.assert_array_equal(fit_sample(sample), sample)  # taking it again: the same
        np.testing.assert_array_equal(fit_sample(view[:, :3] + ss.origin),
                                      sample[:, :3] + ss.origin)


def _slab(rng, n=20000):
    """A flat slab in the xy plane: terrain seen with +Z up, a wall (an object) with +Y up."""
    p = np.c_[rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(0.0, 0.2, n)]
    return PointCloud(p, np.tile([0.0, 0.0, 1.0], (n, 1)), radii=np.full(n, 0.05, np.float32))


@pytest.mark.parametrize("up", [(0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (0.6, 0.0, 0.8)])
def test_with_up_is_the_scene_constructed_with_that_up_and_shares_the_trees(rng, up):
    """Scene.with_up(u) gives what Scene(..., up=u) gives (the same key: ground level, the
    "auto" look and what came with it), without building a tree again."""
    from pointviz.surfels import SurfelScene

    slab = _slab(rng)
    tree = SurfelScene(_slab(np.random.default_rng(1)))
    for clouds in ([slab], [tree], [slab, tree]):
        scene = Scene(clouds)
        assert scene.build() == sum(not isinstance(c, SurfelScene) for c in clouds)
        turned = scene.with_up(up)
        fresh = Scene(clouds, up=up)
        assert turned.key == fresh.key
        np.testing.assert_array_equal(turned.up, fresh.up)
        np.testing.assert_allclose(turned.ground_point(), fresh.ground_point())
        assert turned.look == fresh.look and turned.ground == fresh.ground
        assert turned.build() == 0  # the trees are the scene's own
        assert all(turned.geometry(i) is scene.geometry(i) for i in range(len(clouds)))
        # and back: the first up's ground level again (kept per up, not overwritten)
        back = turned.with_up(scene.up)
        np.testing.assert_allclose(back.ground_point(), scene.ground_point())
        assert back.key == scene.key
    assert scene.with_up(scene.up) is scene


def test_with_up_resolves_again_only_what_was_left_to_the_constructor(rng):
    """A flat slab: studio with +Y up (a wall), outdoor with +Z (terrain). An "auto" look
    follows the up, with its ground and sky; a look, ground or sky given stays."""
    from pointviz.scene import GROUND_MATERIALS, LOOKS

    slab = _slab(rng)
    auto = Scene(slab)
    assert auto.look == LOOKS["studio"] and auto.ground is not None
    z = auto.with_up((0, 0, 1))
    assert z.look == LOOKS["outdoor"] and z.ground is None and dict(z.sky) == dict(LOOKS["outdoor"].sky or {})
    assert z.with_up((0, 1, 0)).look == LOOKS["studio"]
    given = Scene(slab, look="studio", ground="mirror", sky=(0.5, 0.5, 0.5)).with_up((0, 0, 1))
    assert given.look == LOOKS["studio"] and given.ground == GROUND_MATERIALS["mirror"]
    assert dict(given.sky)["zenith"] == (0.5, 0.5, 0.5)
    # a copy remembers what was left to the constructor, through replace() and pickling
    import pickle

    copy = pickle.loads(pickle.dumps(auto.replace(background=(1.0, 1.0, 1.0))))
    assert copy.with_up((0, 0, 1)).look == LOOKS["outdoor"]
    # with_look gives a look: the up no longer changes it
    assert auto.with_look("studio").with_up((0, 0, 1)).look == LOOKS["studio"]


def test_with_up_rejects_a_bad_up_by_name(blob):
    from pointviz.errors import InputError

    for bad in ((0, 0, 0), (np.nan, 1, 0), (1, 2)):
        with pytest.raises(InputError, match="up"):
            Scene(blob).with_up(bad)
