"""Progress of the commands that take more than a moment (diagnose, fit, emps, ...), on stderr.

The count, its total and the time left: on a terminal a tqdm bar; elsewhere (a pipe, a log file,
CI) one plain line per step at most every :data:`LINE_INTERVAL` seconds, so that a log shows it
without a bar's carriage returns. ``--json`` changes nothing here: stdout carries the JSON alone,
stderr the progress (a 100 s ``hil emps --json`` is not silent). The library reports progress
through a callback: ``progress(name)``, one step done (or started) with its name; and, where it
learns of more work as it goes (a diagnosis chain's next step), ``progress.expect(n)``: n more
steps to the total (:func:`hil.ident.progress.expect`).
"""
from __future__ import annotations

import sys
import time
from contextlib import contextmanager

__all__ = ["bar", "shown", "LINE_INTERVAL", "announce_compiles", "COMPILE_NOTICE"]

# the least time between two plain progress lines (not a terminal)
LINE_INTERVAL = 2.0

# said once, where a run must compile the simulator's loops (numba's cache has none for this
# installation): else a first run is silent for a while (hil move: 12 s at load 1.9 on 2 cores)
COMPILE_NOTICE = ("hil: compiling the simulator once for this installation (some 10-60 s; later runs "
                  "load it from numba's cache)")
_OWN_PACKAGES = ("sim_plant.", "drivers.", "hil.")
_announced = False


def announce_compiles(stream=None) -> None:
    """Say :data:`COMPILE_NOTICE` on stderr the first time in this process that numba compiles one
    of the project's functions. numba raises its ``numba:compile`` event on a cache miss alone (a
    loop loaded from the cache raises none), so a warm installation says nothing."""
    from numba.core import event

    class _Notice(event.Listener):
        def on_start(self, ev):
            global _announced
            fn = getattr(ev.data.get("dispatcher"), "py_func", None)
            if _announced or not str(getattr(fn, "__module__", "")).startswith(_OWN_PACKAGES):
                return
            _announced = True
            print(COMPILE_NOTICE, file=stream or sys.stderr, flush=True)

        def on_end(self, ev):
            pass

    if not getattr(announce_compiles, "installed", False):
        event.register("numba:compile", _Notice())
        announce_compiles.installed = True


def shown(args=None) -> bool:
    """Whether a progress bar (tqdm, redrawn in place) is drawn: only on a terminal. Off a terminal
    :func:`bar` writes plain lines instead; ``--json`` is no reason to hide progress (it goes to
    stderr, the JSON to stdout)."""
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


def _clock(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 60}:{s % 60:02d}" if s >= 60 else f"{s} s"


class _Lines:
    """Plain progress lines: ``emps: 3/12 fits (25 %), 0:41 elapsed, ETA 2:03: coulomb_friction``."""

    def __init__(self, desc: str, total: int | None, unit: str, stream):
        self.desc, self.total, self.unit, self.stream = desc, total, unit, stream
        self.n, self.t0, self.last = 0, time.perf_counter(), -float("inf")

    def update(self, name=None) -> None:
        self.n += 1
        now = time.perf_counter()
        if now - self.last < LINE_INTERVAL and self.n != self.total:
            return
        self.last = now
        elapsed = now - self.t0
        if self.total:
            left = elapsed / self.n * max(self.total - self.n, 0)
            text = (f"{self.desc}: {self.n}/{self.total} {self.unit}s ({100 * self.n / self.total:.0f} %), "
                    f"{_clock(elapsed)} elapsed, ETA {_clock(left)}")
        else:
            text = f"{self.desc}: {self.n} {self.unit}s, {_clock(elapsed)} elapsed"
        print(text + (f": {name}" if name else ""), file=self.stream, flush=True)


@contextmanager
def bar(desc: str, args=None, total: int | None = None, unit: str = "fit"):
    """``with bar("diagnose", args, total=n) as step: ... step("coulomb_friction")``: one step per
    call, its name shown beside the count; ``step.expect(k)`` adds k steps to the total."""
    if shown(args):
        from tqdm import tqdm
        b = tqdm(desc=desc, total=total, unit=unit, file=sys.stderr, leave=False, dynamic_ncols=True)

        def step(name=None):
            b.update(1)
            if name:
                b.set_postfix_str(str(name), refresh=True)

        def expect(n: int) -> None:
            b.total = (b.total or 0) + int(n)
            b.refresh()
    else:
        lines = _Lines(desc, total, unit, sys.stderr)
        b = None

        def step(name=None):
            lines.update(name)

        def expect(n: int) -> None:
            lines.total = (lines.total or 0) + int(n)
    step.expect = expect
    try:
        yield step
    finally:
        if b is not None:
            b.close()
