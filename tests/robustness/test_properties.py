"""Property-based tests of the surfel queries (hypothesis, derandomized: every run is the same).

Hypothesis draws the *shape* of a case (cloud layout, size, scale, offset, seed, options); numpy
draws the arrays from the seed, so cases are cheap and still shrink to a small reproducer. For
every random cloud and ray batch:

- nothing is NaN; ``t_hit`` is >= 0 or inf; hit normals are unit; indices are valid;
- with interpolation "none" and LoD off, every hit lies on the plane of the surfel it names and
  within its radius, and ``cast_rays`` equals a float64 brute force over all surfels;
- with interpolation and LoD on, hits still lie near the surfel set (never garbage far away).

Each test prints how many cases it ran.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pointviz import PointCloud, SurfelScene

#: Examples per property in the default run (a few seconds each) and in the slow run.
EXAMPLES = 200
EXAMPLES_SLOW = 3000
#: Rim band in which float32 rounding may put a hit on either side of a disk's edge.
RIM = 1e-3
#: Below this |cos| between ray and disk, a hit's t is numerically unstable (grazing).
STABLE_COS = 0.05

LAYOUTS = ("blob", "sphere", "plane", "line", "duplicates", "single", "two-sheets")

case_strategy = st.fixed_dictionaries({
    "layout": st.sampled_from(LAYOUTS),
    "n": st.integers(1, 150),
    "scale_exp": st.integers(-4, 4),
    "offset": st.sampled_from([0.0, 1e3, 1e7, -3e7]),
    "seed": st.integers(0, 2**31 - 1),
    "n_rays": st.integers(1, 80),
    "leaf_size": st.sampled_from([1, 2, 8, 31]),
    "variant": st.sampled_from(["full", "kdtree", "lod", "lod+cull"]),
})


def make_case(c):
    """Cloud arrays and rays (world coordinates, float64) for a drawn case."""
    rng = np.random.default_rng(c["seed"])
    n, s = c["n"], 10.0 ** c["scale_exp"]
    layout = c["layout"]
    if layout == "single":
        n = 1
    if layout == "blob":
        p = rng.normal(size=(n, 3))
    elif layout == "sphere":
        p = rng.normal(size=(n, 3))
        p /= np.linalg.norm(p, axis=1, keepdims=True)
    elif layout == "plane":
        p = np.column_stack([rng.uniform(-1, 1, (n, 2)), np.zeros(n)])
    elif layout == "line":
        p = np.outer(rng.uniform(-1, 1, n), rng.normal(size=3))
    elif layout == "two-sheets":  # two facing sheets closer than a disk radius
        p = np.column_stack([rng.uniform(-1, 1, (n, 2)), np.where(np.arange(n) % 2, 0.02, -0.02)])
    else:  # duplicates
        p = np.repeat(rng.normal(size=(1, 3)), n, axis=0)
    normals = rng.normal(size=(n, 3))
    if layout in ("plane", "two-sheets") and rng.random() < 0.7:
        normals = np.tile([0.0, 0.0, 1.0], (n, 1))
        if layout == "two-sheets":
            normals[np.arange(n) % 2 == 0] *= -1
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    radii = rng.uniform(0.05, 0.4, n)
    offset = np.full(3, c["offset"]) * np.array([1.0, -0.5, 0.25])
    points = p * s + offset
    # rays from a shell around the cloud toward random points in its box (some grazing)
    m = c["n_rays"]
    v = rng.normal(size=(m, 3))
    origins = 3.0 * v / np.linalg.norm(v, axis=1, keepdims=True)
    targets = rng.uniform(-1.2, 1.2, (m, 3))
    if layout in ("plane", "two-sheets"):
        targets[: m // 3, 2] = origins[: m // 3, 2] * rng.uniform(0.0, 1e-3, m // 3)  # grazing
    dirs = (targets - origins) * rng.uniform(0.1, 10.0, (m, 1))  # any direction length
    rays = np.hstack([origins * s + offset, dirs * s])
    cloud = PointCloud(points, normals=normals, radii=radii * s)
    return cloud, rays


def brute_force(cloud, rays):
    """Float64 nearest disk per ray: (t_certain, t_possible) in units of each ray's direction."""
    p = cloud.points - cloud.points.mean(axis=0)  # the same frame for all; exact in float64
    shift = cloud.points.mean(axis=0)
    o = rays[:, None, :3] - shift
    d = rays[:, 3:] / np.linalg.norm(rays[:, 3:], axis=1, keepdims=True)
    n = cloud.normals.astype(np.float64)
    r = cloud.radii.astype(np.float64)
    facing = d @ n.T  # (m, k)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("mkj,kj->mk", p[None] - o, n) / facing
        q = o + d[:, None, :] * t[..., None] - p[None]
        u2 = np.einsum("mkj,mkj->mk", q, q) / r**2
    valid = (np.abs(facing) >= 1e-6) & (t >= 0)
    certain = valid & (u2 <= 1 - RIM) & (np.abs(facing) > STABLE_COS)
    possible = valid & (u2 <= 1 + RIM)
    length = np.linalg.norm(rays[:, 3:], axis=1)
    tc = np.where(certain, t, np.inf).min(axis=1) / length
    tp = np.where(possible, t, np.inf).min(axis=1) / length
    return tc, tp


