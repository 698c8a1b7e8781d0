"""Tests of pointviz.distributed: frames rendered on a 2-process Dask LocalCluster are
byte-identical to the serial render (the oracle), the scene is built once per worker, and a
worker killed mid-run does not stop the path from finishing. The default scheduler ("auto")
renders in this process: its frames are checked against a real LocalCluster's (the other
backend as the oracle), in Python and on the command line, with progress, cancel and resume.

The cluster tests start real worker processes (three clusters of two, about 6 s in all on a
2-core machine, so they are not marked slow). Timeouts are generous on purpose (the machine is
shared).
"""

from __future__ import annotations

import os
import pickle
import signal

import pytest

from pointviz.cli import main
from pointviz.distributed import core_identity, render_frame_task
from pointviz.errors import CancelledError
from pointviz.path import CameraPath, is_complete_png, render_path

distributed = pytest.importorskip("distributed")

W, H = 64, 48
SETTINGS = {"spp": 1, "reflections": 0, "threads": 1}
#: Seconds allowed for workers to start or restart on a busy 2-core machine.
CLUSTER_TIMEOUT_S = 120


@pytest.fixture(scope="module")
def path(scene):
    return CameraPath.orbit(scene, seconds=1.0, fps=8, width=W, height=H)  # 9 frames


@pytest.fixture(scope="module")
def serial_frames(scene, path, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    render_path(scene, path, out, progress=False, **SETTINGS)
    return {p.name: p.read_bytes() for p in out.glob("frame_*.png")}


def start_cluster(n=2):
    cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                       dashboard_address=":0", silence_logs=40)
    client = distributed.Client(cluster, timeout=CLUSTER_TIMEOUT_S)
    client.wait_for_workers(n, timeout=CLUSTER_TIMEOUT_S)
    return cluster, client


@pytest.fixture(scope="module")
def cluster():
    cluster, client = start_cluster()
    yield cluster, client
    client.close()
    cluster.close()


def frames_of(folder):
    return {p.name: p.read_bytes() for p in folder.glob("frame_*.png")}


def test_scene_pickles_without_trees_and_rebuilds_the_same_frame(scene, path):
    from pointviz import Scene

    fresh = Scene([o.geometry for o in scene.objects], up=scene.up)
    assert fresh.key == scene.key  # stable content hash
    copy = pickle.loads(pickle.dumps(scene))
    assert copy.key == scene.key
    assert all(g is None for g in copy._built.geometries)  # no trees travel
    cam = path.cameras()[3].to_dict()
    local, _ = render_frame_task(scene, cam, SETTINGS)
    remote, info = render_frame_task(copy, cam, SETTINGS, core_identity())
    assert info["built"] and remote == local
    _, again = render_frame_task(copy, cam, SETTINGS)
    assert not again["built"]  # built once per process, then reused


def test_scene_spec_is_a_deprecated_alias(scene):
    import pointviz.distributed as dist
    from pointviz import Scene

    with pytest.warns(DeprecationWarning, match="scene_spec"):
        assert dist.scene_spec(scene) is scene
    with pytest.warns(DeprecationWarning, match="SceneSpec"):
        assert dist.SceneSpec is Scene


def test_cluster_frames_identical_to_serial(scene, path, serial_frames, cluster, tmp_path):
    _, client = cluster
    summary = render_path(scene, path, tmp_path, scheduler=client, progress=False, **SETTINGS)
    assert frames_of(tmp_path) == serial_frames
    assert summary["rendered"] == path.n_frames and summary["workers"] == 2
    # the scene is built at most once per worker process
    assert all(n == 1 for n in summary["scene_builds"].values())
    pids = set(client.run(os.getpid).values())
    assert set(summary["scene_builds"]) <= pids


def test_cluster_by_address_resumes(scene, path, serial_frames, cluster, tmp_path):
    local_cluster, _ = cluster
    render_path(scene, path, tmp_path, progress=False, **SETTINGS)
    for name in ("frame_00002.png", "frame_00007.png"):
        (tmp_path / name).unlink()
    summary = render_path(scene, path, tmp_path, scheduler=local_cluster.scheduler_address,
                          progress=False, **SETTINGS)
    assert summary["rendered"] == 2 and summary["skipped"] == path.n_frames - 2
    assert frames_of(tmp_path) == serial_frames


def test_local_cluster(scene, path, serial_frames, tmp_path):
    summary = render_path(scene, path, tmp_path, scheduler="local", workers=2, progress=False,
                          **SETTINGS)
    assert summary["workers"] == 2
    assert frames_of(tmp_path) == serial_frames


