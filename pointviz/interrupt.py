"""Cooperative interruption: one cancel token, set by whoever wants the work to stop, checked by
the work at safe points.

* The CLI installs :func:`sigint_cancels`: its SIGINT handler only sets the token. Nothing raises
  ``KeyboardInterrupt`` into arbitrary code (a ``KeyboardInterrupt`` raised in the middle of
  SciPy's threaded k-NN query let the interpreter free arrays its threads were still writing:
  the segfault after ``pointviz: interrupted``).
* Long core calls poll the token through :func:`poll` (the C++ runner calls it every few ms on
  the calling thread and sets ``Progress::cancel``); Python code calls :func:`check` or
  :func:`stage` between steps. Both raise :class:`~pointviz.errors.CancelledError`, which the
  CLI maps to exit status 130 and the single line ``pointviz: interrupted``.
* The token in force is a context variable (:func:`cancel_scope`), so library code finds it
  without every function taking a ``cancel`` argument, and two scopes in two threads do not mix.

Test hook. With ``POINTVIZ_TEST_PAUSE_AT=<stage>`` in the environment, the first time the process
reaches that stage it writes the file named by ``POINTVIZ_TEST_SIGNAL_FILE`` and waits (at most
PAUSE_TIMEOUT_S) until its token is set, so a test can send SIGINT at exactly that stage.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import signal
import threading
import time

from .errors import CancelledError

#: Named stages, in the order a command reaches them (see :func:`stage`).
STAGES = (
    "imported",     # the command's modules are imported, nothing read yet
    "loaded",       # the input is read
    "normals",      # normals and radii are estimated
    "built",        # the surfel trees are built
    "cluster",      # (Dask) the cluster is up and connected
    "scattered",    # (Dask) the scene is on every worker
    "first_tile",   # a render has finished its first tile
    "first_frame",  # (path) the first frame has arrived
    "writing",      # an output's temporary file is written, not yet renamed into place
    "encoding",     # (video) the encoder has its first frame
)
#: Environment variables of the test hook.
PAUSE_ENV = "POINTVIZ_TEST_PAUSE_AT"
SIGNAL_FILE_ENV = "POINTVIZ_TEST_SIGNAL_FILE"
#: Longest a paused stage waits for its interrupt, seconds: a test that never sends it fails on
#: its own assertion instead of hanging the suite.
PAUSE_TIMEOUT_S = 120.0
#: Sleep slice of that wait; Python runs signal handlers between slices.
PAUSE_SLICE_S = 0.005

_paused: set[str] = set()
#: The callback of :func:`reporting` and the name of the step in force (:func:`step_named`).
_reporter: contextvars.ContextVar = contextvars.ContextVar("pointviz_reporter", default=None)
_step_name: contextvars.ContextVar = contextvars.ContextVar("pointviz_step_name", default=None)


class CancelToken:
    """A cancel flag shared between the code that sets it (a signal handler, a GUI button) and
    the code that checks it (any thread)."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def set(self) -> None:
        self._event.set()

    def is_set(self) -> bool:
        return self._event.is_set()

    def check(self) -> None:
        """Raise :class:`CancelledError` once the token is set."""
        if self._event.is_set():
            raise CancelledError("interrupted")


_current: contextvars.ContextVar[CancelToken | None] = contextvars.ContextVar(
    "pointviz_cancel_token", default=None)


def current() -> CancelToken | None:
    """The token of the innermost :func:`cancel_scope` of this thread, or None."""
    return _current.get()


def cancelled() -> bool:
    """Whether the token in force is set."""
    token = _current.get()
    return token is not None and token.is_set()


def check() -> None:
    """Raise :class:`CancelledError` if the token in force is set."""
    token = _current.get()
    if token is not None:
        token.check()


def poll(done: int = 0, total: int = 0) -> bool:
    """The core's progress callback when its caller passes none: False (stop) once cancelled.
    Inside :func:`reporting` and a :func:`step_named` step, it also reports the step's progress."""
    report = _reporter.get()
    if report is not None and total:
        name = _step_name.get()
        if name is not None:
            report(name, done, total)
    return not cancelled()


@contextlib.contextmanager
def reporting(callback):
    """Inside, the core's calls that take no progress callback of their own (the
    preprocessing: neighbours, normals, radii, the surface fit, ...) report to
    ``callback(name, done, total)``, ``name`` the step's (:func:`step_named`), and once more with
    ``done == total`` when the step ends. The command line shows them as bars
    (:class:`pointviz.progress.StepBars`)."""
    with _in_force(_reporter, callback):
        yield callback


@contextlib.contextmanager
def step_named(name: str):
    """The core calls inside report their progress under ``name`` (see :func:`reporting`)."""
    with _in_force(_step_name, name):
        yield
        report = _reporter.get()
        if report is not None:
            report(name, 1, 1)


@contextlib.contextmanager
def cancel_scope(token: CancelToken | None = None):
    """Make ``token`` (a new one by default) the token in force for this thread's code inside."""
    token = CancelToken() if token is None else token
    with _in_force(_current, token):
        yield token


@contextlib.contextmanager
def _in_force(var: contextvars.ContextVar, value):
    """``var`` set to ``value`` inside, its previous value back on the way out."""
    reset = var.set(value)
    try:
        yield value
    finally:
        var.reset(reset)


@contextlib.contextmanager
def sigint_cancels(token: CancelToken, restore: bool = True):
    """Inside, SIGINT (Ctrl-C) sets ``token`` instead of raising ``KeyboardInterrupt``; with
    ``restore`` the previous handler is put back on the way out.

    Only the main thread can install signal handlers; elsewhere this does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield token
        return
    previous = signal.signal(signal.SIGINT, lambda signum, frame: token.set())
    try:
        yield token
    finally:
        if restore:
            signal.signal(signal.SIGINT, previous)


def stage(name: str) -> None:
    """Mark that the process reached the named stage (one of STAGES): a cancellation point
    (raises :class:`CancelledError` once cancelled) and the test hook's pause point."""
    if name not in STAGES:
        raise ValueError(f"stage: unknown stage {name!r}; expected one of {STAGES}")
    if os.environ.get(PAUSE_ENV) == name and name not in _paused:
        _paused.add(name)
        _pause(name)
    check()


def _pause(name: str) -> None:
    """Tell the test (signal file) and wait until the token is set or PAUSE_TIMEOUT_S passes."""
    path = os.environ.get(SIGNAL_FILE_ENV)
    if path:
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "w") as f:
            f.write(name)
        os.replace(tmp, path)  # the test sees the whole file or none
    token = _current.get()
    deadline = time.monotonic() + PAUSE_TIMEOUT_S
    while not (token is not None and token.is_set()) and time.monotonic() < deadline:
        time.sleep(PAUSE_SLICE_S)
