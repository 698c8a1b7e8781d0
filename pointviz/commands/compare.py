"""``pointviz compare INPUT -o DIR``: surfels against meshes reconstructed from the same points,
rendered with the same shading, scored against a reference; writes DIR/index.html."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from ..errors import InputError
from ..interrupt import stage
from ..settings import check_int
from .common import parse_up


def add_parser(sub) -> None:
    p = sub.add_parser("compare", help="quality/speed report: surfels vs reconstructed meshes",
                       description=__doc__)
    p.add_argument("input", help="point cloud, mesh, .conf scans, or demo/sphere/torus/box")
    p.add_argument("--reference", metavar="MESH", help="reference mesh (default: the input "
                   "mesh, the exact shape, else surfels at full detail)")
    p.add_argument("--camera", metavar="CAM.json", help="camera file")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="report folder")
    p.add_argument("--methods", default=None,
                   help="comma-separated subset of discs,surfels-paper,surfels-smooth,poisson,"
                        "ball-pivoting,alpha-shape")
    p.add_argument("--quick", action="store_true", help="small sizes (seconds, for tests)")
    p.add_argument("--stability", action="store_true", help="also run the stability sweeps")
    p.add_argument("--max-points", type=int, default=None, metavar="N",
                   help="subsample the input to N points")
    p.add_argument("--up", default=None, metavar="AXIS",
                   help="the data's up direction: x, y, z, -x, -y, -z or X,Y,Z (--up=-z); "
                        "default: the file's convention")
    p.add_argument("--width", type=int, default=None)
    p.add_argument("--height", type=int, default=None)
    p.add_argument("--spp", type=int, default=None)
    p.add_argument("--overwrite", action="store_true",
                   help="replace the report in DIR if there is one")
    p.set_defaults(run=run)


def run(args) -> int:
    from ..comparison import compare
    from ..comparison.run import Settings

    stage("imported")
    output = Path(args.output)
    existing = output / "index.html"
    if existing.exists() and not args.overwrite:
        raise FileExistsError(f"{existing}: a report is already there; pass --overwrite to replace it")
    settings = Settings.quick() if args.quick else Settings.full()
    for key in ("width", "height", "spp", "max_points"):
        value = getattr(args, key)
        if value is not None:
            setattr(settings, key, check_int(value, f"--{key.replace('_', '-')}"))
    up = parse_up(args.up)
    if up is not None:
        settings.up = up
    methods = None if args.methods is None else [m.strip() for m in args.methods.split(",") if m.strip()]
    with staged_folder(output, args.overwrite) as staging:
        doc = compare(args.input, reference=args.reference, camera=args.camera, out_dir=staging,
                      methods=methods, quick=args.quick, stability=args.stability,
                      settings=settings, overwrite=args.overwrite)
    print(f"wrote {existing} ({len(doc['entries'])} method settings)")
    return 0


@contextlib.contextmanager
def staged_folder(output: Path, overwrite: bool):
    """A hidden folder beside ``output`` to write a report into. Its files move into ``output``
    only once the report is complete: Ctrl-C or an error leaves ``output`` as it was and no
    temporary folder behind."""
    if output.exists() and not output.is_dir():
        raise InputError(f"{output}: is a file, not a folder")
    output.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{output.name}.", suffix=".part", dir=output.parent))
    try:
        yield staging
        stage("writing")
        files = sorted(p.relative_to(staging) for p in staging.rglob("*") if p.is_file())
        clash = [f for f in files if (output / f).exists()]
        if clash and not overwrite:
            raise FileExistsError(f"{output / clash[0]}: exists; pass --overwrite to replace it")
        for f in files:
            (output / f).parent.mkdir(parents=True, exist_ok=True)
            os.replace(staging / f, output / f)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
