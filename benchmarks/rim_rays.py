"""Rim holes of fitted surfels, ray by ray, against every disk (brute force, float64).

For the pixels of a view whose centre ray enters the exact torus and that the surfels' tracer
misses, tests the ray against every surfel in float64 (the disk test of disk_kernel.h: plane hit
t, (distance from the centre / radius)^2 = u2, facing) and prints what the nearest disks say:
the smallest u2 of any disk (> 1: no disk covers the ray, the tracer is right), how far the ray
passes outside that disk's rim, the signed distance of those disks' centres to the exact torus,
and how deep the ray enters the torus.

Example
-------
python benchmarks/rim_rays.py --noise 0.001 --seed 11
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_preprocess as bp


def penetration(exact, rays):
    """Deepest point of each ray inside the exact shape (-min signed distance along it)."""
    o, d = rays[:, :3], rays[:, 3:]
    dist = np.linalg.norm(o[0])
    ts = np.linspace(dist - 1.36, dist + 1.36, 400)
    best = np.full(len(o), np.inf)
    tbest = np.zeros(len(o))
    for t in ts:
        sd = exact.signed_distance(o + t * d)
        better = sd < best
        best[better], tbest[better] = sd[better], t
    step = ts[1] - ts[0]
    for _ in range(30):  # refine by ternary search around the coarse minimum
        step *= 0.5
        for sgn in (-1.0, 1.0):
            tt = tbest + sgn * step
            sd = exact.signed_distance(o + tt[:, None] * d)
            better = sd < best
            best[better], tbest[better] = sd[better], tt[better]
    return -best


def main(argv=None):
    import pointviz
    from pointviz.comparison.scans import virtual_scans

    ap = argparse.ArgumentParser()
    ap.add_argument("--noise", type=float, default=0.001)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--view", type=int, default=0)
    ap.add_argument("--show", type=int, default=8)
    args = ap.parse_args(argv)
    raw, exact = virtual_scans("torus", scans=8, resolution=200, noise=args.noise,
                               misregistration=bp.MISREGISTRATION, seed=args.seed)
    cloud = pointviz.PointCloud(raw.points, viewpoints=raw.viewpoints, scan_index=raw.scan_index)
    fitted = cloud.fitted()
    P, N, R = fitted.points, fitted.normals.astype(np.float64), fitted.radii.astype(np.float64)
    cam = bp._cameras(320, 240)[args.view]
    rays = cam.rays(dtype=np.float64)
    depth = penetration(exact, rays)
    scene = pointviz.SurfelScene(fitted, cull=False)
    hit = scene.cast_rays(cam.rays(), lod_pixels=0, stats=False)["index"] != -1
    inside = depth > 0
    holes = np.flatnonzero(inside & ~hit)
    px = 2.0 * cam.tan_half * float(np.linalg.norm(rays[0, :3])) / cam.height
    print(f"{inside.sum()} pixels enter the torus, {len(holes)} missed "
          f"({100 * len(holes) / inside.sum():.3f}%); a pixel spans {px:.2e} at the centre")
    sd = exact.signed_distance(P)
    print(f"surfels: {len(P)}, mean signed distance {sd.mean():+.2e}")
    covered_f64 = 0
    gaps = []
    for i in holes:
        o, d = rays[i, :3], rays[i, 3:]
        facing = N @ d
        t = np.einsum("ij,ij->i", P - o, N) / facing
        q = o + t[:, None] * d - P
        u2 = np.einsum("ij,ij->i", q, q) / (R * R)
        ok = (np.abs(facing) >= 1e-6) & (t > 0)
        u2 = np.where(ok, u2, np.inf)
        order = np.argsort(u2)[:5]
        covered_f64 += bool(u2[order[0]] <= 1.0)
        # distance from the ray to the nearest disk's rim, in its plane
        j = order[0]
        gaps.append((np.sqrt(u2[j]) - 1) * R[j])
        if len(gaps) <= args.show:
            print(f" ray {i}: enters by {depth[i]:.2e}; nearest disks u2 "
                  + ", ".join(f"{u2[k]:.3f}" for k in order)
                  + "; their centres' signed distance "
                  + ", ".join(f"{sd[k]:+.1e}" for k in order)
                  + "; |facing| " + ", ".join(f"{abs(facing[k]):.3f}" for k in order)
                  + "; radii " + ", ".join(f"{R[k]:.1e}" for k in order))
    gaps = np.array(gaps)
    print(f"hole rays covered by some disk in float64: {covered_f64} of {len(holes)}")
    if len(gaps):
        print(f"gap to the nearest disk's rim: median {np.median(gaps):.2e}, max {gaps.max():.2e}; "
              f"ray depth inside the torus median {np.median(depth[holes]):.2e}, max "
              f"{depth[holes].max():.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