def test_default_mode_renders_here_identical_to_a_local_cluster(scene, path, tmp_path):
    settings = {**SETTINGS, "threads": None}  # the default's threads: every core of this process
    local = render_path(scene, path, tmp_path / "local", scheduler="local", workers=2,
                        progress=False, **settings)
    assert local["workers"] == 2 and sum(local["scene_builds"].values()) >= 1
    oracle = frames_of(tmp_path / "local")
    assert len(oracle) == path.n_frames

    calls = []
    summary = render_path(scene, path, tmp_path / "default",
                          progress=lambda done, total: calls.append((done, total)), **settings)
    assert summary["scheduler"] == "serial" and summary["workers"] == 0  # no cluster started
    assert summary["scene_builds"] == {} and summary["startup_seconds"] == 0.0
    assert frames_of(tmp_path / "default") == oracle
    assert calls == [(i, path.n_frames) for i in range(path.n_frames + 1)]

    # cancelled from its progress callback: the finished frames stay whole, a rerun resumes
    out = tmp_path / "cancelled"
    stop_after = 4
    with pytest.raises(CancelledError):
        render_path(scene, path, out, progress=lambda done, total: done < stop_after, **settings)
    assert sorted(frames_of(out)) == sorted(oracle)[:stop_after]
    assert all(is_complete_png(f, W, H) for f in out.glob("frame_*.png"))
    assert not [f for f in out.iterdir() if f.name.startswith(".")]
    resumed = render_path(scene, path, out, progress=False, **settings)
    assert resumed["skipped"] == stop_after and resumed["rendered"] == path.n_frames - stop_after
    assert frames_of(out) == oracle


def test_cli_default_renders_here_identical_to_local_cluster(tmp_path, capsys):
    args = ["--width", str(W), "--height", str(H), "--spp", "1", "--reflections", "0",
            "--orbit", "0.5", "--fps", "8", "--no-denoise"]
    assert main(["path", "demo", "orbit", "-o", str(tmp_path / "local"), *args,
                 "--scheduler", "local", "--workers", "2"]) == 0
    assert "on 2 workers at tcp://" in capsys.readouterr().out
    assert main(["path", "demo", "orbit", "-o", str(tmp_path / "default"), *args,
                 "--progress"]) == 0
    captured = capsys.readouterr()
    assert "in this process" in captured.out or "on this process" in captured.out
    assert "path: 100%" in captured.err  # the progress lines (stderr is not a terminal here)
    assert len(frames_of(tmp_path / "local")) == 5
    assert frames_of(tmp_path / "default") == frames_of(tmp_path / "local")
    # rerun in the default mode after losing two frames: only those are rendered again
    for name in ("frame_00001.png", "frame_00003.png"):
        (tmp_path / "default" / name).unlink()
    assert main(["path", "demo", "orbit", "-o", str(tmp_path / "default"), *args]) == 0
    assert "(2 rendered, 3 already there)" in capsys.readouterr().out
    assert frames_of(tmp_path / "default") == frames_of(tmp_path / "local")


def test_killed_worker_still_finishes(scene, serial_frames, tmp_path):
    # a longer path so that frames remain queued when the worker dies
    path = CameraPath.orbit(scene, seconds=1.0, fps=24, width=W, height=H)  # 25 frames
    cluster, client = start_cluster()
    try:
        victims = []

        def kill_one_worker_after_first_frame(done, total):
            if done == 1 and not victims:
                pid = next(iter(client.run(os.getpid).values()))
                victims.append(pid)
                os.kill(pid, signal.SIGKILL)  # the worker process dies mid-run; its nanny restarts it
            return True

        summary = render_path(scene, path, tmp_path / "dist", scheduler=client, retries=3,
                              progress=kill_one_worker_after_first_frame, **SETTINGS)
        assert victims and summary["rendered"] == path.n_frames
        assert victims[0] not in set(client.run(os.getpid).values())  # a new process took over
    finally:
        client.close()
        cluster.close()
    render_path(scene, path, tmp_path / "serial", progress=False, **SETTINGS)
    assert frames_of(tmp_path / "dist") == frames_of(tmp_path / "serial")


def test_worker_with_another_core_build_refuses(scene, path):
    from pointviz.errors import PointvizError

    copy = pickle.loads(pickle.dumps(scene))
    with pytest.raises(PointvizError, match="differs from the client's"):
        render_frame_task(copy, path.cameras()[0].to_dict(), SETTINGS, "0.0.0+another-build")
