"""Progress of the commands that take more than a moment (diagnose, fit, emps, sweep, frf, ...).

One bar on stderr (tqdm), shown only to a person: silent with ``--json`` and whenever stderr is
not a terminal (a pipe, a log file, CI, the tests), so that what a script reads is never mixed
with it. The library reports progress through a callback (``progress(name)``: one step done);
:func:`bar` gives that callback and closes the bar when the work ends.
"""
from __future__ import annotations

import sys
from contextlib import contextmanager

__all__ = ["bar", "shown"]


def shown(args=None) -> bool:
    """Whether a progress bar is shown: not with --json, and only on a terminal."""
    if args is not None and getattr(args, "json", False):
        return False
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


@contextmanager
def bar(desc: str, args=None, total: int | None = None, unit: str = "fit"):
    """``with bar("diagnose", args) as step: ... step("coulomb_friction")``: one step per call, its
    name shown beside the count; nothing at all when :func:`shown` is false."""
    if not shown(args):
        yield lambda name=None: None
        return
    from tqdm import tqdm
    b = tqdm(desc=desc, total=total, unit=unit, file=sys.stderr, leave=False, dynamic_ncols=True)

    def step(name=None):
        b.update(1)
        if name:
            b.set_postfix_str(str(name), refresh=True)
    try:
        yield step
    finally:
        b.close()
