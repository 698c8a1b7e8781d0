"""Nothing lost: outputs appear atomically, existing files are never replaced silently, and an
interrupted or failed write leaves neither a corrupt output nor a stray ``.part`` file."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

import pointviz
from pointviz import Camera, PointCloud, interrupt
from pointviz.errors import CancelledError
from pointviz.images import atomic_write_bytes, save_image

from . import samples as S

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _leftovers(folder):
    return [p.name for p in folder.iterdir() if p.name.endswith(".part") or p.name.startswith(".")]


@pytest.fixture(scope="module")
def small_frame():
    pts = S.sample_points(300, seed=1).astype(np.float64)
    cloud = PointCloud(pts, normals=pts, radii=0.15)
    cam = Camera.look_at((0, 0.5, 4), (0, 0, 0), width=24, height=18)
    return pointviz.render(cloud, cam, spp=1, reflections=0), cloud, cam


def test_save_refuses_to_overwrite_and_leaves_the_file_untouched(tmp_path, small_frame):
    frame, _, _ = small_frame
    out = tmp_path / "frame.png"
    out.write_bytes(b"precious bytes")
    with pytest.raises(FileExistsError, match="overwrite"):
        frame.save(out)
    assert out.read_bytes() == b"precious bytes"
    frame.save(out, overwrite=True)
    assert out.read_bytes().startswith(PNG_MAGIC)
    assert not _leftovers(tmp_path)


def _writer_module():
    """The module whose code writes the bytes (imageio delegates to pointviz.files)."""
    return sys.modules[atomic_write_bytes.__module__]


@pytest.mark.parametrize("failure", ["publish", "fsync", "write"])
def test_a_failed_write_leaves_the_old_file_and_no_part_file(tmp_path, monkeypatch, failure):
    out = tmp_path / "img.png"
    out.write_bytes(b"old")

    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    if failure == "publish":  # the final rename (or link) fails
        monkeypatch.setattr(os, "replace", boom)
        monkeypatch.setattr(os, "link", boom)
    elif failure == "fsync":
        monkeypatch.setattr(os, "fsync", boom)
    else:  # the disk fills halfway through the data
        monkeypatch.setattr(_writer_module(), "open", lambda *a, **k: _HalfWriter(open(*a, **k)),  # noqa: SIM115
                            raising=False)
    with pytest.raises(OSError, match="No space"):
        atomic_write_bytes(out, b"new data" * 1000, overwrite=True)
    assert out.read_bytes() == b"old"
    assert not _leftovers(tmp_path)


class _HalfWriter:
    """A file whose write stores half the data, then fails like a full disk."""

    def __init__(self, f):
        self.f = f

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()
        return False

    def write(self, data):
        self.f.write(data[: len(data) // 2])
        raise OSError(28, "No space left on device")

    def __getattr__(self, name):
        return getattr(self.f, name)


def test_a_new_file_appears_whole_or_not_at_all(tmp_path, monkeypatch):
    out = tmp_path / "new.png"

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupt)
    monkeypatch.setattr(os, "link", interrupt)
    with pytest.raises(KeyboardInterrupt):
        save_image(out, np.zeros((4, 4, 3), np.float32))
    assert not out.exists() and not _leftovers(tmp_path)


def test_saved_files_get_ordinary_permissions(tmp_path, small_frame):
    frame, _, _ = small_frame
    umask = os.umask(0o022)
    try:
        path = frame.save(tmp_path / "perm.png")
    finally:
        os.umask(umask)
    assert (path.stat().st_mode & 0o777) == 0o644


def test_a_cancel_while_writing_leaves_the_old_file_and_no_temporary(tmp_path, small_frame):
    """Ctrl-C between writing the temporary file and renaming it (stage "writing"): the
    temporary goes, a new path stays absent and an existing file keeps its bytes."""
    frame, _, _ = small_frame
    (tmp_path / "old.png").write_bytes(b"precious bytes")
    with interrupt.cancel_scope() as token:
        token.set()
        with pytest.raises(CancelledError):
            frame.save(tmp_path / "new.png")
        with pytest.raises(CancelledError):
            frame.save(tmp_path / "old.png", overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.png"]
    assert (tmp_path / "old.png").read_bytes() == b"precious bytes"


def _cli(args, cwd, **kw):
    return subprocess.run([sys.executable, "-m", "pointviz.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300, check=False, **kw)


def test_cli_render_refuses_then_overwrites_on_request(tmp_path):
    (tmp_path / "in.ply").write_bytes(S.ply_binary(S.sample_points(200)))
    args = ["render", "in.ply", "-o", "out.png", "--width", "16", "--height", "12", "--spp", "1"]
    first = _cli(args, tmp_path)
    assert first.returncode == 0, first.stderr
    before = (tmp_path / "out.png").read_bytes()
    (tmp_path / "out.png").write_bytes(before + b"user's edit")  # the user's file now
    second = _cli(args, tmp_path)
    assert second.returncode == 2 and "exists" in second.stderr
    assert len(second.stderr.strip().splitlines()) == 1
    assert (tmp_path / "out.png").read_bytes() == before + b"user's edit"
    third = _cli([*args, "--overwrite"], tmp_path)
    assert third.returncode == 0, third.stderr
    assert (tmp_path / "out.png").read_bytes() == before  # deterministic render, replaced whole
    assert not _leftovers(tmp_path)
