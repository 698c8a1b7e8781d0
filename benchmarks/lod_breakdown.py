"""Issue 18: where a frame's time goes, for full detail, ``lod_pixels=1`` and the error budget.

``bench_lod.py``'s frames (480x360, 1 spp, shadows, sky occlusion, one reflection bounce, the
studio look over the default ground, one thread), each split into:

* ``primary``, ``reflection``: closest-hit queries of the camera and reflection rays (objects
  and ground), from the core's phase timers (``Frame.stats["phase_seconds"]``);
* ``shadow``: shadow and sky-visibility rays against the objects and the ground;
* ``shading``: the rest of a bounce (materials, lights, sampling the secondary rays);
* ``tile``: a tile's camera rays and its output (and the tiles proven to show only
  background, written without a ray: ``RenderSettings.background_shortcut``);
* ``rest``: the rest of ``render()`` (Python: the scene to the core, the exposure; the core's
  buffers and worker start);
* ``tone map``: ``Frame.to_srgb8()`` (outside ``render()``; what a saved frame costs on top).

Also the share of rays of each kind that met an object's bounds (and so were traced against its
tree at all), and the camera samples of the background tiles. Medians over ``--repeat`` interleaved repeats of process CPU time (the phases: the
tracer thread's CPU time; one thread by default).

Examples
--------
python benchmarks/lod_breakdown.py --models dragon-raw --factors 7.5
python benchmarks/lod_breakdown.py --quick
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_lod
import common
import paper_figures as pf

#: The frames split.
VARIANTS = (("full", {"lod_pixels": 0.0}), ("1px", {"lod_pixels": 1.0}),
            ("auto", {"lod_pixels": "auto", "max_error": bench_lod.DEFAULT_BUDGET}),
            ("coarsest", {"lod_pixels": bench_lod.COARSEST}))
#: Parts of a frame, in the order printed.
PARTS = ("primary", "reflection", "shadow", "shading", "tile", "rest", "tone map")


def split(scene, cam, v: dict, threads: int) -> dict:
    """One frame's parts in seconds, and its ray counts."""
    import pointviz

    t0 = time.process_time()
    fr = pointviz.render(scene, cam, spp=1, shadows=True, reflections=1, threads=threads,
                         phase_times=True, **v)
    total = time.process_time() - t0
    t0 = time.process_time()
    fr.to_srgb8()
    tone = time.process_time() - t0
    st = fr.stats
    ph = dict(st["phase_seconds"])
    out = {k: ph[k] for k in ("primary", "reflection", "shadow", "shading", "tile")}
    out["rest"] = total - sum(out.values())
    out["tone map"] = tone
    out["render"] = total
    rays = {k: (st[f"{k}_traced"], st[f"{k}_rays"]) for k in ("primary", "shadow", "reflection")}
    rays["background"] = (st["primary_background"], st["primary_rays"])
    return {"parts": out, "rays": rays}


def measure(model, args) -> list[dict]:
    import pointviz

    scene = pointviz.SurfelScene(model.cloud, variant="full", threads=args.threads)
    w, h = (pf.QUICK_PIXELS, pf.QUICK_PIXELS) if args.quick else (bench_lod.WIDTH, bench_lod.HEIGHT)
    base = pointviz.Camera.fit(model.cloud, width=w, height=h)
    rows = []
    for factor in args.factors:
        cam = pf.camera_at(base, factor)
        runs = {name: [] for name, _ in VARIANTS}
        for _ in range(args.repeat):
            for name, v in VARIANTS:
                runs[name].append(split(scene, cam, v, args.threads))
        for name, _ in VARIANTS:
            parts = {k: statistics.median(r["parts"][k] for r in runs[name])
                     for k in PARTS + ("render",)}
            rays = runs[name][0]["rays"]
            rows.append({"model": model.name, "factor": factor, "variant": name, "parts": parts,
                         "rays": rays})
            print(f"{model.name:<11}{factor:>5g}x {name:<9}" + " ".join(
                f"{k} {1e3 * parts[k]:6.2f}" for k in PARTS) + f"  render {1e3 * parts['render']:6.2f} ms"
                + "  traced " + " ".join(f"{k} {a}/{b}" for k, (a, b) in rays.items()), flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    p = pf.base_parser(__doc__.split("\n\n")[0], "lod_breakdown")
    p.add_argument("--size", type=int, default=bench_lod.ANALYTIC_SIZE, help="surfels of the torus")
    p.add_argument("--models", nargs="+", default=["torus", "dragon-raw", "armadillo"],
                   choices=["torus", "dragon-raw", "armadillo"])
    p.add_argument("--factors", nargs="+", type=float, default=[1.0, 7.5])
    args = p.parse_args(argv)
    common.probe_pointviz()
    if args.quick:
        args.repeat = 1
    rows = []
    for model in bench_lod.load(args):
        rows += measure(model, args)
    result = {"benchmark": "lod_breakdown", "date": time.strftime("%Y-%m-%d %H:%M:%S"),
              "machine": pf.machine_info(), "args": {k: str(v) for k, v in vars(args).items()},
              "rows": rows}
    print(f"wrote {pf.write_json(args.out, 'lod_breakdown.json', result)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
