"""Several Python threads on one scene: same results as serial runs; cancelling is safe.

The core keeps no global state (each call spawns and joins its own workers, every render gets its
own tile renderers), so concurrent calls on one SurfelScene or Scene must not interfere.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import pointviz
from pointviz import Camera, PointCloud, Scene, SurfelScene
from pointviz.errors import CancelledError

from . import samples as S

N_THREADS = 4


@pytest.fixture(scope="module")
def setup():
    pts = S.sample_points(3000, seed=2).astype(np.float64)
    colors = (pts + 1) / 2
    cloud = PointCloud(pts, normals=pts, radii=0.06, colors=colors)
    surfels = SurfelScene(cloud, threads=2)
    scene = Scene([cloud])
    cam = Camera.look_at((0.3, 0.8, 3.5), (0, 0, 0), width=40, height=30)
    rng = np.random.default_rng(4)
    o = rng.normal(size=(4000, 3))
    o = 3 * o / np.linalg.norm(o, axis=1, keepdims=True)
    rays = np.hstack([o, rng.uniform(-0.8, 0.8, (4000, 3)) - o])
    return cloud, surfels, scene, cam, rays


def _cast(surfels, rays, cam):
    out = surfels.cast_rays(rays, camera=cam)
    occ = surfels.occluded(rays, 0.5)
    return out["t_hit"], out["normals"], out["index"], occ


def _render(scene, cam, seed):
    f = pointviz.render(scene, cam, spp=2, reflections=1, seed=seed, threads=2)
    return f.color, f.depth, f.alpha


def test_threads_casting_and_rendering_match_serial(setup):
    _, surfels, scene, cam, rays = setup
    serial_cast = _cast(surfels, rays, cam)
    serial_frames = {s: _render(scene, cam, s) for s in (0, 1)}
    start = threading.Barrier(N_THREADS)

    def job(k):
        start.wait()  # all threads hit the scene at the same moment
        results = []
        for rep in range(2):
            if (k + rep) % 2:
                results.append(("cast", None, _cast(surfels, rays, cam)))
            else:
                seed = k % 2
                results.append(("render", seed, _render(scene, cam, seed)))
        return results

    with ThreadPoolExecutor(N_THREADS) as pool:
        all_results = [r for rs in pool.map(job, range(N_THREADS)) for r in rs]
    assert len(all_results) == 2 * N_THREADS
    for kind, seed, got in all_results:
        want = serial_cast if kind == "cast" else serial_frames[seed]
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)


def test_cancel_from_another_thread_is_safe(setup):
    """A render cancelled from another thread while it runs raises CancelledError, and the
    scene renders exactly as before afterwards."""
    _, _, scene, cam, _ = setup
    before = _render(scene, cam, 0)
    big = cam.with_size(640, 480)
    stop = threading.Event()
    started = threading.Event()
    outcome = {}

    def progress(done, total):
        started.set()
        assert stop.wait(120), "the test never cancelled"  # the render waits for the cancel
        return True

    def run():
        try:
            outcome["frame"] = pointviz.render(scene, big, spp=16, cancel=stop, progress=progress,
                                               threads=2)
        except CancelledError as exc:
            outcome["cancelled"] = exc
        except BaseException as exc:  # noqa: BLE001 - the test reports anything else
            outcome["other"] = exc

    t = threading.Thread(target=run)
    t.start()
    assert started.wait(120), "the render never reported progress"
    stop.set()
    t.join(120)
    assert not t.is_alive()
    assert "other" not in outcome, repr(outcome.get("other"))
    assert "cancelled" in outcome, "the render finished although it was cancelled mid-frame"
    after = _render(scene, cam, 0)
    for x, y in zip(before, after):
        np.testing.assert_array_equal(x, y)


def test_many_cancels_while_others_render(setup):
    """Renders cancelled at random moments while other threads render the same scene."""
    _, _, scene, cam, _ = setup
    want = _render(scene, cam, 0)
    rng = np.random.default_rng(9)
    delays = rng.uniform(0.0, 0.05, 6)

    def cancelled_render(delay):
        ev = threading.Event()
        timer = threading.Timer(delay, ev.set)
        timer.start()
        try:
            pointviz.render(scene, cam.with_size(320, 240), spp=4, cancel=ev, threads=1)
            return "done"
        except CancelledError:
            return "cancelled"
        finally:
            timer.cancel()

    def full_render(_):
        return _render(scene, cam, 0)

    with ThreadPoolExecutor(N_THREADS) as pool:
        cancels = pool.map(cancelled_render, delays)
        fulls = pool.map(full_render, range(3))
        outcomes = list(cancels)
        frames = list(fulls)
    assert set(outcomes) <= {"done", "cancelled"}
    print(f"\nrandom cancels: {outcomes.count('cancelled')} cancelled, {outcomes.count('done')} done")
    for got in frames:
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)
