"""LiDAR's estimation: orientation of clouds seen from above against analytic normals, and the
radii of returns that are not a surface (a volumetric "tree", sparse returns over "water")
against brute-force spacing, with the ground plane's coverage checked by rays cast onto the
analytic plane. Every oracle is computed here, independently of the core."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pointviz import PointCloud
from pointviz import estimation as est
from pointviz.errors import InputError

UP = (0.0, 0.0, 1.0)


def jittered_grid(rng, nx, ny, sx=1.0, sy=1.0, jitter=0.3):
    x, y = np.meshgrid(np.arange(nx) * sx, np.arange(ny) * sy)
    xy = np.c_[x.ravel(), y.ravel()]
    return xy + rng.uniform(-jitter, jitter, xy.shape) * [sx, sy]


def vertical_ray_misses(points, normals, radii, probes):
    """Fraction of the probes (on the analytic surface) that a vertical ray through them does
    not hit within any disk (brute force over the disks whose centre lies within reach)."""
    tree = cKDTree(points)
    reach = 1.5 * float(radii.max())
    d = np.array([0.0, 0.0, -1.0])
    missed = 0
    for q, near in zip(probes, tree.query_ball_point(probes, reach)):
        near = np.asarray(near, int)
        if near.size == 0:
            missed += 1
            continue
        o = q + [0.0, 0.0, 10.0]
        dn = normals[near] @ d
        ok = np.abs(dn) > 1e-9
        t = ((points[near] - o) * normals[near]).sum(1) / np.where(ok, dn, 1.0)
        hit = o + t[:, None] * d
        missed += not np.any(ok & (np.linalg.norm(hit - points[near], axis=1) <= radii[near]))
    return missed / len(probes)


# ------------------------------------------------------------------------------------------
# orientation seen from above


def terrain(rng, n=20000):
    """Random samples of a height field z = h(x, y) with hills and a 45-degree bank, and the
    analytic upward normals (-h_x, -h_y, 1) / |.|."""
    xy = rng.uniform(0, 60, (n, 2))
    x, y = xy[:, 0], xy[:, 1]
    z = 3 * np.sin(x / 6) * np.cos(y / 8) + np.clip(x - 40, 0, 8)
    hx = 0.5 * np.cos(x / 6) * np.cos(y / 8) + ((x > 40) & (x < 48))
    hy = -3 / 8 * np.sin(x / 6) * np.sin(y / 8)
    nrm = np.c_[-hx, -hy, np.ones(n)]
    return np.c_[xy, z], nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


def test_terrain_seen_from_above_faces_up(rng):
    """Every normal of a sampled height field faces the side of its analytic (upward) normal,
    as the spanning tree's do, and agrees with it in direction."""
    pts, exact = terrain(rng)
    above = est.estimate_normals(pts, up=UP, from_above=True)
    facing = np.einsum("ij,ij->i", above, exact)
    assert np.all(facing > 0)
    assert np.median(np.degrees(np.arccos(np.clip(facing, -1, 1)))) < 3.0
    mst = est.estimate_normals(pts, up=UP)
    assert np.all(np.einsum("ij,ij->i", mst, exact) > 0)  # the reference it replaces


def building(rng, spacing=0.5):
    """Ground around a 10 x 10 x 6 box (roof and four walls, as aerial and terrestrial LiDAR
    would sample them; no floor under it), and each point's outward analytic normal."""
    g = rng.uniform(-15, 15, (int(900 / spacing**2), 2))
    g = g[(np.abs(g) > 5).any(axis=1)]
    parts = [np.c_[g, np.zeros(len(g))]]
    normals = [np.tile([0.0, 0.0, 1.0], (len(g), 1))]
    roof = rng.uniform(-5, 5, (int(100 / spacing**2), 2))
    parts.append(np.c_[roof, np.full(len(roof), 6.0)])
    normals.append(np.tile([0.0, 0.0, 1.0], (len(roof), 1)))
    m = int(60 / spacing**2)
    for axis in (0, 1):
        for side in (-1.0, 1.0):
            s = rng.uniform(-5, 5, m)
            h = rng.uniform(0, 6, m)
            w = np.zeros((m, 3))
            w[:, axis] = 5.0 * side
            w[:, 1 - axis] = s
            w[:, 2] = h
            parts.append(w)
            nn = np.zeros((m, 3))
            nn[:, axis] = side
            normals.append(nn)
    return np.vstack(parts), np.vstack(normals)


