"""A quick run of benchmarks/bench_preprocess.py, so the preprocessing benchmark never rots: it
must write every section, with ratios computed from the numbers next to them."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from test_benchmarks_paper_smoke import run_script  # noqa: E402


@pytest.mark.slow
def test_bench_preprocess_quick_writes_every_section(shared_data, tmp_path):
    pytest.importorskip("open3d")
    res = run_script("bench_preprocess.py", tmp_path, shared_data)
    scene = res["scene_vs_embree"]
    assert scene["pointviz_seconds"] > 0
    if "embree_seconds" in scene:
        assert scene["ratio"] == pytest.approx(scene["pointviz_seconds"] / scene["embree_seconds"])
    rows = res["virtual_scans"]
    assert [r["noise"] for r in rows] == [0.001, 0.004]
    for r in rows:
        s, p = r["surfels"], r["poisson"]
        assert r["speedup"] == pytest.approx(p["seconds"] / s["seconds"])
        assert 0 < s["kept"] < r["points"]
        for m in (s, p):
            assert 0 <= m["interior_holes"] <= 1 and 0 <= m["holes"] <= 1
            assert 0 <= m["outside"] <= 1
            assert m["normal_error_deg"] > 0 and m["depth_error"] > 0
        assert set(r["offset"]) == {"raw_points", "surfels", "poisson_vertices"}
        assert 0 <= r["surfels_two_sided"]["holes"] <= 1
    dragon = res["dragon"]
    assert dragon["fit_report"]["points_kept"] < dragon["points"]
