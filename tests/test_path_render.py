"""Tests of pointviz.render_path (serial): atomic frames, resume, manifest, cancel, video, CLI.

The oracle for every frame is an independent ``pointviz.render`` of the same camera (renders are
deterministic per seed), encoded the same way; the oracle for videos is imageio's decoder.
"""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from pointviz import render
from pointviz.cli import main
from pointviz.errors import CancelledError, FileFormatError, InputError
from pointviz.images import encode_png
from pointviz.path import MANIFEST_NAME, CameraPath, is_complete_png, render_path
from pointviz.scene import Scene
from pointviz.shapes import sphere

#: Small frames and one sample per pixel keep a whole path well under a second.
W, H = 64, 48
SETTINGS = {"spp": 1, "reflections": 0, "threads": 1}


@pytest.fixture(scope="module")
def path(scene):
    return CameraPath.orbit(scene, seconds=1.0, fps=6, width=W, height=H)  # 7 frames


def frame_files(folder):
    return sorted(p for p in folder.iterdir() if p.name.startswith("frame_"))


def leftovers(folder):
    """Temporary files of interrupted atomic writes."""
    return [p for p in folder.iterdir() if p.name.startswith(".")]


def test_render_path_writes_every_frame_as_the_single_frame_render(scene, path, tmp_path):
    out = tmp_path / "frames"
    summary = render_path(scene, path, out, progress=False, **SETTINGS)
    files = frame_files(out)
    assert [f.name for f in files] == [f"frame_{i:05d}.png" for i in range(path.n_frames)]
    assert summary["rendered"] == path.n_frames and summary["skipped"] == 0
    for f, cam in zip(files, path.cameras()):  # every frame at the path's one exposure
        oracle = encode_png(render(scene, cam, **SETTINGS, exposure=summary["exposure"]).to_srgb8())
        assert f.read_bytes() == oracle
    assert (out / MANIFEST_NAME).is_file()
    assert not leftovers(out)


def test_render_path_size_override_keeps_aspect(scene, path, tmp_path):
    render_path(scene, path, tmp_path, width=32, progress=False, **SETTINGS)
    assert all(is_complete_png(f, 32, 24) for f in frame_files(tmp_path))


def test_resume_renders_only_missing_frames(scene, path, tmp_path):
    render_path(scene, path, tmp_path, progress=False, **SETTINGS)
    files = frame_files(tmp_path)
    before = {f.name: (f.stat().st_mtime_ns, f.read_bytes()) for f in files}
    missing = [files[1], files[4]]
    for f in missing:
        f.unlink()
    files[5].write_bytes(files[5].read_bytes()[:100])  # truncated by hand: not a whole PNG
    calls = []
    summary = render_path(scene, path, tmp_path, progress=lambda d, t: calls.append((d, t)),
                          **SETTINGS)
    assert summary["rendered"] == 3 and summary["skipped"] == path.n_frames - 3
    assert calls[0] == (path.n_frames - 3, path.n_frames) and calls[-1][0] == path.n_frames
    redone = {f.name for f in missing} | {files[5].name}
    for f in frame_files(tmp_path):
        mtime, data = before[f.name]
        assert f.read_bytes() == data  # deterministic: the re-rendered frames are the same
        if f.name not in redone:
            assert f.stat().st_mtime_ns == mtime  # untouched


def test_resume_refuses_other_settings_unless_overwrite(scene, path, tmp_path):
    render_path(scene, path, tmp_path, progress=False, **SETTINGS)
    with pytest.raises(InputError, match="render settings changed"):
        render_path(scene, path, tmp_path, progress=False, **{**SETTINGS, "spp": 2})
    other = CameraPath.orbit(scene, seconds=1.0, fps=6, width=W, height=H, elevation_deg=40)
    with pytest.raises(InputError, match="camera path"):
        render_path(scene, other, tmp_path, progress=False, **SETTINGS)
    moved = Scene([sphere(3000, 0.6, (-0.4, 0.6, 0.0))], up=(0, 1, 0))
    with pytest.raises(InputError, match="the scene changed"):
        render_path(moved, path, tmp_path, progress=False, **SETTINGS)
    summary = render_path(scene, path, tmp_path, progress=False, overwrite=True,
                          **{**SETTINGS, "spp": 2})
    assert summary["rendered"] == path.n_frames


