"""Ctrl-C at every named stage of the CLI: exit status 130, the single line ``pointviz:
interrupted``, no partial or temporary file, never death by a signal.

No sleeps decide anything here: the CLI runs with the test hook of :mod:`pointviz.interrupt`
(``POINTVIZ_TEST_PAUSE_AT``), which pauses the process at the named stage and writes a signal
file; the test then sends SIGINT to the process group, as a terminal's Ctrl-C does.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import pointviz
from pointviz import Camera, PointCloud, interrupt
from pointviz.errors import CancelledError
from pointviz.path import is_complete_png

from . import samples as S

#: Longest a CLI run may take to reach its stage or to end after the interrupt, seconds (a
#: LocalCluster start on a loaded 2-core machine takes ~10 s; a hang fails here, not at 300 s).
RUN_TIMEOUT_S = 180
INTERRUPTED = "pointviz: interrupted"


def _input(folder):
    """A small PLY without normals (so estimation runs) in ``folder``; its name."""
    (folder / "in.ply").write_bytes(S.ply_binary(S.sample_points(3000, seed=3)))
    return "in.ply"


def _interrupt_at(stage, args, cwd, tmp_path):
    """Run ``pointviz ARGS`` in ``cwd`` paused at ``stage``, send Ctrl-C, return the result."""
    flag = tmp_path / f"reached-{stage}"
    env = dict(os.environ, **{interrupt.PAUSE_ENV: stage, interrupt.SIGNAL_FILE_ENV: str(flag)})
    proc = subprocess.Popen([sys.executable, "-m", "pointviz.cli", *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)  # its own process group, like a terminal job
    try:
        deadline = time.monotonic() + RUN_TIMEOUT_S
        while not flag.exists():  # the hook's signal, not a guess at timing
            if proc.poll() is not None:
                out, err = proc.communicate()
                pytest.fail(f"ended ({proc.returncode}) before reaching stage {stage!r}:\n{err[-2000:]}")
            assert time.monotonic() < deadline, f"stage {stage!r} not reached in {RUN_TIMEOUT_S} s"
            time.sleep(0.01)
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=RUN_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode, out, err


def _check_interrupted(code, err, stage):
    assert code == 130, f"stage {stage}: exit {code}\n{err[-2000:]}"
    assert err.strip() == INTERRUPTED, f"stage {stage}: stderr {err[-2000:]!r}"


def _leftovers(folder, keep=("in.ply",)):
    """Everything in ``folder`` (recursively) that the test did not put there."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.name not in keep)


RENDER_STAGES = ("imported", "loaded", "normals", "built", "first_tile", "writing")


@pytest.mark.slow
@pytest.mark.parametrize("stage", RENDER_STAGES)
def test_render_interrupted_at_each_stage(tmp_path, stage):
    work = tmp_path / "work"
    work.mkdir()
    args = ["render", _input(work), "-o", "out.png", "--width", "64", "--height", "48", "--spp", "2"]
    code, _, err = _interrupt_at(stage, args, work, tmp_path)
    _check_interrupted(code, err, stage)
    assert _leftovers(work) == []


@pytest.mark.slow
def test_render_demo_interrupted_mid_render_with_a_progress_bar(tmp_path):
    """The reported case, made deterministic (it used to send SIGINT when the progress bar
    appeared, and lost the race now and then): the demo at 1280x960, spp 24, progress on."""
    args = ["render", "demo", "-o", "big.png", "--width", "1280", "--height", "960", "--spp", "24",
            "--progress"]
    work = tmp_path / "work"
    work.mkdir()
    code, _, err = _interrupt_at("first_tile", args, work, tmp_path)
    assert code == 130, err[-2000:]
    assert err.strip().splitlines()[-1] == INTERRUPTED and "Traceback" not in err
    assert _leftovers(work) == []


PATH_STAGES = ("imported", "loaded", "normals", "built", "first_tile", "first_frame", "writing",
               "encoding")


def _check_frames_folder(frames):
    """Frames kept by an interrupted path render are whole (a rerun resumes after them)."""
    if not frames.exists():
        return
    for p in frames.iterdir():
        assert not p.name.startswith("."), f"temporary file left: {p.name}"
        if p.suffix == ".png":
            assert is_complete_png(p, 32, 24), f"partial frame {p.name}"


DASK_STAGES = ("loaded", "cluster", "scattered", "first_frame", "writing")


@pytest.mark.slow
@pytest.mark.parametrize("scheduler, stage", [("serial", s) for s in PATH_STAGES]
                         + [("local", s) for s in DASK_STAGES])
