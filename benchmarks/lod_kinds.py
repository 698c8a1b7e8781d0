"""Issue 18 on real scans: the budget frame's error and time broken down per kind of ray.

For each model and distance of ``bench_lod.py`` (480x360 studio frames, 1 spp, shadows, one
reflection, one thread, E = 0.005) renders, interleaved and repeated:

* ``full``: full detail (the FLIP reference and the time anchor);
* ``auto``: the budget as the core has it;
* ``camera``: the budget on camera (and reflection) rays only, shadow and sky rays at full detail
  (their weights set to NEVER);
* ``shadow`` / ``sky``: that kind of visibility ray at its weight, the other at full detail, and
  camera rays at (practically) full detail: the camera rays' budget scale times 1e-6;
* ``camera xK``: the camera rays' per-pixel budget times K (for an uncoloured model the same as
  the spread weight divided by K), secondary rays at their weights;
* ``shadow /K``, ``sky /K``: that kind's weight divided by K, the rest as the core has it.

Per frame: mean LDR-FLIP against full detail at full detail's exposure, CPU-time ratio to full.

python benchmarks/lod_kinds.py --models dragon-raw armadillo torus --repeat 3
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_lod
import common
import paper_figures as pf

NEVER = 1e9
E = 0.005


def variants(sh, sk):
    v = [("full", dict(lod=0.0)), ("auto", dict()),
         ("camera", dict(shadow=NEVER, sky=NEVER)),
         ("shadow", dict(cam=1e-6, sky=NEVER)), ("sky", dict(cam=1e-6, shadow=NEVER))]
    v += [(f"camera x{k:g}", dict(cam=k)) for k in (2, 4)]
    v += [(f"shadow /{k:g}", dict(shadow=sh / k)) for k in (2, 4)]
    v += [(f"sky /{k:g}", dict(sky=sk / k)) for k in (2, 4)]
    return v


def measure(model, args):
    import flip_evaluator
    import pointviz
    from pointviz import rendering

    scene = pointviz.SurfelScene(model.cloud, variant="full", threads=args.threads)
    opts = scene._options
    sh, sk = opts.shadow_flip_weight, opts.sky_flip_weight
    orig_scale, orig_fo = rendering.budget_scale, rendering.footprint_offsets
    base = pointviz.Camera.fit(model.cloud, width=bench_lod.WIDTH, height=bench_lod.HEIGHT)
    kw = dict(spp=1, shadows=True, reflections=1, threads=args.threads)
    rows = []

    def render(cam, v):
        opts.shadow_flip_weight = v.get("shadow", sh)
        opts.sky_flip_weight = v.get("sky", sk)
        k = v.get("cam", 1.0)
        rendering.budget_scale = lambda b, c: k * orig_scale(b, c)
        # the offsets' choice keeps the frame's own share scale
        rendering.footprint_offsets = lambda lp, me, s: orig_fo(lp, me, None if s is None else s / k)
        scene.__dict__.pop(rendering._CORE_MEMO, None)
        try:
            if "lod" in v:
                return pointviz.render(scene, cam, lod_pixels=v["lod"], **kw)
            return pointviz.render(scene, cam, lod_pixels="auto", max_error=E, **kw)
        finally:
            rendering.budget_scale = orig_scale
            rendering.footprint_offsets = orig_fo
            opts.shadow_flip_weight, opts.sky_flip_weight = sh, sk

    for factor in args.factors:
        cam = pf.camera_at(base, factor)
        times = {n: [] for n, _ in variants(sh, sk)}
        frames = {}
        for _ in range(args.repeat):
            for n, v in variants(sh, sk):
                t0 = time.process_time()
                frames[n] = render(cam, v)
                times[n].append(time.process_time() - t0)
        exp = frames["full"].exposure
        ref = frames["full"].to_srgb8().astype(np.float32) / 255.0
        full_t = statistics.median(times["full"])
        for n, _ in variants(sh, sk):
            img = frames[n].to_srgb8(exposure=exp).astype(np.float32) / 255.0
            flip = float(flip_evaluator.evaluate(ref, img, pf.FLIP_RANGE, applyMagma=False)[1])
            t = statistics.median(times[n])
            rows.append({"model": model.name, "factor": factor, "variant": n, "flip": flip,
                         "seconds": t, "ratio_full": t / full_t})
            print(f"{model.name:<11}{factor:>5g}x {n:<11} {t * 1e3:8.1f} ms x{t / full_t:5.3f} "
                  f"FLIP {flip:.4f}", flush=True)
    return rows


def main(argv=None):
    p = pf.base_parser(__doc__.split("\n\n")[0], "lod_kinds")
    p.add_argument("--size", type=int, default=bench_lod.ANALYTIC_SIZE)
    p.add_argument("--models", nargs="+", default=["dragon-raw", "armadillo", "torus"])
    p.add_argument("--factors", nargs="+", type=float, default=[1.0, 2.5, 7.5])
    args = p.parse_args(argv)
    common.probe_pointviz()
    rows = [row for model in bench_lod.load(args) for row in measure(model, args)]
    path = pf.write_json(args.out, "lod_kinds.json", {
        "benchmark": "lod_kinds", "date": time.strftime("%Y-%m-%d %H:%M:%S"), "rows": rows,
        "machine": pf.machine_info(), "args": {k: str(v) for k, v in vars(args).items()}})
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
