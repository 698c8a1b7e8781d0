"""Issue 18: why the error budget lets a model's nodes stop or not, and how far the predictor is
from the measured error there.

For each model and camera distance (the framing distance, 2.5x and 7.5x farther; 480x360, the
budget E = 0.005 and the frame's ``budget_scale`` as ``render`` uses them):

* **refusals**: for every pixel whose full-detail ray hits the model, the ancestors of the hit's
  leaf within the size cap (2r <= kBudgetMaxExtent footprints, in front of the ray) are
  classified by the first term of ``budget_allows`` (lod.h) that refuses them: no normal cone,
  the colour term, the spread term; or they stop. Also the quartiles of those ancestors' cone
  sines and, per pixel, of the smallest predicted error over the budget (1: would just stop);
* **FLIP against E**: studio frames (1 spp, shadows, one reflection) at budgets E in
  ``--budgets``, mean LDR-FLIP against the full-detail frame at its exposure (as bench_lod.py
  reports it): a predictor that bounds the error tightly gives FLIP close to E; far below E it
  is over-conservative for the model.

The node fields are the tree's own (``node_arrays``: cone, decoded colour spread), the
constants those of lod.h, repeated here (``SPREAD_TERM``, ``COLOUR_TERM``): a change there must
be made here too.

Examples
--------
python benchmarks/lod_refusals.py --models dragon-raw
python benchmarks/lod_refusals.py --quick
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_lod
import common
import lod_budget
import paper_figures as pf

#: lod.h: kBudgetScale * kSpreadWeight, kBudgetScale * kColourWeight, kBudgetFloor, kBudgetMaxExtent.
SPREAD_TERM, COLOUR_TERM, FLOOR, MAX_EXTENT = 2.16 * 0.262 / 8, 2.16 * 0.454, 0.0005, 8.0
#: The budget the statistics are about.
BUDGET = bench_lod.DEFAULT_BUDGET
#: Budgets of the FLIP-against-E frames.
FLIP_BUDGETS = (0.005, 0.01, 0.02, 0.04, 0.08)


def refusals(scene, cloud, camera) -> dict:
    """Classify the ancestors within the size cap of every hit pixel's leaf (module docstring)."""
    from pointviz.rendering import as_scene, budget_scale
    from pointviz.surfels import SIZE_RULE_ERROR

    st = lod_budget.node_statistics(scene, cloud)
    na = scene.tree.node_arrays()
    cone = np.asarray(na["cone"], np.float64)
    colour = np.asarray(na["colour_spread"], np.float64)  # as stored: what the traversal reads
    scale = budget_scale(as_scene(scene).bounds(), camera)
    budget = (BUDGET - FLOOR) * scale
    share = min(1.0, BUDGET / SIZE_RULE_ERROR)
    rays = pf.rays64(camera)
    local = rays.copy()
    local[:, :3] -= scene.origin
    local[:, 3:] /= np.linalg.norm(local[:, 3:], axis=1, keepdims=True)
    full = scene.cast_rays(rays)
    hit = np.flatnonzero(full["index"] >= 0)
    cur = st["parent"][st["leaf_of_surfel"][st["inv_order"][full["index"][hit]]]]
    o, d = local[hit, :3], local[hit, 3:]
    counts = {"no_cone": 0, "colour": 0, "spread": 0, "stop": 0}
    may_stop = np.zeros(len(hit), bool)
    in_cap = np.zeros(len(hit), bool)
    best = np.full(len(hit), np.inf)
    cones = []
    live = cur >= 0
    while live.any():
        i = np.flatnonzero(live)
        c = cur[i]
        t2 = np.einsum("ij,ij->i", st["center"][c] - o[i], d[i])
        fp = camera.pixel_angle * t2
        size = 2.0 * st["radius"][c]
        cap = (t2 > 0) & (size <= MAX_EXTENT * fp)
        has = cone[c] < 2.0
        col = COLOUR_TERM * colour[c]
        pred = col + SPREAD_TERM * np.minimum(cone[c], 1.0)
        ok = cap & has & (col <= budget) & ((size <= share * fp) | (pred <= budget))
        counts["no_cone"] += int(np.sum(cap & ~has))
        counts["colour"] += int(np.sum(cap & has & (col > budget)))
        counts["spread"] += int(np.sum(cap & has & (col <= budget) & ~ok))
        counts["stop"] += int(np.sum(ok))
        may_stop[i[ok]] = True
        in_cap[i[cap]] = True
        sel = cap & has
        best[i[sel]] = np.minimum(best[i[sel]], pred[sel] / budget)
        cones.append(np.minimum(cone[c][sel], 1.0))
        cur[i] = st["parent"][c]
        live = cur >= 0
    cones = np.concatenate(cones)
    finite = best[np.isfinite(best)]
    q = (25, 50, 75)
    return {"budget_scale": float(scale), "pixel_budget": float(budget),
            "spread_limit": float(budget / SPREAD_TERM), "hit_pixels": int(len(hit)),
            "share_in_cap": float(in_cap.mean()) if len(hit) else 0.0,
            "share_may_stop": float(may_stop.mean()) if len(hit) else 0.0,
            "ancestors": counts,
            "interior_without_cone": float(np.mean(cone[~st["leaf"]] >= 2.0)),
            "cone_quartiles": np.percentile(cones, q).tolist() if len(cones) else None,
            "best_over_budget_quartiles": np.percentile(finite, q).tolist() if len(finite) else None}


