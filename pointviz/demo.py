"""``python -m pointviz.demo``: render the built-in scene and write a short report.

Needs no data: the scene is generated (a sphere, a torus and a box of surfels over a mirror
floor). Writes ``OUT/demo.png`` and ``OUT/index.html``.
"""

from __future__ import annotations

import argparse
import html
import json
import sys
import time
from dataclasses import fields
from pathlib import Path

from .commands.common import add_setting_option
from .settings import RenderSettings


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pointviz.demo", description=__doc__)
    parser.add_argument("--out", default="out", help="output folder (default: out)")
    spp = next(f for f in fields(RenderSettings) if f.name == "spp")
    add_setting_option(parser, spp)  # flag, default and help from RenderSettings
    parser.add_argument("--detail", type=float, default=1.0, help="surfel density multiplier")
    parser.add_argument("--no-compare", action="store_true",
                        help="skip the comparison report (surfels vs reconstructed meshes)")
    args = parser.parse_args(argv)

    from .images import atomic_write_bytes
    from .progress import ProgressBar
    from .rendering import render
    from .shapes import demo_scene

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    scene, camera = demo_scene(args.detail)
    for i in range(len(scene.objects)):
        scene.surfel_scene(i)
    t_build = time.perf_counter() - t0
    frame = render(scene, camera, spp=args.spp, progress=ProgressBar("demo", enabled=True))
    png = frame.save(out / "demo.png", overwrite=True)
    n = sum(scene.surfel_scene(i).n_surfels for i in range(len(scene.objects)))
    mem = sum(scene.surfel_scene(i).memory_bytes for i in range(len(scene.objects)))
    facts = {
        "surfels": n,
        "build_seconds": round(t_build, 3),
        "bytes_per_surfel": round(mem / n, 1),
        "render_seconds": round(frame.stats["seconds"], 3),
        "size": f"{camera.width}x{camera.height}",
        "spp": args.spp,
        "rays": frame.stats["primary_rays"] + frame.stats["shadow_rays"] + frame.stats["reflection_rays"],
        "mrays_per_second": round(frame.stats["rays_per_second"] / 1e6, 2),
    }
    compare_link = ""
    if not args.no_compare:
        from .comparison import compare

        doc = compare("demo", out_dir=out / "compare", quick=True, overwrite=True,
                      log=lambda *a, **k: None)
        best = min(doc["entries"], key=lambda e: e["metrics"]["flip"])
        facts["compare_best"] = f"{best['label']}: FLIP {best['metrics']['flip']:.4f}"
        compare_link = ('<p>Quality check: <a href="compare/index.html">surfels against meshes '
                        'reconstructed from the same points</a> (speed against accuracy).</p>')
    labels = {"surfels": "surfels", "build_seconds": "tree build (s)",
              "bytes_per_surfel": "bytes per surfel (tree included)",
              "render_seconds": "render (s)", "size": "image size", "spp": "samples per pixel",
              "rays": "rays traced (primary, shadow, reflection)",
              "mrays_per_second": "million rays per second", "compare_best": "most accurate method"}
    rows = "".join(f"<tr><th>{html.escape(labels.get(k, k))}</th><td>{html.escape(str(v))}</td></tr>"
                   for k, v in facts.items())
    page = f"""<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>pointviz demo</title><style>body{{font-family:sans-serif;margin:2em;max-width:900px}}
img{{max-width:100%}} th{{text-align:left;padding-right:1em}}</style></head><body>
<h1>pointviz demo</h1><p>Surfels ray traced directly (no meshing): shadows and a mirror floor.</p>
<img src="{png.name}" alt="ray-traced demo scene"><table>{rows}</table>{compare_link}</body></html>"""
    atomic_write_bytes(out / "index.html", page.encode(), overwrite=True)
    atomic_write_bytes(out / "demo.json", json.dumps(facts, indent=2).encode(), overwrite=True)
    print(f"wrote {png} and {out / 'index.html'}: {n} surfels, render {facts['render_seconds']} s")
    if compare_link:
        print(f"wrote {out / 'compare' / 'index.html'}: best {facts['compare_best']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
