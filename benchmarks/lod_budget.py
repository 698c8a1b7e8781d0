"""Level of detail by an error budget: a per-node error predictor, calibrated against FLIP.

The design experiment for ``render(..., lod_pixels="auto", max_error=E)`` (issue 18), run on the
current hierarchy without touching its traversal. For every pixel of a frame rendered with a fixed
threshold ``lod_pixels = L`` we find the node at which the traversal stopped (the shallowest
ancestor of the hit surfel's leaf whose sphere projects below L footprints: the paper's rule as
``trace.h`` applies it), describe that node by what the tree stores or can store, and fit how
much image error such a stop causes:

* ``spread`` — sine of the node's normal-cone half-angle (the children's disks tilt by up to it);
* ``thickness`` — RMS distance of the node's surfels from its mean plane, in pixel footprints
  (what the slab half-width bounds);
* ``colour`` — RMS deviation of the node's surfel colours from its mean colour (0..1 units);
* ``overhang`` — projected diameter in pixels, counted only where the node's normal cone reaches a
  direction perpendicular to the ray (|dot(axis, d)| <= spread): the node may hold a silhouette,
  where a disk sticks out by up to its radius.

Predicted mean error of a frame = sum_k a_k * mean over pixels of feature_k (0 for pixels that hit
a leaf: full detail). The coefficients a_k >= 0 are fitted by non-negative least squares to the
measured mean LDR-FLIP of frames (shaded, primary rays only, spp 1: ``pointviz.render`` with
``shadows=False, reflections=0``) against the full-detail frame, over models, distances and
thresholds (the dragon scans held out); the bound is then ``scale * predicted + floor`` with the
smallest scale and floor that cover every calibration frame (see :func:`fit`), and the held-out
model checks it.

The per-node rule this gives for the traversal (to be wired into the wide tree): at a node seen
with footprint fp, stop when
``a_spread * spread + a_thickness * thickness / fp + a_colour * colour
+ a_overhang * [|dot(axis, d)| <= spread] * 2 r / fp  <=  E``:
a per-pixel error within E keeps the frame's mean within E.

Secondary rays (``--secondary``): shadow and sky-visibility rays take the visibility model of
``lod.h`` (a coarser node flips a ray's visibility with a chance proportional to its normal
cone's sine; a flip costs the pixel that ray's share of it), one weight per kind of ray. Each
kind is calibrated alone: on ``bench_lod.py``'s studio frames (480x360, 1 spp, shadows, sky
occlusion, one reflection) at every distance, the budget frame (E = 0.005) with that kind's
weight set to each value of SECONDARY_WEIGHTS and the other kind at full detail is compared
(mean LDR-FLIP, at the reference's exposure) with the budget frame whose secondary rays all keep
full detail: the error that kind's level of detail adds. The calibrated weight is the smallest
one whose added error stays within KIND_SHARE x (E - floor) on every frame; the chart shows
the added error against the weight.

The colour term's response within a pixel (``--colour``): a node no wider than the ray's
footprint is charged ``response x`` its colour term (lod.h, kColourPixelResponse: FLIP's
contrast sensitivity attenuates a difference at the pixel's scale). The budget frames (1 spp,
shadows, sky occlusion, one reflection) of the striped torus at 1x, 2.5x and 7.5x, for each
response in COLOUR_RESPONSES and each E in COLOUR_BUDGETS, are compared with the full-detail frame
(mean LDR-FLIP at full detail's exposure and at the frame's own: the automatic exposure follows
the object's mean, the first thing to give). At E = 0.005 (the default) the smallest response
whose frames all stay within E at both exposures is where the automatic exposure starts to give;
the core takes the next larger value tried, one step from it. Frames at E = 0.002 are reported
(the 8M torus exceeds 0.002 with a response of 1 already). Cases: the 200k torus at 160x120 (the test's frame, where the
stripes alias), 1M and the issue's 8M at 480x360.

Examples
--------
python benchmarks/lod_budget.py --quick
python benchmarks/lod_budget.py             # torus 1M (coloured), Armadillo 1M, dragon scans
python benchmarks/lod_budget.py --secondary --out benchmarks/results/lod_budget/secondary
python benchmarks/lod_budget.py --colour --out benchmarks/results/lod_budget/colour
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import paper_figures as pf

#: Camera distances (x the fitted distance): the issue's framing, 2.5x and 7.5x views.
DISTANCES = (1.0, 2.5, 7.5)
#: Fixed thresholds whose frames calibrate the predictor.
THRESHOLDS = (0.5, 1.0, 2.0, 4.0, 8.0)
#: Image size (the paper's).
PIXELS = 400
#: Surfels of the analytic torus and of the Armadillo sample.
SIZE = 1_000_000
#: The predictor's features, in the order of the fitted coefficients.
FEATURES = ("spread", "thickness", "colour", "overhang")
#: Colour stripes around the analytic torus (one period every 9 degrees of its major angle, about
#: 0.16 units wide), so that the colour term has something to measure (the scans carry no colour).
STRIPES = 40
#: Predicted frame errors below this count as "no stop": their measured FLIP is the noise floor.
NOISE_PRED = 2e-4
#: The model held out of the fit to check the bound.
HELD_OUT = "dragon-raw"


# ----------------------------------------------------------------------------------------------
# node statistics from the tree and its surfels


def node_statistics(scene, cloud) -> dict:
    """Per-node statistics of a SurfelTree, from its nodes and its surfels (tree order).

    Returns
    -------
    dict of (n_nodes,) arrays
        ``center`` (n, 3), ``radius``, ``axis`` (n, 3), ``spread`` (cone sine; 2 = no cone),
        ``thickness`` (RMS distance to the mean plane), ``colour`` (RMS colour deviation),
        ``parent`` (-1 for the root), ``leaf_of_surfel`` (tree position -> leaf node), ``inv_order``
        (input index -> tree position).
    """
    na = scene.tree.node_arrays()
    count, index = np.asarray(na["count"]), np.asarray(na["index"]).astype(np.int64)
    n_nodes = len(count)
    order = np.asarray(na["order"]).astype(np.int64)
    pts = np.asarray(cloud.points, dtype=np.float64)[order]
    pts -= pts.mean(axis=0)
    cols = (np.zeros((len(order), 3)) if getattr(cloud, "colors", None) is None
            else np.asarray(cloud.colors, dtype=np.float64)[order])
    # Each node owns a contiguous range of surfels in tree order: leaves [index, index + count),
    # interior nodes from their first child's start to their second child's end (bottom-up).
    lo, hi = np.zeros(n_nodes, np.int64), np.zeros(n_nodes, np.int64)
    leaf = count > 0
    lo[leaf], hi[leaf] = index[leaf], index[leaf] + count[leaf]
    parent = np.full(n_nodes, -1, np.int64)
    interior = np.flatnonzero(~leaf)
    parent[index[interior]] = interior
    parent[index[interior] + 1] = interior
    for i in interior[::-1]:  # breadth-first layout: children after parents
        lo[i], hi[i] = lo[index[i]], hi[index[i] + 1]
    # prefix sums of positions, outer products and colours give every node's moments at once
    def prefix(a):
        return np.vstack([np.zeros((1, a.shape[1])), np.cumsum(a, axis=0)])
    m = (hi - lo)[:, None].astype(np.float64)
    cp, cpp = prefix(pts), prefix((pts[:, :, None] * pts[:, None, :]).reshape(-1, 9))
    cc, ccc = prefix(cols), prefix((cols * cols).sum(axis=1, keepdims=True))
    mean = (cp[hi] - cp[lo]) / m
    cov = ((cpp[hi] - cpp[lo]) / m).reshape(-1, 3, 3) - mean[:, :, None] * mean[:, None, :]
    axis = np.asarray(na["normal"], dtype=np.float64)
    thickness = np.sqrt(np.maximum(np.einsum("ni,nij,nj->n", axis, cov, axis), 0.0))
    cmean = (cc[hi] - cc[lo]) / m
    colour = np.sqrt(np.maximum((ccc[hi] - ccc[lo])[:, 0] / m[:, 0] - (cmean**2).sum(axis=1), 0.0))
    leaf_of_surfel = np.empty(len(order), np.int64)
    for i in np.flatnonzero(leaf):
        leaf_of_surfel[lo[i]:hi[i]] = i
    inv_order = np.empty_like(order)
    inv_order[order] = np.arange(len(order))
    return {"center": np.asarray(na["center"], np.float64),
            "radius": np.asarray(na["radius"], np.float64),
            "axis": axis, "spread": np.asarray(na["cone"], np.float64), "thickness": thickness,
            "colour": colour, "parent": parent, "leaf": leaf, "leaf_of_surfel": leaf_of_surfel,
            "inv_order": inv_order}


def stop_nodes(stats: dict, rays_local: np.ndarray, hit_index: np.ndarray, pixel_angle: float,
               lod_pixels: float) -> np.ndarray:
    """The node where the size rule stops each hit ray (-1: it reached a leaf, full detail).

    Walks from the hit surfel's leaf to the root and keeps the shallowest interior ancestor
    with a normal cone, in front of the ray, whose diameter is within ``lod_pixels`` footprints.
    """
    node = np.full(len(hit_index), -1, np.int64)
    ok = hit_index >= 0
    cur = np.full(len(hit_index), -1, np.int64)
    cur[ok] = stats["leaf_of_surfel"][stats["inv_order"][hit_index[ok]]]
    cur[ok] = stats["parent"][cur[ok]]  # LoD applies to interior nodes only
    o, d = rays_local[:, :3], rays_local[:, 3:]
    while True:
        live = cur >= 0
        if not live.any():
            return node
        i = np.flatnonzero(live)
        c = cur[i]
        t2 = np.einsum("ij,ij->i", stats["center"][c] - o[i], d[i])
        stop = ((stats["spread"][c] < 2.0) & (t2 > 0)
                & (2.0 * stats["radius"][c] <= lod_pixels * pixel_angle * t2))
        node[i[stop]] = c[stop]  # overwritten by shallower ancestors that also stop
        cur[i] = stats["parent"][c]


def pixel_features(stats: dict, node: np.ndarray, rays_local: np.ndarray,
                   pixel_angle: float) -> np.ndarray:
    """(n_rays, 4) features of each ray's stop node (zeros where no LoD stop happened)."""
    f = np.zeros((len(node), len(FEATURES)))
    i = np.flatnonzero(node >= 0)
    c = node[i]
    o, d = rays_local[i, :3], rays_local[i, 3:]
    fp = pixel_angle * np.maximum(np.einsum("ij,ij->i", stats["center"][c] - o, d), 1e-30)
    spread = np.minimum(stats["spread"][c], 1.0)
    grazing = np.abs(np.einsum("ij,ij->i", stats["axis"][c], d)) <= spread
    f[i, 0] = spread
    f[i, 1] = stats["thickness"][c] / fp
    f[i, 2] = stats["colour"][c]
    f[i, 3] = grazing * 2.0 * stats["radius"][c] / fp
    return f


