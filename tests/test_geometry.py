"""The Geometry interface: surfels and meshes are both Geometry, a scene renders either through
it, and rendering a mesh in one scene leaves it unchanged for every other scene."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

import pointviz
from pointviz import shapes
from pointviz.comparison import analytic
from pointviz.geometry import Geometry
from pointviz.meshes import MeshGeometry
from pointviz.scene import Scene

needs_embreex = pytest.mark.skipif(importlib.util.find_spec("embreex") is None,
                                   reason="embreex is not installed: pip install 'pointviz[compare]'")


def test_surfels_and_meshes_are_geometry_and_clouds_are_not():
    cloud = shapes.sphere(500)
    assert isinstance(pointviz.SurfelScene(cloud), Geometry)
    v, f = analytic.sphere_mesh(1.0, res=8)
    assert isinstance(MeshGeometry(v, f), Geometry)
    assert not isinstance(cloud, Geometry)


def test_mesh_extent_is_its_bounds_and_lowest_corner():
    v, f = analytic.sphere_mesh(1.0, center=(0.5, 2.0, -1.0), res=16)
    lo, hi, level = MeshGeometry(v, f).extent((0.0, 1.0, 0.0))
    used = v[np.unique(f)]
    np.testing.assert_array_equal(lo, used.min(axis=0))
    np.testing.assert_array_equal(hi, used.max(axis=0))
    assert level == pytest.approx(used[:, 1].min())


@needs_embreex
def test_a_mesh_shared_by_scenes_with_other_origins_renders_the_same():
    """Each scene hands the mesh its own origin; a render in a scene centred elsewhere must not
    change what another scene (or the mesh's own queries) sees. Oracle: a fresh mesh."""
    v, f = analytic.sphere_mesh(1.0, res=32)
    shared = MeshGeometry(v, f)
    cam = pointviz.Camera((0.0, 0.5, 4.0), (0.0, 0.0, 0.0), width=24, height=18)
    alone = Scene([shared], ground="none")
    far = Scene([shared, shapes.sphere(400, center=(30.0, 0.0, 0.0))], ground="none")
    first = pointviz.render(alone, cam, spp=1, shadows=False, reflections=0)
    pointviz.render(far, cam, spp=1, shadows=False, reflections=0)  # another origin
    again = pointviz.render(alone, cam, spp=1, shadows=False, reflections=0)
    fresh = pointviz.render(Scene([MeshGeometry(v, f)], ground="none"), cam, spp=1,
                            shadows=False, reflections=0)
    np.testing.assert_array_equal(again.color, first.color)
    np.testing.assert_array_equal(fresh.color, first.color)
    assert first.alpha.max() == 1.0  # the mesh is in view
    # the mesh's own world-space queries agree with a fresh mesh's too
    rays = np.array([[0.0, 0.0, 5.0, 0.0, 0.0, -1.0], [0.3, 0.2, 5.0, 0.0, 0.0, -1.0]])
    a, b = shared.cast_rays(rays), MeshGeometry(v, f).cast_rays(rays)
    np.testing.assert_array_equal(a["t_hit"], b["t_hit"])
