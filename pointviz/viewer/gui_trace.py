"""What the GUI thread did, and when: a ring buffer of timed spans and the window's phases.

The viewer wraps each piece of its own work on the GUI thread (the tick event, the handlers that
worker threads post, the live frame's upload, redraw requests) in :meth:`GuiTrace.span`, and
marks the window's phases (first tick, preview orbit, live on, orbit, hold, screenshot, close)
with :meth:`GuiTrace.mark` and one-time events (first live frame, first still pass, first denoised
frame) with :meth:`GuiTrace.event`. Time the GUI thread spends inside Open3D between two traced
spans (drawing the window, handling events) shows up as the gap between them. Garbage
collections are recorded too (with the thread that ran them: a collection on any thread holds
the GIL, so the GUI thread's Python work waits for it).

A driver that timed a round trip to the GUI thread asks :meth:`GuiTrace.explain` what happened
during it. Appending to a bounded deque costs about a microsecond; the trace is always on.
"""

from __future__ import annotations

import collections
import contextlib
import gc
import threading
import time

#: Spans kept (the oldest are dropped): about 40 s of a busy live view at ~100 ticks a second
#: with a few spans each.
CAPACITY = 16384
#: Garbage collections shorter than this are not recorded, seconds.
GC_MIN_S = 0.002


class GuiTrace:
    """Timed spans of the GUI thread's work and the window's phases.

    Times are ``time.monotonic()`` seconds relative to ``t0`` (the viewer's start).

    Attributes
    ----------
    spans : deque of (start, what, seconds)
    marks : list of (time, phase)
        The window's phases (startup before the first).
    events : list of (time, name)
        One-time events within them (the first live frame...).
    """

    def __init__(self, t0: float | None = None, capacity: int = CAPACITY):
        self.t0 = time.monotonic() if t0 is None else t0
        self.spans: collections.deque = collections.deque(maxlen=capacity)
        self.marks: list = []
        self.events: list = []
        self._gc_start: dict = {}
        self._gc_hooked = False

    def now(self) -> float:
        return time.monotonic() - self.t0

    @contextlib.contextmanager
    def span(self, what: str):
        """Time the enclosed work as ``what``."""
        t = time.monotonic()
        try:
            yield
        finally:
            self.spans.append((t - self.t0, what, time.monotonic() - t))

    def add(self, what: str, start: float, seconds: float) -> None:
        """Record a span measured elsewhere (``start`` in ``time.monotonic()`` seconds)."""
        self.spans.append((start - self.t0, what, seconds))

    def mark(self, phase: str) -> None:
        """The window enters ``phase`` now (each phase is recorded once, the first time)."""
        if all(p != phase for _, p in self.marks):
            self.marks.append((self.now(), phase))

    def event(self, name: str) -> None:
        """``name`` happens now (recorded the first time only)."""
        if all(n != name for _, n in self.events):
            self.events.append((self.now(), name))

    def phase_at(self, t: float) -> str:
        """The last phase marked at or before ``t`` (seconds since t0); "startup" before any."""
        phase = "startup"
        for tm, p in self.marks:
            if tm <= t:
                phase = p
        return phase

    # -- garbage collections (any thread)
    def hook_gc(self) -> None:
        if not self._gc_hooked:
            gc.callbacks.append(self._on_gc)
            self._gc_hooked = True

    def unhook_gc(self) -> None:
        if self._gc_hooked:
            gc.callbacks.remove(self._on_gc)
            self._gc_hooked = False

    def _on_gc(self, phase, info) -> None:
        tid = threading.get_ident()
        if phase == "start":
            self._gc_start[tid] = time.monotonic()
            return
        t = self._gc_start.pop(tid, None)
        if t is not None and time.monotonic() - t >= GC_MIN_S:
            self.add(f"gc gen{info.get('generation')} ({threading.current_thread().name})",
                     t, time.monotonic() - t)

    # -- reading
    def explain(self, start: float, seconds: float) -> dict:
        """What the GUI thread did during ``[start, start + seconds]`` (``time.monotonic()``
        seconds): the phase, the traced spans overlapping it (longest first, at most 6), and
        the longest stretch in it without any traced span (time inside Open3D: drawing the
        window, or waiting for the GIL or the CPU)."""
        a, b = start - self.t0, start - self.t0 + seconds
        over = [s for s in list(self.spans) if s[0] < b and s[0] + s[2] > a]
        gap, edge = 0.0, a
        for t, _, d in sorted(over):
            if t > edge:
                gap = max(gap, t - edge)
            edge = max(edge, t + d)
        gap = max(gap, b - edge)
        top = sorted(over, key=lambda s: -s[2])[:6]
        return {"t": round(a, 4), "seconds": round(seconds, 4), "phase": self.phase_at(a),
                "untraced_s": round(gap, 4),
                "spans": [[round(t, 4), w, round(d, 4)] for t, w, d in top]}

    def to_dict(self) -> dict:
        """The trace for a JSON report: phases, and per kind of span its count, total and
        longest seconds, and the spans of 20 ms or more."""
        spans = list(self.spans)
        kinds: dict = {}
        for _, what, d in spans:
            k = kinds.setdefault(what, [0, 0.0, 0.0])
            k[0] += 1
            k[1] += d
            k[2] = max(k[2], d)
        return {"phases": [[round(t, 4), p] for t, p in self.marks],
                "events": [[round(t, 4), n] for t, n in self.events],
                "kinds": {w: {"count": n, "total_s": round(s, 4), "max_s": round(m, 4)}
                          for w, (n, s, m) in sorted(kinds.items())},
                "slow_spans": [[round(t, 4), w, round(d, 4)] for t, w, d in spans
                               if d >= 0.02],
                "spans_kept": len(spans)}


__all__ = ["GuiTrace"]