# ----------------------------------------------------------------------------------------------
# models


def striped_torus(n: int):
    """The analytic torus (major 1, minor 0.35) with colour stripes around its tube."""
    import pointviz
    from pointviz import shapes

    t = shapes.torus(n, 1.0, 0.35)
    p = np.asarray(t.points)
    s = 0.5 + 0.5 * np.sin(STRIPES * np.arctan2(p[:, 2], p[:, 0]))
    colors = np.c_[0.2 + 0.7 * s, 0.3 + 0.2 * (1 - s), 0.8 - 0.6 * s]
    return pf.Model("torus", pointviz.PointCloud(p, normals=t.normals, colors=colors, name="torus"),
                    None, {"source": "pointviz.shapes.torus(n, 1.0, 0.35) with colour stripes"})


def load(args) -> list:
    """The calibration models: striped torus, Armadillo sample, dragon raw scans."""
    n = pf.QUICK_SIZE if args.quick else SIZE
    models = [striped_torus(n)]
    models += pf.load_models(args, ["armadillo"], n)
    models += pf.load_models(args, ["dragon-raw"], n)
    return models


# ----------------------------------------------------------------------------------------------
# measurement


def measure(model, args) -> list[dict]:
    """Frames at every distance and threshold: measured FLIP, mean features, time."""
    import flip_evaluator
    import pointviz

    px = pf.QUICK_PIXELS if args.quick else PIXELS
    scene = pointviz.SurfelScene(model.cloud, variant="full", threads=args.threads)
    stats = node_statistics(scene, model.cloud)
    base = pf.fit_camera(model.cloud, px)
    rows = []
    for factor in DISTANCES:
        cam = pf.camera_at(base, factor)
        rays = pf.rays64(cam)
        local = rays.copy()
        local[:, :3] -= scene.origin
        local[:, 3:] /= np.linalg.norm(local[:, 3:], axis=1, keepdims=True)
        full = scene.cast_rays(rays)  # the full-detail hit of each pixel centre
        kw = dict(shadows=False, reflections=0, spp=1, threads=args.threads)
        ref = pointviz.render(scene, cam, lod_pixels=0.0, **kw)
        ref_img = ref.to_srgb8().astype(np.float32) / 255.0
        for lp in THRESHOLDS:
            fr = pointviz.render(scene, cam, lod_pixels=lp, **kw)
            img = fr.to_srgb8().astype(np.float32) / 255.0
            _, mean, _ = flip_evaluator.evaluate(ref_img, img, pf.FLIP_RANGE, applyMagma=False)
            node = stop_nodes(stats, local, full["index"], cam.pixel_angle, lp)
            # check of the simulated cut: pixels whose nearest disk the traversal took from a node
            lod_out = scene.cast_rays(rays, camera=cam, lod_pixels=lp)
            lod_hits = float(np.mean(lod_out["index"] == -2))
            feats = pixel_features(stats, node, local, cam.pixel_angle)
            rows.append({"model": model.name, "factor": factor, "lod_pixels": lp,
                         "flip": float(mean), "features": feats.mean(axis=0).tolist(),
                         "stopped_fraction": float(np.mean(node >= 0)),
                         "lod_hit_fraction": lod_hits,
                         "seconds": fr.stats["seconds"], "full_seconds": ref.stats["seconds"]})
            print(f"{model.name:<11}{factor:>5g}x {lp:>4g}px  FLIP {mean:.4f}  stopped "
                  f"{100 * rows[-1]['stopped_fraction']:5.1f}% (traversal {100 * lod_hits:5.1f}%)"
                  "  features "
                  + " ".join(f"{v:.4g}" for v in rows[-1]["features"]), flush=True)
    return rows


