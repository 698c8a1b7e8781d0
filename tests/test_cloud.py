"""Tests of pointviz.cloud: validation, estimation of normals and radii, derived clouds."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pointviz.cloud import RADIUS_FACTOR, PointCloud, estimate_radii
from pointviz.errors import InputError

# ------------------------------------------------------------------------------------------
# helpers


def ray_cover_ratio(cloud, origins, dirs, candidates=16):
    """For each ray, min over the nearest disks of |hit - centre| / radius (<= 1: covered).

    The candidates are the disks nearest to the ray origin, which is put on the true surface.
    """
    pts, nrm, rad = cloud.points, cloud.normals.astype(float), cloud.radii.astype(float)
    _, idx = cKDTree(pts).query(origins, k=candidates)
    p, n = pts[idx], nrm[idx]
    denom = np.einsum("bkj,bj->bk", n, dirs)
    safe = np.where(np.abs(denom) > 1e-9, denom, np.nan)
    t = np.einsum("bkj,bkj->bk", n, p - origins[:, None, :]) / safe
    hit = origins[:, None, :] + t[..., None] * dirs[:, None, :]
    ratio = np.linalg.norm(hit - p, axis=2) / rad[idx]
    return np.where(np.isfinite(ratio), ratio, np.inf).min(axis=1)


def mean_nn_spacing(points):
    return cKDTree(points).query(points, k=2)[0][:, 1].mean()


def jittered_grid(rng, side=60, jitter=0.25):
    g = np.stack(np.meshgrid(np.arange(side, dtype=float), np.arange(side, dtype=float)), -1)
    g = g.reshape(-1, 2) + rng.uniform(-jitter, jitter, (side * side, 2))
    return np.c_[g, np.zeros(len(g))]


# ------------------------------------------------------------------------------------------
# construction and validation


def test_arrays_are_copied_to_documented_dtypes(rng):
    base = rng.random((10, 6)).astype(np.float32)
    strided = base[::2, ::2]  # non-contiguous (5, 3) float32
    normals = rng.normal(size=(5, 3)) * 3
    cloud = PointCloud(
        strided, normals, radii=np.arange(1, 6), colors=np.full((5, 3), 255, np.uint8)
    )
    assert cloud.points.dtype == np.float64 and cloud.points.flags.c_contiguous
    np.testing.assert_array_equal(cloud.points, strided.astype(np.float64))
    assert cloud.normals.dtype == np.float32 and cloud.normals.flags.c_contiguous
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1, atol=1e-6)
    assert cloud.radii.dtype == np.float32 and cloud.radii.shape == (5,)
    assert cloud.colors.dtype == np.float32 and np.all(cloud.colors == 1.0)
    assert cloud.has_normals and cloud.has_colors and len(cloud) == 5
    base[:] = 0  # the cloud owns its data
    assert cloud.points.any()


def test_large_coordinates_keep_float64_precision():
    pts = np.array(
        [
            [637000.123456, 849000.654321, 412.5],
            [637000.5, 849000.25, 412.75],
            [637001.0, 849001.0, 413.0],
        ]
    )
    cloud = PointCloud(pts)
    np.testing.assert_array_equal(cloud.points, pts)


def test_bounds_center_diagonal():
    cloud = PointCloud([[0, 0, 0], [2, 4, 4], [1, 1, 1]])
    lo, hi = cloud.bounds
    np.testing.assert_array_equal(lo, [0, 0, 0])
    np.testing.assert_array_equal(hi, [2, 4, 4])
    np.testing.assert_array_equal(cloud.center, [1, 2, 2])
    assert cloud.diagonal == pytest.approx(6.0)
    assert lo.dtype == np.float64


def _nan_points():
    p = np.zeros((30, 3))
    p[[17, 20, 25], 1] = np.nan
    return p


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"points": np.zeros((5, 2))}, r"points: expected shape \(n, 3\), got \(5, 2\)"),
        ({"points": np.zeros(3)}, r"points: expected shape \(n, 3\)"),
        ({"points": np.zeros((2, 3, 1))}, r"points: expected shape \(n, 3\)"),
        ({"points": np.array([["a", "b", "c"]])}, r"points: expected a real numeric array"),
        ({"points": np.zeros((2, 3), dtype=bool)}, r"points: expected a real numeric array"),
        ({"points": np.zeros((2, 3), dtype=complex)}, r"points: expected a real numeric array"),
        ({"points": np.zeros((0, 3))}, r"points: the cloud is empty"),
        ({"points": _nan_points()}, r"points: 3 rows contain NaN or inf \(first at row 17\)"),
        (
            {"normals": np.r_[np.ones((3, 3)), [[0, 0, np.inf]]]},
            r"normals: 1 rows contain NaN or inf \(first at row 3\)",
        ),
        (
            {"normals": np.r_[np.ones((2, 3)), np.zeros((2, 3))]},
            r"normals: 2 rows have zero length \(first at row 2\)",
        ),
        ({"normals": np.ones((3, 3))}, r"normals: has 3 rows but points has 4"),
        ({"radii": [1, 1, -1, 1]}, r"radii: 1 values are zero or negative \(first at row 2"),
        ({"radii": [1, 0, 1, 1]}, r"radii: 1 values are zero or negative \(first at row 1"),
        ({"radii": [1, 1, np.nan, 1]}, r"radii: 1 values are NaN or inf \(first at row 2\)"),
        ({"radii": np.ones(5)}, r"radii: expected shape \(4,\)"),
        ({"colors": np.full((4, 3), 1.5)}, r"colors: 4 rows are outside \[0, 1\]"),
        ({"colors": -np.ones((4, 3))}, r"colors: 4 rows are outside \[0, 1\]"),
        ({"colors": np.full((4, 3), 300)}, r"colors: integer colours must be 8-bit"),
        ({"colors": np.ones((3, 3))}, r"colors: has 3 rows but points has 4"),
        ({"colors": np.ones((4, 2))}, r"colors: expected shape \(n, 3\)"),
        ({"up": [0, 0, 0]}, r"up: must not be the zero vector"),
        ({"up": [0, 1]}, r"up: expected shape \(3,\)"),
        ({"viewpoints": np.zeros((3, 3))}, r"viewpoints: expected shape \(3,\) or \(4, 3\)"),
        ({"name": 3}, r"name: expected a str"),
        ({"intensity": np.ones(3)}, r"intensity: expected shape \(4,\)"),
        ({"scan_index": np.ones(4)}, r"scan_index: expected integers"),
    ],
)
def test_invalid_input_names_the_argument(kwargs, message):
    args = {"points": np.arange(12, dtype=float).reshape(4, 3)}
    args.update(kwargs)
    with pytest.raises(InputError, match=message):
        PointCloud(**args)


def test_colors_integer_and_rgba():
    rgba = np.array([[255, 0, 0, 255], [0, 128, 0, 10]], dtype=np.uint8)
    cloud = PointCloud(np.zeros((2, 3)), colors=rgba)
    np.testing.assert_allclose(cloud.colors, [[1, 0, 0], [0, 128 / 255, 0]], rtol=1e-6)
    wide = PointCloud(np.zeros((1, 3)), colors=np.array([[65535, 0, 0]], dtype=np.uint16))
    np.testing.assert_allclose(wide.colors, [[1, 0, 0]])


def test_scalar_radius_is_broadcast():
    cloud = PointCloud(np.zeros((3, 3)), radii=0.5)
    np.testing.assert_array_equal(cloud.radii, np.full(3, 0.5, np.float32))


def test_arrays_are_read_only(sphere_cloud):
    with pytest.raises(ValueError):
        sphere_cloud.points[0, 0] = 1.0
    with pytest.raises(ValueError):
        sphere_cloud.normals[0, 0] = 1.0


# ------------------------------------------------------------------------------------------
# normals


def test_normals_are_estimated_lazily_and_cached(fibonacci):
    cloud = PointCloud(fibonacci(500))
    assert not cloud.has_normals
    assert cloud._normals is None  # nothing computed at construction
    first = cloud.normals
    assert cloud.normals is first
    assert not cloud.has_normals  # still "not given"
    assert first.dtype == np.float32 and first.shape == (500, 3)


def angles_deg(a, b):
    cos = np.einsum("ij,ij->i", a.astype(float), b.astype(float))
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def test_sphere_normals_point_outward(sphere_cloud):
    """PCA + MST orientation on the closed unit sphere vs the analytic normals.

    Measured: 100% within 10 degrees (median 0.32, worst 0.85 degrees) for 4000 Fibonacci points.
    """
    est = PointCloud(sphere_cloud.points).normals
    ang = angles_deg(est, sphere_cloud.normals)
    assert np.mean(ang < 10) > 0.99
    assert np.median(ang) < 1.0


def test_sphere_normals_at_georeferenced_coordinates(fibonacci):
    """A 1 m sphere sitting at 1e6..1e7: the PCA must centre neighbourhoods in float64."""
    unit = fibonacci(2000)
    offset = np.array([6.4e5, 4.9e6, 2.3e3])
    est = PointCloud(unit + offset).normals
    assert np.mean(angles_deg(est, unit) < 10) > 0.99


def test_noisy_sphere_normals(fibonacci, rng):
    unit = fibonacci(4000)
    noisy = unit * (1 + rng.normal(0, 0.003, (4000, 1)))  # ~10% of the spacing
    est = PointCloud(noisy).normals
    assert np.mean(angles_deg(est, unit) < 10) > 0.99


def test_two_separate_spheres_both_outward(fibonacci):
    unit = fibonacci(1500)
    pts = np.r_[unit, unit * 0.5 + [5, 0, 0]]
    est = PointCloud(pts).normals
    assert np.mean(angles_deg(est, np.r_[unit, unit]) < 10) > 0.99


def test_viewpoint_orients_toward_scanner(rng):
    pts = jittered_grid(rng, side=20)
    down = PointCloud(pts, viewpoints=[10, 10, -5]).normals
    assert np.all(down[:, 2] < -0.99)
    per_point = np.tile([10.0, 10.0, 5.0], (len(pts), 1))
    up = PointCloud(pts, viewpoints=per_point).normals
    assert np.all(up[:, 2] > 0.99)


def test_open_plane_faces_up_hint(rng):
    pts = jittered_grid(rng, side=30)
    for up in ([0, 0, 1], [0, 0, -1]):
        est = PointCloud(pts, up=up).normals
        assert np.all(est[:, 2] * up[2] > 0.99)


def test_too_few_points_for_normals():
    with pytest.raises(InputError, match="normals: cannot be estimated from 2 point"):
        PointCloud(np.eye(3)[:2]).normals  # noqa: B018


# ------------------------------------------------------------------------------------------
# radii


def test_radii_cover_sphere(sphere_cloud, rng):
    """Rays from the centre through 200k random directions must all hit a disk.

    Measured: the largest fraction of a radius any ray needs is 0.93; the mean radius is 0.81x
    the mean nearest-neighbour spacing (the spacing-only rule, 0.65 x d_8, gave 1.10x).
    """
    cloud = PointCloud(sphere_cloud.points, sphere_cloud.normals)
    dirs = rng.normal(size=(200_000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ratio = ray_cover_ratio(cloud, dirs, dirs)
    assert np.all(ratio <= 1.0)
    spacing = mean_nn_spacing(cloud.points)
    assert cloud.radii.mean() <= 0.9 * spacing


def test_radii_cover_jittered_plane(rng):
    """A 60x60 grid jittered by +-0.25 spacing, probed by 200k vertical rays inside it.

    Measured: mean radius 1.43x the mean NN spacing (jitter shortens it to 0.80 grid steps),
    i.e. about 1.0 grid step.
    """
    pts = jittered_grid(rng)
    cloud = PointCloud(pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)))
    probes = np.c_[rng.uniform(3, 56, (200_000, 2)), np.zeros(200_000)]
    ratio = ray_cover_ratio(cloud, probes, np.tile([0.0, 0.0, -1.0], (200_000, 1)))
    assert np.all(ratio <= 1.0)
    assert cloud.radii.mean() <= 1.5 * mean_nn_spacing(pts)
    assert cloud.radii.mean() <= 1.1  # in units of the grid step


def test_radii_with_estimated_normals_cover_anisotropic_grid(rng):
    """Range-scan-like sampling: rows twice as far apart as columns."""
    g = np.stack(np.meshgrid(np.arange(40.0), np.arange(0.0, 80.0, 2.0)), -1).reshape(-1, 2)
    cloud = PointCloud(np.c_[g, np.zeros(len(g))])
    probes = np.c_[
        rng.uniform(3, 36, (50_000, 1)), rng.uniform(6, 72, (50_000, 1)), np.zeros(50_000)
    ]
    ratio = ray_cover_ratio(cloud, probes, np.tile([0.0, 0.0, 1.0], (50_000, 1)))
    assert np.all(ratio <= 1.0)


def test_radii_cover_uniform_random_plane(rng):
    """Uniform random (Poisson) sampling has far larger gaps than a jittered grid: the
    spacing-only rule (0.65 x d_8) left 1.3% of such a plane uncovered; the Voronoi-cell rule
    must leave none."""
    pts = np.c_[rng.uniform(0, 100, (20_000, 2)), np.zeros(20_000)]
    cloud = PointCloud(pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)))
    probes = np.c_[rng.uniform(5, 95, (200_000, 2)), np.zeros(200_000)]
    ratio = ray_cover_ratio(cloud, probes, np.tile([0.0, 0.0, -1.0], (200_000, 1)), candidates=24)
    assert np.all(ratio <= 1.0)
    old = estimate_radii(pts, factor=RADIUS_FACTOR)
    old_cloud = PointCloud(pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)), radii=old)
    old_ratio = ray_cover_ratio(old_cloud, probes, np.tile([0.0, 0.0, -1.0], (200_000, 1)),
                                candidates=24)
    assert np.mean(old_ratio > 1.0) > 0.005  # the oracle sees the holes the old rule left


def test_radii_guard_duplicates(fibonacci):
    pts = np.repeat(fibonacci(300), 10, axis=0)  # every point 10 times: d_8 == 0
    radii = PointCloud(pts).radii
    assert np.all(radii > 0) and np.all(np.isfinite(radii))
    spacing = mean_nn_spacing(fibonacci(300))
    assert 0.1 * spacing < radii.min() and radii.max() < 2 * spacing


def test_radii_of_coincident_points_cannot_be_estimated():
    with pytest.raises(InputError, match="radii: cannot be estimated, all 4 points coincide"):
        PointCloud(np.ones((4, 3))).radii  # noqa: B018
    with pytest.raises(InputError, match="radii: cannot be estimated from a single point"):
        PointCloud(np.ones((1, 3))).radii  # noqa: B018


def test_radii_follow_local_density(rng):
    dense = np.c_[rng.uniform(0, 1, (2000, 2)), np.zeros(2000)]
    sparse = np.c_[rng.uniform(2, 3, (200, 2)), np.zeros(200)]
    radii = estimate_radii(np.r_[dense, sparse])
    assert np.median(radii[2000:]) > 2.5 * np.median(radii[:2000])


# ------------------------------------------------------------------------------------------
# derived clouds


def test_subset_keeps_present_attributes(rng):
    n = 50
    cloud = PointCloud(
        rng.random((n, 3)),
        rng.normal(size=(n, 3)),
        rng.random(n) + 0.1,
        rng.random((n, 3)),
        up=[0, 0, 1],
        name="x",
        viewpoints=rng.random((n, 3)),
        intensity=rng.random(n),
        scan_index=np.arange(n) % 3,
    )
    mask = np.arange(n) % 2 == 0
    sub = cloud.subset(mask)
    assert len(sub) == 25 and sub.name == "x" and sub.has_normals and sub.has_colors
    for attr in ("points", "normals", "radii", "colors", "viewpoints", "intensity", "scan_index"):
        np.testing.assert_array_equal(getattr(sub, attr), getattr(cloud, attr)[mask])
    np.testing.assert_array_equal(sub.up, cloud.up)
    idx = np.array([3, 1, 1])
    np.testing.assert_array_equal(cloud.subset(idx).points, cloud.points[idx])


def test_subset_reestimates_radii_but_keeps_estimated_normals(fibonacci):
    cloud = PointCloud(fibonacci(2000))
    normals, radii = cloud.normals, cloud.radii
    sub = cloud.subset(np.arange(0, 2000, 4))
    assert not sub.has_normals
    np.testing.assert_array_equal(sub.normals, normals[::4])
    assert sub.radii.mean() > 1.5 * radii.mean()  # a quarter of the density


@pytest.mark.parametrize(
    "sel, message",
    [
        (np.zeros(3, bool), "boolean mask must have shape"),
        (np.zeros(10, bool), "selects no points"),
        (np.array([0, 10]), "indices must be in"),
        (np.array([0.5]), "expected a boolean mask or integer indices"),
    ],
)
def test_subset_rejects_bad_selections(sel, message):
    cloud = PointCloud(np.arange(30.0).reshape(10, 3))
    with pytest.raises(InputError, match=message):
        cloud.subset(sel)


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_transformed_rotates_normals_and_scales_radii(sphere_cloud):
    m = np.eye(4)
    m[:3, :3] = 2.0 * rotation([1, 2, 3], 0.7)
    m[:3, 3] = [10, -5, 3]
    cloud = PointCloud(sphere_cloud.points, sphere_cloud.normals, radii=0.01, up=[0, 1, 0])
    moved = cloud.transformed(m)
    np.testing.assert_allclose(moved.points, cloud.points @ m[:3, :3].T + m[:3, 3])
    # still the outward normals of the (bigger) sphere around the new centre
    expected = (moved.points - m[:3, 3]) / 2.0
    np.testing.assert_allclose(moved.normals, expected, atol=1e-5)
    np.testing.assert_allclose(moved.radii, 0.02, rtol=1e-6)
    np.testing.assert_allclose(moved.up, rotation([1, 2, 3], 0.7) @ [0, 1, 0], atol=1e-12)
    assert moved.has_normals and moved.has_radii
    np.testing.assert_array_equal(cloud.points, sphere_cloud.points)  # original untouched


def test_transformed_reflection_and_shear_keep_normals_outward(sphere_cloud):
    m = np.diag([-1.0, 1.0, 3.0, 1.0])  # mirror and stretch into an ellipsoid
    moved = sphere_cloud.transformed(m)
    # outward normal of x^2 + y^2 + (z/3)^2 = 1 is proportional to (x, y, z/9)
    p = moved.points
    expected = p * [1, 1, 1 / 9]
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(moved.normals, expected, atol=1e-5)


def test_transformed_rejects_bad_matrices(sphere_cloud):
    with pytest.raises(InputError, match=r"matrix: expected shape \(4, 4\)"):
        sphere_cloud.transformed(np.eye(3))
    proj = np.eye(4)
    proj[3, 2] = 1
    with pytest.raises(InputError, match="matrix: last row must be"):
        sphere_cloud.transformed(proj)
    with pytest.raises(InputError, match="singular"):
        sphere_cloud.transformed(np.diag([1.0, 0.0, 1.0, 1.0]))


# ------------------------------------------------------------------------------------------
# meshes and converters


def octahedron():
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    f = np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    )
    return v, f


def test_from_mesh_vertices_get_outward_face_normals():
    v, f = octahedron()
    cloud = PointCloud.from_mesh(v, f)
    np.testing.assert_allclose(cloud.normals, v, atol=1e-6)
    assert cloud.has_normals


def test_from_mesh_turns_a_closed_mesh_wound_inside_out():
    v, f = octahedron()
    for faces in (f[:, ::-1], f[:, [0, 2, 1]]):  # every face wound the other way
        cloud = PointCloud.from_mesh(v, faces)
        np.testing.assert_allclose(cloud.normals, v, atol=1e-6)  # outward all the same
        assert any("inside out" in n for n in cloud.notes)
        sampled = PointCloud.from_mesh(v, faces, sample=500, rng=0)
        assert (np.einsum("ij,ij->i", sampled.normals, sampled.points) > 0).all()
    assert not PointCloud.from_mesh(v, f).notes


def test_from_mesh_keeps_an_open_meshs_winding():
    # a square of two faces wound downward (-z), and an octahedron missing two of its eight
    # faces (a quarter of its edges on the boundary), wound inside out: no inside to go by
    sq = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    cloud = PointCloud.from_mesh(sq, [[0, 2, 1], [0, 3, 2]])
    np.testing.assert_allclose(cloud.normals, np.tile([0, 0, -1.0], (4, 1)), atol=1e-9)
    v, f = octahedron()
    cloud = PointCloud.from_mesh(v, f[2:, ::-1])
    assert (np.einsum("ij,ij->i", cloud.normals, v) < 0).all()
    assert not cloud.notes


def test_from_mesh_loose_vertex_borrows_nearest_normal():
    v, f = octahedron()
    v = np.r_[v, [[0, 0, 1.01]]]
    cloud = PointCloud.from_mesh(v, f)
    np.testing.assert_allclose(cloud.normals[-1], [0, 0, 1], atol=1e-6)
    assert "1 of 7 vertices" in cloud.notes[0]


def test_from_mesh_loose_vertices_cover_no_more_than_their_face_vertex():
    # a fan of triangles in the z = 0 plane and, beyond its edge, a row of loose vertices out
    # of the plane: their own tangent-plane cells (the normal borrowed from the fan) open
    # towards the fan and would reach far; the faces already cover the surface
    ring = np.linspace(0, np.pi, 9)
    fan = np.c_[np.cos(ring), np.sin(ring), np.zeros(9)]
    v = np.r_[[[0.0, 0.0, 0.0]], fan]
    f = np.array([[0, i, i + 1] for i in range(1, 9)])
    row = np.c_[np.linspace(-0.3, 0.3, 7), np.full(7, -0.05), np.full(7, 0.4)]
    cloud = PointCloud.from_mesh(np.r_[v, row], f)
    mesh_only = PointCloud.from_mesh(v, f)
    loose = np.arange(len(v), len(v) + len(row))
    # the oracle: each loose vertex's nearest face vertex, by brute force, and its radius
    d = np.linalg.norm(row[:, None, :] - v[None, :, :], axis=2)
    nearest = np.argmin(d, axis=1)
    assert np.all(cloud.radii[loose] <= cloud.radii[nearest])
    np.testing.assert_allclose(cloud.normals[loose], 0 * row + [0, 0, 1], atol=1e-6)
    # the face vertices' own cover does not depend on the loose vertices' radii
    assert not cloud.has_radii and np.all(cloud.radii > 0)
    assert np.max(cloud.radii[loose]) <= np.max(mesh_only.radii) * 1.5


def test_from_mesh_sample_is_uniform_on_the_surface(rng):
    # two triangles in the z=0 plane with areas 1/2 (x + y <= 1) and 1 (x + y >= 1)
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [3, 0, 0], [0, 3, 0]], float)
    f = np.array([[0, 1, 2], [1, 3, 2]])
    cloud = PointCloud.from_mesh(v, f, sample=20_000, rng=rng)
    assert len(cloud) == 20_000
    np.testing.assert_allclose(cloud.normals, np.tile([0, 0, 1], (20_000, 1)), atol=1e-6)
    in_small = cloud.points[:, 0] + cloud.points[:, 1] <= 1
    assert np.mean(in_small) == pytest.approx(1 / 3, abs=0.01)  # 3 sigma ~ 0.01
    assert np.all(cloud.points[:, :2] >= -1e-12) and np.all(cloud.points.sum(1) <= 3 + 1e-9)


def _uv_sphere(n=24):
    """A closed UV sphere of radius 1: (vertices, outward faces)."""
    th, ph = np.linspace(0, np.pi, n + 1)[1:-1], np.linspace(0, 2 * np.pi, 2 * n, endpoint=False)
    v = np.r_[[[0, 0, 1.0]], np.stack([np.outer(np.sin(th), np.cos(ph)).ravel(),
                                       np.outer(np.sin(th), np.sin(ph)).ravel(),
                                       np.repeat(np.cos(th), len(ph))], 1), [[0, 0, -1.0]]]
    m, rows = len(ph), len(th)
    ring = lambda r, j: 1 + r * m + j % m  # noqa: E731
    f = [[0, ring(0, j), ring(0, j + 1)] for j in range(m)]
    for r in range(rows - 1):
        for j in range(m):
            f += [[ring(r, j), ring(r + 1, j), ring(r + 1, j + 1)],
                  [ring(r, j), ring(r + 1, j + 1), ring(r, j + 1)]]
    f += [[len(v) - 1, ring(rows - 1, j + 1), ring(rows - 1, j)] for j in range(m)]
    return v, np.array(f)


def test_from_mesh_samples_take_the_smooth_surfaces_normals(rng):
    """On a coarse sphere mesh the sampled normals follow the sphere (blended vertex normals),
    several times closer to it than the flat faces' normals; on a cube (90° creases) every
    sample keeps its face's normal exactly."""
    v, f = _uv_sphere(12)
    cloud = PointCloud.from_mesh(v, f, sample=20_000, rng=rng)
    exact = cloud.points / np.linalg.norm(cloud.points, axis=1)[:, None]
    err = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", cloud.normals, exact), -1, 1)))
    a, b, c = (v[f[:, k]] for k in range(3))
    flat = np.cross(b - a, c - a)
    flat /= np.linalg.norm(flat, axis=1)[:, None]
    centres = (a + b + c) / 3
    centres /= np.linalg.norm(centres, axis=1)[:, None]
    flat_err = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", flat, centres), -1, 1)))
    assert err.mean() < flat_err.mean() / 3, (err.mean(), flat_err.mean())
    # a cube, two triangles per side: corners on 90° creases keep the faces' own normals
    cv = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    cf = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                   [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    cube = PointCloud.from_mesh(cv, cf, sample=3000, rng=rng)
    axis = np.abs(cube.normals).argmax(axis=1)
    np.testing.assert_allclose(np.abs(cube.normals[np.arange(3000), axis]), 1.0, atol=1e-6)
    side = np.where(cube.normals[np.arange(3000), axis] > 0, 1.0, 0.0)
    np.testing.assert_allclose(cube.points[np.arange(3000), axis], side, atol=1e-6)


def test_from_mesh_rejects_bad_faces():
    v, f = octahedron()
    with pytest.raises(InputError, match=r"faces: indices must be in 0\.\.5"):
        PointCloud.from_mesh(v, f + 1)
    with pytest.raises(InputError, match=r"faces: expected shape \(f, 3\)"):
        PointCloud.from_mesh(v, f[:, :2])
    with pytest.raises(InputError, match="sample: expected a positive integer"):
        PointCloud.from_mesh(v, f, sample=0)


def test_open3d_roundtrip(sphere_cloud):
    o3d = pytest.importorskip("open3d")
    colored = PointCloud(
        sphere_cloud.points, sphere_cloud.normals, colors=np.full((len(sphere_cloud), 3), 0.25)
    )
    pcd = colored.to_open3d()
    assert isinstance(pcd, o3d.geometry.PointCloud)
    back = PointCloud.from_open3d(pcd)
    np.testing.assert_array_equal(back.points, colored.points)
    np.testing.assert_allclose(back.normals, colored.normals, atol=1e-6)
    np.testing.assert_allclose(back.colors, 0.25)
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    from_mesh = PointCloud.from_open3d(mesh)
    cos = np.einsum("ij,ij->i", from_mesh.normals, from_mesh.points)
    assert cos.min() > 0.99  # coarse sphere: face-averaged normals are within ~8 degrees
    with pytest.raises(InputError, match="geometry: expected an open3d"):
        PointCloud.from_open3d(object())


def test_from_pyvista():
    pv = pytest.importorskip("pyvista")
    sphere = pv.Sphere(radius=2.0)
    cloud = PointCloud.from_pyvista(sphere)
    assert cloud.has_normals and len(cloud) == sphere.n_points
    np.testing.assert_allclose(cloud.normals, cloud.points / 2.0, atol=0.05)
    bare = pv.PolyData(np.asarray(sphere.points), faces=np.asarray(sphere.faces))
    from_faces = PointCloud.from_pyvista(bare)
    assert np.mean(np.einsum("ij,ij->i", from_faces.normals, cloud.normals) > 0.99) > 0.95
    sampled = PointCloud.from_pyvista(bare, sample=500, rng=0)
    assert len(sampled) == 500
    np.testing.assert_allclose(np.linalg.norm(sampled.points, axis=1), 2.0, atol=0.05)
    cloud_only = pv.PolyData(np.asarray(sphere.points))
    cloud_only["RGB"] = np.full((sphere.n_points, 3), 255, np.uint8)
    colored = PointCloud.from_pyvista(cloud_only)
    assert colored.has_colors and not colored.has_normals


def test_import_does_no_heavy_work():
    code = (
        "import sys, pointviz.cloud, pointviz.io\n"
        "heavy = [m for m in ('open3d', 'laspy', 'pyvista', 'trimesh') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_normals_of_a_large_cloud_are_checked_block_by_block():
    """Normalised in blocks (bounded temporaries): the same float32 values as the whole-array
    formula, and zero rows in several blocks are all counted, the first one named."""
    from pointviz.array_checks import CHECK_BLOCK

    rng = np.random.default_rng(12)
    n = 2 * CHECK_BLOCK + 5
    pts = rng.normal(size=(n, 3))
    nrm = rng.normal(size=(n, 3)) * rng.uniform(1e-3, 1e3, (n, 1))
    whole = (nrm / np.sqrt((nrm * nrm).sum(axis=1))[:, None]).astype(np.float32)
    got = PointCloud(pts, normals=nrm, radii=0.1).normals
    np.testing.assert_allclose(got, whole, rtol=0, atol=1e-7)
    nrm[[CHECK_BLOCK + 1, 3, n - 1]] = 0.0
    with pytest.raises(InputError, match=r"normals: 3 rows have zero length \(first at row 3\)"):
        PointCloud(pts, normals=nrm, radii=0.1)
