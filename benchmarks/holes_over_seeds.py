"""Issue 15's holes question over several draws of the virtual scans.

One draw of the scans' misregistration moves the whole scanned surface by a fraction of a pixel
inward or outward, and holes on the one-pixel rim of the outline follow it. This runs section 2
of ``bench_preprocess.py`` (the same scans, cameras, frames and measures: a hole is a pixel whose
centre ray hits the exact torus's mesh and misses the method's surface, the same test for both)
for several seeds at both noise levels and prints, per method, the mean and spread over seeds
of: holes, pixels hit outside the exact silhouette (the other side of the same sub-pixel offset),
holes more than a pixel inside the silhouette, normal and depth error, and the mean signed
distance to the exact torus of the raw points, the surfels and Poisson's vertices.

Examples
--------
python benchmarks/holes_over_seeds.py --seeds 1 2 3 4 5
python benchmarks/holes_over_seeds.py --seeds 1 2 --no-poisson --json out.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_preprocess as bp

MEASURES = ("holes", "outside", "interior_holes", "normal_error_deg", "depth_error")


def one_draw(noise: float, seed: int, poisson: bool, resolution: int, size) -> dict:
    from pointviz.comparison.mesh import MeshGeometry
    from pointviz.comparison.run import Settings
    from pointviz.comparison.scans import virtual_scans

    settings = Settings(width=size[0], height=size[1], spp=1)
    cameras = bp._cameras(settings.width, settings.height)
    raw, exact = virtual_scans("torus", scans=8, resolution=resolution, noise=noise,
                               misregistration=bp.MISREGISTRATION, seed=seed)
    v, f = exact.mesh(512)
    reference = bp._frames(MeshGeometry(v, f), cameras, settings)
    diagonal = float(np.linalg.norm(np.ptp(raw.points, axis=0)))
    s_frames, s_sec, fitted, _ = bp.surfels_pipeline(raw, cameras, settings)
    out = {"noise": noise, "seed": seed,
           "surfels": {**bp._scores(reference, s_frames, diagonal), "seconds": s_sec,
                       "offset": float(exact.signed_distance(fitted.points).mean())},
           "raw_offset": float(exact.signed_distance(raw.points).mean())}
    if poisson:
        p_frames, p_sec, rec = bp.poisson_pipeline(raw, cameras, settings)
        out["poisson"] = {**bp._scores(reference, p_frames, diagonal), "seconds": p_sec,
                          "offset": float(exact.signed_distance(rec.vertices).mean())}
    return out


def noisy_exact(sigmas, offsets, size, seed=0) -> list[dict]:
    """The exact torus's mesh with its vertices moved along their normals by Gaussian noise of
    standard deviation ``sigma`` plus a uniform ``offset``, against the exact mesh: how holes
    and pixels hit outside follow a surface's noise and offset alone (same frames and measures
    as the methods'). A ray at the outline grazes the surface over a stretch; an outward bump
    anywhere along it stops the ray, an inward one does not open a hole behind the rest: the
    outline of a noisier surface lies farther out."""
    from pointviz.comparison.mesh import MeshGeometry
    from pointviz.comparison.run import Settings
    from pointviz.comparison.scans import ExactShape

    settings = Settings(width=size[0], height=size[1], spp=1)
    cameras = bp._cameras(settings.width, settings.height)
    exact = ExactShape("torus")
    v, f = exact.mesh(512)
    reference = bp._frames(MeshGeometry(v, f), cameras, settings)
    nrm = exact.normal(v)
    rng = np.random.default_rng(seed)
    out = []
    for sigma in sigmas:
        for offset in offsets:
            moved = v + (offset + rng.normal(0.0, sigma, len(v)))[:, None] * nrm
            frames = bp._frames(MeshGeometry(moved, f), cameras, settings)
            s = bp._scores(reference, frames, float(exact.size))
            out.append({"sigma": sigma, "offset": offset, **s})
            print(f"exact torus, vertices moved by {offset:+.1e} + N(0, {sigma:.1e}): holes "
                  f"{100 * s['holes']:.3f}%  hit outside {100 * s['outside']:.3f}%", flush=True)
    return out


def summary(rows: list[dict], method: str) -> dict:
    out = {}
    for key in (*MEASURES, "offset"):
        vals = np.array([r[method][key] for r in rows if method in r])
        if vals.size:
            out[key] = {"mean": float(vals.mean()), "std": float(vals.std(ddof=1)) if
                        vals.size > 1 else 0.0, "min": float(vals.min()),
                        "max": float(vals.max())}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--noises", type=float, nargs="+", default=list(bp.NOISES))
    ap.add_argument("--no-poisson", action="store_true")
    ap.add_argument("--resolution", type=int, default=200)
    ap.add_argument("--size", type=int, nargs=2, default=(320, 240))
    ap.add_argument("--json", type=Path)
    ap.add_argument("--noisy-exact", action="store_true",
                    help="only the exact torus with noisy / offset vertices (no scans)")
    args = ap.parse_args(argv)
    with open("/proc/loadavg") as fh:
        print(f"load {fh.read().split()[0]}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    if args.noisy_exact:
        noisy_exact((0.0, 0.5e-3, 1e-3, 2e-3, 3e-3), (0.0, -0.5e-3), tuple(args.size))
        return 0
    rows = []
    for noise in args.noises:
        for seed in args.seeds:
            r = one_draw(noise, seed, not args.no_poisson, args.resolution, tuple(args.size))
            rows.append(r)
            line = (f"noise {noise:g} seed {seed:3d}: raw offset {r['raw_offset']:+.2e}  surfels "
                    f"holes {100 * r['surfels']['holes']:.3f}% out "
                    f"{100 * r['surfels']['outside']:.3f}% offset {r['surfels']['offset']:+.2e}")
            if "poisson" in r:
                p = r["poisson"]
                line += (f" | Poisson holes {100 * p['holes']:.3f}% out {100 * p['outside']:.3f}%"
                         f" offset {p['offset']:+.2e}")
            print(line, flush=True)
    result = {"rows": rows, "summary": {}}
    for noise in args.noises:
        sel = [r for r in rows if r["noise"] == noise]
        result["summary"][str(noise)] = {}
        print(f"noise {noise:g}, {len(sel)} seeds: mean (std) [min, max]")
        for method in ("surfels", "poisson"):
            s = summary(sel, method)
            if not s:
                continue
            result["summary"][str(noise)][method] = s
            for key in (*MEASURES, "offset"):
                m = s[key]
                scale = 100.0 if key in ("holes", "outside", "interior_holes") else 1.0
                print(f"  {method:<8} {key:<17} {scale * m['mean']:.4g} ({scale * m['std']:.2g})"
                      f" [{scale * m['min']:.4g}, {scale * m['max']:.4g}]")
        if all("poisson" in r for r in sel):
            d = np.array([r["surfels"]["holes"] - r["poisson"]["holes"] for r in sel])
            print(f"  surfels - Poisson holes: {100 * d.mean():+.4f} pt (std {100 * d.std(ddof=1) if d.size > 1 else 0:.4f})"
                  f", surfels <= Poisson in {(d <= 0).sum()} of {d.size}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