def fit(rows: list[dict]) -> dict:
    """NNLS coefficients on the calibration rows, and the affine bound built on them.

    The bound is ``scale * predicted + floor``: ``floor`` is the largest FLIP of a calibration
    frame where the predictor sees (almost) no stop (below ``NOISE_PRED``: single pixels flipping
    at silhouettes), ``scale`` the largest ratio (FLIP - floor) / predicted over the others.
    """
    from scipy.optimize import nnls

    held = np.array([r["model"] == HELD_OUT for r in rows])
    cal = ~held if (~held).any() else np.ones(len(rows), bool)
    feats = np.array([r["features"] for r in rows])
    flip = np.array([r["flip"] for r in rows])
    a, _ = nnls(feats[cal], flip[cal])
    pred = feats @ a
    quiet = cal & (pred < NOISE_PRED)
    floor = float(flip[quiet].max()) if quiet.any() else 0.0
    loud = cal & (pred >= NOISE_PRED)
    scale = float(max(1.0, ((flip[loud] - floor) / pred[loud]).max())) if loud.any() else 1.0
    for r, p in zip(rows, pred):
        r["predicted"] = float(p)
        r["bound"] = float(scale * p + floor)
        r["bounded"] = bool(r["flip"] <= r["bound"])
    return {"coefficients": dict(zip(FEATURES, a.tolist())), "bound_scale": scale,
            "bound_floor": floor, "held_out": HELD_OUT,
            "held_out_bounded": bool(all(r["bounded"] for r, h in zip(rows, held) if h)),
            "corr": float(np.corrcoef(pred, flip)[0, 1]) if len(rows) > 2 else None}


