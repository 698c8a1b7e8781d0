"""Coverage of surfels against the exact shape they sample, silhouettes included.

The oracle is the analytic torus of :mod:`pointviz.comparison.scans`: for each pixel's ray, the
deepest its path goes inside the exact surface (the minimum of the exact signed distance along
the ray). A ray that enters the torus at all must hit a surfel, however grazing; a ray that hits
a surfel may pass outside the torus by no more than the largest disk radius.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import numpy as np
import pytest

import pointviz
from pointviz import estimation as est
from pointviz.comparison.scans import ExactShape, virtual_scans

sys.path.insert(0, str(Path(__file__).resolve().parent))

from test_estimation import fibonacci_torus  # noqa: E402

TORUS = ExactShape("torus")
#: Views (elevation, azimuth in degrees) of the torus: oblique, edge-on (the tube's contour
#: runs along the whole outline), and from below.
VIEWS = ((35.0, 20.0), (0.0, 140.0), (-30.0, 250.0))
#: Steps of the coarse search for the minimum of the signed distance along each ray, then
#: golden-section steps around it (bracket 2 x 2.72 / 160, shrunk by 0.618 per step: 1e-9).
COARSE_STEPS = 160
GOLDEN_STEPS = 40


@functools.lru_cache(maxsize=None)
def cameras(width=200, height=150):
    out = []
    for elev, azim in VIEWS:
        e, a = np.radians(elev), np.radians(azim)
        eye = 3.6 * np.array([np.cos(e) * np.cos(a), np.sin(e), np.cos(e) * np.sin(a)])
        out.append(pointviz.Camera.look_at(eye, (0, 0, 0), width=width, height=height))
    return tuple(out)


@functools.lru_cache(maxsize=None)
def penetration(view: int) -> np.ndarray:
    """(h * w,) deepest point of each pixel-centre ray of camera ``view`` inside the exact torus
    (the negated minimum signed distance along it; negative for a ray that passes outside)."""
    rays = cameras()[view].rays(dtype=np.float64)
    o, d = rays[:, :3], rays[:, 3:]
    dist = np.linalg.norm(o[0])
    ts = np.linspace(dist - 1.36, dist + 1.36, COARSE_STEPS)
    sd = np.stack([TORUS.signed_distance(o + t * d) for t in ts])
    step = ts[1] - ts[0]
    lo, hi = ts[np.argmin(sd, axis=0)] - step, ts[np.argmin(sd, axis=0)] + step
    g = (np.sqrt(5.0) - 1.0) / 2.0

    def f(t):
        return TORUS.signed_distance(o + t[:, None] * d)

    for _ in range(GOLDEN_STEPS):
        a, b = hi - g * (hi - lo), lo + g * (hi - lo)
        left = f(a) < f(b)
        hi = np.where(left, b, hi)
        lo = np.where(left, lo, a)
    return -np.minimum(f(0.5 * (lo + hi)), sd.min(axis=0))


def surfel_hits(points, normals, radii, cam) -> np.ndarray:
    """(h * w,) whether each pixel-centre ray hits a surfel (full detail)."""
    scene = pointviz.SurfelScene(pointviz.PointCloud(points, normals, radii=radii))
    hits = scene.cast_rays(cam.rays(), lod_pixels=0, stats=False)
    return hits["index"] != -1


def on_torus(points):
    """Points moved onto the exact torus, with its normals there."""
    n = TORUS.normal(points)
    centre = points - (TORUS.signed_distance(points) + 0.35)[:, None] * n
    return centre + 0.35 * n, n


def assert_covers(points, normals, radii):
    """Every ray entering the exact torus hits a surfel; every surfel hit lies within the
    largest radius of the torus."""
    for view, cam in enumerate(cameras()):
        depth = penetration(view)
        hit = surfel_hits(points, normals, radii, cam)
        inside = depth > 0
        assert inside.sum() > 1000
        missed = inside & ~hit
        assert not missed.any(), (f"{missed.sum()} pixels missed, entering the torus by up to "
                                  f"{depth[missed].max():.2e}")
        assert np.all(depth[hit] > -float(radii.max()))


@pytest.mark.parametrize("seed", [1, 2])
def test_coverage_radii_cover_the_silhouette_of_random_samplings(seed):
    """Uniform random points on the exact torus with its normals: coverage radii leave no
    pixel uncovered that the exact torus covers, at the outline too."""
    pts, nrm = fibonacci_torus(12_000, np.random.default_rng(seed))
    radii = est.coverage_radii(pts, nrm)
    assert_covers(pts, nrm, radii)


def test_coverage_radii_cover_the_silhouette_of_virtual_scans():
    """The sampling of virtual range scans (dense where seen head-on, sparse and stretched where
    grazing, several overlapping layers), on the exact surface: no pixel of the exact torus is
    missed."""
    cloud, exact = virtual_scans("torus", scans=8, resolution=70, noise=0.0,
                                 misregistration=0.0, seed=5)
    pts, nrm = on_torus(cloud.points)
    assert np.abs(exact.signed_distance(pts)).max() < 1e-12
    radii = est.coverage_radii(pts, nrm)
    assert_covers(pts, nrm, radii)


def test_fitted_surfels_of_noisy_scans_miss_only_a_rim_thinner_than_the_noise():
    """Surfels fitted to noisy, misregistered scans: every pixel the exact torus covers by more
    than the scans' depth noise (0.1 % of the size) is hit; what is missed is a rim along the
    outline, where the fitted surface lies within the noise of the exact one."""
    cloud, exact = virtual_scans("torus", scans=8, resolution=120, noise=0.001,
                                 misregistration=0.0005, seed=11)
    fitted = cloud.fitted()
    sigma = 0.001 * exact.size
    for view, cam in enumerate(cameras()):
        depth = penetration(view)
        hit = surfel_hits(fitted.points, fitted.normals, fitted.radii, cam)
        missed = (depth > 0) & ~hit
        assert not np.any(missed & (depth > sigma)), depth[missed].max()
