"""The paper's open questions, measured: where to switch from boxes to spheres, and another LoD rule.

**Q1 — the box/sphere switch level.** A cost model predicts, from the tree's own node data
(``scene.tree.node_arrays()`` of a tree built with ``box_depth="all"``), the per-ray count of
visited nodes, box tests, sphere tests and disk tests for every switch level k (levels < k use
boxes). A ray reaches a node with the geometric probability of section 2.2.2: the number of
primary rays that cross a convex bound is its projected area divided by the pixel footprint
area at its distance, ``A / (pixel_angle * t)^2`` (A = pi r^2 for a sphere; for a box, its area
projected along the direction from the eye; ``--isotropic`` uses the mean projected area, a
quarter of the surface area, as in the paper's S_B / S_A). Nodes below a LoD stop are not
visited; a LoD stop costs two disk tests, a leaf ``count`` disk tests, any other visited node two
bound tests of its children's type. Occlusion (front-to-back early exit) is ignored, so absolute
counts are upper bounds; what matters is how they change with k.

The per-operation costs (visit, box test, sphere test, disk test) are fitted by non-negative
least squares to four micro-benchmark runs on the same rays — boxes everywhere and spheres
everywhere, each with LoD on and off — i.e. only the two ends of the sweep. The model's choice is
then checked against an exhaustive sweep of k = 0..depth (time and nodes visited, interleaved
repeats) that it never saw, and against the current rule ``box_depth="auto"`` (boxes while they
cost <= 1.5 B/surfel). Box memory is 24 B per boxed node and is reported for every k.

**Q2 — a LoD criterion other than projected sphere size.** ``lod_criterion="size"`` (the paper's)
against ``"deviation"`` (the node's deviation from its mean plane, diameter x sin(normal-cone
half-angle), projected; ``lod_max_extent`` caps the node size): both swept over ``lod_pixels`` at
several distances; time against image error (FLIP and PSNR of the normal image against the
no-LoD image) with the Pareto front of each.

Examples
--------
python benchmarks/paper_questions.py --quick
python benchmarks/paper_questions.py --size 1e6
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import paper_figures as pf

#: Bytes of one node's box (two float3): the memory side of the switch level.
BOX_BYTES = 24
#: The current default rule in pointviz/surfels.py (boxes while <= this many bytes per surfel).
AUTO_BUDGET = 1.5
#: A switch level "ties" with the best when its measured time is within this fraction: the
#: sweep's own repeat-to-repeat noise on a shared machine is of this order.
TIE = 0.03

#: Q2: LoD thresholds swept for each criterion (pixels), and the distances (x fitted distance).
LOD_PIXELS = (0.5, 1.0, 2.0, 4.0, 8.0)
DEVIATION_PIXELS = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0)
CRITERION_DISTANCES = (1.0, 2.0, 4.0)
#: Q1: distances (x fitted) whose k = 0 and k = depth runs calibrate the model's costs.
CALIBRATION_DISTANCES = (1.0, 2.0, 4.0)


# ----------------------------------------------------------------------------------------------
# Q1: cost model


def tree_levels(tree) -> np.ndarray:
    """Level of every node (breadth-first layout: level L is level_start[L]..level_start[L+1])."""
    ls = np.asarray(tree.level_start)
    return np.repeat(np.arange(len(ls) - 1), np.diff(ls))


def predicted_counts(tree, camera, origin, box_depth: int, lod: bool, lod_pixels: float,
                     n_rays: int, isotropic: bool = False, depth_image=None) -> dict:
    """Expected per-ray visits and tests of a traversal with boxes at levels < ``box_depth``.

    Parameters
    ----------
    tree : pointviz._core.SurfelTree
        Built with boxes at every level (``box_depth="all"``).
    camera : pointviz.Camera
    origin : (3,) float64
        The tree's local origin (node data are relative to it).
    box_depth : int
    lod : bool
    lod_pixels : float
    n_rays : int
        Rays of the image (the probabilities are divided by it).
    isotropic : bool
        Mean projected area (surface / 4) instead of the area projected toward the eye.
    depth_image : (h, w) float, optional
        Distance of the first hit per pixel (inf on a miss). When given, a node whose bound
        starts behind the first hit at the pixel of its centre is not visited (the front-to-back
        traversal skips it once the ray has a hit); its parent still pays the bound test.

    Returns
    -------
    dict
        ``visits``, ``box_tests``, ``sphere_tests``, ``disk_tests`` per ray.
    """
    arr = tree.node_arrays()
    c, r = arr["center"].astype(np.float64), arr["radius"].astype(np.float64)
    boxes = arr["boxes"].astype(np.float64)
    count, index = arr["count"], arr["index"]
    level = tree_levels(tree)
    eye = np.asarray(camera.eye, dtype=np.float64) - origin
    to = c - eye
    dist = np.linalg.norm(to, axis=1)
    u = to / dist[:, None]
    ext = boxes[:, 3:] - boxes[:, :3]
    if isotropic:
        a_box = 0.5 * (ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0])
    else:
        a_box = (ext[:, 1] * ext[:, 2] * np.abs(u[:, 0]) + ext[:, 0] * ext[:, 2] * np.abs(u[:, 1])
                 + ext[:, 0] * ext[:, 1] * np.abs(u[:, 2]))
    a_sph = np.pi * r * r
    pa = camera.pixel_angle
    area = np.where(level < box_depth, a_box, a_sph)
    # Rays crossing the bound; a bound closer than the footprint is still crossed by <= all rays.
    p = np.minimum(area / (pa * dist) ** 2, n_rays) / n_rays
    leaf = count > 0
    t2 = np.einsum("ij,j->i", to, np.asarray(camera.forward, dtype=np.float64))
    stop = (~leaf) & lod & (t2 > 0) & (2.0 * r <= lod_pixels * pa * t2)
    # Alive: no ancestor stopped (top-down over the breadth-first levels).
    alive = np.ones(len(r), dtype=bool)
    ls = np.asarray(tree.level_start)
    for lvl in range(len(ls) - 1):
        nodes = np.arange(ls[lvl], ls[lvl + 1])
        inner = nodes[~leaf[nodes]]
        ok = alive[inner] & ~stop[inner]
        alive[index[inner]] = ok
        alive[index[inner] + 1] = ok
    visible = np.ones(len(r), dtype=bool)
    if depth_image is not None:
        h, w = depth_image.shape
        uv = np.asarray(camera.project(c + origin)[0])
        ok = np.isfinite(uv).all(axis=1)
        col = np.clip(np.nan_to_num(uv[:, 0]).astype(np.int64), 0, w - 1)
        row = np.clip(np.nan_to_num(uv[:, 1]).astype(np.int64), 0, h - 1)
        bound_near = dist - np.where(level < box_depth, 0.5 * np.linalg.norm(ext, axis=1), r)
        visible = ~ok | (bound_near <= depth_image[row, col])
    pv = p * alive * visible
    expand = (~leaf) & (~stop)
    child_box = (level + 1) < box_depth
    return {"visits": float(pv.sum()),
            "box_tests": float(2 * pv[expand & child_box].sum()),
            "sphere_tests": float(2 * pv[expand & ~child_box].sum()),
            "disk_tests": float((pv * np.where(stop, 2, np.where(leaf, count, 0))).sum())}


OPS = ("visits", "box_tests", "sphere_tests", "disk_tests")


def fit_costs(calib: list[tuple[dict, float]]) -> np.ndarray:
    """Non-negative least squares of seconds/ray = sum(cost_op * count_op) over calibration runs.

    Parameters
    ----------
    calib : list of (predicted counts dict, measured seconds per ray)

    Returns
    -------
    (4,) float64
        Seconds per visit, box test, sphere test, disk test.
    """
    from scipy.optimize import nnls

    a = np.array([[c[k] for k in OPS] for c, _ in calib])
    b = np.array([t for _, t in calib])
    scale = a.max(axis=0)
    scale[scale == 0] = 1.0
    x, _ = nnls(a / scale, b)
    return x / scale


def switch_level(model: pf.Model, args) -> dict:
    """Q1 on one model: model prediction for every k, exhaustive measured sweep, auto rule.

    The model's four per-operation costs are fitted on the two ends of the sweep only (k = 0 and
    k = depth), with LoD on and off, at the fitted distance and at CALIBRATION_DISTANCES (more
    equations than unknowns, different mixes of operations); every intermediate k at the fitted
    distance is a prediction checked against the measured sweep.
    """
    import pointviz
    from pointviz.surfels import _auto_box_depth

    px = pf.QUICK_PIXELS if args.quick else pf.PAPER_WIDTH
    base = pf.fit_camera(model.cloud, px)
    scene = pointviz.SurfelScene(model.cloud, variant="full", box_depth="all", threads=args.threads)
    tree, origin, depth, n = scene.tree, scene.origin, scene.depth, scene.n_surfels
    ls = np.asarray(tree.level_start)
    ks = list(range(depth + 1))
    configs = {"lod": {"lod": True, "cull": True}, "nolod": {"lod": False, "cull": False}}

    def setup(factor):
        cam = pf.camera_at(base, factor)
        rays = pf.rays64(cam)
        ref, _ = pf.core_cast(scene, rays, 0.0, args.threads)
        depth_img = (ref["t_hit"].astype(np.float64)
                     * np.linalg.norm(rays[:, 3:], axis=1)).reshape(cam.height, cam.width)
        return cam, rays, depth_img

    def predict(cam, depth_img, k, lod, isotropic):
        return predicted_counts(tree, cam, origin, k, lod, scene.lod_pixels, cam.width * cam.height,
                                isotropic=isotropic, depth_image=depth_img)

    cam, rays, depth_img = setup(1.0)
    pa = {"lod": cam.pixel_angle, "nolod": 0.0}
    # Measured sweep: every (config, k) once per repeat, all interleaved.
    calls = {(cfg, k): (lambda cfg=cfg, k=k: pf.core_cast(scene, rays, pa[cfg], args.threads,
                                                          box_depth=k, **configs[cfg]))
             for cfg in configs for k in ks}
    times = pf.interleaved(calls, args.repeat, args.clock)
    rec = {"model": model.name, "n": n, "depth": depth, "pixels": px,
           "level_start": ls.tolist(), "configs": {}, "calibration": []}
    models = {"pred": False, "pred_iso": True}
    for cfg, knobs in configs.items():
        rows = []
        for k in ks:
            _, st = pf.core_cast(scene, rays, pa[cfg], args.threads, stats=True, box_depth=k, **knobs)
            row = {"k": k, "seconds": times[(cfg, k)]["median"], "runs": times[(cfg, k)]["runs"],
                   "nodes_visited": st["nodes_visited"], "disk_tests": st["disk_tests"],
                   "box_bytes_per_surfel": BOX_BYTES * int(ls[min(k, depth)]) / n}
            for key, iso in models.items():
                row[key] = predict(cam, depth_img, k, knobs["lod"], iso)
            rows.append(row)
        rec["configs"][cfg] = {"rows": rows}
    # Calibration runs: the two ends, LoD on/off, at every calibration distance.
    calib = {key: [] for key in models}
    for factor in (1.0,) + tuple(f for f in CALIBRATION_DISTANCES if f != 1.0):
        if factor == 1.0:
            for cfg, cfgrec in rec["configs"].items():
                for i in (0, len(ks) - 1):
                    row = cfgrec["rows"][i]
                    for key in models:
                        calib[key].append((row[key], row["seconds"] / len(rays)))
            continue
        c2, r2, d2 = setup(factor)
        pa2 = {"lod": c2.pixel_angle, "nolod": 0.0}
        calls2 = {(cfg, k): (lambda cfg=cfg, k=k, r2=r2, pa2=pa2: pf.core_cast(
                                 scene, r2, pa2[cfg], args.threads, box_depth=k, **configs[cfg]))
                  for cfg in configs for k in (0, depth)}
        t2 = pf.interleaved(calls2, args.repeat, args.clock)
        for (cfg, k), t in t2.items():
            for key, iso in models.items():
                calib[key].append((predict(c2, d2, k, configs[cfg]["lod"], iso),
                                   t["median"] / len(r2)))
            rec["calibration"].append({"factor": factor, "config": cfg, "k": k,
                                       "seconds": t["median"]})
    for key in models:
        costs = fit_costs(calib[key])
        rec[f"costs_ns_{key}"] = dict(zip(OPS, (1e9 * costs).tolist()))
        for cfgrec in rec["configs"].values():
            for row in cfgrec["rows"]:
                row[f"model_seconds_{key}"] = len(rays) * float(
                    sum(c * row[key][op] for c, op in zip(costs, OPS)))
    k_auto = min(_auto_box_depth(n, 8), depth)
    rec["k_auto"] = k_auto
    for cfg, cfgrec in rec["configs"].items():
        rows = cfgrec["rows"]
        meas = np.array([r["seconds"] for r in rows])
        best = int(np.argmin(meas))
        summary = {"k_best_measured": best, "best_seconds": float(meas[best]),
                   "k_ties": [r["k"] for r in rows if r["seconds"] <= (1 + TIE) * meas[best]],
                   "auto": {"k": k_auto, "excess": float(meas[k_auto] / meas[best] - 1)}}
        for key in models:
            model_t = np.array([r[f"model_seconds_{key}"] for r in rows])
            km = int(np.argmin(model_t))
            # Cheapest-memory level the model says is within TIE of its own optimum.
            k_knee = int(np.flatnonzero(model_t <= (1 + TIE) * model_t.min())[0])
            summary[key] = {"k_model": km, "excess": float(meas[km] / meas[best] - 1),
                            "k_knee": k_knee, "knee_excess": float(meas[k_knee] / meas[best] - 1),
                            "knee_box_bytes_per_surfel": rows[k_knee]["box_bytes_per_surfel"],
                            "corr_time": float(np.corrcoef(model_t, meas)[0, 1]),
                            "corr_nodes": float(np.corrcoef(
                                [r[key]["visits"] for r in rows],
                                [r["nodes_visited"] for r in rows])[0, 1])}
        cfgrec["summary"] = summary
    return rec


def print_switch(rec: dict) -> None:
    """Table of the sweep with the model's prediction next to it."""
    print(f"\n== Q1 switch level: {rec['model']} ({rec['n']:,} surfels, depth {rec['depth']}), "
          f"fitted costs ns/op (view model): "
          + ", ".join(f"{k} {v:.2f}" for k, v in rec["costs_ns_pred"].items()))
    for cfg, cfgrec in rec["configs"].items():
        print(f"-- {cfg}: k = levels with boxes")
        print(f"{'k':>3}{'meas ms':>9}{'model ms':>9}{'iso ms':>8}{'nodes/ray':>10}"
              f"{'pred nodes':>11}{'box B/surfel':>13}")
        for r in cfgrec["rows"]:
            print(f"{r['k']:>3}{1e3 * r['seconds']:>9.1f}{1e3 * r['model_seconds_pred']:>9.1f}"
                  f"{1e3 * r['model_seconds_pred_iso']:>8.1f}{r['nodes_visited']:>10.1f}"
                  f"{r['pred']['visits']:>11.1f}{r['box_bytes_per_surfel']:>13.2f}")
        s = cfgrec["summary"]
        print(f"   best measured k={s['k_best_measured']} (ties within {100 * TIE:.0f}%: "
              f"{s['k_ties']}); auto k={s['auto']['k']} (+{100 * s['auto']['excess']:.1f}%)")
        for key, label in (("pred", "view model"), ("pred_iso", "isotropic model")):
            m = s[key]
            print(f"   {label}: argmin k={m['k_model']} (+{100 * m['excess']:.1f}% vs best), knee "
                  f"k={m['k_knee']} (+{100 * m['knee_excess']:.1f}%, "
                  f"{m['knee_box_bytes_per_surfel']:.2f} B/surfel); corr(time)={m['corr_time']:.3f}"
                  f" corr(nodes)={m['corr_nodes']:.3f}")


