"""The recorder: every position tick's channels, streamed to a measurement file as the run goes.

Each row reaches the file in the cycle it is recorded: one ``write()`` of the whole row to an
unbuffered file (the operating system's page cache holds it; no ``fsync`` in the cycle, one at
the end). A host killed outright (``kill -9``, a crash of the interpreter) leaves every row it
recorded but possibly the last, cut in its ``write()``; the reader
(:func:`hil.io.measurement.read`) drops a last line that is cut. A run that aborts in an orderly
way (exception, Ctrl-C, fault) leaves a complete file.

A JSON file beside it (``<name>.json``, the status) says how the run ended and why. While the run
goes it says ``"status": "running"`` with the rows recorded so far (``rows``), the record time of
the last (``t_s``), the wall time (``time``) and the recording process (``pid``), rewritten
every ``status_every`` seconds (0.5 s) by a thread of its own, outside the cycle, each time at
once (hil.io.safe_write.write_atomic). A status still ``running`` whose process is gone is a run
that did not end cleanly (:func:`status_of`).
"""
from __future__ import annotations

import json
import os
import threading
import time
from operator import truediv
from pathlib import Path

import numpy as np

from hil.io.measurement import CHANNELS, UNITS, WRITE_UNIT, format_rows, header_name
from hil.io.record_status import status_of
from hil.io.safe_write import open_new, write_atomic

__all__ = ["Recorder", "status_of", "STATUS_EVERY"]

STATUS_EVERY = 0.5      # s between the status file's updates while a run goes


class Recorder:
    """``with Recorder(path, channels, meta) as rec: rec.append(t=..., x_cmd=..., ...)``.

    Parameters
    ----------
    path : str or Path
        The record (CSV, hil.io.measurement's format); the status is ``path`` with ``.json``.
    channels : list of str
        The columns, in order.
    meta : dict, optional
        ``# key = value`` lines before the header.
    status_every : float or None
        Seconds between the status file's updates while rows come in (None: only at the start
        and at the end).
    """

    def __init__(self, path: str | Path, channels: list[str], meta: dict | None = None,
                 status_every: float | None = STATUS_EVERY):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.names = list(channels)
        kinds = [CHANNELS.get(n, "dimensionless") for n in self.names]
        self._factors = [float(UNITS[WRITE_UNIT[k]][1]) for k in kinds]
        # one row as one string: "%.10g,%.10g,...\n" (the same text as format_rows writes)
        self._row_format = ",".join(["%.10g"] * len(self.names)) + "\n"
        self._t_index = self.names.index("t") if "t" in self.names else None
        # O_NOFOLLOW: a symbolic link planted at the record's name is refused, not followed;
        # unbuffered: every write() goes to the file at once (the page cache survives kill -9)
        self._fh = open_new(self.path, binary=True)
        head = "".join(f"# {k} = {_one_line(v)}\n" for k, v in (meta or {}).items())
        head += ",".join(header_name(n, k) for n, k in zip(self.names, kinds)) + "\n"
        self._write(head.encode("utf-8"))
        self.rows = 0
        self.last_t = float("nan")
        self.status = "running"
        self.reason = ""
        self._status_lock = threading.Lock()
        self._write_status()
        self._updater = None
        if status_every is not None and status_every > 0:
            self._updater = _StatusUpdater(self, float(status_every))
            self._updater.start()

    @property
    def status_path(self) -> Path:
        return self.path.with_suffix(".json")

    def _write(self, data: bytes) -> None:
        """All of ``data`` to the file (an unbuffered write may take part of it)."""
        view = memoryview(data)
        while view:
            n = self._fh.write(view)
            view = view[n:]

    def _write_status(self, extra: dict | None = None, sync: bool = True) -> None:
        with self._status_lock:
            info = {"file": self.path.name, "status": self.status, "rows": self.rows, "reason": self.reason,
                    "time": time.strftime("%Y-%m-%dT%H:%M:%S"), "pid": os.getpid()}
            if self.last_t == self.last_t:             # not NaN: a row has been recorded
                info["t_s"] = self.last_t
            if extra:
                info.update(extra)
            # a fresh temporary name in the folder, renamed over the status (not a fixed .json.tmp)
            write_atomic(self.status_path, json.dumps(info, indent=2), sync=sync)

    def write_row(self, values) -> None:
        """One row: a value (SI) for every channel of the header, in its order (real-time: one
        ``write()``, no flush to the disk)."""
        self._write((self._row_format % tuple(map(truediv, values, self._factors))).encode("ascii"))
        if self._t_index is not None:
            self.last_t = values[self._t_index]
        self.rows += 1

    def append(self, **values: float) -> None:
        """One row: a value (SI) for every channel of the header, by name."""
        self.write_row([values[n] for n in self.names])

    def extend(self, columns: dict[str, np.ndarray]) -> None:
        """Many rows at once (a simulated run recorded in one go)."""
        cols = [np.asarray(columns[n], float) for n in self.names]
        self._write(format_rows(cols, list(self._factors)).encode("ascii"))
        self.rows += len(cols[0])
        if self._t_index is not None and len(cols[0]):
            self.last_t = float(cols[self._t_index][-1])

    def flush(self) -> None:
        """Nothing is held back: every row is written as it comes (kept for callers that flush)."""

    def close(self, status: str = "complete", reason: str = "", extra: dict | None = None) -> None:
        """Close the record with its status and reason. Once closed, a later call changes neither
        (the first to close a run that stopped is the one that knows why: the cycle loop), but
        its ``extra`` (loop statistics, the trip record, where the run started) is added."""
        if self._updater is not None:
            self._updater.finish()
            self._updater = None
        if self._fh.closed:
            if extra:
                self._write_status(extra)
            return
        os.fsync(self._fh.fileno())           # the end of the run: on the disk, not only in the cache
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


class _StatusUpdater(threading.Thread):
    """Rewrites a running record's status every ``every`` seconds while rows come in: outside the
    cycle (the loop only counts rows), without fsync (the page cache survives the process)."""

    def __init__(self, rec: Recorder, every: float):
        super().__init__(name=f"status {rec.status_path.name}", daemon=True)
        self.rec = rec
        self.every = every
        self._done = threading.Event()

    def run(self) -> None:
        written = self.rec.rows
        while not self._done.wait(self.every):
            rows = self.rec.rows
            if rows == written:
                continue
            try:
                self.rec._write_status(sync=False)
            except Exception:         # a full disk, a removed folder: the record goes on, the end tells
                continue
            written = rows

    def finish(self) -> None:
        self._done.set()
        if self is not threading.current_thread():
            self.join()


def _one_line(value) -> str:
    """A metadata value on its comment line (a line break in it would end the comment)."""
    return " ".join(str(value).splitlines())
