"""Report charts whose labels do not overlap, and the report's one-line verdict."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pointviz.comparison.report import MARKER_CLEARANCE, place_labels, verdict


def _overlap(a, b):
    w = min(a.x1, b.x1) - max(a.x0, b.x0)
    h = min(a.y1, b.y1) - max(a.y0, b.y0)
    return w > 0 and h > 0


def test_crowded_labels_do_not_overlap(rng):
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    # a cluster like the report's (several settings of one method within a few per cent)
    x = 1.0 + rng.uniform(0, 0.08, 9)
    y = 0.005 + rng.uniform(0, 0.0006, 9)
    ax.plot(x, y, "o")
    ax.plot([0.5, 20.0], [0.0, 0.02], alpha=0)  # axes much wider than the cluster
    ax.set_xscale("log")
    items = [(xi, yi, f"LoD {i} px, depth {i}") for i, (xi, yi) in enumerate(zip(x, y))]
    boxes = place_labels(ax, items)
    assert len(boxes) == len(items)
    for a, b in itertools.combinations(boxes, 2):
        assert not _overlap(a, b)
    # and no label covers a marker
    px = ax.transData.transform(np.column_stack([x, y]))
    c = MARKER_CLEARANCE
    for box in boxes:
        for mx, my in px:
            assert not (box.x0 < mx + c and box.x1 > mx - c and box.y0 < my + c and box.y1 > my - c)
    plt.close(fig)


def _entry(method, label, flip, first):
    return {"method": method, "label": label, "metrics": {"flip": flip},
            "times": {"first_image": first}}


def test_verdict_names_the_best_surfels_and_mesh():
    doc = {"entries": [_entry("surfels-smooth", "surfels smooth", 0.005, 1.0),
                       _entry("discs", "discs", 0.0075, 1.1),
                       _entry("poisson", "Poisson depth 8", 0.0147, 2.3),
                       _entry("ball-pivoting", "ball pivoting", 0.0031, 1.9)]}
    v = verdict(doc)
    assert v.startswith("Surfels are further from the reference than the best mesh")
    assert "surfels smooth (FLIP 0.0050" in v and "ball pivoting (FLIP 0.0031" in v
    assert "1.9x sooner" in v
    doc["entries"][3]["metrics"]["flip"] = float("nan")
    assert verdict(doc).startswith("Surfels are closer")
    assert verdict({"entries": []}).startswith("No method")