def test_path_interrupted_at_each_stage(tmp_path, scheduler, stage):
    """Serial, and on a local Dask cluster (whose workers get the Ctrl-C too and stay quiet)."""
    if scheduler == "local":
        pytest.importorskip("distributed", reason="the Dask path needs the 'paths' extra")
    work = tmp_path / "work"
    work.mkdir()
    args = ["path", _input(work), "orbit", "-o", "frames", "--orbit", "1", "--fps", "3",
            "--width", "32", "--height", "24", "--spp", "1", "--scheduler", scheduler,
            "--workers", "1", "--video", "orbit.mp4"]
    code, _, err = _interrupt_at(stage, args, work, tmp_path)
    _check_interrupted(code, err, stage)
    assert not (work / "orbit.mp4").exists()
    assert not [p for p in work.iterdir() if p.name.startswith(".")]
    _check_frames_folder(work / "frames")


COMPARE_STAGES = ("imported", "first_tile", "writing")


@pytest.mark.slow
@pytest.mark.parametrize("stage", COMPARE_STAGES)
def test_compare_interrupted_at_each_stage(tmp_path, stage):
    work = tmp_path / "work"
    work.mkdir()
    args = ["compare", _input(work), "-o", "report", "--quick", "--methods", "discs"]
    code, _, err = _interrupt_at(stage, args, work, tmp_path)
    _check_interrupted(code, err, stage)
    assert _leftovers(work) == []


# ------------------------------------------------------------------------ in-process mechanism


def test_stage_names_are_checked():
    with pytest.raises(ValueError, match="unknown stage"):
        interrupt.stage("halfway")


def test_check_and_stage_raise_only_once_the_token_in_force_is_set():
    interrupt.check()  # no scope: nothing to check
    with interrupt.cancel_scope() as outer:
        interrupt.stage("loaded")
        with interrupt.cancel_scope() as inner:
            inner.set()
            with pytest.raises(CancelledError):
                interrupt.stage("loaded")
            assert not outer.is_set()
        interrupt.check()  # the outer token is in force again
        outer.set()
        with pytest.raises(CancelledError):
            interrupt.check()
    assert not interrupt.cancelled()


def test_sigint_sets_the_token_and_the_old_handler_comes_back():
    before = signal.getsignal(signal.SIGINT)
    token = interrupt.CancelToken()
    with interrupt.sigint_cancels(token):
        signal.raise_signal(signal.SIGINT)  # runs the handler before returning
        assert token.is_set()
    assert signal.getsignal(signal.SIGINT) is before


@pytest.fixture(scope="module")
def slow_render_args():
    """A cloud and camera whose render takes many polls (~100 tiles of spp 16)."""
    pts = S.sample_points(2000, seed=5).astype(np.float64)
    cloud = PointCloud(pts, normals=pts, radii=0.08)
    return cloud, Camera.look_at((0, 0.5, 4), (0, 0, 0), width=160, height=120)


def test_an_exception_in_the_progress_callback_propagates_unchanged(slow_render_args):
    cloud, cam = slow_render_args

    class Boom(Exception):
        pass

    def progress(done, total):
        raise Boom("from the callback")

    with pytest.raises(Boom, match="from the callback"):
        pointviz.render(cloud, cam, spp=16, progress=progress)
    # the worker has ended and left the core usable
    assert pointviz.render(cloud, cam.with_size(8, 6), spp=1).color.shape == (6, 8, 3)


def test_sigint_during_a_render_under_the_default_handler_raises_keyboardinterrupt(
        slow_render_args):
    """Library use (no CLI): Python's own handler runs on the calling thread while the core
    works; its KeyboardInterrupt stops the render and propagates as itself."""
    cloud, cam = slow_render_args
    calls = []

    def progress(done, total):
        if not calls:
            signal.raise_signal(signal.SIGINT)
        calls.append(done)

    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with pytest.raises(KeyboardInterrupt):
        pointviz.render(cloud, cam, spp=16, progress=progress)
    assert len(calls) <= 1


def test_sigint_during_a_render_under_the_cli_handler_cancels(slow_render_args):
    cloud, cam = slow_render_args
    token = interrupt.CancelToken()

    def progress(done, total):
        signal.raise_signal(signal.SIGINT)

    with interrupt.sigint_cancels(token), interrupt.cancel_scope(token), \
            pytest.raises(CancelledError):
        pointviz.render(cloud, cam, spp=16, progress=progress)
    assert token.is_set()


def test_the_token_in_force_cancels_a_tree_build(slow_render_args):
    from pointviz.surfels import SurfelScene

    cloud, _ = slow_render_args
    with interrupt.cancel_scope() as token:
        token.set()
        with pytest.raises(CancelledError):
            SurfelScene(cloud)
    assert SurfelScene(cloud).tree is not None
