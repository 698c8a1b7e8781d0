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


#: Draws of the scans' noise and misregistration for the tests over draws: one draw moves the
#: whole scanned surface by a fraction of a pixel (its raw points' mean signed distance to the
#: torus ranges over +-0.3e-3 from seed to seed), which decides the holes on the outline's rim.
SEEDS = (1, 2, 3, 4)
NOISES = (0.001, 0.004)


@functools.lru_cache(maxsize=None)
def fitted_scans(noise: float, seed: int):
    """(raw cloud, fitted cloud) of 8 noisy, misregistered scans of the exact torus."""
    cloud, _ = virtual_scans("torus", scans=8, resolution=120, noise=noise,
                             misregistration=0.0005, seed=seed)
    return cloud, cloud.fitted()


@pytest.mark.parametrize("noise", NOISES)
def test_surface_fit_lies_where_the_scans_do_over_draws(noise):
    """The fit is unbiased: averaged over draws, the fitted surfels' mean signed distance to the
    exact torus is the raw points' own. The fit's plane passes pull curved parts inward: without
    the pull given back, the fitted surfels of these draws lie 0.95e-3 / 1.03e-3 inside the raw
    points (0.1 % / 0.4 % noise; 0.36e-3 / 0.42e-3 on the denser 200 x 200 scans of
    benchmarks/holes_over_seeds.py), a tenth of a pixel of the frames below; with it, 0.006e-3
    / 0.065e-3. Bound: 0.12e-3."""
    diffs = []
    for seed in SEEDS:
        raw, fitted = fitted_scans(noise, seed)
        diffs.append(TORUS.signed_distance(fitted.points).mean()
                     - TORUS.signed_distance(raw.points).mean())
    assert abs(np.mean(diffs)) < 1.2e-4, diffs


@pytest.mark.parametrize("noise", NOISES)
def test_fitted_surfels_rim_holes_over_draws(noise):
    """Surfels fitted to noisy, misregistered scans, over several draws: no pixel the exact
    torus covers by more than the depth noise is missed (no hole inside the silhouette), and
    the rim pixels missed along the outline stay below a bound. Measured (these 4 draws, 3
    views of 200 x 150): 0.068 % / 0.082 % of the torus's pixels (0.1 % / 0.4 % noise) with
    the fit's pull given back, 0.21 % / 0.21 % without; bound 0.10 %."""
    sigma = noise * TORUS.size
    missed_total, inside_total = 0, 0
    for seed in SEEDS:
        _, fitted = fitted_scans(noise, seed)
        for view, cam in enumerate(cameras()):
            depth = penetration(view)
            hit = surfel_hits(fitted.points, fitted.normals, fitted.radii, cam)
            missed = (depth > 0) & ~hit
            assert not np.any(missed & (depth > sigma)), (seed, view, depth[missed].max())
            missed_total += int(missed.sum())
            inside_total += int((depth > 0).sum())
    assert missed_total / inside_total < 0.001, missed_total / inside_total
