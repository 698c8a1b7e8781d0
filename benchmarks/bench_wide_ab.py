"""Two builds of pointviz, one process each: CPU time per ray of the default traversal.

Runs with whichever pointviz the interpreter imports (a venv per build), on the models and rays
of ``bench_core.py`` (the 400k sphere and torus samplings, or the dragon's registered scans;
640x480 primary rays of the fitted camera and as many random rays), one thread, and appends one
JSON line to OUT: bytes per surfel, and per ray set the fastest of 5 runs of the closest-hit
query (interpolated, no statistics) and of the any-hit query (tmax = U(0.5, 1.5) x the closest
hit), in process CPU ns per ray, with the load average. Alternate the builds' processes to
compare them::

    for m in sphere torus dragon; do for v in main other; do
        /work/venvs/$v/bin/python benchmarks/bench_wide_ab.py $m results.jsonl; done; done

The dragon's cloud (pointviz.load of the shared data's conf) is cached in CACHE (not the repo).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common  # noqa: E402

import pointviz as pv  # noqa: E402
from pointviz import shapes  # noqa: E402

CACHE = Path("/tmp/pointviz_bench_wide_ab_dragon.npz")
RANDOM_SEED = 1234
REPEAT = 5


def load(model: str, data: Path):
    if model != "dragon":
        return getattr(shapes, model)(400000)
    if not CACHE.exists():
        conf = common.require_data(data, common.DRAGON_CONF)
        cloud = pv.load(str(conf))
        np.savez(CACHE, p=np.asarray(cloud.points), n=np.asarray(cloud.normals),
                 r=np.asarray(cloud.radii))
    z = np.load(CACHE)
    return pv.PointCloud(z["p"], normals=z["n"], radii=z["r"])


def main(model: str, out: Path, data: Path, packets: bool = True) -> None:
    cloud = load(model, data)
    scene = pv.SurfelScene(cloud, variant="full", threads=1)
    # Builds with packets of coherent rays (packet_trace.h) can turn them off for comparison.
    has_packets = hasattr(scene._options, "packets")
    if has_packets:
        scene._options.packets = packets
    cam = pv.Camera.fit(cloud, width=640, height=480)
    primary = np.ascontiguousarray(np.asarray(cam.rays(), np.float32).reshape(-1, 6))
    rays = {"primary": primary,
            "random": common.random_rays(np.asarray(cloud.points, np.float64), len(primary),
                                         RANDOM_SEED)}
    res = {"model": model, "B_per_surfel": scene.memory_bytes / scene.n_surfels,
           "pointviz": pv.__file__, "packets": packets and has_packets}
    for name, r in rays.items():
        t = scene.cast_rays(r)["t_hit"]
        rng = np.random.default_rng(5)
        tmax = np.where(np.isfinite(t), t * rng.uniform(0.5, 1.5, len(t)), 1e30).astype(np.float32)
        best_c = best_o = float("inf")
        for _ in range(REPEAT):
            c0 = time.process_time()
            scene.cast_rays(r, stats=False)
            c1 = time.process_time()
            scene.occluded(r, tmax, stats=False)
            c2 = time.process_time()
            best_c, best_o = min(best_c, c1 - c0), min(best_o, c2 - c1)
        res[name] = {"closest_ns": 1e9 * best_c / len(r), "any_ns": 1e9 * best_o / len(r),
                     "hits": int(np.isfinite(t).sum())}
    res["loadavg"] = open("/proc/loadavg").read().split()[:3]
    with open(out, "a") as f:
        f.write(json.dumps(res) + "\n")
    print(json.dumps(res))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("model", choices=("sphere", "torus", "dragon"))
    p.add_argument("out", type=Path, help="JSON-lines file the result is appended to")
    p.add_argument("--data", type=Path, default=common.default_data_dir(),
                   help="shared data folder (the dragon's scans)")
    p.add_argument("--no-packets", action="store_true",
                   help="closest and any hits one ray at a time in builds that have packets")
    return p.parse_args(argv)


if __name__ == "__main__":
    args = parse_args()
    main(args.model, args.out, args.data, not args.no_packets)