def chart_switch(records: list, out_dir: Path) -> Path:
    """Measured and modelled time against the switch level, with box memory on a second axis."""
    plt = pf.pyplot()
    fig, axes = plt.subplots(len(records), 2, figsize=(11, 3.3 * len(records)), squeeze=False)
    for row_axes, rec in zip(axes, records):
        for ax, (cfg, cfgrec) in zip(row_axes, rec["configs"].items()):
            rows = cfgrec["rows"]
            k = [r["k"] for r in rows]
            ax.plot(k, [1e3 * r["seconds"] for r in rows], "-o", ms=3, label="measured")
            ax.plot(k, [1e3 * r["model_seconds_pred"] for r in rows], "--", label="model (view)")
            ax.plot(k, [1e3 * r["model_seconds_pred_iso"] for r in rows], ":", label="model (isotropic)")
            s = cfgrec["summary"]
            ax.axvline(s["auto"]["k"], color="gray", lw=0.8, label="current auto")
            ax.axvline(s["pred"]["k_knee"], color="C1", lw=0.8, ls="--", label="model knee")
            ax.set_xlabel("switch level k (levels < k use boxes)")
            ax.set_ylabel("traversal ms (1 thread)")
            ax.set_title(f"{rec['model']} {rec['n'] / 1e6:.2g}M, {cfg}")
            ax2 = ax.twinx()
            ax2.semilogy(k, [max(r["box_bytes_per_surfel"], 1e-4) for r in rows], color="0.6", lw=0.8)
            ax2.set_ylabel("box bytes / surfel", color="0.5")
            ax.legend(fontsize=7, loc="upper right")
    fig.suptitle("Q1: where to switch from boxes to spheres (time: process CPU, median)", y=1.02)
    return pf.save_figure(fig, out_dir, "q1_switch_level.png")


