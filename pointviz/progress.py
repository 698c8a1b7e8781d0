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


class StepBars:
    """Progress of successive named steps (``callback(name, done, total)`` of
    :func:`pointviz.interrupt.reporting`): one :class:`ProgressBar` per step, shown once the
    step has run SHOW_AFTER_S seconds, so that quick steps say nothing."""

    #: A step shorter than this shows no bar, seconds.
    SHOW_AFTER_S = 0.5

    def __init__(self, enabled: bool | None = None):
        self.enabled = enabled
        self._name = None
        self._bar = None
        self._start = 0.0

    def __call__(self, name: str, done: int, total: int):
        now = time.monotonic()
        if name != self._name:
            self._name, self._bar, self._start = name, None, now
        if self._bar is None and now - self._start >= self.SHOW_AFTER_S:
            self._bar = ProgressBar(name, enabled=self.enabled)
            self._bar.start = self._start
        if done >= total:
            self._name = None  # the step ended: the same name again is a new step
        return True if self._bar is None else self._bar(done, total)
