"""Progress display on stderr for long library calls (a ``progress=`` callable).

The library's long calls take ``progress=callable(done, total)``; :class:`ProgressBar` is the
one such callable they (``render_path(progress=True)``) and the command line share.
"""

from __future__ import annotations

import sys
import time


class ProgressBar:
    """Progress on stderr: a bar redrawn in place on a terminal; elsewhere (logs, CI), one line
    every LOG_STEP percent. Silent when stderr is not a terminal, unless ``enabled=True``."""

    #: Percent between two lines when stderr is not a terminal.
    LOG_STEP = 10

    def __init__(self, label: str, enabled: bool | None = None, width: int = 30):
        self.label = label
        self.tty = sys.stderr.isatty()
        self.enabled = self.tty if enabled is None else enabled
        self.width = width
        self.start = time.monotonic()
        self._last = -1

    def __call__(self, done: int, total: int):
        if not self.enabled or total <= 0:
            return True
        pct = int(100 * done / total)
        step = 1 if self.tty else self.LOG_STEP
        if pct // step == self._last // step and self._last >= 0 and done < total:
            return True
        if pct == self._last:
            return True
        self._last = pct
        el = time.monotonic() - self.start
        if self.tty:
            fill = int(self.width * done / total)
            sys.stderr.write(f"\r{self.label} [{'#' * fill}{'.' * (self.width - fill)}] {pct:3d}% {el:5.1f}s")
            if done >= total:
                sys.stderr.write("\n")
        else:
            sys.stderr.write(f"{self.label}: {pct:3d}% {el:6.1f}s\n")
        sys.stderr.flush()
        return True
