"""Neighbours within range scans that carry no stored grid: binned by direction from each
scan's viewpoint (``scan_neighbours.h``). The oracle is the per-scan KD-tree search the same
call makes when no scan has a single viewpoint, and brute force in the core's own tests."""
import numpy as np
import pytest

from pointviz.estimation import estimate_normals, fit_surface


def sphere_before_plane_scans(rng, noise):
    """Range scans of a unit sphere in front of the plane z = -1.6 (a depth jump at the
    sphere's outline), each a grid of rays from its own scanner: points, scan index, viewpoints."""
    pts, scan, views = [], [], []
    for s, eye in enumerate(([0.3, -0.2, 4.0], [-2.6, 1.1, 2.4], [1.4, 2.2, 2.9])):
        eye = np.array(eye)
        w = -eye / np.linalg.norm(eye)
        u = np.cross(w, [0.3, 0.5, 0.8])
        u /= np.linalg.norm(u)
        v = np.cross(w, u)
        a, b = np.meshgrid(np.linspace(-0.45, 0.45, 70), np.linspace(-0.45, 0.45, 70))
        d = w + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        ed = d @ eye
        disc = ed**2 - (eye @ eye - 1.0)
        t = np.where(disc > 0, -ed - np.sqrt(np.maximum(disc, 0.0)), np.inf)
        with np.errstate(divide="ignore"):
            tp = np.where(d[:, 2] < 0, (-1.6 - eye[2]) / d[:, 2], np.inf)
        t = np.where(np.isfinite(t), t, tp)
        hit = np.isfinite(t)
        p = eye + (t[hit] + rng.normal(scale=noise, size=hit.sum()))[:, None] * d[hit]
        pts.append(p)
        scan.append(np.full(len(p), s, np.int32))
        views.append(np.repeat(eye[None], len(p), axis=0))
    return np.concatenate(pts), np.concatenate(scan), np.concatenate(views)


@pytest.mark.parametrize("noise", [0.0, 0.003])
def test_view_grid_normals_equal_the_per_scan_trees(rng, noise):
    pts, scan, views = sphere_before_plane_scans(rng, noise)
    # the same viewpoints nudged per point: no scan has a single viewpoint, each uses its tree
    nudged = views + rng.normal(scale=1e-9, size=views.shape)
    ref, d_ref = estimate_normals(pts, viewpoints=nudged, scan_index=scan, details=True)
    assert d_ref["view_grid_neighbours"] == 0 and d_ref["tree_neighbours"] == len(pts)
    for threads in (1, 2, 3):
        got, d = estimate_normals(pts, viewpoints=views, scan_index=scan, threads=threads,
                                  details=True)
        assert np.array_equal(got, ref)
        assert d["view_grid_neighbours"] > 0.9 * len(pts)
        assert d["view_grid_neighbours"] + d["tree_neighbours"] == len(pts)
        assert d["grid_neighbours"] == 0


def test_surface_fit_counts_where_scan_neighbours_came_from(rng):
    pts, scan, views = sphere_before_plane_scans(rng, 0.002)
    fit = fit_surface(pts, viewpoints=views, scan_index=scan)
    counts = fit.scan_neighbours
    # rows across scans that hold enough of the point's own scan need no search
    assert counts["grid"] == 0 and counts["across"] > 0
    assert counts["view_grid"] > 0.9 * (len(pts) - counts["across"])
    assert counts["view_grid"] + counts["tree"] + counts["across"] == len(pts)