# ----------------------------------------------------------------------------------------------
# secondary rays: the visibility model's weights


#: Weights tried for each kind of visibility ray (lod.h, kShadowFlipWeight, kSkyFlipWeight).
SECONDARY_WEIGHTS = (0.005, 0.0075, 0.01, 0.015, 0.02, 0.03)
#: A weight that lets no node stop (the kind at full detail).
NEVER = 1e9
#: The budget the secondary frames are rendered with, its floor (lod.h, kBudgetFloor), and the
#: share of E - floor each kind's added error may take on a calibration frame.
SECONDARY_BUDGET, BUDGET_FLOOR, KIND_SHARE = 0.005, 0.0005, 0.25
#: The kinds, as TraceOptions names their weights.
KINDS = ("shadow", "sky")


def measure_secondary(model, args) -> list[dict]:
    """Per distance and kind: the error each weight adds to the budget frame."""
    import bench_lod
    import flip_evaluator
    import pointviz

    w, h = (pf.QUICK_PIXELS, pf.QUICK_PIXELS) if args.quick else (bench_lod.WIDTH, bench_lod.HEIGHT)
    scene = pointviz.SurfelScene(model.cloud, variant="full", threads=args.threads)
    opts = scene._options  # the weights ride on the scene's traversal options
    base = pointviz.Camera.fit(model.cloud, width=w, height=h)
    kw = dict(spp=1, shadows=True, reflections=1, threads=args.threads, lod_pixels="auto",
              max_error=SECONDARY_BUDGET)

    def frame(shadow: float, sky: float):
        opts.shadow_flip_weight, opts.sky_flip_weight = shadow, sky
        return pointviz.render(scene, cam, **kw)

    rows = []
    for factor in DISTANCES:
        cam = pf.camera_at(base, factor)
        full = pointviz.render(scene, cam, **{**kw, "lod_pixels": 0.0, "max_error": None})
        ref = frame(NEVER, NEVER)
        ref_img = ref.to_srgb8(exposure=full.exposure).astype(np.float32) / 255.0
        for kind in KINDS:
            for weight in SECONDARY_WEIGHTS:
                fr = frame(weight, NEVER) if kind == "shadow" else frame(NEVER, weight)
                img = fr.to_srgb8(exposure=full.exposure).astype(np.float32) / 255.0
                added = float(flip_evaluator.evaluate(ref_img, img, pf.FLIP_RANGE,
                                                      applyMagma=False)[1])
                rows.append({"model": model.name, "factor": factor, "kind": kind,
                             "weight": weight, "added_flip": added})
                print(f"{model.name:<11}{factor:>5g}x {kind:<7} weight {weight:<7g} added FLIP "
                      f"{added:.4f}", flush=True)
    opts.shadow_flip_weight, opts.sky_flip_weight = scene_defaults()
    return rows


