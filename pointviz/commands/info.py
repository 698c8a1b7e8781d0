"""``pointviz info INPUT``: what a file holds and what its surfel tree costs."""

from __future__ import annotations

import json
import time

import numpy as np

from .common import add_input_options, parse_up


def add_parser(sub) -> None:
    p = sub.add_parser("info", help="describe a point cloud and its surfel tree", description=__doc__)
    add_input_options(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.set_defaults(run=run)


def run(args) -> int:
    from ..io import load
    from ..surfels import SurfelScene

    t0 = time.perf_counter()
    up = parse_up(args.up)
    cloud = load(args.input, sample=args.sample, fit=args.fit, **({} if up is None else {"up": up}))
    t_load = time.perf_counter() - t0
    t0 = time.perf_counter()
    radii = cloud.radii
    t_est = time.perf_counter() - t0
    scene = SurfelScene(cloud)
    lo, hi = cloud.bounds
    facts = {
        "file": str(args.input),
        "points": len(cloud),
        "normals": "given" if cloud.has_normals else "estimated",
        "colors": bool(cloud.has_colors),
        "up": None if cloud.up is None else [float(v) for v in cloud.up],
        "bounds_min": [float(v) for v in lo],
        "bounds_max": [float(v) for v in hi],
        "radius_median": float(np.median(radii)),
        "radius_p99": float(np.quantile(radii, 0.99)),
        "load_seconds": round(t_load, 3),
        "estimate_seconds": round(t_est, 3),
        "tree_build_seconds": round(scene.build_seconds, 3),
        "tree_depth": scene.depth,
        "nodes_per_surfel": round(scene.nodes_per_surfel, 3),
        "bytes_per_surfel": round(scene.memory_bytes / len(cloud), 1),
    }
    if cloud.fit_report is not None:
        facts["surface_fit"] = cloud.fit_report["summary"]
    if cloud.notes:  # what the reader assumed or changed (dropped rows, a mesh sampled...)
        facts["notes"] = "; ".join(cloud.notes)
    if args.json:
        print(json.dumps(facts, indent=1))
    else:
        width = max(len(k) for k in facts)
        for k, v in facts.items():
            print(f"{k:<{width}}  {v}")
    return 0
