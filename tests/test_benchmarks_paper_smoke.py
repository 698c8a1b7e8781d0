"""Smoke runs of the issue-7 benchmark scripts at tiny sizes, so they never rot.

Each script runs as a subprocess with ``--quick`` into a temporary results folder; the test checks
that it exits 0 and writes its JSON with the keys the README's tables are made from. Timings are
never asserted (the machine is shared); they are what the scripts are for. Skipped when
../shared/data is absent (the ``shared_data`` fixture).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pointviz.rendering import MAX_BUDGET_SCALE

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"

#: A quick run takes seconds; this bounds a hung run on a heavily shared machine.
TIMEOUT_SECONDS = 300


def run_script(name: str, out: Path, data: Path, *extra: str) -> dict:
    """Run ``benchmarks/<name>`` with --quick; return the parsed JSON it wrote (asserts exit 0)."""
    cmd = [sys.executable, str(BENCHMARKS / name), "--quick", "--data", str(data), "--out",
           str(out), *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT_SECONDS, check=False)
    assert proc.returncode == 0, f"{name} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
    files = sorted(out.glob("*.json"))
    assert len(files) == 1, f"{name} wrote {files}"
    return json.loads(files[0].read_text())


def test_paper_figures_quick_writes_figures_5_to_7(shared_data, tmp_path):
    res = run_script("paper_figures.py", tmp_path, shared_data, "--models", "armadillo,dragon")
    assert [r["model"] for r in res["fig5"]] == ["armadillo", "dragon"]
    for rec in res["fig5"]:
        assert set(rec["variants"]) == {"kdtree", "bvh", "lod", "lod+cull", "full"}
        for v in rec["variants"].values():
            assert v["seconds"] > 0
            assert {"nodes_visited", "disk_tests", "max_depth"} <= set(v["all_rays"])
            assert "drop_vs_kdtree" in v and "drop_vs_bvh" in v
    assert "embree discs" in res["fig5"][0]["embree"]
    assert "embree triangles" in res["fig5"][0]["embree"]  # Armadillo has its source mesh
    for rec in res["fig7"]:
        assert [r["factor"] for r in rec["rows"]] == [1.0, 1.5, 2.0, 4.0, 8.0]
        for r in rec["rows"]:
            assert {"lod", "no lod", "kdtree", "bvh"} <= set(r["seconds"])
            assert set(r["full_drop_vs"]) == {"kdtree", "bvh"}
            assert 0.0 <= r["flip"] <= 1.0
    assert {p.name for p in tmp_path.glob("*.png")} == {
        "fig5_traversal_time.png", "fig6_stats.png", "fig7_distance.png"}


def test_paper_questions_quick_writes_switch_level_and_criteria(shared_data, tmp_path):
    res = run_script("paper_questions.py", tmp_path, shared_data, "--models", "armadillo")
    (q1,) = res["q1"]
    assert set(q1["configs"]) == {"lod", "nolod"}
    for cfg in q1["configs"].values():
        assert [r["k"] for r in cfg["rows"]] == list(range(q1["depth"] + 1))
        assert {"k_best_measured", "auto", "pred", "pred_iso"} <= set(cfg["summary"])
        assert 0 <= cfg["summary"]["pred"]["k_model"] <= q1["depth"]
    assert {"size", "deviation"} == {r["criterion"] for r in res["q2"]["distances"][0]["rows"]}
    assert (tmp_path / "q1_switch_level.png").is_file()
    assert (tmp_path / "q2_lod_criteria.png").is_file()


def test_bench_scaling_quick_writes_sizes_and_threads(shared_data, tmp_path):
    res = run_script("bench_scaling.py", tmp_path, shared_data)
    assert len(res["sizes"]) >= 2
    for rec in res["sizes"]:
        assert set(rec["threads"]) == {"1", "2"}
        for row in rec["threads"].values():
            assert row["mrays"]["pointviz"] > 0
            assert row["bytes_per_surfel"] > 0
            assert "build_seconds" in row
    assert (tmp_path / "scaling.png").is_file()


def test_bench_frame_quick_writes_ratio(shared_data, tmp_path):
    res = run_script("bench_frame.py", tmp_path, shared_data)
    assert res["frame_seconds"] > 0 and res["primary_seconds"] > 0
    assert res["ratio"] == pytest.approx(res["frame_seconds"] / res["primary_seconds"])
    assert {"ratio", "seconds"} == set(res["meets"])


def test_lod_budget_quick_fits_a_bound(shared_data, tmp_path):
    res = run_script("lod_budget.py", tmp_path, shared_data)
    assert set(res["fit"]["coefficients"]) == {"spread", "thickness", "colour", "overhang"}
    assert all(v >= 0 for v in res["fit"]["coefficients"].values())
    # The script's simulated LoD cut agrees with the core traversal's own LoD hits (it misses the
    # few rays that hit a coarser node's disk in front of their full-detail surfel).
    sim = np.array([r["stopped_fraction"] for r in res["rows"]])
    core = np.array([r["lod_hit_fraction"] for r in res["rows"]])
    assert np.all(np.abs(sim - core) <= 0.02 + 0.25 * core), np.c_[sim, core]
    assert core.max() > 0.1 and np.corrcoef(sim, core)[0, 1] > 0.95
    assert all(0.0 <= r["flip"] <= 1.0 for r in res["rows"])
    assert {p.name for p in tmp_path.glob("*.png")} == {"lod_budget_calibration.png"}


def test_bench_lod_quick_writes_rows_and_popping(shared_data, tmp_path):
    res = run_script("bench_lod.py", tmp_path, shared_data, "--models", "torus", "--path")
    variants = {r["variant"] for r in res["rows"]}
    assert {"full", "1px", "auto 0.005"} <= variants
    assert {r["factor"] for r in res["rows"]} == {1.0, 2.5, 7.5}
    assert all(0.0 <= r["flip"] <= 1.0 and r["seconds"] > 0 for r in res["rows"])
    assert set(res["popping"]["torus"]) == {"full", "1px", "auto"}
    assert {p.name for p in tmp_path.glob("*.png")} == {"bench_lod.png"}


def test_lod_refusals_quick_accounts_for_every_ancestor(shared_data, tmp_path):
    res = run_script("lod_refusals.py", tmp_path, shared_data, "--models", "torus")
    assert {r["factor"] for r in res["rows"]} == {1.0, 2.5, 7.5}
    for r in res["rows"]:
        assert set(r["ancestors"]) == {"no_cone", "colour", "spread", "stop"}
        assert 0.0 <= r["share_may_stop"] <= r["share_in_cap"] <= 1.0
        assert 1.0 <= r["budget_scale"] <= MAX_BUDGET_SCALE
        assert all(0.0 <= v <= 1.0 for v in r["flip"].values())
