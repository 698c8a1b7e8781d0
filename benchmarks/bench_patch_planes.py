"""Depth-camera frames: the patch planes' speed (benchmarks/README.md, 2026-11-25: "the patch
planes' speed" and "the depth steps in the core").

Times ``pointviz.depth_steps.patch_planes`` (the C++ core's) on PCL's depth-camera frames against
the numpy version (``patch_planes_numpy``; ``--numpy-vs-reference``: the numpy version against the
first implementation, ``tests/depth_steps_reference.py``), alternated in one process, and checks
that the two give the same radii and flying pixels and points and normals within the tests'
tolerance (printing the largest differences; the numpy pair: to the bit).

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
    ap.add_argument("--numpy-vs-reference", action="store_true",
                    help="the numpy version against the first implementation (to the bit)")
    args = ap.parse_args(argv)
    if args.numpy_vs_reference:
        pair = (("reference", reference.patch_planes), ("numpy", depth_steps.patch_planes_numpy))
    else:
        pair = (("numpy", depth_steps.patch_planes_numpy), ("core", depth_steps.patch_planes))
    (old, old_fn), (new, new_fn) = pair
    for name in args.frames:
        call = frame_args(Path(args.data) / f"{name}.pcd")
        for edges in (True, False):
            want = old_fn(*call, edges=edges)
            got = new_fn(*call, edges=edges)
            same = all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in zip(want, got))
            dp = float(np.abs(got[0] - want[0]).max())
            dn = float(np.abs(got[1] - want[1]).max())
            dr = int((got[2] != want[2]).sum())
            df = int((got[3] != want[3]).sum())
            times = {old: [], new: []}
            for i in range(args.repeat):
                order = ((old, old_fn), (new, new_fn))
                for label, fn in order if i % 2 else order[::-1]:
                    t = time.perf_counter()
                    fn(*call, edges=edges)
                    times[label].append(time.perf_counter() - t)
            a, b = (statistics.median(times[k]) for k in (old, new))
            print(f"{name[:16]:16s} edges={edges!s:5s} bit-identical={same} max|dpoint| {dp:.1e} "
                  f"max|dnormal| {dn:.1e} radii differ {dr} flying differ {df}; {old} {a:.3f} s, "
                  f"{new} {b:.3f} s (medians of {args.repeat}; min {min(times[old]):.3f} / "
                  f"{min(times[new]):.3f}): {a / b:.2f}x  load {os.getloadavg()[0]:.2f}",
                  flush=True)


if __name__ == "__main__":
    main()