def scene_defaults() -> tuple[float, float]:
    """The core's calibrated weights (TraceOptions' defaults)."""
    from pointviz import _core

    o = _core.TraceOptions()
    return o.shadow_flip_weight, o.sky_flip_weight


def fit_secondary(rows: list[dict]) -> dict:
    """Per kind, the smallest weight whose added error fits KIND_SHARE x (E - floor) everywhere."""
    limit = KIND_SHARE * (SECONDARY_BUDGET - BUDGET_FLOOR)
    out = {"limit": limit, "core_defaults": dict(zip(KINDS, scene_defaults()))}
    for kind in KINDS:
        ok = [wt for wt in SECONDARY_WEIGHTS
              if all(r["added_flip"] <= limit for r in rows if r["kind"] == kind and r["weight"] == wt)]
        worst = {wt: max(r["added_flip"] for r in rows if r["kind"] == kind and r["weight"] == wt)
                 for wt in SECONDARY_WEIGHTS}
        out[kind] = {"weight": min(ok) if ok else None, "worst_added_flip": worst}
    return out


def main_secondary(args) -> int:
    import bench_lod

    models = [striped_torus(pf.QUICK_SIZE if args.quick else SIZE)]
    models += pf.load_models(args, ["dragon-raw"], None)
    models += pf.load_models(args, ["armadillo"], bench_lod.ARMADILLO_SIZE)
    rows = []
    for model in models:
        rows += measure_secondary(model, args)
    result_fit = fit_secondary(rows)
    for kind in KINDS:
        f = result_fit[kind]
        print(f"{kind}: calibrated weight {f['weight']} (added FLIP <= {result_fit['limit']:.5f}); "
              "worst added FLIP per weight " + ", ".join(f"{k:g}: {v:.4f}"
                                                         for k, v in f["worst_added_flip"].items()))
    result = {"benchmark": "lod_budget_secondary", "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
              "machine": pf.machine_info(), "args": {k: str(v) for k, v in vars(args).items()},
              "fit": result_fit, "rows": rows}
    plt = pf.pyplot()
    fig, axes = plt.subplots(1, len(KINDS), figsize=(5 * len(KINDS), 4), squeeze=False)
    for ax, kind in zip(axes[0], KINDS):
        for name in dict.fromkeys(r["model"] for r in rows):
            for factor, marker in zip(DISTANCES, "os^"):
                rr = [r for r in rows if r["kind"] == kind and r["model"] == name
                      and r["factor"] == factor]
                ax.semilogy([r["weight"] for r in rr], [max(r["added_flip"], 1e-5) for r in rr],
                            marker + "-", ms=4, label=f"{name} {factor:g}x")
        ax.axhline(result_fit["limit"], color="grey", lw=0.8)
        ax.set_title(f"{kind} rays alone (E = {SECONDARY_BUDGET})")
        ax.set_xlabel("weight")
        ax.set_ylabel("added mean FLIP")
        ax.legend(fontsize=6)
    fig.tight_layout()
    chart = pf.save_figure(fig, args.out, "lod_secondary_calibration.png")
    path = pf.write_json(args.out, "lod_secondary.json", result)
    print(f"\nwrote {path} and {chart.name}")
    return 0