def test_refuses_folder_with_foreign_frames(scene, path, tmp_path):
    (tmp_path / "frame_00000.png").write_bytes(b"somebody's file")
    with pytest.raises(InputError, match="no pointviz_path.json"):
        render_path(scene, path, tmp_path, progress=False, **SETTINGS)
    assert (tmp_path / "frame_00000.png").read_bytes() == b"somebody's file"


def test_no_resume_needs_overwrite(scene, path, tmp_path):
    render_path(scene, path, tmp_path, progress=False, **SETTINGS)
    with pytest.raises(InputError, match="resume=False"):
        render_path(scene, path, tmp_path, progress=False, resume=False, **SETTINGS)
    s = render_path(scene, path, tmp_path, progress=False, resume=False, overwrite=True, **SETTINGS)
    assert s["rendered"] == path.n_frames


def test_cancel_from_progress_keeps_finished_frames_and_resumes(scene, path, tmp_path):
    stop_after = 3
    with pytest.raises(CancelledError):
        render_path(scene, path, tmp_path, progress=lambda d, t: d < stop_after, **SETTINGS)
    assert len(frame_files(tmp_path)) == stop_after
    assert all(is_complete_png(f, W, H) for f in frame_files(tmp_path))
    assert not leftovers(tmp_path)
    summary = render_path(scene, path, tmp_path, progress=False, **SETTINGS)
    assert summary["skipped"] == stop_after


def test_cancel_event_mid_frame_leaves_no_partial_file(scene, path, tmp_path):
    event = threading.Event()
    polls = []

    def cancel():  # set after the first frame's tiles were polled a few times
        polls.append(1)
        if len(polls) > 2:
            event.set()
        return event.is_set()

    with pytest.raises(CancelledError):
        render_path(scene, path, tmp_path, progress=False, cancel=cancel, **SETTINGS)
    assert all(is_complete_png(f, W, H) for f in frame_files(tmp_path))
    assert not leftovers(tmp_path)


def test_interrupted_write_leaves_no_part_file(scene, path, tmp_path, monkeypatch):
    real_fsync = os.fsync
    writes = []

    def fsync_then_interrupt(fd):
        writes.append(fd)
        if len(writes) == 4:  # manifest, frames 0 and 1, then frame 2's write is interrupted
            raise KeyboardInterrupt
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        render_path(scene, path, tmp_path, progress=False, **SETTINGS)
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert [f.name for f in frame_files(tmp_path)] == ["frame_00000.png", "frame_00001.png"]
    assert not leftovers(tmp_path)


def test_stale_part_files_are_removed_on_resume(scene, path, tmp_path):
    render_path(scene, path, tmp_path, progress=False, **SETTINGS)
    (tmp_path / ".frame_00002.png.abc123.part").write_bytes(b"half")  # a kill -9 mid-write
    render_path(scene, path, tmp_path, progress=False, **SETTINGS)
    assert not leftovers(tmp_path)


#: Mean absolute difference (0..255) between a decoded video frame and its PNG: H.264 at CRF 18
#: and GIF's 256-colour palette are lossy (measured: mp4 ~1, gif ~3).
VIDEO_TOLERANCE = {".mp4": 4.0, ".gif": 8.0}


@pytest.mark.parametrize("ext", [".mp4", ".gif"])
def test_video_decodes_to_every_frame(scene, path, tmp_path, ext):
    iio = pytest.importorskip("imageio.v3")
    pytest.importorskip("imageio_ffmpeg")
    odd = (W - 1, H - 1)  # MP4 pads odd sizes to even
    video = tmp_path / f"orbit{ext}"
    render_path(scene, path, tmp_path / "f", width=odd[0], height=odd[1], video=video,
                progress=False, **SETTINGS)
    plugin = "FFMPEG" if ext == ".mp4" else "pillow"
    frames = list(iio.imiter(video, plugin=plugin))
    assert len(frames) == path.n_frames
    expect = (H, W) if ext == ".mp4" else (odd[1], odd[0])
    assert frames[0].shape[:2] == expect
    # every decoded frame shows its own PNG (lossy codecs: a small mean difference), and is
    # closer to it than to any other frame's (a wrong or reordered frame fails)
    pngs = [iio.imread(f)[:, :, :3].astype(float) for f in sorted((tmp_path / "f").glob("frame_*.png"))]
    diff = np.array([[np.abs(v[: odd[1], : odd[0], :3].astype(float) - p).mean() for p in pngs]
                     for v in frames])
    assert np.all(np.diag(diff) < VIDEO_TOLERANCE[ext]), np.diag(diff)
    distinct = np.array([[np.any(p != q) for q in pngs] for p in pngs])  # an orbit ends where it began
    assert np.all((diff > np.diag(diff)[:, None]) | ~distinct), diff
    with pytest.raises(FileExistsError):
        render_path(scene, path, tmp_path / "f", width=odd[0], height=odd[1], video=video,
                    progress=False, **SETTINGS)


