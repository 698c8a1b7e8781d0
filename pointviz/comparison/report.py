"""The comparison report: PNGs (frames, FLIP maps, side-by-side, charts), ``metrics.json``
(validated against :data:`pointviz.comparison.schema.SCHEMA`) and an offline ``index.html`` with
relative links only."""

from __future__ import annotations

import html
import json
import re
from pathlib import Path

import numpy as np

from ..files import atomic_write_bytes, atomic_write_text
from ..images import encode_png
from .schema import SCHEMA, json_safe, validate
from .settings import REFERENCE_SPP_FACTOR
from .style import STYLE


def slug(label: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", label.lower()).strip("_")


def _png(path: Path, rgb: np.ndarray, overwrite: bool) -> str:
    arr = np.asarray(rgb)
    if arr.dtype != np.uint8:
        arr = (np.clip(arr, 0, 1) * 255 + 0.5).astype(np.uint8)
    atomic_write_bytes(path, encode_png(arr), overwrite=overwrite)
    return path.name


class ImageWriter:
    """Writes each entry's frame and FLIP map next to the report and remembers them for the
    side-by-side figure."""

    def __init__(self, out: Path, reference_frame, overwrite: bool):
        self.out = Path(out)
        self.overwrite = overwrite
        self.reference = reference_frame.to_srgb8()
        self.reference_png = _png(self.out / "reference.png", self.reference, overwrite)
        self.frames: dict[str, np.ndarray] = {}

    def save(self, entry: dict, frame, flip_map: np.ndarray) -> None:
        s = slug(entry["label"])
        img = frame.to_srgb8()
        self.frames[entry["label"]] = img
        entry["images"] = {"frame": _png(self.out / f"{s}.png", img, self.overwrite),
                           "flip": _png(self.out / f"{s}_flip.png", flip_map, self.overwrite)}

    def side_by_side(self, entries) -> str | None:
        """surfels | mesh from reconstruction | reference, using each family's best entry."""
        def best(fam):
            cand = [e for e in entries if e["method"] in fam and e["label"] in self.frames]
            return min(cand, key=lambda e: e["metrics"]["flip"]) if cand else None
        picks = [best(("surfels-smooth", "surfels-paper", "discs")),
                 best(("poisson", "ball-pivoting", "alpha-shape"))]
        tiles = [self.frames[e["label"]] for e in picks if e is not None] + [self.reference]
        gap = np.full((self.reference.shape[0], 4, 3), 255, np.uint8)
        row = tiles[0]
        for t in tiles[1:]:
            row = np.concatenate([row, gap, t], axis=1)
        self.side_labels = [e["label"] for e in picks if e is not None] + ["reference"]
        return _png(self.out / "side_by_side.png", row, self.overwrite)


def pareto(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point beats in both coordinates (lower is better), in
    increasing x."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], np.inf
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def speed_accuracy_chart(entries, path: Path, overwrite: bool) -> str:
    """x = time to first image (log s), y = FLIP (left) and normal error (right); Pareto fronts."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    labels: dict[int, list] = {}
    for ax, key, title in ((axes[0], "flip", "FLIP error"),
                           (axes[1], "normal_error_deg", "normal error (degrees)")):
        pts = []
        for method in STYLE:
            es = [e for e in entries if e["method"] == method
                  and np.isfinite(e["metrics"][key] if e["metrics"][key] is not None else np.nan)]
            if not es:
                continue
            x = [e["times"]["first_image"] for e in es]
            y = [e["metrics"][key] for e in es]
            mk, col = STYLE[method]
            ax.plot(x, y, mk + "-", color=col, label=method, alpha=0.85, ms=7)
            for e, xi, yi in zip(es, x, y):
                short = e["label"].replace(method, "").strip() or method
                labels.setdefault(id(ax), []).append((xi, yi, short))
            pts += list(zip(x, y))
        if pts:
            front = pareto(pts)
            fx = [pts[i][0] for i in front]
            fy = [pts[i][1] for i in front]
            ax.step(fx, fy, where="post", color="k", lw=1.2, ls="--", label="Pareto front")
        ax.set_xscale("log")
        ax.set_xlabel("time to first image: preprocessing + render (s, log)")
        ax.set_ylabel(title)
        ax.grid(alpha=0.3)
        ax.set_title(f"speed vs {title}")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    for ax in axes:
        place_labels(ax, labels.get(id(ax), []))
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue(), overwrite=overwrite)
    return path.name


#: Candidate label positions around a point: offsets in points and the text's alignment.
LABEL_OFFSETS = [(dx, dy, ha, va) for dist in (4, 12, 22)
                 for dx, dy, ha, va in ((dist, dist, "left", "bottom"), (dist, -dist, "left", "top"),
                                        (-dist, dist, "right", "bottom"),
                                        (-dist, -dist, "right", "top"),
                                        (0, dist + 2, "center", "bottom"),
                                        (0, -dist - 2, "center", "top"))]
#: Half size of the box kept clear around each marker, in display pixels.
MARKER_CLEARANCE = 5.0
LABEL_FONTSIZE = 7


def place_labels(ax, items) -> list:
    """Annotate ``items`` ((x, y, text) in data coordinates) so that no two labels overlap,
    nor a label a marker: each label, in turn, takes the first of LABEL_OFFSETS whose box is
    clear (else the least-overlapping one, with a leader line when it sits far away).

    Returns
    -------
    list of matplotlib.transforms.Bbox
        The labels' boxes in display coordinates.
    """
    fig = ax.figure
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    from matplotlib.transforms import Bbox

    xy = ax.transData.transform([(x, y) for x, y, _ in items]) if items else np.zeros((0, 2))
    c = MARKER_CLEARANCE
    obstacles = [Bbox([[px - c, py - c], [px + c, py + c]]) for px, py in xy]
    frame = ax.get_window_extent(renderer)
    placed = []

    def overlap(a, b):
        w = min(a.x1, b.x1) - max(a.x0, b.x0)
        h = min(a.y1, b.y1) - max(a.y0, b.y0)
        return w * h if w > 0 and h > 0 else 0.0

    for x, y, text in items:
        best = None
        for k, (dx, dy, ha, va) in enumerate(LABEL_OFFSETS):
            ann = ax.annotate(text, (x, y), xytext=(dx, dy), textcoords="offset points",
                              fontsize=LABEL_FONTSIZE, ha=ha, va=va)
            box = ann.get_window_extent(renderer)
            cost = sum(overlap(box, o) for o in obstacles + placed)
            cost += box.width * box.height - overlap(box, frame)  # outside the axes
            if best is None or cost < best[0]:
                if best is not None:
                    best[1].remove()
                best = (cost, ann, box, k)
            else:
                ann.remove()
            if cost == 0:
                break
        _, ann, box, k = best
        if LABEL_OFFSETS[k][0] ** 2 + LABEL_OFFSETS[k][1] ** 2 > 12 ** 2:
            ann.remove()
            dx, dy, ha, va = LABEL_OFFSETS[k]
            ann = ax.annotate(text, (x, y), xytext=(dx, dy), textcoords="offset points",
                              fontsize=LABEL_FONTSIZE, ha=ha, va=va,
                              arrowprops={"arrowstyle": "-", "lw": 0.5, "color": "0.5"})
        placed.append(box)
    return placed


def verdict(doc: dict) -> str:
    """The report's one-line verdict: which geometry matches the reference best, and how the
    best surfel entry compares with the best mesh in error and time to first image."""
    entries = [e for e in doc["entries"] if e["metrics"].get("flip") is not None
               and np.isfinite(e["metrics"]["flip"])]
    if not entries:
        return "No method produced a frame to compare."
    surf = [e for e in entries if e["method"] in ("surfels-smooth", "surfels-paper", "discs")]
    mesh = [e for e in entries if e not in surf]

    def flip(e):
        return e["metrics"]["flip"]

    def desc(e):
        return (f"{e['label']} (FLIP {flip(e):.4f}, first image in "
                f"{e['times']['first_image']:.2f} s)")

    best = min(entries, key=flip)
    if not surf or not mesh:
        return f"Closest to the reference: {desc(best)}."
    s, m = min(surf, key=flip), min(mesh, key=flip)
    closer = "closer to" if flip(s) < flip(m) else "further from"
    speed = m["times"]["first_image"] / max(s["times"]["first_image"], 1e-9)
    return (f"Surfels are {closer} the reference than the best mesh: {desc(s)} against "
            f"{desc(m)}; surfels reach the first image {speed:.1f}x "
            f"{'sooner' if speed >= 1 else 'later'}.")


def _fmt(v, spec):
    return "–" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def entries_table(entries) -> str:
    head = ("<tr><th>method</th><th>settings</th><th>preprocess s</th><th>render s</th>"
            "<th>first image s</th><th>FLIP</th><th>PSNR dB</th><th>SSIM</th>"
            "<th>normal °</th><th>depth / diag</th><th>IoU</th><th>holes</th><th>images</th></tr>")
    rows = []
    for e in entries:
        m, t = e["metrics"], e["times"]
        rows.append(
            f"<tr><td>{html.escape(e['method'])}</td><td>{html.escape(e['label'])}</td>"
            f"<td>{t['preprocess']:.2f}</td><td>{t['render']:.2f}</td><td>{t['first_image']:.2f}</td>"
            f"<td>{_fmt(m['flip'], '.4f')}</td><td>{_fmt(m['psnr'], '.1f')}</td>"
            f"<td>{_fmt(m['ssim'], '.3f')}</td><td>{_fmt(m['normal_error_deg'], '.2f')}</td>"
            f"<td>{_fmt(m['depth_error'], '.2e')}</td><td>{_fmt(m['iou'], '.3f')}</td>"
            f"<td>{_fmt(m['holes'], '.3f')}</td>"
            f"<td><a href=\"{e['images']['frame']}\">frame</a> · "
            f"<a href=\"{e['images']['flip']}\">FLIP</a></td></tr>")
    return f"<table>{head}{''.join(rows)}</table>"


def render_settings_table(used: dict) -> str:
    """The render settings of the run, one row per :class:`~pointviz.settings.RenderSettings`
    field: the value used, the default, what it accepts and what it does (all read from
    RenderSettings)."""
    from ..settings import RenderSettings

    def cell(v):
        return f"<td>{html.escape(str(v))}</td>"

    head = ("<tr><th>setting</th><th>used</th><th>default</th><th>accepts</th>"
            "<th>meaning</th></tr>")
    rows = "".join(f"<tr>{cell(r['name'])}{cell(r['value'])}{cell(r['default'])}"
                   f"{cell(r['accepted'])}{cell(r['help'])}</tr>"
                   for r in RenderSettings.describe(used))
    return f'<table id="render-settings">{head}{rows}</table>'


def write_report(out: Path, doc: dict, writer: ImageWriter, overwrite: bool = True) -> Path:
    """Write ``metrics.json``, the figures and ``index.html``; returns the index path."""
    out = Path(out)
    entries = doc["entries"]
    side = writer.side_by_side(entries)
    chart = speed_accuracy_chart(entries, out / "speed_accuracy.png", overwrite)
    safe = json_safe(doc)
    validate(safe)
    atomic_write_text(out / "metrics.json", json.dumps(safe, indent=1), overwrite=overwrite)
    atomic_write_text(out / "metrics.schema.json", json.dumps(SCHEMA, indent=1),
                      overwrite=overwrite)
    gallery = "".join(
        f"<figure><img src=\"{e['images']['frame']}\" alt=\"{html.escape(e['label'])}\">"
        f"<img src=\"{e['images']['flip']}\" alt=\"FLIP map of {html.escape(e['label'])}\">"
        f"<figcaption>{html.escape(e['label'])} — FLIP {_fmt(e['metrics']['flip'], '.4f')}"
        f"</figcaption></figure>" for e in entries)
    stab = ""
    if "stability" in doc:
        from .stability import stability_html

        stab = stability_html(doc["stability"])
    labels = " | ".join(html.escape(s) for s in getattr(writer, "side_labels", []))
    ref = doc["reference"]
    caveat = (f'<p class="note"><b>Note on the reference.</b> {html.escape(ref["note"])}</p>'
              if ref.get("note") else "")
    load = (f" Reading the input took {doc['load_seconds']:.2f} s, shared by every method and "
            "not counted in their times." if "load_seconds" in doc else "")
    settings_section = ""
    if "render" in doc:
        settings_section = (
            f"<h2>Render settings</h2><p>Every frame is rendered with these settings; the level "
            "of detail (<code>lod_pixels</code>) is each entry's (above), and a reference made "
            f"of surfels (no mesh given) takes {REFERENCE_SPP_FACTOR}× the samples.</p>"
            + render_settings_table(doc["render"]))
    page = f"""<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>pointviz compare: {html.escape(doc['input'])}</title>
<style>body{{font-family:sans-serif;margin:1.5em;max-width:1300px}} img{{max-width:100%}}
table{{border-collapse:collapse;font-size:13px}} td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}
td:first-child,td:nth-child(2),#render-settings td{{text-align:left}} figure{{display:inline-block;margin:4px;width:330px;font-size:12px}}
figure img{{width:160px}} .note{{background:#f4f4f4;padding:.5em 1em}}</style></head><body>
<h1>Surfels vs meshes: {html.escape(doc['input'])}</h1>
<p class="verdict"><b>{html.escape(verdict(doc))}</b></p>
<img src="{side}" alt="side by side: {labels}"><p>{labels}</p>
<p class="note">{doc['points']} points, {doc['image']['width']}×{doc['image']['height']} pixels,
{doc['image']['spp']} samples per pixel. Reference: <b>{html.escape(ref['description'])}</b>.
Every image is rendered by the same shading code (camera, lights, materials); only the geometry
backend differs. Times: preprocessing (normals, radii, tree / reconstruction, BVH; for raw scans
the surfels' surface fit, which estimates its own normals, instead of the normals) and rendering
(the whole render call); first image = their sum, each stage in metrics.json.{load}
<a href="metrics.json">metrics.json</a> (schema: <a href="metrics.schema.json">metrics.schema.json</a>).</p>
{caveat}
<h2>Speed against accuracy</h2><img src="{chart}" alt="speed-accuracy chart">
<h2>All methods and settings</h2>{entries_table(entries)}
{settings_section}
<h2>Frames and FLIP error maps</h2><p><img src="{writer.reference_png}" alt="reference" style="width:320px"><br>reference</p>{gallery}
{stab}
</body></html>"""
    return atomic_write_text(out / "index.html", page, overwrite=overwrite)