def test_walls_seen_from_above_face_outward(rng):
    """The walls' normals (too steep for the up to decide) take their sign from the roof and
    the ground through the creases: nearly all face out of the building."""
    pts, exact = building(rng)
    nrm, info = est.estimate_normals(pts, up=UP, from_above=True, details=True)
    walls = np.abs(exact[:, 2]) < 0.5
    assert info["steep"] >= walls.sum() * 0.7  # (near the creases PCA tilts them)
    facing = np.einsum("ij,ij->i", nrm, exact)
    assert np.mean(facing[walls] > 0) > 0.97  # (a corner patch may still follow a tilted seed)
    assert np.mean(facing[~walls] > 0) > 0.999


def test_orientation_from_above_is_the_same_for_any_thread_count(rng):
    pts, _ = building(rng)
    a = est.estimate_normals(pts, up=UP, from_above=True, threads=1)
    b = est.estimate_normals(pts, up=UP, from_above=True, threads=2)
    np.testing.assert_array_equal(a, b)
    flipped = a * np.where(rng.random(len(a)) < 0.5, -1.0, 1.0)[:, None]
    c = est.orient_normals(pts, flipped, up=UP, from_above=True, threads=1)
    d = est.orient_normals(pts, flipped, up=UP, from_above=True, threads=2)
    np.testing.assert_array_equal(c, d)
    # the same signs from any starting ones, but for a wall's normal that nothing decides (no
    # oriented neighbour's vote, no vertical part): it keeps the sign it came with
    assert np.mean(np.einsum("ij,ij->i", c, a) > 0) > 0.999


def test_from_above_needs_up(rng):
    pts = rng.random((50, 3))
    with pytest.raises(InputError, match="from_above"):
        est.estimate_normals(pts, from_above=True)
    with pytest.raises(InputError, match="from_above"):
        est.orient_normals(pts, np.tile([0, 0, 1.0], (50, 1)), from_above=True)
    with pytest.raises(InputError, match="seen_from_above"):
        PointCloud(pts, seen_from_above=True)


# ------------------------------------------------------------------------------------------
# radii of what is not a surface


def ground_and_tree(rng):
    """A jittered grid of ground (spacing 1) and a volumetric random cluster above it."""
    ground = jittered_grid(rng, 50, 50)
    ground = np.c_[ground, np.zeros(len(ground))]
    tree = rng.uniform([20, 20, 3], [30, 30, 9], (3000, 3))
    return ground, tree


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(7)
    ground, tree = ground_and_tree(rng)
    pts = np.vstack([ground, tree])
    nrm = est.estimate_normals(pts, up=UP, from_above=True)
    return pts, nrm, len(ground)


def test_ground_stays_hole_free_beside_a_tree(scene):
    """Vertical rays onto the analytic ground plane, under the tree too: all hit a ground disk
    with the non-surface bounds on, as without them. The ground's radii are the surface
    model's but at one-sided points, whose grazing directions the bounds leave out: the median
    within 0.1 %, none larger."""
    pts, nrm, ng = scene
    radii = est.coverage_radii(pts, nrm, volume=True)
    probes = np.c_[np.random.default_rng(1).uniform(2, 47, (20000, 2)), np.zeros(20000)]
    assert vertical_ray_misses(pts[:ng], nrm[:ng], radii[:ng], probes) == 0.0
    plain = est.coverage_radii(pts, nrm)
    np.testing.assert_allclose(np.median(radii[:ng]), np.median(plain[:ng]), rtol=1e-3)
    assert np.all(radii[:ng] <= plain[:ng] * (1 + 1e-6))


def test_tree_radii_stay_within_their_spacing(scene):
    """The cluster's radii against each point's brute-force nearest-neighbour distance d1:
    at most VOLUME_FACTOR x d1 for nearly all points (those whose neighbours by chance lie in
    one plane keep a cell's radius, which is capped at their 10th neighbour's distance),
    where the surface model makes most of them several times larger."""
    pts, nrm, ng = scene
    tree = pts[ng:]
    d = np.linalg.norm(tree[:, None, :] - pts[None, :, :], axis=2)
    d[np.arange(len(tree)), ng + np.arange(len(tree))] = np.inf
    d.sort(axis=1)
    d1, d10 = d[:, 0], d[:, 9]
    radii = est.coverage_radii(pts, nrm, volume=True)[ng:]
    plain = est.coverage_radii(pts, nrm)[ng:]
    ratio = radii / d1
    assert np.mean(ratio <= est.VOLUME_FACTOR * (1 + 1e-5)) > 0.9
    assert np.quantile(ratio, 0.95) < 1.5
    assert np.all(radii <= d10 * (1 + 1e-5))
    assert np.mean(plain / d1 <= est.VOLUME_FACTOR * (1 + 1e-5)) < 0.5  # what the rule changes


