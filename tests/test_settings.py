"""RenderSettings is the one definition of the render defaults, ranges and choices: render(),
the command line, the viewer and path manifests all agree with it."""

from __future__ import annotations

import inspect
import json
from dataclasses import MISSING, fields

import numpy as np
import pytest

import pointviz
from pointviz.cli import build_parser
from pointviz.errors import InputError
from pointviz.settings import (
    DEFAULTS,
    GROUNDS,
    INTERPOLATIONS,
    LOOKS,
    RenderSettings,
    check_int,
)


def _expected_cli_default(f):
    return f.default if f.metadata["cli_default"] is MISSING else f.metadata["cli_default"]


@pytest.mark.parametrize("command", ["render", "path", "view"])
def test_cli_defaults_are_the_render_settings(command, tmp_path):
    argv = {"render": ["render", "in.ply", "-o", "out.png"], "path": ["path", "in.ply", "orbit", "-o", "out"],
            "view": ["view", "in.ply"]}[command]
    args = build_parser().parse_args(argv)
    for f in fields(RenderSettings):
        assert getattr(args, f.name) == _expected_cli_default(f), f.name
    # the one stated exception: final frames from the command line are denoised when possible
    differing = [f.name for f in fields(RenderSettings) if f.metadata["cli_default"] is not MISSING]
    assert differing == ["denoise"]


def test_cli_choices_and_ranges_come_from_the_settings(capsys):
    parser = build_parser()
    with pytest.raises(SystemExit):
        parser.parse_args(["render", "in.ply", "-o", "o.png", "--ground", "lava"])
    err = capsys.readouterr().err
    assert all(g in err for g in GROUNDS)
    with pytest.raises(SystemExit):
        parser.parse_args(["render", "in.ply", "-o", "o.png", "--look", "noir"])
    err = capsys.readouterr().err
    assert all(name in err for name in LOOKS)
    args = parser.parse_args(["render", "in.ply", "-o", "o.png", "--no-shadows", "--lod", "2.5", "--spp", "9"])
    assert (args.shadows, args.lod_pixels, args.spp) == (False, 2.5, 9)


def test_viewer_defaults_are_the_render_settings():
    from pointviz.viewer.model import GROUNDS as VIEWER_GROUNDS
    from pointviz.viewer.model import RENDER_FIELDS, ViewerSettings

    vs = ViewerSettings()
    for name in RENDER_FIELDS:
        assert getattr(vs, name) == getattr(DEFAULTS, name), name
    assert vs.render_kwargs() == {name: getattr(DEFAULTS, name) for name in RENDER_FIELDS}
    assert set(VIEWER_GROUNDS) <= set(GROUNDS)
    with pytest.raises(InputError, match="reflections"):
        ViewerSettings(reflections=17)


def test_render_signature_defaults_are_the_render_settings():
    params = inspect.signature(pointviz.render).parameters
    for f in fields(RenderSettings):
        assert params[f.name].default == f.default, f.name


def test_named_choices_match_what_they_name():
    from pointviz.denoise import DENOISE_QUALITIES, denoise_quality
    from pointviz.scene import GROUND_MATERIALS
    from pointviz.scene import LOOKS as SCENE_LOOKS
    from pointviz.surfels import INTERPOLATIONS as SURFEL_INTERPOLATIONS

    assert set(GROUNDS) == {"auto", "none", *GROUND_MATERIALS}
    assert set(LOOKS) == {"auto", *SCENE_LOOKS}
    assert SURFEL_INTERPOLATIONS == INTERPOLATIONS
    for q in DENOISE_QUALITIES:
        assert RenderSettings(denoise=q).denoise == denoise_quality(q)


def test_check_int_against_the_definition():
    for lo, hi in [(1, None), (0, None), (0, 16), (1, 4096), (-2, 3)]:
        for v in range(-5, 20):
            inside = v >= lo and (hi is None or v <= hi)
            for value in (v, np.int32(v), np.int64(v)):
                if inside:
                    assert check_int(value, "n", lo, hi) == v
                    assert type(check_int(value, "n", lo, hi)) is int
                else:
                    with pytest.raises(InputError, match="^n: expected"):
                        check_int(value, "n", lo, hi)
    for bad in (True, False, 1.0, "1", None, np.float64(2.0), np.bool_(True)):
        with pytest.raises(InputError, match="^k: expected"):
            check_int(bad, "k", 0, 10)
    with pytest.raises(InputError, match="k: expected a positive integer, got 0"):
        check_int(0, "k")
    with pytest.raises(InputError, match=r"k: expected an integer >= 2 \(why\), got 1"):
        check_int(1, "k", 2, note=" (why)")


def _bad_values(f):
    m = f.metadata
    out = ["bogus"] if m["kind"] is not str else []
    if m["kind"] in (int, float):
        out += [float("nan"), True]
        if m["lo"] is not None:
            out.append(m["kind"](m["lo"]) - 1)
        if m["hi"] is not None:
            out.append(m["kind"](m["hi"]) + 1)
        if m["kind"] is int:
            out.append(1.5)
    if m["kind"] is bool:
        out += [2, "yes"]
    if m["choices"] is not None:
        out.append("not-a-choice")
    if not m["optional"]:
        out.append(None)
    if m["objects"]:  # other objects are checked by their own type where they are used
        out = [v for v in out if isinstance(v, str)]
    return out


@pytest.mark.parametrize("name", RenderSettings.names())
def test_every_setting_rejects_bad_values_by_name(name):
    f = next(f for f in fields(RenderSettings) if f.name == name)
    bad = _bad_values(f)
    assert bad
    for value in bad:
        with pytest.raises(InputError, match=f"^{name}: expected"):
            RenderSettings(**{name: value})
        with pytest.raises(InputError, match=f"^{name}: expected"):
            DEFAULTS.replace(**{name: value})


def test_settings_are_frozen_and_normalised():
    s = RenderSettings(spp=np.int64(8), lod_pixels=2, shadows=np.bool_(False))
    assert (type(s.spp), type(s.lod_pixels), type(s.shadows)) == (int, float, bool)
    with pytest.raises(AttributeError):
        s.spp = 2
    assert s.replace(spp=2).spp == 2 and s.spp == 8
    with pytest.raises(TypeError):
        s.replace(nonsense=1)
    with pytest.raises(InputError, match=r"render_path: unknown render option\(s\) \['nonsense'\]"):
        RenderSettings.from_kwargs({"nonsense": 1}, "render_path")


def test_path_manifest_records_every_image_setting(tmp_path):
    from pointviz.path import MANIFEST_NAME, CameraPath, Keyframe, render_path

    scene = pointviz.Scene(pointviz.PointCloud(np.random.default_rng(0).normal(size=(200, 3))))
    path = CameraPath([Keyframe((0, 0, 6), (0, 0, 0))], width=8, height=6)
    render_path(scene, path, tmp_path / "a", progress=False, spp=1, look="flat")
    settings = json.loads((tmp_path / "a" / MANIFEST_NAME).read_text())["settings"]
    assert set(settings) == set(RenderSettings.names()) - {"threads"}
    assert settings["look"] == "flat" and settings["denoise"] is False and settings["spp"] == 1
    # a change of look is a different render: refused without overwrite
    with pytest.raises(InputError, match="render settings"):
        render_path(scene, path, tmp_path / "a", progress=False, spp=1, look="studio")
