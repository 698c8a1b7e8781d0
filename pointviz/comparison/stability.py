"""Where methods fail: sweeps of sampling density, position noise, normal noise (and missing
normals), thin structures, open boundaries and grazing views, on generated shapes with exact
references. Per method the error along each sweep and the first value where it breaks; the
report's advice is derived from these numbers."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from .. import shapes
from ..camera import Camera
from ..cloud import PointCloud
from ..meshes import MeshGeometry
from . import analytic, metrics
from .settings import Settings, render_geometry
from .style import STYLE

#: A method "breaks" at the first sweep value where one of these is exceeded: a FLIP of 0.1 is
#: a clearly visible difference over the whole object, 5% of the reference silhouette missing is
#: a visible hole, and 10 degrees of mean normal error visibly changes the shading.
BREAK_FLIP = 0.10
BREAK_HOLES = 0.05
BREAK_NORMAL_DEG = 10.0

#: Methods of the sweeps (a representative setting of each family).
STABILITY_METHODS = ("discs", "surfels-smooth", "poisson", "ball-pivoting")


def _noisy_normals(n, sigma_deg, rng):
    t = rng.normal(size=n.shape)
    t -= (t * n).sum(1, keepdims=True) * n
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    ang = np.radians(np.abs(rng.normal(0, sigma_deg, len(n))))[:, None]
    return n * np.cos(ang) + t * np.sin(ang)


def sweeps(quick: bool):
    """Yields (sweep name, x label, [(value, label, cloud, (V, F, smooth), camera)])."""
    rng = np.random.default_rng(7)
    cam_s = lambda w, h: Camera.look_at((0, 0.8, 3.0), (0, 0, 0), width=w, height=h)  # noqa: E731
    sph = analytic.sphere_mesh(1.0, res=256)
    n0 = 3000 if quick else 8000
    out = []
    dens = (300, 1200, 5000) if quick else (300, 1000, 3000, 10000, 30000)
    out.append(("sampling density", "points on the unit sphere",
                [(n, str(n), shapes.sphere(n), sph + (True,), cam_s) for n in dens]))
    noise = (0.0, 0.01, 0.04) if quick else (0.0, 0.005, 0.01, 0.02, 0.04)
    rows = []
    for s in noise:
        c = shapes.sphere(n0)
        p = c.points + rng.normal(0, s, c.points.shape)
        rows.append((s, f"{s:g}", PointCloud(p, c.normals, c.radii), sph + (True,), cam_s))
    out.append(("position noise", "noise sigma / radius", rows))
    rows = []
    for k, s in enumerate((0, 20, 40) if quick else (0, 10, 20, 40)):
        c = shapes.sphere(n0)
        rows.append((k, f"{s} deg", PointCloud(c.points, _noisy_normals(c.normals, s, rng), c.radii),
                     sph + (True,), cam_s))
    c = shapes.sphere(n0)
    rows.append((len(rows), "estimated", PointCloud(c.points), sph + (True,), cam_s))
    out.append(("normal noise / missing normals", "normal perturbation", rows))
    # thin plate: two sheets `g` apart, g in disk radii
    rows = []
    nb = 6000 if quick else 20000
    r0 = shapes.box(nb, (1.6, 0.05, 1.6)).radii.max()
    for g in ((4, 1, 0.5) if quick else (8, 4, 2, 1, 0.5)):
        size = (1.6, float(g * r0), 1.6)
        cam = lambda w, h: Camera.look_at((0, 1.2, 2.4), (0, 0, 0), width=w, height=h)  # noqa: E731
        rows.append((g, f"{g:g} r", shapes.box(nb, size), analytic.box_mesh(size) + (False,), cam))
    out.append(("thin structures", "sheet gap / disk radius", rows))
    rows = []
    cam_b = lambda w, h: Camera.look_at((0, -2.0, 2.6), (0, 0, 0), width=w, height=h)  # noqa: E731
    for h in ((-1.0, 0.0, 0.5) if quick else (-1.0, -0.5, 0.0, 0.5)):
        c = shapes.sphere(n0)
        keep = c.points[:, 1] > h
        rows.append((h, f"y > {h:g}", c.subset(keep), analytic.sphere_mesh(1.0, res=256, y_min=h)
                     + (True,), cam_b))
    out.append(("open boundaries", "cap kept above height", rows))
    rows = []
    pl = shapes.plane(n0, 2.0, jitter=0.5, seed=3)
    for e in ((30, 8, 2) if quick else (60, 30, 15, 8, 4, 2)):
        a = np.radians(e)
        cam = (lambda a: lambda w, h: Camera.look_at((0, 3 * np.sin(a), 3 * np.cos(a)), (0, 0, 0),
                                                     width=w, height=h))(a)
        rows.append((e, f"{e} deg", pl, analytic.plane_mesh(2.0) + (False,), cam))
    out.append(("grazing views", "elevation (degrees)", rows))
    return out


def _method_frame(method, cloud, camera, settings, depth):
    from ..reconstruct import ball_pivoting, poisson
    from ..surfels import SurfelScene

    if method == "discs":
        return render_geometry(SurfelScene(cloud, interpolation="none"), camera, settings, 0.0)
    if method == "surfels-smooth":
        return render_geometry(SurfelScene(cloud, interpolation="smooth"), camera, settings, 1.0)
    rec = poisson(cloud, depth) if method == "poisson" else ball_pivoting(cloud)
    if len(rec.faces) == 0:
        return None
    return render_geometry(MeshGeometry(rec.vertices, rec.faces), camera, settings)


def broken(m: dict) -> bool:
    return bool(m["flip"] > BREAK_FLIP or m["holes"] > BREAK_HOLES
                or not (m["normal_error_deg"] <= BREAK_NORMAL_DEG))


def run_stability(out: Path, quick: bool = False, log=print, overwrite: bool = True) -> dict:
    """Run the sweeps; writes ``stability.png``; returns the stability section of metrics.json."""
    settings = Settings(width=96 if quick else 160, height=72 if quick else 120, spp=1)
    depth = 7 if quick else 8
    result = {"thresholds": {"flip": BREAK_FLIP, "holes": BREAK_HOLES,
                             "normal_error_deg": BREAK_NORMAL_DEG},
              "methods": list(STABILITY_METHODS), "poisson_depth": depth, "sweeps": []}
    for name, xlabel, rows in sweeps(quick):
        sw = {"name": name, "xlabel": xlabel, "values": [r[1] for r in rows],
              "x": [float(r[0]) for r in rows], "results": {m: [] for m in STABILITY_METHODS}}
        for value, label, cloud, (v, f, smooth), cam in rows:
            camera = cam(settings.width, settings.height)
            ref = render_geometry(MeshGeometry(v, f, smooth=smooth), camera, settings)
            lo, hi = np.min(v, 0), np.max(v, 0)
            diag = float(np.linalg.norm(hi - lo))
            for method in STABILITY_METHODS:
                frame = _method_frame(method, cloud, camera, settings, depth)
                if frame is None:
                    m = {"flip": 1.0, "holes": 1.0, "normal_error_deg": float("nan"), "iou": 0.0}
                else:
                    full, _ = metrics.compare_frames(ref, frame, diag)
                    m = {k: full[k] for k in ("flip", "holes", "normal_error_deg", "iou")}
                m["broken"] = broken(m)
                sw["results"][method].append(m)
            log(f"  stability {name} = {label}: " + ", ".join(
                f"{k} {sw['results'][k][-1]['flip']:.3f}" for k in STABILITY_METHODS))
        sw["breaks_at"] = {m: next((sw["values"][i] for i, r in enumerate(sw["results"][m])
                                    if r["broken"]), None) for m in STABILITY_METHODS}
        sw["advice"] = advice(sw)
        result["sweeps"].append(sw)
    result["chart"] = stability_chart(result, Path(out) / "stability.png", overwrite)
    result["summary"] = [s["advice"] for s in result["sweeps"]]
    return result


def advice(sw: dict) -> str:
    """One plain sentence from the numbers: which method to trust along this sweep."""
    mean = {m: float(np.mean([r["flip"] for r in rs])) for m, rs in sw["results"].items()}
    n_ok = {m: sum(not r["broken"] for r in rs) for m, rs in sw["results"].items()}
    best = min(mean, key=lambda m: (-n_ok[m], mean[m]))
    parts = [f"{sw['name']}: trust {best} (mean FLIP {mean[best]:.3f}, holds on "
             f"{n_ok[best]} of {len(sw['values'])} values)"]
    for m, at in sw["breaks_at"].items():
        if at is not None:
            parts.append(f"{m} breaks at {at}")
    never = [m for m, at in sw["breaks_at"].items() if at is None]
    if never:
        parts.append(f"never broken: {', '.join(never)}")
    return "; ".join(parts) + "."


def stability_chart(result: dict, path: Path, overwrite: bool) -> str:
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..files import atomic_write_bytes

    sws = result["sweeps"]
    fig, axes = plt.subplots(2, (len(sws) + 1) // 2, figsize=(15, 7.5))
    for ax, sw in zip(axes.ravel(), sws):
        xs = np.arange(len(sw["values"]))
        for m, rs in sw["results"].items():
            mk, col = STYLE[m]
            y = [r["flip"] for r in rs]
            ax.plot(xs, y, mk + "-", color=col, label=m)
            bx = [x for x, r in zip(xs, rs) if r["broken"]]
            ax.plot(bx, [y[i] for i in bx], "x", color="k", ms=9, mew=1.5)
        ax.axhline(result["thresholds"]["flip"], color="k", lw=0.8, ls=":")
        ax.set_xticks(xs, sw["values"], fontsize=8)
        ax.set_xlabel(sw["xlabel"])
        ax.set_ylabel("FLIP")
        ax.set_title(sw["name"])
        ax.grid(alpha=0.3)
    axes.ravel()[0].legend(fontsize=8, title="x = broken", title_fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue(), overwrite=overwrite)
    return path.name


def stability_html(st: dict) -> str:
    items = "".join(f"<li>{html.escape(s)}</li>" for s in st["summary"])
    th = st["thresholds"]
    return (f"<h2>Where methods fail</h2><p>Generated shapes with exact references; a method is "
            f"<i>broken</i> where FLIP &gt; {th['flip']}, holes &gt; {th['holes']:.0%} or mean "
            f"normal error &gt; {th['normal_error_deg']}°. Poisson at depth {st['poisson_depth']}, "
            f"surfels-smooth at 1 px LoD, discs without interpolation or LoD.</p>"
            f"<h3>Which method to trust where</h3><ul>{items}</ul>"
            f"<img src=\"{st['chart']}\" alt=\"stability sweeps\">")