def test_sparse_returns_are_not_blown_up_but_scan_lines_are_covered(rng):
    """A dense plane (spacing 1) with a 'river' of returns 6x sparser: nearly all the river's
    radii stay within TYPICAL_CAP x the dense part's median radius (a return whose cell is
    elongated keeps its radius, capped at its 10th neighbour's distance, as before); ground
    sampled in scan lines 4x farther apart than the samples along them stays hole-free."""
    dense = jittered_grid(rng, 60, 30)
    river = rng.uniform([0, 32], [60, 60], (int(60 * 28 / 36), 2))
    pts = np.c_[np.vstack([dense, river]), np.zeros(len(dense) + len(river))]
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    radii = est.coverage_radii(pts, nrm, volume=True)
    plain = est.coverage_radii(pts, nrm)
    typical = np.median(plain[: len(dense)])
    capped = radii[len(dense):] <= est.TYPICAL_CAP * typical * 1.05
    assert capped.mean() > 0.9
    assert np.all(radii <= plain)
    assert np.mean(plain[len(dense):] <= est.TYPICAL_CAP * typical * 1.05) < 0.5  # the change
    lines = jittered_grid(rng, 120, 30, sx=0.5, sy=2.0, jitter=0.1)
    pts = np.c_[lines, np.zeros(len(lines))]
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    radii = est.coverage_radii(pts, nrm, volume=True)
    probes = np.c_[rng.uniform(3, 56, (20000, 2))[:, 0], rng.uniform(3, 56, 20000), np.zeros(20000)]
    assert vertical_ray_misses(pts, nrm, radii, probes) == 0.0


def test_radii_with_volume_are_the_same_for_any_thread_count(scene):
    pts, nrm, _ = scene
    np.testing.assert_array_equal(est.coverage_radii(pts, nrm, volume=True, threads=1),
                                  est.coverage_radii(pts, nrm, volume=True, threads=2))


def test_a_cloud_seen_from_above_uses_both(scene):
    """PointCloud(seen_from_above=True) estimates with the orientation from above and the
    non-surface radii; without it, radii are the surface model's (meshes, range scans)."""
    pts, nrm, _ = scene
    lidar = PointCloud(pts, up=UP, seen_from_above=True)
    np.testing.assert_array_equal(lidar.normals, est.estimate_normals(pts, up=UP, from_above=True))
    # (from the normals' own search: equal but where equidistant neighbours tie)
    np.testing.assert_allclose(lidar.radii, est.coverage_radii(pts, lidar.normals, volume=True),
                               rtol=1e-5)
    plain = PointCloud(pts, normals=lidar.normals, up=UP)
    np.testing.assert_array_equal(plain.radii, est.coverage_radii(pts, lidar.normals))
    assert lidar.subset(np.arange(100)).seen_from_above


def test_normals_and_radii_from_one_search_match_the_two_steps(rng):
    """normals_and_radii against estimate_normals + coverage_radii (the oracle here: the two
    steps, each tested above against brute force and ray casts), on a cloud without exact ties
    (random float coordinates), for 1 and 2 threads: the normals bit for bit, the radii to
    within a float's rounding (the surface model's search without the bounds visits the rows
    fused, in another order: 3 of 5,500 radii differ by 1 ulp; with the open directions of the
    volume bound, 1 of 5,500 by 1 ulp: a direction's edge at its threshold)."""
    ground, tree = ground_and_tree(rng)
    pts = np.vstack([ground, tree])
    want_n = est.estimate_normals(pts, up=UP, from_above=True)
    want_r = est.coverage_radii(pts, want_n, volume=True)
    for threads in (1, 2):
        n, r = est.normals_and_radii(pts, up=UP, from_above=True, volume=True, threads=threads)
        np.testing.assert_array_equal(n, want_n)
        np.testing.assert_allclose(r, want_r, rtol=1e-6)
        assert np.mean(r != want_r) < 1e-3
    n, r = est.normals_and_radii(pts, up=UP)  # the spanning tree, the surface model
    np.testing.assert_array_equal(n, est.estimate_normals(pts, up=UP))
    np.testing.assert_allclose(r, est.coverage_radii(pts, n), rtol=1e-6)


# ------------------------------------------------------------------------------------------
# part two: fewer neighbours for the normals from above; the petals' open directions