# ----------------------------------------------------------------------------------------------
# Q2: LoD criteria


def pareto(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the (time, error) points no other point beats on both (lower is better)."""
    keep = []
    for i, (t, e) in enumerate(points):
        if not any((t2 <= t and e2 <= e) and (t2 < t or e2 < e) for t2, e2 in points):
            keep.append(i)
    return keep


def lod_criteria(model: pf.Model, args) -> dict:
    """Q2: time vs image error of the size and deviation criteria over lod_pixels and distance."""
    import pointviz

    px = pf.QUICK_PIXELS if args.quick else pf.PAPER_WIDTH
    base = pf.fit_camera(model.cloud, px)
    scene = pointviz.SurfelScene(model.cloud, variant="full", threads=args.threads)
    settings = ([("size", lp, None) for lp in LOD_PIXELS]
                + [("deviation", lp, None) for lp in DEVIATION_PIXELS]
                + [("deviation", lp, 16.0) for lp in (2.0, 4.0, 8.0)])
    rec = {"model": model.name, "n": model.n, "pixels": px, "distances": []}
    for factor in CRITERION_DISTANCES:
        cam = pf.camera_at(base, factor)
        rays = pf.rays64(cam)

        calls = {"no lod": lambda r=rays: pf.core_cast(scene, r, 0.0, args.threads)}
        for s in settings:
            calls[s] = (lambda s=s, r=rays, c=cam: pf.core_cast(scene, r, c.pixel_angle, args.threads,
                                                                **_criterion_knobs(*s)))
        times = pf.interleaved(calls, args.repeat, args.clock)
        ref_out, _ = pf.core_cast(scene, rays, 0.0, args.threads)
        ref = pf.normal_image(ref_out, cam)
        rows = []
        for s in settings:
            out, st = pf.core_cast(scene, rays, cam.pixel_angle, args.threads, stats=True,
                                   **_criterion_knobs(*s))
            img = pf.normal_image(out, cam)
            rows.append({"criterion": s[0], "lod_pixels": s[1], "lod_max_extent": s[2] or 8.0,
                         "seconds": times[s]["median"], "nodes_visited": st["nodes_visited"],
                         "flip": pf.flip(ref, img), "psnr_db": pf.psnr(ref, img)})
        rec["distances"].append({"factor": factor, "no_lod_seconds": times["no lod"]["median"],
                                 "rows": rows})
    return rec


def _criterion_knobs(crit: str, lod_pixels: float, max_extent: float | None) -> dict:
    """TraceOptions overrides of one Q2 setting."""
    from pointviz import _core

    names = {m.lower(): m for m in dir(_core.LodCriterion) if not m.startswith("_")}
    k = {"lod_criterion": names.get(crit, crit), "lod_pixels": lod_pixels}
    if max_extent is not None:
        k["lod_max_extent"] = max_extent
    return k


def matched_comparison(rows: list) -> dict:
    """Deviation's time at the image error of size with lod_pixels 1 (interpolated on its front)."""
    size1 = next(r for r in rows if r["criterion"] == "size" and r["lod_pixels"] == 1.0)
    dev = sorted((r for r in rows if r["criterion"] == "deviation"), key=lambda r: r["flip"])
    ok = [r for r in dev if r["flip"] <= size1["flip"]]
    best = min(ok, key=lambda r: r["seconds"]) if ok else None
    return {"size_1px": {"seconds": size1["seconds"], "flip": size1["flip"]},
            "deviation_best_at_same_or_lower_flip": best,
            "time_ratio": best["seconds"] / size1["seconds"] if best else None}


def print_criteria(rec: dict) -> None:
    """Q2 tables."""
    print(f"\n== Q2 LoD criteria: {rec['model']} ({rec['n']:,} surfels)")
    for d in rec["distances"]:
        print(f"-- distance {d['factor']:g}x fit: no LoD {1e3 * d['no_lod_seconds']:.1f} ms")
        print(f"{'criterion':<10}{'px':>5}{'ext':>5}{'ms':>8}{'nodes':>7}{'FLIP':>8}{'PSNR':>7}")
        front = set(pareto([(r["seconds"], r["flip"]) for r in d["rows"]]))
        for i, r in enumerate(d["rows"]):
            print(f"{r['criterion']:<10}{r['lod_pixels']:>5g}{r['lod_max_extent']:>5g}"
                  f"{1e3 * r['seconds']:>8.1f}{r['nodes_visited']:>7.1f}{r['flip']:>8.4f}"
                  f"{r['psnr_db']:>7.1f}{'  pareto' if i in front else ''}")
        m = d["matched"] = matched_comparison(d["rows"])
        b = m["deviation_best_at_same_or_lower_flip"]
        if b:
            print(f"   at FLIP <= size@1px ({m['size_1px']['flip']:.4f}): deviation px={b['lod_pixels']:g}"
                  f" ext={b['lod_max_extent']:g} takes {m['time_ratio']:.2f}x the time of size@1px")


def chart_criteria(rec: dict, out_dir: Path) -> Path:
    """Time against FLIP per distance, one series per criterion (Pareto fronts drawn)."""
    plt = pf.pyplot()
    ds = rec["distances"]
    fig, axes = plt.subplots(1, len(ds), figsize=(4.5 * len(ds), 3.6), squeeze=False)
    for ax, d in zip(axes[0], ds):
        for crit, mk in (("size", "o-"), ("deviation", "s-")):
            rows = sorted((r for r in d["rows"] if r["criterion"] == crit
                           and r["lod_max_extent"] == 8.0), key=lambda r: r["lod_pixels"])
            ax.plot([r["flip"] for r in rows], [1e3 * r["seconds"] for r in rows], mk, ms=4,
                    label=f"{crit} (max extent 8)" if crit == "deviation" else crit)
            for r in rows:
                ax.annotate(f"{r['lod_pixels']:g}", (r["flip"], 1e3 * r["seconds"]), fontsize=6)
        ext = [r for r in d["rows"] if r["lod_max_extent"] == 16.0]
        ax.plot([r["flip"] for r in ext], [1e3 * r["seconds"] for r in ext], "^", ms=4,
                label="deviation (max extent 16)")
        ax.axhline(1e3 * d["no_lod_seconds"], color="gray", ls="--", lw=0.8, label="no LoD")
        ax.set_xlabel("FLIP vs no-LoD (normal image)")
        ax.set_ylabel("traversal ms (1 thread)")
        ax.set_title(f"{rec['model']} at {d['factor']:g}x fit distance")
        ax.legend(fontsize=6)
    fig.suptitle("Q2: LoD criterion, time vs image error (labels: lod_pixels)", y=1.03)
    return pf.save_figure(fig, out_dir, "q2_lod_criteria.png")


# ----------------------------------------------------------------------------------------------
# main


def main(argv: list[str] | None = None) -> int:
    """Run Q1 and Q2; print the tables, write JSON and PNGs; return the exit code."""
    p = pf.base_parser(__doc__.split("\n\n")[0], "paper_questions")
    p.add_argument("--size", type=float, default=1e6, help="Armadillo surfels (default 1e6)")
    p.add_argument("--models", default="armadillo,dragon",
                   help="models for Q1 (Q2 uses the first): armadillo, dragon (scans, not upsampled)")
    p.add_argument("--questions", default="1,2")
    p.add_argument("--replot", action="store_true",
                   help="redraw the charts from the JSON already in --out (no measurement)")
    args = p.parse_args(argv)
    if args.replot:
        import json

        result = json.loads((args.out / "paper_questions.json").read_text())
        if result["q1"]:
            chart_switch(result["q1"], args.out)
        if result["q2"]:
            chart_criteria(result["q2"], args.out)
        return 0
    if args.quick:
        args.repeat = 1
    probe = common.probe_pointviz()
    if not probe.available:
        print(probe.reason)
        return 2
    qs = {q.strip() for q in args.questions.split(",")}
    result = {"benchmark": "paper_questions", "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
              "machine": pf.machine_info(), "args": {k: str(v) for k, v in vars(args).items()},
              "timing": "median of --repeat interleaved runs, --clock (cpu: process CPU time)",
              "q1": [], "q2": None}
    # The dragon scans as they are (no upsampling): a second tree shape and size for Q1.
    models = []
    for name in (m.strip() for m in args.models.split(",") if m.strip()):
        models += pf.load_models(args, [name], int(args.size) if name == "armadillo" else 0)
    charts = []
    if "1" in qs:
        for model in models:
            rec = switch_level(model, args)
            print_switch(rec)
            result["q1"].append(rec)
        charts.append(chart_switch(result["q1"], args.out))
    if "2" in qs and models:
        rec = lod_criteria(models[0], args)
        print_criteria(rec)
        result["q2"] = rec
        charts.append(chart_criteria(rec, args.out))
    result["peak_rss_bytes"] = common.peak_rss_bytes()
    result["charts"] = [c.name for c in charts]
    path = pf.write_json(args.out, "paper_questions.json", result)
    print(f"\nwrote {path} and {', '.join(c.name for c in charts)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
