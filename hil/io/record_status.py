"""The status beside a record (``<name>.json``, written by :class:`hil.io.recorder.Recorder`),
read back: how the run ended, or that it did not end cleanly (still ``running``, its process
gone: killed or crashed). Read by the recorder's users and by the measurement reader, which
imports nothing of the recorder."""
from __future__ import annotations

import json
import os
from pathlib import Path

__all__ = ["status_of"]

STATUS_MAX_BYTES = 1 << 20


def status_of(record: str | Path) -> dict | None:
    """The status beside ``record`` (``<name>.json``), or None where there is none or it is not
    one. A status still ``running`` whose process is gone (or that names none) gets
    ``"ended_cleanly": False``: the run was killed or crashed before it closed its record."""
    p = Path(record).with_suffix(".json")
    try:
        if not p.is_file() or p.stat().st_size > STATUS_MAX_BYTES:
            return None
        info = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(info, dict) or "status" not in info:
        return None
    if info["status"] == "running":
        info["ended_cleanly"] = False if not _alive(info.get("pid")) else None
    else:
        info["ended_cleanly"] = True
    return info


def _alive(pid) -> bool:
    if not isinstance(pid, int) or pid <= 0:
        return False
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:           # exists, another user's
        return True
    return True
