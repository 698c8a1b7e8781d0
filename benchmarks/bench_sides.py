"""One side or two on real data: what ``SurfelScene(cull="auto")`` decides, and what it fixes.

For each point cloud and mesh in ``../shared/data`` (as ``pointviz.load`` reads it, with the
defaults of ``pointviz render``), one tree built two-sided (``cull=False``) and one with
``cull="auto"``:

* the probe's share of back faces among its first hits (:func:`pointviz.sides.back_face_share`)
  and the decision (one-sided when at most ``CLOSED_BACK_SHARE``);
* what the probe costs against the tree's build (process CPU time, medians of ``--repeat``);
* in the default camera's 640x480 primary rays (``Camera.fit``), the hits that are back faces
  two-sided (the rim flecks of a closed scan) and with the decision, and the hits each has.

Examples
--------
python benchmarks/bench_sides.py
python benchmarks/bench_sides.py --files stanford_dragon/dragon_stand/dragonStandRight.conf
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import paper_figures as pf

#: Every cloud and mesh of ../shared/data that ``pointviz render`` reads, one per kind of data.
FILES = (
    "stanford_dragon/dragon_stand/dragonStandRight.conf",
    "stanford_bunny/data/bun.conf",
    "stanford_bunny/data/bun000.ply",
    "stanford_bunny/reconstruction/bun_zipper.ply",
    "stanford_armadillo/Armadillo.ply",
    "stanford_dragon/recon_derived/dragon_vrip_res3_meshlab.ply",
    "stanford_lucy/lucy_vtk_decimated.ply",
    "stanford_drill/data/drill_1.6mm_cyb.conf",
    "misc_scans/horse_cyberware.ply",
    "misc_scans/pepper_artec.ply",
    "synthetic_controls/spot.obj",
    "synthetic_controls/teapot.obj",
    "photogrammetry/ggg_benchmarksfm/owl_decimated.vtp",
    "photogrammetry/ggg_benchmarksfm/blackVase_decimated.vtp",
    "photogrammetry/demosthenes/demosthenes-low-res.obj",
    "lidar/simple.las",
    "lidar/autzen_trim.laz",
    "pcl_testdata/office1.pcd",
    "pcl_testdata/bunny.pcd",
    "open3d_testdata/fragment.pcd",
)


def back_hits(scene, rays) -> tuple[int, int]:
    """(hits, back-face hits) of ``rays`` at full detail."""
    out = scene.cast_rays(rays, lod_pixels=0.0, stats=False)
    hit = np.isfinite(out["t_hit"])
    back = hit & (np.einsum("ij,ij->i", out["normals"], rays[:, 3:]) > 0)
    return int(hit.sum()), int(back.sum())


def measure(path: Path, args) -> dict:
    import pointviz
    from pointviz import sides

    cloud = pointviz.load(path)
    build, probe = [], []
    for _ in range(args.repeat):
        t0 = time.process_time()
        two = pointviz.SurfelScene(cloud, cull=False)
        build.append(time.process_time() - t0)
        t0 = time.process_time()
        share = sides.back_face_share(two)
        probe.append(time.process_time() - t0)
    auto = pointviz.SurfelScene(cloud, cull="auto")
    cam = pointviz.Camera.fit(cloud, width=640, height=480)
    rays = cam.rays()
    hits2, back2 = back_hits(two, rays)
    hits1, back1 = back_hits(auto, rays)
    return {"file": str(path.relative_to(args.data)), "surfels": two.n_surfels,
            "back_face_share": share, "one_sided": auto.cull,
            "build_s": statistics.median(build), "probe_s": statistics.median(probe),
            "two_sided_hits": hits2, "two_sided_back_hits": back2,
            "auto_hits": hits1, "auto_back_hits": back1}


def main(argv: list[str] | None = None) -> int:
    p = pf.base_parser(__doc__.split("\n\n")[0], "bench_sides")
    p.add_argument("--files", nargs="+", default=list(FILES),
                   help="files under --data (default: one of each kind of data)")
    args = p.parse_args(argv)
    if not args.data.is_dir():
        print(f"bench_sides: {args.data} is absent: nothing to measure", file=sys.stderr)
        return 1
    rows = []
    print(f"{'file':<58} {'surfels':>8} {'back %':>7} {'sides':>5} {'probe ms':>8} "
          f"{'/ build':>7}  primary back-face hits: two-sided / auto (of hits)")
    for name in args.files:
        path = args.data / name
        if not path.exists():
            print(f"{name}: absent, skipped")
            continue
        r = measure(path, args)
        rows.append(r)
        share = "-" if r["back_face_share"] is None else f"{100 * r['back_face_share']:.2f}"
        sides = "one" if r["one_sided"] else "two"
        print(f"{r['file']:<58} {r['surfels']:>8} {share:>7} {sides:>5} "
              f"{1e3 * r['probe_s']:8.1f} {r['probe_s'] / r['build_s']:7.2f}  "
              f"{r['two_sided_back_hits']} / {r['auto_back_hits']} (of {r['two_sided_hits']} / "
              f"{r['auto_hits']})", flush=True)
    print("wrote", pf.write_json(args.out, "bench_sides.json",
                                 {"machine": pf.machine_info(), "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
