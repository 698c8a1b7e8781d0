"""The comparison run: load, choose the reference, render every method and setting, score."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, InputError
from ..meshes import MeshGeometry
from . import analytic, metrics
from .settings import REFERENCE_SPP_FACTOR, Settings, render_geometry

#: Method names, in report order.
METHODS = ("discs", "surfels-paper", "surfels-smooth", "poisson", "ball-pivoting", "alpha-shape")

_INTERP = {"discs": "none", "surfels-paper": "paper", "surfels-smooth": "smooth"}

#: A reference mesh with fewer vertices than this fraction of the input's points is coarse: its
#: vertex spacing is more than twice the input's (spacing grows as 1/sqrt(count)), so it is a
#: smoothed surface and favours smooth reconstructions over surfels that keep the scans' detail.
COARSE_REFERENCE_FRACTION = 0.25


def reference_note(kind: str, ref_vertices: int | None, points: int) -> str | None:
    """What the report must say about the reference, or None: a coarse mesh favours smooth
    reconstructions (the dragon's 23k-vertex reference against 469k scanned points)."""
    if kind != "mesh" or ref_vertices is None or ref_vertices >= COARSE_REFERENCE_FRACTION * points:
        return None
    return (f"The reference is coarse: {ref_vertices:,} vertices for {points:,} input points "
            f"({ref_vertices / points:.1%}), a vertex spacing about "
            f"{(points / ref_vertices) ** 0.5:.1f}x the input's. It is a smoothed surface, so it "
            "favours smooth reconstructions (Poisson) over surfels, which keep the scans' detail "
            "and their noise; errors against it measure agreement with that smoothed surface, "
            "not with the true one.")


def load_input(source, settings: Settings, reference=None):
    """(cloud, reference (vertices, faces, smooth) or None, reference kind, description)."""
    from .. import io

    if isinstance(source, str) and source in analytic.SHAPES:
        cloud, (v, f) = analytic.shape(source, settings.generated_points)
        smooth = source != "box"
        return cloud, (v, f, smooth), "analytic", f"exact {source} (fine triangulation)"
    path = Path(source)
    if not path.exists():
        raise FileFormatError(f"{path}: no such file")
    mesh = None
    if path.suffix.lower() in (".ply", ".obj", ".off", ".stl"):
        import open3d as o3d

        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            m = o3d.io.read_triangle_mesh(str(path))
        if len(m.triangles):
            mesh = (np.asarray(m.vertices), np.asarray(m.triangles), True)
    cloud, seconds = _timed(lambda: io.load(path, estimate=False))
    cloud._compare_load_seconds = seconds
    kind = "surfels-full-detail"
    desc = f"surfels (smooth, no LoD, {REFERENCE_SPP_FACTOR}x spp): no mesh was given"
    if mesh is not None:
        kind, desc = "mesh", f"the input mesh {path.name}"
    if reference is not None:
        rp = Path(reference)
        import open3d as o3d

        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            m = o3d.io.read_triangle_mesh(str(rp))
        if not len(m.triangles):
            raise FileFormatError(f"{rp}: --reference must be a triangle mesh (no faces read)")
        mesh = (np.asarray(m.vertices), np.asarray(m.triangles), True)
        kind, desc = "mesh", f"the mesh {rp.name}"
    return cloud, mesh, kind, desc


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def _subsample(cloud, n, seed):
    if n is None or len(cloud) <= n:
        return cloud
    idx = np.sort(np.random.default_rng(seed).choice(len(cloud), n, replace=False))
    return cloud.subset(idx)


def shared_preprocess(cloud) -> dict:
    """Seconds of the preprocessing every method shares: normal estimation and orientation
    (when the input has none) and disk radii (surfels only; not for registered raw scans, whose
    surfels are fitted first and get the fitted points' radii, see :func:`run_methods`).
    Measured once per cloud, on first call, and cached on the cloud, so a reference rendered
    from the same cloud does not hide it."""
    cached = getattr(cloud, "_compare_preprocess", None)
    if cached is not None:
        return cached
    out = {}
    raw = cloud.is_raw_scan
    if not cloud.has_normals:
        _, out["normals"] = _timed(lambda: cloud.normals)
    if not raw:
        _, out["radii"] = _timed(lambda: cloud.radii)
    cloud._compare_preprocess = out
    return out


def _without_estimates(cloud):
    """The same points and per-point data as ``cloud`` without the normals and radii estimated
    on it (the arrays are shared, nothing is copied or checked again)."""
    return cloud._derive(cloud.points, None, False, None, False, cloud.colors,
                         up=cloud.up, viewpoints=cloud.viewpoints, intensity=cloud.intensity,
                         scan_index=cloud.scan_index, scan_grid=cloud.scan_grid)


def run_methods(cloud, camera, settings: Settings, methods, reference_frame, diagonal,
                on_frame=None, log=print):
    """Render every method/setting and score it. ``on_frame(entry, frame, flip_map)`` is
    called for each (to save images). Returns the list of entries."""
    from ..surfels import SurfelScene

    entries = []
    shared = shared_preprocess(cloud)
    steps0 = {k: v for k, v in shared.items() if k == "normals"}

    def score(method, label, sett, steps, frame, wall, geom):
        # render: the whole render() call, as a user waits for it (the core's frame is part)
        m, emap = metrics.compare_frames(reference_frame, frame, diagonal)
        pre = float(sum(steps.values()))
        ren = float(wall)
        e = {"method": method, "label": label, "settings": sett,
             "times": {"preprocess": pre, "render": ren, "first_image": pre + ren,
                       "steps": steps, "render_in_core": float(frame.stats["seconds"])},
             "metrics": m, "geometry": geom, "images": {}}
        if on_frame is not None:
            on_frame(e, frame, emap)
        log(f"  {label:34s} pre {pre:7.2f} s  render {ren:6.2f} s  FLIP {m['flip']:.4f}  "
            f"normal {m['normal_error_deg']:5.1f} deg  holes {m['holes']:.3f}")
        entries.append(e)

    surfels, surfel_steps = cloud, None
    for method in methods:
        if method in _INTERP:
            if surfel_steps is None and cloud.is_raw_scan:
                # registered raw scans: the surfels a user gets (`pointviz render`'s default),
                # made as it makes them: from the raw points, the fit estimates each scan's
                # normals and the neighbourhood size each point's normal chose, and fits over
                # at least that many points. The fit (its normals included) and the fitted
                # points' radii are the surfels' preprocessing; the shared normals are not
                # theirs (the meshes' reconstructions need them, the surfels do not use them).
                raw = _without_estimates(cloud)
                surfels, t_fit = _timed(raw.fitted)
                _, t_fit_radii = _timed(lambda: surfels.radii)
                surfel_steps = {"fit": t_fit, "radii": t_fit_radii}
                log(f"  surfels: {surfels.fit_report['summary']}")
            elif surfel_steps is None:
                surfel_steps = dict(steps0, radii=shared["radii"])
            ss, t_build = _timed(lambda: SurfelScene(surfels, interpolation=_INTERP[method]))
            for lod in settings.lods:
                steps = dict(surfel_steps, tree=t_build)
                frame, wall = _timed(lambda: render_geometry(ss, camera, settings, lod=lod))
                score(method, f"{method} lod {lod:g} px", {"interpolation": _INTERP[method],
                      "lod_pixels": float(lod)}, steps, frame, wall, {"surfels": len(surfels)})
            continue
        if method == "poisson":
            from ..reconstruct import poisson
            runs = [(f"poisson depth {d}", (lambda d=d: poisson(cloud, d))) for d in
                    settings.poisson_depths]
        elif method == "ball-pivoting":
            from ..reconstruct import ball_pivoting
            if len(cloud) > settings.bpa_max_points:
                log(f"  ball-pivoting skipped: {len(cloud)} points > {settings.bpa_max_points}")
                continue
            runs = [("ball-pivoting", lambda: ball_pivoting(cloud))]
        elif method == "alpha-shape":
            from ..reconstruct import alpha_shape
            if len(cloud) > settings.alpha_max_points:
                log(f"  alpha-shape skipped: {len(cloud)} points > {settings.alpha_max_points}")
                continue
            runs = [("alpha-shape", lambda: alpha_shape(cloud))]
        else:
            raise InputError(f"methods: unknown method {method!r}; expected some of {METHODS}")
        for label, fn in runs:
            rec = fn()
            if len(rec.faces) == 0:
                log(f"  {label}: no triangles, skipped")
                continue
            geom = MeshGeometry(rec.vertices, rec.faces, rec.colors)
            frame, wall = _timed(lambda: render_geometry(geom, camera, settings))
            # the mesh's Embree BVH is built inside its first render() (when the scene is
            # handed to the core): it is a step of its own, so the render is the rest, as the
            # surfels' tree is a step and their render does not build it
            wall -= geom.build_seconds
            steps = dict(steps0, **rec.timings, bvh=geom.build_seconds)
            score(method, label, dict(rec.params), steps, frame, wall,
                  {"vertices": len(rec.vertices), "faces": len(rec.faces)})
    return entries


def compare(input, reference=None, camera=None, out_dir="compare_out", methods=None,
            quick: bool = False, stability: bool = False, settings: Settings | None = None,
            overwrite: bool = True, log=print) -> dict:
    """Compare surfels with reconstructed meshes on one input and write a report.

    Parameters
    ----------
    input : str or os.PathLike or PointCloud
        A point cloud / mesh file, Stanford ``.conf`` scans, or a generated shape
        (``demo``, ``sphere``, ``torus``, ``box``).
    reference : path, optional
        A mesh to use as the reference. Default: the input itself when it is a mesh, the exact
        shape for generated inputs, else the surfels at full detail (flagged in the report).
    camera : Camera or path to camera JSON, optional
        Default: ``Camera.fit`` on the cloud.
    out_dir : path
        Report folder (created): ``index.html``, ``metrics.json``, PNGs.
    methods : list of str, optional
        Subset of :data:`METHODS`.
    quick : bool
        Small sizes (tests).
    stability : bool
        Also run the stability sweeps (:mod:`pointviz.comparison.stability`).

    Returns
    -------
    dict
        The metrics document (as in ``metrics.json``) plus ``report`` (path of index.html).
    """
    from ..camera import Camera
    from . import report

    settings = settings or (Settings.quick() if quick else Settings.full())
    methods = list(METHODS if methods is None else methods)
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise InputError(f"methods: unknown {bad}; expected some of {list(METHODS)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = str(input)
    if hasattr(input, "points"):
        cloud, ref_mesh, kind, desc = input, None, "surfels-full-detail", "surfels at full detail"
        name = getattr(input, "name", None) or "cloud"
    else:
        cloud, ref_mesh, kind, desc = load_input(str(input), settings, reference)
    load_seconds = getattr(cloud, "_compare_load_seconds", None)
    cloud = _subsample(cloud, settings.max_points, settings.seed)
    if camera is None:  # (settings.up, when given, frames the view as it places the ground)
        camera = Camera.fit(cloud, width=settings.width, height=settings.height, up=settings.up)
    elif not hasattr(camera, "pixel_angle"):
        camera = Camera.from_json(camera).with_size(settings.width, settings.height)
    lo, hi = cloud.bounds
    diagonal = float(np.linalg.norm(hi - lo))
    log(f"compare {name}: {len(cloud)} points, {camera.width}x{camera.height}, spp {settings.spp}")
    if settings.up is None and getattr(cloud, "up", None) is not None:
        from dataclasses import replace

        settings = replace(settings, up=tuple(float(x) for x in cloud.up))
    shared_preprocess(cloud)  # timed before anything (the reference) computes normals/radii
    t0 = time.perf_counter()
    if ref_mesh is not None:
        ref_geom = MeshGeometry(ref_mesh[0], ref_mesh[1], smooth=ref_mesh[2])
        reference_frame = render_geometry(ref_geom, camera, settings)
    else:
        from ..surfels import SurfelScene

        reference_frame = render_geometry(SurfelScene(cloud, interpolation="smooth"), camera,
                                          settings, lod=0.0,
                                          spp=REFERENCE_SPP_FACTOR * settings.spp)
    log(f"  reference ({desc}): {time.perf_counter() - t0:.2f} s")
    writer = report.ImageWriter(out, reference_frame, overwrite)
    entries = run_methods(cloud, camera, settings, methods, reference_frame, diagonal,
                          on_frame=writer.save, log=log)
    reference_doc = {"kind": kind, "description": desc}
    if ref_mesh is not None:
        reference_doc["vertices"] = int(len(ref_mesh[0]))
        note = reference_note(kind, len(ref_mesh[0]), len(cloud))
        if note is not None:
            reference_doc["note"] = note
    doc = {"schema": "pointviz.compare/1", "input": name, "points": int(len(cloud)),
           "reference": reference_doc,
           "image": {"width": camera.width, "height": camera.height, "spp": settings.spp},
           "render": settings.render_settings().to_json(),
           "camera": camera.to_dict(), "entries": entries}
    if load_seconds is not None:
        doc["load_seconds"] = float(load_seconds)
    if stability:
        from .stability import run_stability

        doc["stability"] = run_stability(out, quick=quick, log=log, overwrite=overwrite)
    path = report.write_report(out, doc, writer, overwrite=overwrite)
    doc = dict(doc, report=str(path))
    return doc