def test_bad_arguments_are_named(scene, path, tmp_path):
    with pytest.raises(InputError, match="video"):
        render_path(scene, path, tmp_path, video=tmp_path / "x.avi", progress=False)
    with pytest.raises(InputError, match="path: expected a CameraPath"):
        render_path(scene, [1, 2, 3], tmp_path, progress=False)
    with pytest.raises(FileFormatError, match="missing.json"):
        render_path(scene, tmp_path / "missing.json", tmp_path, progress=False)
    with pytest.raises(InputError, match="unknown render option"):
        render_path(scene, path, tmp_path, progress=False, sppp=2)
    with pytest.raises(InputError, match="scheduler"):
        render_path(scene, path, tmp_path, progress=False, scheduler="nowhere:1", **SETTINGS)
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a file"):
        render_path(scene, path, tmp_path / "file", progress=False)


def test_cli_orbit_and_path_file(scene, path, tmp_path, capsys):
    args = ["--width", str(W), "--height", str(H), "--spp", "1", "--reflections", "0",
            "--threads", "1", "--scheduler", "serial"]
    assert main(["path", "demo", "orbit", "-o", str(tmp_path / "o"), "--orbit", "0.5",
                 "--fps", "4", *args]) == 0
    assert len(frame_files(tmp_path / "o")) == 3
    saved = path.save(tmp_path / "p.json")
    assert main(["path", "demo", str(saved), "-o", str(tmp_path / "p"), *args]) == 0
    assert len(frame_files(tmp_path / "p")) == path.n_frames
    # same command again: everything is skipped; other settings: refused with exit code 2
    assert main(["path", "demo", str(saved), "-o", str(tmp_path / "p"), *args]) == 0
    assert "0 rendered" in capsys.readouterr().out
    assert main(["path", "demo", str(saved), "-o", str(tmp_path / "p"), *args, "--spp", "2"]) == 2
    assert "render settings changed" in capsys.readouterr().err
    assert main(["path", "demo", str(tmp_path / "missing.json"), "-o", str(tmp_path / "m"),
                 *args]) == 2
    assert main(["path", "demo", "orbit", "-o", str(tmp_path / "m"), "--orbit", "0", *args]) == 2
    assert np.all([is_complete_png(f, W, H) for f in frame_files(tmp_path / "p")])


def half_dark_sphere(n=6000):
    """A sphere white on one side (x > 0) and nearly black on the other: its mean luminance,
    and so a frame's own automatic exposure, changes by a factor of several around an orbit."""
    from pointviz import PointCloud

    ball = sphere(n, 0.6)
    colors = np.where(ball.points[:, :1] > 0, 0.9, 0.04) * np.ones((1, 3))
    return Scene([PointCloud(ball.points, ball.normals, colors=colors)], up=(0, 1, 0))


def test_path_frames_share_one_metered_exposure(tmp_path):
    """The frames' own automatic exposures would swing (the oracle: render() of each camera);
    the path's frames share one, the geometric mean of the metering views' own (an independent
    render of each view that path_exposure picks), and the backdrop stays put."""
    from math import exp, fsum, log

    from PIL import Image

    from pointviz.path.exposure import meter_cameras

    scene = half_dark_sphere()
    path = CameraPath.orbit(scene, seconds=2.0, fps=6, width=W, height=H, easing="linear")  # 13
    own = [render(scene, cam, **SETTINGS).exposure for cam in path.cameras()]
    assert max(own) / min(own) > 2.0  # one exposure per frame would pump by that much
    summary = render_path(scene, path, tmp_path, progress=False, **SETTINGS)
    views = meter_cameras([c.to_dict() for c in path.cameras()])
    assert len(views) == 9 and (views[0].width, views[0].height) == (W, H)
    metered = [render(scene, v, **SETTINGS).exposure for v in views]
    assert summary["exposure"] == pytest.approx(exp(fsum(map(log, metered)) / 9), rel=1e-12)
    assert min(own) < summary["exposure"] < max(own)
    frames = [np.asarray(Image.open(f)) for f in frame_files(tmp_path)]
    corners = {tuple(f[0, 0]) for f in frames} | {tuple(f[0, -1]) for f in frames}
    assert len(corners) == 1  # the backdrop, the same in every frame


