"""The ``pointviz`` command line. Each subcommand lives in ``pointviz/commands/<name>.py`` with
``add_parser(subparsers)`` and ``run(args) -> int``. Errors print one line and exit non-zero."""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import warnings

from .errors import CancelledError, PointvizError
from .interrupt import CancelToken, cancel_scope, reporting, sigint_cancels
from .progress import StepBars


def _spawned_by_the_cli() -> bool:
    """Whether this process is a child that multiprocessing spawned from the CLI: the local Dask
    cluster's workers start by re-importing the parent's main module (this one, or the
    ``pointviz`` script that imports it) under the name ``__mp_main__``, after naming the
    process (the parent's process is always "MainProcess")."""
    mp = sys.modules.get("multiprocessing")
    return "__mp_main__" in sys.modules and mp is not None and (
        mp.current_process().name != "MainProcess")


if _spawned_by_the_cli():
    # Ctrl-C reaches the whole process group; the CLI process handles it (cancels the frames,
    # closes the cluster), so its workers ignore it instead of each printing a KeyboardInterrupt
    # traceback. (Blocking SIGINT while the cluster starts does not reach them: the signal mask
    # is reset in the spawned process.)
    signal.signal(signal.SIGINT, signal.SIG_IGN)

#: Subcommands, in the order ``pointviz --help`` lists them.
COMMANDS = ("render", "view", "compare", "path", "info")
#: Commands run with one OpenBLAS thread (:func:`_single_threaded_blas`): their heavy work is in
#: the core, numpy's matrix products on their small arrays gain nothing from threads, and
#: starting OpenBLAS's pool when numpy loads costs ~0.02-0.03 s of CPU, its idle workers
#: spinning beside the core's threads more.
SINGLE_THREADED_BLAS = ("render", "path")
#: Commands whose process keeps the memory it frees for its own later allocations
#: (:func:`_reuse_freed_memory`): one pipeline whose stages each allocate and free large
#: arrays (the fit's, the tree's, the frame's, the denoiser's), ending when the output is
#: written. (Not ``path``: on the dragon's scans it raised a path render's peak from 228 to
#: 297 MiB, the fit's freed arrays kept; a gain in time was not measured. 2026-11-25.)
REUSE_FREED_MEMORY = ("render",)
#: glibc's mallopt parameters, and the values set for REUSE_FREED_MEMORY: blocks under 1 GiB
#: come from the heap, and freed memory stays in it (not trimmed).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
HEAP_BLOCKS_BELOW = 1 << 30


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line (``pointviz: error: ...``) and exit status 2, like every other
    error of the CLI; ``--help`` still prints the full usage."""

    def error(self, message):
        self.exit(2, f"pointviz: error: {self.prog.split()[-1]}: {' '.join(message.split())}\n"
                     if " " in self.prog else f"pointviz: error: {' '.join(message.split())}\n")


def build_parser(argv=None) -> argparse.ArgumentParser:
    """The parser of every subcommand; given the arguments (``argv``) that name one, the parser
    of that one only, so that a run imports its own command's module and not the others' (the
    ``path`` command's, for one, imports the camera paths and their batch renderer)."""
    parser = _Parser(
        prog="pointviz", description="Ray trace point clouds as surfels; view, compare, animate.")
    parser.add_argument("--version", action="version", version=f"pointviz {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    named = _named_command(argv)
    for name in COMMANDS if named is None else (named,):
        try:
            module = importlib.import_module(f".commands.{name}", __package__)
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.endswith(f"commands.{name}"):
                continue  # not built yet
            raise
        module.add_parser(sub)
    return parser


def _named_command(argv) -> str | None:
    """The subcommand the arguments name, or None: no arguments, an unknown command, or an
    option before it (``--help``, ``--version``), which need the full parser."""
    if argv is None or not argv or argv[0] not in COMMANDS:
        return None
    return argv[0]


def _version() -> str:
    from . import __version__

    return __version__


def main(argv=None) -> int:
    """Run one command. Ctrl-C (SIGINT) only sets a cancel token (:mod:`pointviz.interrupt`);
    the work stops at its next check, outputs in progress are discarded, and the exit status is
    130 with the single line ``pointviz: interrupted``.

    Run as a program (``argv`` None), a command that sets ``exit_fast`` in its parser's
    defaults (``render``: its output is complete, renamed into place, once it returns) ends the
    process as soon as it succeeds, without the interpreter's teardown (:func:`_exit_now`)."""
    if argv is None and _named_command(sys.argv[1:]) in SINGLE_THREADED_BLAS:
        _single_threaded_blas()
    if argv is None and _named_command(sys.argv[1:]) in REUSE_FREED_MEMORY:
        _reuse_freed_memory()
    status, fast = _run(argv)
    if fast and status == 0:
        _exit_now(status)
    return status


def _single_threaded_blas() -> None:
    """One OpenBLAS thread for this process unless the environment says otherwise; only before
    numpy is imported (OpenBLAS reads it once, when numpy loads it)."""
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _reuse_freed_memory() -> bool:
    """Have glibc's allocator keep what the process frees and serve later blocks from it, for
    a run that ends once its output is written: by default every block of 128 kB or more (up
    to 32 MB, as it adapts) is a fresh mapping, returned to the system when freed, so that
    each stage's arrays are page-faulted in again (the sphere scans' render: 177k minor faults,
    ~0.5 s of system time, at load 10; 112k and ~0.3 s with this). The peak memory grows by
    what the heap cannot reuse (+9 % there). Nothing happens where mallopt is missing (not
    glibc); returns whether it was set."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, HEAP_BLOCKS_BELOW)) and bool(
        mallopt(M_TRIM_THRESHOLD, 2**31 - 1))


def _exit_now(status: int) -> None:
    """End the process with ``status`` now: standard output and error flushed, no atexit
    handlers, finalizers or module teardown (tens of ms with numpy, the core and the denoiser
    loaded). Only for a command that leaves nothing to clean up."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be written anyway
            pass
    os._exit(status)


def _run(argv) -> tuple[int, bool]:
    """(exit status, whether the process may end without its teardown)."""
    token = CancelToken()
    # Run as a program (argv None), the handler stays after the run: a Ctrl-C between the end of
    # the command and the end of the process must not become a traceback.
    with sigint_cancels(token, restore=argv is not None), cancel_scope(token), \
            warnings.catch_warnings():
        warnings.showwarning = _warning_line
        fast = False
        try:
            args_in = sys.argv[1:] if argv is None else list(argv)
            parser = build_parser(args_in)
            args = parser.parse_args(args_in)
            fast = argv is None and bool(getattr(args, "exit_fast", False))
            # the preprocessing's steps as progress bars (on a terminal, or with --progress)
            bars = StepBars(enabled=True if getattr(args, "progress", False) else None)
            with reporting(bars):
                status = int(args.run(args) or 0)
            token.check()  # interrupted after the last check: the run did not end normally
            return status, fast
        except (CancelledError, KeyboardInterrupt):
            print("pointviz: interrupted", file=sys.stderr)
            return 130, fast
        except BrokenPipeError as exc:
            if _stdout_closed():  # `pointviz info F | head`: the reader has what it wanted
                return EXIT_BROKEN_PIPE, fast
            print(f"pointviz: error: {_one_line(exc)}", file=sys.stderr)  # another pipe
            return 2, fast
        except (PointvizError, OSError, MemoryError) as exc:
            print(f"pointviz: error: {_one_line(exc)}", file=sys.stderr)
            return 2, fast


def _warning_line(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning raised during a command, as the one line ``pointviz: MESSAGE`` on standard
    error (``office1.pcd: dropped 52744 of 307200 points with NaN/inf coordinates ...``), not
    Python's two lines naming the module and echoing its source. The filters are Python's:
    each warning once per place it is raised, none that Python hides by default."""
    try:
        print(f"pointviz: {_one_line(message)}", file=sys.stderr if file is None else file)
    except (OSError, ValueError):  # standard error closed: a warning is not worth failing for
        pass


#: Exit status when the reader of standard output went away: a filter ended by SIGPIPE's.
EXIT_BROKEN_PIPE = 128 + 13


def _stdout_closed() -> bool:
    """Whether standard output's reader has gone (a write to it fails with a broken pipe); if
    so, standard output is pointed at /dev/null, so that what is still buffered (and the
    interpreter's flush at exit) goes nowhere instead of raising again."""
    import select

    try:
        fd = sys.stdout.fileno()
        poll = select.poll()
        poll.register(fd, select.POLLOUT)
        gone = any(events & select.POLLERR for _, events in poll.poll(0))  # a pipe's, no reader
    except (OSError, ValueError, AttributeError):  # no file descriptor, or no poll here
        return False
    if gone:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, fd)
        os.close(devnull)
    return gone


def _one_line(exc: BaseException) -> str:
    """The error as one readable line: an OSError as "FILE: what" (its message when that already
    names the file), without Python's "[Errno N]" prefix and repeated file name."""
    if isinstance(exc, OSError) and exc.strerror:
        text = exc.strerror
        if exc.filename is not None and str(exc.filename) not in text:
            text = f"{exc.filename}: {text}"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