def test_normals_from_above_use_at_most_normal_k_max_above(rng):
    """A cloud seen from above grows its normals to NORMAL_K_MAX_ABOVE points, not
    NORMAL_K_MAX; on a height field with height noise of 0.2 spacings the normals stay within
    a few degrees of the analytic ones (measured mean 2.96 degrees at 20, 1.97 at 32)."""
    pts, exact = terrain(rng, n=40000)
    spacing = 60 / np.sqrt(40000)
    pts[:, 2] += rng.normal(scale=0.2 * spacing, size=len(pts))
    nrm, info = est.estimate_normals(pts, up=UP, from_above=True, details=True)
    assert info["support"].max() == est.NORMAL_K_MAX_ABOVE < est.NORMAL_K_MAX
    err = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", nrm, exact), -1, 1)))
    assert err.mean() < 3.5 and np.all(err < 90)
    _, plain = est.estimate_normals(pts, up=UP, details=True)
    assert plain["support"].max() == est.NORMAL_K_MAX


def cell_radii_with_open_directions(points, normals, k=est.COVER_K, nd=est.COVER_DIRECTIONS):
    """Brute force (numpy, scipy's tree) of a point's coverage radius on a plane with the open
    directions left out: along each of nd directions the nearest perpendicular bisector among
    the k nearest neighbours; at a one-sided point (some direction meets no bisector) a
    direction is open when that bisector lies farther than its own neighbour; the cell is the
    largest extent over the other directions (over all bounded ones if none is left), the
    radius min(COVER_MARGIN x cell, the k-th neighbour's distance). Also returns which points
    are one-sided."""
    d, idx = cKDTree(points).query(points, k + 1)
    d, idx = d[:, 1:], idx[:, 1:]
    t1 = np.cross(normals, [1.0, 0.0, 0.0])
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    rel = points[idx] - points[:, None, :]
    x, y = np.einsum("ikj,ij->ik", rel, t1), np.einsum("ikj,ij->ik", rel, t2)
    r = np.hypot(x, y)
    th = 2 * np.pi * np.arange(nd) / nd
    proj = x[:, :, None] * np.cos(th) + y[:, :, None] * np.sin(th)
    ok = proj > 1e-6 * r[:, :, None]
    s = np.where(ok, r[:, :, None] ** 2 / (2 * np.where(ok, proj, 1)), np.inf)
    win = np.argmin(s, axis=1)
    edge = np.take_along_axis(s, win[:, None, :], 1)[:, 0]
    beside = edge > np.take_along_axis(r, win, 1)  # farther than its own neighbour
    finite = np.isfinite(edge)
    one_sided = ~finite.all(1)
    closed = finite & ~(one_sided[:, None] & beside)
    cell = np.where(closed.any(1), np.where(closed, edge, 0).max(1),
                    np.where(finite, edge, 0).max(1))
    return np.minimum(est.COVER_MARGIN * cell, d[:, -1]), one_sided


def test_open_directions_against_brute_force_on_a_plane(rng):
    """On a plane (every neighbourhood a surface: the volume bounds leave it alone) with a
    ragged edge, the radii with the volume bounds on are the brute force's above, and the
    points with an open direction lose their grazing far ends (the petals' cause)."""
    xy = rng.uniform(0, 30, (3000, 2))
    xy = xy[xy[:, 1] < 20 + 3 * np.sin(xy[:, 0])]  # an edge with one-sided points along it
    pts = np.c_[xy, np.zeros(len(xy))]
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    got = est.coverage_radii(pts, nrm, volume=True)
    want, one_sided = cell_radii_with_open_directions(pts, nrm)
    close = np.isclose(got, want, rtol=1e-4)
    assert close.mean() > 0.995, np.flatnonzero(~close)[:10]
    plain = est.coverage_radii(pts, nrm)
    assert np.all(got <= plain * (1 + 1e-6))
    np.testing.assert_allclose(got[~one_sided], plain[~one_sided], rtol=1e-6)
    assert one_sided.sum() > 50 and np.median(got[one_sided] / plain[one_sided]) < 0.95


@pytest.mark.parametrize("seed", range(4))
def test_uniform_random_ground_stays_hole_free_with_open_directions(seed):
    """Uniform random samples of a plane (whose 10 nearest lie to one side of a point now and
    then): every vertical ray onto it hits a disk with the volume bounds on."""
    rng = np.random.default_rng(seed)
    pts = np.c_[rng.uniform(0, 60, (4000, 2)), np.zeros(4000)]
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    radii = est.coverage_radii(pts, nrm, volume=True)
    probes = np.c_[rng.uniform(5, 55, (20000, 2)), np.zeros(20000)]
    assert vertical_ray_misses(pts, nrm, radii, probes) == 0.0