#: Responses of the colour term within a pixel tried by --colour, the budgets, and the cases
#: (surfels, width, height).
COLOUR_RESPONSES = (1.0, 0.5, 0.375, 0.3, 0.25, 0.125)
COLOUR_BUDGETS = (0.002, 0.005)
DEFAULT_COLOUR_BUDGET = 0.005
COLOUR_CASES = ((200_000, 160, 120), (1_000_000, 480, 360), (8_000_000, 480, 360))


def measure_colour(n: int, w: int, h: int, args) -> list[dict]:
    """Per distance, E and response: the budget frame's FLIP against full detail."""
    import flip_evaluator
    import pointviz

    model = striped_torus(n)
    scene = pointviz.SurfelScene(model.cloud, variant="full", threads=args.threads)
    opts = scene._options  # the response rides on the scene's traversal options
    default = opts.colour_pixel_response
    base = pointviz.Camera.fit(model.cloud, width=w, height=h)
    kw = dict(spp=1, shadows=True, reflections=1, threads=args.threads)
    rows = []
    for factor in DISTANCES:
        cam = pf.camera_at(base, factor)
        full = pointviz.render(scene, cam, lod_pixels=0.0, **kw)
        ref = full.to_srgb8().astype(np.float32) / 255.0

        def flip(frame, exposure):
            img = frame.to_srgb8(exposure=exposure).astype(np.float32) / 255.0
            return float(flip_evaluator.evaluate(ref, img, pf.FLIP_RANGE, applyMagma=False)[1])

        for e in COLOUR_BUDGETS:
            for resp in COLOUR_RESPONSES:
                opts.colour_pixel_response = resp
                fr = pointviz.render(scene, cam, lod_pixels="auto", max_error=e, **kw)
                row = {"n": n, "size": f"{w}x{h}", "factor": factor, "max_error": e,
                       "response": resp, "flip": flip(fr, full.exposure), "flip_own": flip(fr, None)}
                rows.append(row)
                print(f"torus {n:>9} {w}x{h} {factor:>4g}x E {e:<6g} response {resp:<6g} FLIP "
                      f"{row['flip']:.4f} (own exposure {row['flip_own']:.4f})", flush=True)
    opts.colour_pixel_response = default
    return rows


def fit_colour(rows: list[dict]) -> dict:
    """The smallest response within E = DEFAULT_COLOUR_BUDGET at both exposures on every frame,
    and the calibrated one: the next larger response tried."""
    from pointviz import _core

    def worst_at(e):
        return {r: max(max(x["flip"], x["flip_own"]) / x["max_error"] for x in rows
                       if x["response"] == r and x["max_error"] == e) for r in COLOUR_RESPONSES}

    worst = {e: worst_at(e) for e in COLOUR_BUDGETS}
    ok = sorted(r for r in COLOUR_RESPONSES if worst[DEFAULT_COLOUR_BUDGET][r] <= 1.0)
    larger = [r for r in sorted(COLOUR_RESPONSES) if ok and r > ok[0]]
    fit_ = {"smallest_within_E": ok[0] if ok else None,
            "response": (larger[0] if larger else ok[0]) if ok else None,
            "worst_flip_over_E": {str(e): w for e, w in worst.items()},
            "core_default": _core.TraceOptions().colour_pixel_response}
    return fit_


