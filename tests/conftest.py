"""Shared fixtures: a seeded random generator, the shared real data, an analytic sphere."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) float64 points of a Fibonacci lattice on the unit sphere (near-uniform spacing)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0**0.5) * i  # golden angle increments
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator, so every test run draws the same numbers."""
    return np.random.default_rng(20240607)


@pytest.fixture
def shared_data() -> Path:
    """``../shared/data`` next to the repository; the test is skipped when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"../shared/data is absent: {SHARED_DATA} not found (real scans not available)")
    return SHARED_DATA


@pytest.fixture
def fibonacci():
    """The Fibonacci-lattice generator: ``fibonacci(n) -> (n, 3)`` unit-sphere points."""
    return fibonacci_sphere


@pytest.fixture
def sphere_cloud():
    """A unit sphere as 4000 surfels on a Fibonacci lattice with exact outward normals.

    Radii are left to the estimator (lazy).
    """
    from pointviz.cloud import PointCloud

    points = fibonacci_sphere(4000)
    return PointCloud(points, normals=points, name="fibonacci sphere")


@pytest.fixture(scope="module")
def scene():
    """Two analytic objects (a sphere and a torus), so that camera paths show parallax."""
    from pointviz import Scene
    from pointviz.shapes import sphere, torus

    return Scene([sphere(3000, 0.6, (-0.5, 0.6, 0.0), color=(0.8, 0.3, 0.2)),
                  torus(4000, 0.5, 0.2, (0.6, 0.2, 0.2), color=(0.9, 0.8, 0.3))], up=(0, 1, 0))
