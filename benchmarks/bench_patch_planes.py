"""Depth-camera frames: the patch planes' speed (benchmarks/README.md, 2026-11-25).

Times ``pointviz.depth_steps.patch_planes`` on PCL's depth-camera frames against the first
implementation (``tests/depth_steps_reference.py``, the tests' oracle), alternated in one process,
and checks that the two give the same points, normals, radii and flying pixels to the bit.

Examples
--------
python benchmarks/bench_patch_planes.py /work/shared/data/pcl_testdata
python benchmarks/bench_patch_planes.py DIR --repeat 9 --frames office1 five_people
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import depth_steps_reference as reference  # noqa: E402

from pointviz import depth_steps  # noqa: E402
from pointviz.io import load  # noqa: E402

FRAMES = ("office1", "five_people", "milk_cartoon_all_small_clorox",
          "table_scene_mug_stereo_textured")


def frame_args(path):
    """patch_planes' arguments for a frame, as ``PointCloud.fitted`` passes them."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cloud = load(path, estimate=False, fit=False)
    points = np.asarray(cloud.points, dtype=np.float64)
    vp = np.asarray(cloud.viewpoints, dtype=np.float64).reshape(-1, 3)[0]
    return points, cloud.scan_grid, vp, depth_steps.depth_steps(points[:, 2])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", help="folder of PCL's test frames")
    ap.add_argument("--frames", nargs="+", default=FRAMES)
    ap.add_argument("--repeat", type=int, default=7, help="alternated pairs per frame")
    args = ap.parse_args(argv)
    for name in args.frames:
        call = frame_args(Path(args.data) / f"{name}.pcd")
        for edges in (True, False):
            want = reference.patch_planes(*call, edges=edges)
            got = depth_steps.patch_planes(*call, edges=edges)
            same = all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in zip(want, got))
            times = {"reference": [], "now": []}
            for i in range(args.repeat):
                order = (("reference", reference), ("now", depth_steps))
                for label, module in order if i % 2 else order[::-1]:
                    t = time.perf_counter()
                    module.patch_planes(*call, edges=edges)
                    times[label].append(time.perf_counter() - t)
            ref, now = (statistics.median(times[k]) for k in ("reference", "now"))
            print(f"{name[:16]:16s} edges={edges!s:5s} bit-identical={same} reference "
                  f"{ref:.3f} s, now {now:.3f} s (medians of {args.repeat}; min "
                  f"{min(times['reference']):.3f} / {min(times['now']):.3f}): {ref / now:.2f}x  "
                  f"load {os.getloadavg()[0]:.2f}", flush=True)


if __name__ == "__main__":
    main()
