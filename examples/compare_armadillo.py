"""Surfels against meshes reconstructed from the same points, on the Stanford Armadillo.

The Armadillo mesh is the reference: it is rendered through the embreex mesh backend with the
same camera, lights and shading as the surfels. Writes ``OUT/index.html``, ``OUT/metrics.json``
and the speed-accuracy chart ``OUT/speed_accuracy.png``.

    python examples/compare_armadillo.py [OUT] [--stability]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pointviz

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", nargs="?", default="compare_armadillo", help="report folder")
    ap.add_argument("--stability", action="store_true", help="also run the stability sweeps")
    args = ap.parse_args(argv)
    mesh = DATA / "stanford_armadillo" / "Armadillo.ply"
    if not mesh.is_file():
        print(f"{mesh} not found: this example needs ../shared/data", file=sys.stderr)
        return 1
    doc = pointviz.compare(mesh, out_dir=Path(args.out), stability=args.stability)
    print(f"{'method':28s} {'pre s':>7s} {'render s':>8s} {'FLIP':>7s} {'normal':>7s} {'holes':>6s}")
    for e in doc["entries"]:
        t, m = e["times"], e["metrics"]
        print(f"{e['label']:28s} {t['preprocess']:7.2f} {t['render']:8.2f} {m['flip']:7.4f} "
              f"{m['normal_error_deg']:7.2f} {m['holes']:6.4f}")
    print(f"report: {doc['report']}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