def flip_against_budget(scene, camera, args) -> dict:
    """Mean FLIP (at full detail's exposure) of budget frames for every E in FLIP_BUDGETS."""
    import flip_evaluator
    import pointviz

    kw = dict(spp=1, shadows=True, reflections=1, threads=args.threads)
    full = pointviz.render(scene, camera, lod_pixels=0.0, **kw)
    ref = full.to_srgb8().astype(np.float32) / 255.0
    out = {}
    for e in FLIP_BUDGETS:
        fr = pointviz.render(scene, camera, lod_pixels="auto", max_error=e, **kw)
        img = fr.to_srgb8(exposure=full.exposure).astype(np.float32) / 255.0
        out[e] = float(flip_evaluator.evaluate(ref, img, pf.FLIP_RANGE, applyMagma=False)[1])
    return out


def main(argv: list[str] | None = None) -> int:
    import pointviz

    p = pf.base_parser(__doc__.split("\n\n")[0], "lod_refusals")
    p.add_argument("--size", type=int, default=bench_lod.ANALYTIC_SIZE,
                   help="surfels of the analytic torus")
    p.add_argument("--models", nargs="+", default=["torus", "dragon-raw", "armadillo"],
                   choices=["torus", "dragon-raw", "armadillo"])
    args = p.parse_args(argv)
    common.probe_pointviz()
    rows = []
    for model in bench_lod.load(args):
        scene = pointviz.SurfelScene(model.cloud, variant="full", threads=args.threads)
        w, h = ((pf.QUICK_PIXELS, pf.QUICK_PIXELS) if args.quick
                else (bench_lod.WIDTH, bench_lod.HEIGHT))
        base = pointviz.Camera.fit(model.cloud, width=w, height=h)
        for factor in bench_lod.DISTANCES:
            cam = pf.camera_at(base, factor)
            r = refusals(scene, model.cloud, cam)
            r["flip"] = flip_against_budget(scene, cam, args)
            r.update(model=model.name, factor=factor)
            rows.append(r)
            a = r["ancestors"]
            print(f"{model.name:<11}{factor:>5g}x scale {r['budget_scale']:5.2f} budget "
                  f"{r['pixel_budget']:.4f} (cone sine <= {r['spread_limit']:.4f}); hit px "
                  f"{r['hit_pixels']}, in cap {100 * r['share_in_cap']:.1f} %, may stop "
                  f"{100 * r['share_may_stop']:.1f} %; ancestors in cap: no cone {a['no_cone']}, "
                  f"colour {a['colour']}, spread {a['spread']}, stop {a['stop']}; cone sine "
                  f"quartiles {np.round(r['cone_quartiles'] or [], 3).tolist()}; best pred/budget "
                  f"quartiles {np.round(r['best_over_budget_quartiles'] or [], 2).tolist()}; "
                  f"interior nodes without a cone {100 * r['interior_without_cone']:.1f} %",
                  flush=True)
            print("    FLIP at E: " + ", ".join(f"{e:g} -> {v:.4f}" for e, v in r["flip"].items()),
                  flush=True)
    result = {"benchmark": "lod_refusals", "date": time.strftime("%Y-%m-%d %H:%M:%S"),
              "machine": pf.machine_info(), "args": {k: str(v) for k, v in vars(args).items()},
              "rows": [{**r, "flip": {str(k): v for k, v in r["flip"].items()}} for r in rows]}
    print(f"wrote {pf.write_json(args.out, 'lod_refusals.json', result)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
