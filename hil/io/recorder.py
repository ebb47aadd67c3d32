"""The recorder: every position tick's channels, streamed to a measurement file as the run goes.

Rows are written whole and flushed every ``flush_every`` rows (and at the end), so that a run
that aborts (exception, Ctrl-C, fault) leaves a complete, valid file with everything recorded up
to the abort. A JSON file beside it (``<name>.json``) says how the run ended and why.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from hil.io.measurement import CHANNELS, UNITS, WRITE_UNIT, format_rows, header_name
from hil.io.safe_write import open_new, write_atomic

__all__ = ["Recorder"]


class Recorder:
    """``with Recorder(path, channels, meta) as rec: rec.append(t=..., x_cmd=..., ...)``."""

    def __init__(self, path: str | Path, channels: list[str], meta: dict | None = None, flush_every: int = 25):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.names = list(channels)
        kinds = [CHANNELS.get(n, "dimensionless") for n in self.names]
        self._factors = np.array([UNITS[WRITE_UNIT[k]][1] for k in kinds])
        # O_NOFOLLOW: a symbolic link planted at the record's name is refused, not followed
        self._fh = open_new(self.path)
        for k, v in (meta or {}).items():
            self._fh.write(f"# {k} = {v}\n")
        self._fh.write(",".join(header_name(n, k) for n, k in zip(self.names, kinds)) + "\n")
        self._fh.flush()
        self.flush_every = flush_every
        self.rows = 0
        self._pending = 0
        self.status = "running"
        self.reason = ""
        self._write_status()

    @property
    def status_path(self) -> Path:
        return self.path.with_suffix(".json")

    def _write_status(self, extra: dict | None = None) -> None:
        info = {"file": self.path.name, "status": self.status, "rows": self.rows, "reason": self.reason,
                "time": time.strftime("%Y-%m-%dT%H:%M:%S")}
        if extra:
            info.update(extra)
        # a fresh temporary name in the folder, renamed over the status (not a fixed .json.tmp)
        write_atomic(self.status_path, json.dumps(info, indent=2))

    def append(self, **values: float) -> None:
        """One row: a value (SI) for every channel of the header."""
        row = [values[n] for n in self.names]
        self._fh.write(",".join(f"{v / f:.10g}" for v, f in zip(row, self._factors)) + "\n")
        self.rows += 1
        self._pending += 1
        if self._pending >= self.flush_every:
            self.flush()

    def extend(self, columns: dict[str, np.ndarray]) -> None:
        """Many rows at once (a simulated run recorded in one go)."""
        cols = [np.asarray(columns[n], float) for n in self.names]
        self._fh.write(format_rows(cols, list(self._factors)))
        self.rows += len(cols[0])
        self.flush()

    def flush(self) -> None:
        self._fh.flush()
        self._pending = 0

    def close(self, status: str = "complete", reason: str = "", extra: dict | None = None) -> None:
        """Close the record with its status and reason. Once closed, a later call changes neither
        (the first to close a run that stopped is the one that knows why: the cycle loop), but
        its ``extra`` (loop statistics, the trip record, where the run started) is added."""
        if self._fh.closed:
            if extra:
                self._write_status(extra)
            return
        self.flush()
        os.fsync(self._fh.fileno())
        self._fh.close()
        self.status, self.reason = status, reason
        self._write_status(extra)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close("complete")
        elif issubclass(exc_type, KeyboardInterrupt):
            self.close("aborted", "interrupted (Ctrl-C)")
        else:
            self.close("aborted", f"{exc_type.__name__}: {exc}")
        return False