def check_clean(out, cloud, n_rays, allow_lod_index):
    t = out["t_hit"]
    assert t.shape == (n_rays,) and not np.isnan(t).any()
    assert (t >= 0).all(), "negative t_hit"
    hit = np.isfinite(t)
    for key in ("normals", "colors", "radii"):
        assert np.isfinite(out[key]).all(), key
    np.testing.assert_allclose(np.linalg.norm(out["normals"][hit], axis=1), 1.0, atol=1e-3)
    lo = -2 if allow_lod_index else 0
    idx = out["index"]
    assert ((idx[hit] >= lo) & (idx[hit] < len(cloud))).all() and (idx[~hit] == -1).all()
    assert (out["count"][hit] >= 1).all() and (out["radii"][hit] > 0).all()
    return hit


def run_exact(c):
    """Interpolation none, LoD and culling off: every hit is on the named disk; equals brute force."""
    cloud, rays = make_case(c)
    scene = SurfelScene(cloud, variant=c["variant"], interpolation="none", lod=False, cull=False,
                        leaf_size=c["leaf_size"])
    out = scene.cast_rays(rays)
    hit = check_clean(out, cloud, len(rays), allow_lod_index=False)
    scale = 10.0 ** c["scale_exp"]
    length = np.linalg.norm(rays[:, 3:], axis=1)
    # float32 positions relative to the cloud's centre: errors scale with the cloud's size
    tol = 2e-5 * 6.0 * scale / length / STABLE_COS
    # on the named disk: in its plane, within its radius
    x = rays[hit, :3] + rays[hit, 3:] * out["t_hit"][hit, None].astype(np.float64)
    i = out["index"][hit]
    rel = x - cloud.points[i]
    plane = np.abs(np.einsum("kj,kj->k", rel, cloud.normals[i].astype(np.float64)))
    assert (plane <= 1e-4 * 6.0 * scale).all(), f"hit off its disk's plane by {plane.max():.3g}"
    assert (np.linalg.norm(rel, axis=1) <= cloud.radii[i] * (1 + RIM) + 1e-4 * scale).all()
    # the brute force
    tc, tp = brute_force(cloud, rays)
    t = out["t_hit"].astype(np.float64)
    missed = ~hit & np.isfinite(tc)
    assert not missed.any(), f"tree missed {missed.sum()} rays the brute force hits"
    bad = hit & ((t < tp - tol) | (t > tc + tol))
    assert not bad.any(), f"t differs from brute force on {bad.sum()} rays: {t[bad][:3]} vs {tc[bad][:3]}"
    occ = scene.occluded(rays, np.inf)
    assert (occ >= np.isfinite(tc)).all() and (occ <= np.isfinite(tp)).all()
    return int(hit.sum()), len(rays)


def run_blended(c):
    """Interpolation and LoD on: outputs stay clean and hits stay near the surfel set."""
    cloud, rays = make_case(c)
    scene = SurfelScene(cloud, variant=c["variant"], leaf_size=c["leaf_size"],
                        interpolation=["smooth", "paper"][c["seed"] % 2])
    # any angle: the binding dispatches on the rays' dtype, whatever the other arguments
    # (test_inputs.test_georeferenced_rays_keep_float64_with_a_pixel_angle)
    pixel_angle = [0.0, 1.1e-3, 7.3e-3][c["seed"] % 3]
    out = scene.cast_rays(rays, pixel_angle=pixel_angle)
    hit = check_clean(out, cloud, len(rays), allow_lod_index=True)
    if hit.any():
        x = rays[hit, :3] + rays[hit, 3:] * out["t_hit"][hit, None].astype(np.float64)
        gap = np.linalg.norm(x[:, None] - cloud.points[None], axis=2) - cloud.radii[None]
        # within the cloud's extent plus a disk: LoD disks may stand for whole subtrees
        reach = np.ptp(cloud.points, axis=0).max() + 2 * cloud.radii.max()
        assert (gap.min(axis=1) <= reach + 1e-4 * 10.0 ** c["scale_exp"]).all()
    return int(hit.sum()), len(rays)


COMMON = {"derandomize": True, "deadline": None, "database": None,
          "suppress_health_check": [HealthCheck.too_slow, HealthCheck.data_too_large]}


@pytest.mark.parametrize("prop, examples", [
    (run_exact, EXAMPLES), (run_blended, EXAMPLES),
    pytest.param(run_exact, EXAMPLES_SLOW, marks=pytest.mark.slow),
    pytest.param(run_blended, EXAMPLES_SLOW, marks=pytest.mark.slow),
], ids=["exact", "blended", "exact-long", "blended-long"])
def test_surfel_queries_properties(prop, examples):
    runs: list[tuple[int, int]] = []  # (hits, rays) per case

    @settings(max_examples=examples, **COMMON)
    @given(case_strategy)
    def check(c):
        runs.append(prop(c))

    check()
    hits, rays = np.sum(runs, axis=0)
    print(f"\n{prop.__name__}: {len(runs)} hypothesis cases, {rays} rays, {hits} hits")
    assert len(runs) >= min(examples, 20)
    assert hits > rays // 10, "too few hits for the properties to mean anything"
