"""Worker processes that end with the process that started them.

A pool's workers (the sweep's and the fleet's ``--jobs``, the diagnosis's candidates) are forked
children; where the parent is killed (``kill -9``, a closed terminal, an out-of-memory kill), its
workers were reparented and ran on, each with its task, for as long as the tasks took (23 minutes
were seen). :func:`die_with_parent`, as a pool's initializer, gives each worker a thread that
ends it within :data:`WATCH_PERIOD` of its parent's end: a check of the parent's process id, which
changes when the parent dies, whatever thread of the parent started the worker.
"""
from __future__ import annotations

import os
import threading
import time

__all__ = ["die_with_parent", "WATCH_PERIOD"]

WATCH_PERIOD = 1.0       # s: how often a worker looks for its parent


def _watch(parent: int) -> None:
    while True:
        time.sleep(WATCH_PERIOD)
        if os.getppid() != parent:
            os._exit(1)          # no cleanup to wait for: the parent that would read the results is gone


def die_with_parent(parent: int, then=None, *args) -> None:
    """A pool's initializer: end this worker when the process ``parent`` (the pool's owner,
    ``os.getpid()`` there) is gone; then run ``then(*args)``, the pool's own initializer, if any."""
    if os.getppid() != parent:
        os._exit(1)
    threading.Thread(target=_watch, args=(parent,), name="parent-watch", daemon=True).start()
    if then is not None:
        then(*args)