def main_colour(args) -> int:
    cases = ((pf.QUICK_SIZE, pf.QUICK_PIXELS, pf.QUICK_PIXELS),) if args.quick else COLOUR_CASES
    rows = []
    for n, w, h in cases:
        rows += measure_colour(n, w, h, args)
    fit_ = fit_colour(rows)
    print(f"smallest response within E = {DEFAULT_COLOUR_BUDGET} at both exposures "
          f"{fit_['smallest_within_E']}, calibrated (one step above) {fit_['response']}, core "
          f"default {fit_['core_default']}")
    for e in COLOUR_BUDGETS:
        print(f"  E {e}: worst FLIP / E per response "
              + ", ".join(f"{k:g}: {v:.2f}" for k, v in fit_["worst_flip_over_E"][str(e)].items()))
    result = {"benchmark": "lod_budget_colour", "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
              "machine": pf.machine_info(), "args": {k: str(v) for k, v in vars(args).items()},
              "fit": fit_, "rows": rows}
    path = pf.write_json(args.out, "lod_colour.json", result)
    print(f"\nwrote {path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Measure, fit, print; write JSON and a chart to benchmarks/results/lod_budget/."""
    p = pf.base_parser(__doc__.split("\n\n")[0], "lod_budget")
    p.set_defaults(threads=2)
    p.add_argument("--secondary", action="store_true",
                   help="calibrate the visibility model's weights of shadow and sky rays")
    p.add_argument("--colour", action="store_true",
                   help="calibrate the colour term's response within a pixel")
    args = p.parse_args(argv)
    probe = common.probe_pointviz()
    if not probe.available:
        print(probe.reason)
        return 2
    if args.secondary:
        return main_secondary(args)
    if args.colour:
        return main_colour(args)
    rows = []
    models = load(args)
    for model in models:
        rows += measure(model, args)
    model_fit = fit(rows)
    coef = model_fit["coefficients"]
    print("\ncoefficients " + ", ".join(f"{k} {v:.4g}" for k, v in coef.items())
          + f"; bound {model_fit['bound_scale']:.2f} x pred + {model_fit['bound_floor']:.4f}; "
          f"corr(pred, FLIP) {model_fit['corr']:.3f}; held-out {HELD_OUT} bounded: "
          f"{model_fit['held_out_bounded']}")
    print(f"{'model':<11}{'dist':>5}{'px':>5}{'FLIP':>8}{'pred':>8}{'bound':>8}  ok")
    for r in rows:
        print(f"{r['model']:<11}{r['factor']:>5g}{r['lod_pixels']:>5g}{r['flip']:>8.4f}"
              f"{r['predicted']:>8.4f}{r['bound']:>8.4f}  {'yes' if r['bounded'] else 'NO'}")
    result = {"benchmark": "lod_budget", "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
              "machine": pf.machine_info(), "args": {k: str(v) for k, v in vars(args).items()},
              "features": FEATURES, "fit": model_fit, "rows": rows,
              "models": {m.name: {"n": m.n, "notes": m.notes} for m in models}}
    plt = pf.pyplot()
    fig, ax = plt.subplots(figsize=(5, 4))
    for name in dict.fromkeys(r["model"] for r in rows):
        rr = [r for r in rows if r["model"] == name]
        ax.loglog([max(r["bound"], 1e-5) for r in rr], [max(r["flip"], 1e-5) for r in rr], "o",
                  ms=4, label=name + (" (held out)" if name == HELD_OUT else ""))
    lim = [1e-5, 1.0]
    ax.plot(lim, lim, "k--", lw=0.8, label="measured = bound")
    ax.set_xlabel("predicted bound (mean FLIP)")
    ax.set_ylabel("measured mean FLIP vs full detail")
    ax.legend(fontsize=7)
    chart = pf.save_figure(fig, args.out, "lod_budget_calibration.png")
    path = pf.write_json(args.out, "lod_budget.json", result)
    print(f"\nwrote {path} and {chart.name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
