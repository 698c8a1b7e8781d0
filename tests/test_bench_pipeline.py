"""Smoke test of benchmarks/bench_pipeline.py: its generated scans are what it says they are
(loaded through the .conf reader, they lie on the unit sphere within the stated noise), and a
quick run of the per-frame and loader parts completes and prints its tables."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))

import bench_pipeline as bp


@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii"])
def test_generated_scans_lie_on_the_sphere_and_face_their_scanners(tmp_path, fmt):
    from pointviz.io import load

    scans = bp.sphere_scans(seed=1, grid=40)
    conf = bp.write_conf(tmp_path, scans, fmt)
    cloud = load(conf, estimate=False)
    assert len(cloud) == sum(len(s[0]) for s in scans)
    r = np.linalg.norm(cloud.points, axis=1)
    # depth noise (sigma 2 * SCAN_NOISE) plus misregistration (sigma SCAN_MISREGISTRATION per axis)
    sigma = np.hypot(2 * bp.SCAN_NOISE, np.sqrt(3) * bp.SCAN_MISREGISTRATION)
    assert np.abs(r - 1.0).max() < 6 * sigma  # a wrong placement convention is off by O(1)
    # each scan's viewpoint (the reader puts it on +z of the scan's frame) is on its scanner's side
    for k in range(len(scans)):
        pts = cloud.points[cloud.scan_index == k]
        view = cloud.viewpoints[cloud.scan_index == k][0]
        assert np.dot(view, pts.mean(axis=0)) > 0


@pytest.mark.slow
def test_quick_run_prints_frame_and_loader_tables(capsys):
    assert bp.main(["--quick", "--only", "frame", "--only", "loaders"]) == 0
    out = capsys.readouterr().out
    assert "render(surfel_scene)" in out and "Loaders:" in out
    for name in ("binary.ply", "ascii.ply", "binary.pcd", "ascii.pcd", "points.xyz", "points.laz"):
        assert name in out


@pytest.mark.slow
def test_start_to_png_stages_add_up_to_the_wall_time(tmp_path):
    """The timed CLI keeps each stage's own time (nested timed stages excluded): the stages are
    non-negative and together no more than the process's wall time, and the fit, tree build,
    frame and write were all seen (the radii within the fit)."""
    conf = bp.write_conf(tmp_path / "scans", bp.sphere_scans(seed=2, grid=30), "binary_little_endian")
    med = bp.start_to_png(conf, tmp_path, 1, ["--width", "32", "--height", "24", "--no-denoise"])
    stages = [med[k] for k in bp.STAGES]
    assert min(stages) >= 0.0
    assert sum(stages) <= med["wall"]
    for key in ("fit", "build_total", "frame", "write"):
        assert med[key] > 0.0, key
    # the fitted cloud's radii come from the fit's own call: the thread beside the camera fit
    # and the wait for it find them there
    assert med["radii_beside"] < 0.01 * med["fit"] and med["radii"] < 0.01 * med["fit"]
    assert med["render"] >= med["frame"]
    # the handed-over cloud's camera is fitted beside its tree's build, the wait for it timed
    assert med["camera_fit_beside"] > 0.0 and med["camera_fit"] == 0.0
    assert med["bounds"] > 0.0


@pytest.mark.slow
def test_timed_cli_runs_with_one_blas_thread_as_the_cli_does(tmp_path, monkeypatch):
    """The timed CLI imports numpy before the CLI's main(): it must still give ``render`` the
    single OpenBLAS thread main() gives it when run as a program (idle BLAS workers spinning
    beside the core's threads would be counted as pipeline time)."""
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    scans = bp.sphere_scans(seed=3, grid=20)
    conf = bp.write_conf(tmp_path / "scans", scans, "binary_little_endian")
    med = bp.start_to_png(conf, tmp_path, 1, ["--width", "16", "--height", "12", "--no-denoise"])
    assert med["openblas_threads"] == "1"