def test_path_exposure_given_resumed_and_recorded(tmp_path):
    """A given exposure is every frame's and nothing is metered; a metered one is recorded in
    the manifest and reused by a resumed run (even if metering would now say otherwise); a
    folder rendered at another exposure is refused."""
    import json

    import pointviz.path.batch as batch

    scene = half_dark_sphere(2000)
    path = CameraPath.orbit(scene, seconds=1.0, fps=3, width=W, height=H)  # 4 frames
    summary = render_path(scene, path, tmp_path / "given", progress=False, exposure=0.7, **SETTINGS)
    assert summary["exposure"] == 0.7
    for f, cam in zip(frame_files(tmp_path / "given"), path.cameras()):
        assert f.read_bytes() == encode_png(render(scene, cam, **SETTINGS).to_srgb8(exposure=0.7))
    out = tmp_path / "metered"
    first = render_path(scene, path, out, progress=False, **SETTINGS)
    assert json.loads((out / MANIFEST_NAME).read_text())["exposure"] == first["exposure"]
    frame_files(out)[2].unlink()
    real = batch.path_exposure
    batch.path_exposure = lambda *a, **k: pytest.fail("a resumed render metered again")
    try:
        again = render_path(scene, path, out, progress=False, **SETTINGS)
    finally:
        batch.path_exposure = real
    assert again["exposure"] == first["exposure"] and again["rendered"] == 1
    with pytest.raises(InputError, match="the render settings changed"):
        render_path(scene, path, out, progress=False, exposure=2.0, **SETTINGS)


def test_meter_cameras_pick_the_ends_and_spread_evenly():
    from pointviz.camera import Camera
    from pointviz.path.exposure import METER_VIEWS, meter_cameras

    cams = [Camera(eye=(float(i), 0.0, 5.0), target=(0.0, 0.0, 0.0), width=10, height=7).to_dict()
            for i in range(40)]
    picked = [round(c.eye[0]) for c in meter_cameras(cams)]
    assert len(picked) == METER_VIEWS and picked[0] == 0 and picked[-1] == 39
    assert max(np.diff(picked)) - min(np.diff(picked)) <= 1
    assert [(c.width, c.height) for c in meter_cameras(cams[:1])] == [(10, 7)]
    assert [round(c.eye[0]) for c in meter_cameras(cams[:3])] == [0, 1, 2]


@pytest.mark.parametrize("given", [{}, {"lod_pixels": 4}, {"lod_pixels": "auto"},
                                   {"shadows": False, "reflections": 0, "look": "outdoor"}])
def test_path_exposure_meters_each_view_as_render_would(monkeypatch, given):
    """Each metering view goes to metered_exposure (what render() gives that view) with the
    frames' settings as given: their level of detail, samples and denoiser do not enter it."""
    import pointviz.rendering
    from pointviz.path.exposure import path_exposure

    seen = []

    def fake_meter(scene, cam, cancel=None, **kw):
        seen.append((cam, kw))
        return 0.5

    monkeypatch.setattr(pointviz.rendering, "metered_exposure", fake_meter)
    cams = [c.to_dict() for c in CameraPath.orbit(half_dark_sphere(500), seconds=1.0, fps=3,
                                                   width=W, height=H).cameras()]
    assert path_exposure(None, cams, {"spp": 8, "denoise": True, **given}) == pytest.approx(0.5)
    assert len(seen) == len(cams)
    assert [c.to_dict() for c, _ in seen] == cams
    for _, kw in seen:
        assert kw["spp"] == 8 and kw["denoise"] is True and kw["exposure"] is None
        assert all(kw[k] == v for k, v in given.items())


