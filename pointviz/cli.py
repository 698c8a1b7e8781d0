"""The ``pointviz`` command line. Each subcommand lives in ``pointviz/commands/<name>.py`` with
``add_parser(subparsers)`` and ``run(args) -> int``. Errors print one line and exit non-zero."""

from __future__ import annotations

import argparse
import importlib
import signal
import sys

from .errors import CancelledError, PointvizError
from .interrupt import CancelToken, cancel_scope, sigint_cancels


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


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line (``pointviz: error: ...``) and exit status 2, like every other
    error of the CLI; ``--help`` still prints the full usage."""

    def error(self, message):
        self.exit(2, f"pointviz: error: {self.prog.split()[-1]}: {' '.join(message.split())}\n"
                     if " " in self.prog else f"pointviz: error: {' '.join(message.split())}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="pointviz", description="Ray trace point clouds as surfels; view, compare, animate.")
    parser.add_argument("--version", action="version", version=f"pointviz {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS:
        try:
            module = importlib.import_module(f".commands.{name}", __package__)
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.endswith(f"commands.{name}"):
                continue  # not built yet
            raise
        module.add_parser(sub)
    return parser


def _version() -> str:
    from . import __version__

    return __version__


def main(argv=None) -> int:
    """Run one command. Ctrl-C (SIGINT) only sets a cancel token (:mod:`pointviz.interrupt`);
    the work stops at its next check, outputs in progress are discarded, and the exit status is
    130 with the single line ``pointviz: interrupted``."""
    token = CancelToken()
    # Run as a program (argv None), the handler stays after the run: a Ctrl-C between the end of
    # the command and the end of the process must not become a traceback.
    with sigint_cancels(token, restore=argv is not None), cancel_scope(token):
        try:
            parser = build_parser()
            args = parser.parse_args(argv)
            status = int(args.run(args) or 0)
            token.check()  # interrupted after the last check: the run did not end normally
            return status
        except (CancelledError, KeyboardInterrupt):
            print("pointviz: interrupted", file=sys.stderr)
            return 130
        except (PointvizError, OSError, MemoryError) as exc:
            print(f"pointviz: error: {_one_line(exc)}", file=sys.stderr)
            return 2


def _one_line(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return " ".join(text.split())


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
