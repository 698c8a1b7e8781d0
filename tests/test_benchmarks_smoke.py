"""Smoke tests of the benchmark baselines: Embree discs/triangles against brute force, and a quick
run of benchmarks/bench_core.py.

The Embree tests skip (with the reason) when libembree-dev or a compiler is missing; the benchmark
run skips when ../shared/data is absent.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))

import _baselines
import common

# Relative tolerance of t between Embree (float32, its own operation order) and float64 brute force.
T_RTOL = 1e-5
# Random discs are hit at all angles; at grazing incidence float32 t error grows like 1/cos, so the
# random comparison allows this much relative error.
RANDOM_T_RTOL = 2e-4
# Rays whose hit lies this close (relative) to a disc's rim are ambiguous in float32: excluded
# from the random comparison.
RIM_MARGIN = 1e-3
DISCS_SEED = 5
RANDOM_DISCS = 200
RANDOM_RAYS = 2_000


@pytest.fixture(scope="module")
def embree():
    ok, reason = _baselines.embree_available()
    if not ok:
        pytest.skip(f"Embree baseline unavailable: {reason}")
    return _baselines


def brute_force_discs(centres, normals, radii, rays, tnear=0.0, tfar=math.inf):
    """Closest two-sided disc hit of each ray in float64: (t with inf on miss, disc id or -1)."""
    o, d = rays[:, None, :3].astype(np.float64), rays[:, None, 3:].astype(np.float64)
    c, n, r = centres[None].astype(np.float64), normals[None].astype(np.float64), radii[None]
    denom = np.sum(d * n, axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.sum((c - o) * n, axis=2) / denom
        p = o + t[..., None] * d
        inside = np.sum((p - c) ** 2, axis=2) <= r.astype(np.float64) ** 2
    valid = (np.abs(denom) > 0) & (t > tnear) & (t < tfar) & inside
    t = np.where(valid, t, np.inf)
    idx = np.argmin(t, axis=1)
    best = t[np.arange(len(rays)), idx]
    return best, np.where(np.isfinite(best), idx, -1)


def rim_distance(centres, normals, radii, rays, ids, t):
    """For rays that hit, |1 - |p - c| / r| at the hit disc; the ambiguity of rays near a rim."""
    out = np.full(len(rays), np.inf)
    hit = ids >= 0
    p = rays[hit, :3] + t[hit, None] * rays[hit, 3:]
    out[hit] = np.abs(1.0 - np.linalg.norm(p - centres[ids[hit]], axis=1) / radii[ids[hit]])
    return out


ANALYTIC_CENTRES = np.array([[0, 0, 0], [3, 0, 0], [0, 3, 1], [-3, 0, -2]], dtype=np.float32)
ANALYTIC_NORMALS = np.array([[0, 0, 1], [1, 0, 0], [0, 0.6, 0.8], [0, 0, 1]], dtype=np.float32)
ANALYTIC_RADII = np.array([1.0, 0.5, 0.75, 2.0], dtype=np.float32)
# origin, direction, expected t, expected disc (-1: miss)
ANALYTIC_RAYS = [
    ((0, 0, 5), (0, 0, -1), 5.0, 0),            # straight down onto disc 0's centre
    ((0.9, 0, 5), (0, 0, -1), 5.0, 0),           # inside the rim
    ((1.1, 0.0, 5), (0, 0, -1), math.inf, -1),   # just outside disc 0 (disc 3 is at x<-1... no)
    ((0, 0, -5), (0, 0, 1), 5.0, 0),             # from below: discs are two-sided
    ((10, 0, 0), (-1, 0, 0), 7.0, 1),            # along x onto disc 1 (normal +x)
    ((0, 3, 6), (0, 0, -1), 5.0, 2),             # onto the tilted disc 2 at its centre
    ((-3, 0, 5), (0, 0, -1), 7.0, 3),            # disc 3 at z = -2
    ((-1.5, 0, 5), (0, 0, -1), 7.0, 3),          # disc 3 (radius 2) but not disc 0 (radius 1)
    ((-0.5, 0, 5), (0, 0, -1), 5.0, 0),          # disc 0 occludes disc 3 below it
    ((0, 0, 5), (0, 0, 1), math.inf, -1),        # pointing away
]


def analytic_rays():
    rays = np.array([[*o, *d] for o, d, _, _ in ANALYTIC_RAYS], dtype=np.float32)
    expected_t = np.array([t for _, _, t, _ in ANALYTIC_RAYS])
    expected_id = np.array([i for _, _, _, i in ANALYTIC_RAYS])
    return rays, expected_t, expected_id


@pytest.mark.parametrize("mode", _baselines.QUERY_MODES)
def test_embree_discs_analytic(embree, mode):
    rays, expected_t, expected_id = analytic_rays()
    bf_t, bf_id = brute_force_discs(ANALYTIC_CENTRES, ANALYTIC_NORMALS, ANALYTIC_RADII, rays)
    np.testing.assert_allclose(bf_t, expected_t, rtol=T_RTOL)  # the brute force itself is right
    np.testing.assert_array_equal(bf_id, expected_id)
    with embree.EmbreeScene.discs(ANALYTIC_CENTRES, ANALYTIC_NORMALS, ANALYTIC_RADII,
                                  threads=2) as scene:
        out = scene.intersect(rays, mode=mode)
        np.testing.assert_allclose(out["t_hit"], expected_t, rtol=T_RTOL)
        np.testing.assert_array_equal(out["primitive_ids"], expected_id)
        hit = expected_id >= 0
        ng = out["normals"][hit]
        np.testing.assert_allclose(np.abs(np.sum(ng * ANALYTIC_NORMALS[expected_id[hit]], axis=1)),
                                   1.0, rtol=1e-5)
        # Occlusion straddling the first hit: occluded iff tmax is beyond it.
        for scale, want in ((0.9, False), (1.1, True)):
            tmax = np.where(hit, expected_t * scale, 100.0).astype(np.float32)
            np.testing.assert_array_equal(scene.occluded(rays, tmax, mode=mode), hit & want)
        assert scene.build_seconds >= 0.0
        assert scene.input_bytes == 28 * len(ANALYTIC_RADII)
        assert scene.scene_bytes > 0 and scene.build_peak_bytes >= scene.scene_bytes


@pytest.mark.parametrize("threads", [1, 2])
def test_embree_discs_random_match_brute_force(embree, threads):
    rng = np.random.default_rng(DISCS_SEED)
    centres = rng.uniform(-1, 1, (RANDOM_DISCS, 3)).astype(np.float32)
    normals = rng.normal(size=(RANDOM_DISCS, 3))
    normals = (normals / np.linalg.norm(normals, axis=1, keepdims=True)).astype(np.float32)
    radii = rng.uniform(0.02, 0.2, RANDOM_DISCS).astype(np.float32)
    # Aimed at random points of the box (not at disc centres) so that many rays miss.
    targets = rng.uniform(-1, 1, (RANDOM_RAYS, 3))
    rays = common.random_rays(targets, RANDOM_RAYS, seed=DISCS_SEED)
    bf_t, bf_id = brute_force_discs(centres, normals, radii, rays)
    clear = rim_distance(centres, normals, radii, rays, bf_id, bf_t) > RIM_MARGIN
    assert clear.mean() > 0.9
    with embree.EmbreeScene.discs(centres, normals, radii, threads=threads) as scene:
        answers = [scene.intersect(rays, mode=m) for m in embree.QUERY_MODES]
        for out in answers:  # every packet width gives the same answer as single rays
            np.testing.assert_array_equal(out["t_hit"], answers[0]["t_hit"])
        out = answers[0]
        np.testing.assert_array_equal(out["primitive_ids"][clear], bf_id[clear])
        np.testing.assert_allclose(out["t_hit"][clear], bf_t[clear], rtol=RANDOM_T_RTOL)
        assert 0.2 < np.isfinite(bf_t).mean() < 1.0  # a meaningful mix of hits and misses


def test_embree_triangles_analytic(embree):
    vertices = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], dtype=np.float32)
    faces = np.array([[0, 1, 2]], dtype=np.uint32)
    rays = np.array([[0, 0, 2, 0, 0, -1], [5, 0, 2, 0, 0, -1]], dtype=np.float32)
    for mode in embree.QUERY_MODES:
        with embree.EmbreeScene.triangles(vertices, faces, threads=1) as scene:
            out = scene.intersect(rays, mode=mode)
            np.testing.assert_allclose(out["t_hit"], [2.0, np.inf])
            np.testing.assert_array_equal(out["primitive_ids"], [0, -1])
            np.testing.assert_array_equal(scene.occluded(rays, [3.0, 3.0], mode=mode),
                                          [True, False])


def test_open3d_anchor_matches_embree_triangles(embree):
    pytest.importorskip("open3d")
    vertices = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], dtype=np.float32)
    faces = np.array([[0, 1, 2]], dtype=np.uint32)
    rays = np.array([[0, 0, 2, 0, 0, -1], [5, 0, 2, 0, 0, -1], [0, 0, 2, 0, 0, -1]], np.float32)
    o3d_scene = embree.Open3DTriangles(vertices, faces, threads=1)
    np.testing.assert_allclose(o3d_scene.intersect(rays)["t_hit"], [2.0, np.inf, 2.0])
    np.testing.assert_array_equal(o3d_scene.occluded(rays, [3.0, 3.0, 1.5]), [True, False, False])


def test_camera_convention():
    camera = common.Camera(np.array([0.0, 0.0, 5.0]), np.zeros(3), np.array([0.0, 1.0, 0.0]),
                           40.0, 4, 3)
    rays = camera.rays()
    assert rays.shape == (12, 6)
    np.testing.assert_allclose(np.linalg.norm(rays[:, 3:], axis=1), 1.0, rtol=1e-6)
    first, last = rays[0, 3:], rays[-1, 3:]
    assert first[0] < 0 < first[1]  # row 0 starts at the top-left
    assert last[0] > 0 > last[1]


@pytest.mark.data
def test_bench_core_quick(embree, tmp_path):
    data = common.default_data_dir()
    if not (data / common.ARMADILLO_MESH).is_file():
        pytest.skip(f"shared data absent: {data / common.ARMADILLO_MESH}")
    import bench_core

    out = tmp_path / "core.json"
    assert bench_core.main(["--quick", "--threads", "1", "--models", "sphere,torus,armadillo,dragon",
                            "--output", str(out)]) == 0
    result = json.loads(out.read_text())
    assert [m["name"] for m in result["models"]] == ["sphere-20k", "torus-20k", "armadillo-20k",
                                                     "dragon-scans-20k"]
    discs = result["models"][0]["threads"]["1"]["embree_discs"]
    assert discs["primary"]["closest_best"] > 0
    assert discs["primary"]["modes_identical"]
    assert 0.05 < discs["primary"]["hit_fraction"] < 1.0


@pytest.mark.parametrize("mode", _baselines.QUERY_MODES)
def test_embree_one_sided_discs(embree, mode):
    rays, expected_t, expected_id = analytic_rays()
    with embree.EmbreeScene.discs(ANALYTIC_CENTRES, ANALYTIC_NORMALS, ANALYTIC_RADII,
                                  one_sided=True) as scene:
        out = scene.intersect(rays, mode=mode)
        front = np.sum(rays[:, 3:] * ANALYTIC_NORMALS[np.maximum(expected_id, 0)], axis=1) < 0
        # Front-facing hits are unchanged; the ray from below (index 3) passes through disc 0.
        keep = (expected_id >= 0) & front
        np.testing.assert_allclose(out["t_hit"][keep], expected_t[keep], rtol=T_RTOL)
        assert not np.isfinite(out["t_hit"][3])
        assert not scene.occluded(rays[3:4], [100.0], mode=mode)[0]


def test_bench_scaling_whole_process(tmp_path):
    """One fresh process per size: the sphere it samples is traced and rendered, its peak RSS
    recorded."""
    import bench_scaling

    n = 20_000
    assert bench_scaling.main(["--whole-process", "--sizes", str(n), "--threads-list", "1",
                               "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "scaling_whole_process.json").read_text())["rows"]
    assert [(r["n"], r["threads"]) for r in rows] == [(n, 1)]
    r = rows[0]
    # the camera frames the whole unit sphere: about pi/4 of a square image covers its disc
    assert 0.3 < r["hit_fraction"] < 0.9
    assert r["peak_rss_bytes"] >= r["interpreter_rss_bytes"] > 0
    assert r["memory_bytes_per_surfel"] < 64
    # the render step: a 640x480 frame of the sphere on the default ground, its own peak no
    # higher than the whole run's
    assert 0.2 < r["render_object_fraction"] < 0.9 and r["render_s"] > 0
    render_peak = r["peak_rss_render_per_surfel"]
    # compared per surfel, as the benchmark divides (when the render is the run's peak the two
    # are the same quotient; multiplied back by n it can exceed the peak by a rounding)
    assert render_peak is None or 0 < render_peak <= r["peak_rss_bytes"] / n
    assert (tmp_path / "scaling_whole_process.png").exists()
