"""The recorder: every position tick's channels, kept in memory in the cycle and streamed to a
measurement file beside it.

The cycle writes each row into a preallocated buffer (:meth:`Recorder.write_row`: one store of
the row's values, no text, no file I/O, as LinuxCNC samples through a ring); a thread of the
recorder's own drains the new rows to the file every ``drain_every`` seconds (10 ms): formatted
there, one ``write()`` per batch to an unbuffered file (the operating system's page cache holds
it; no ``fsync`` until the end). The run's result is built from the buffer
(:meth:`Recorder.channels`), not read back from the file. A run that ends in an orderly way
(complete, trip, fault, exception, Ctrl-C) drains every row before the file is closed: nothing
recorded is lost. A host killed outright (``kill -9``, a crash of the interpreter) loses at most
the rows of its last drain interval, and the last line may be cut in its ``write()``; the reader
(:func:`hil.io.measurement.read`) drops a last line that is cut.

A JSON file beside it (``<name>.json``, the status) says how the run ended and why. While the run
goes it says ``"status": "running"`` with the rows written to the file so far (``rows``), the record
time of the last (``t_s``), the wall time (``time``) and the recording process (``pid``), rewritten
every ``status_every`` seconds (0.5 s) by the same thread, each time at once
(hil.io.safe_write.write_atomic). A status still ``running`` whose process is gone is a run that
did not end cleanly (:func:`status_of`).
"""
from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import numpy as np

from hil.io.measurement import CHANNELS, UNITS, WRITE_UNIT, format_rows, header_name
from hil.io.record_status import status_of
from hil.io.safe_write import open_new, write_atomic

__all__ = ["Recorder", "RowBuffer", "status_of", "STATUS_EVERY", "DRAIN_EVERY"]

STATUS_EVERY = 0.5      # s between the status file's updates while a run goes
DRAIN_EVERY = 0.01      # s between the drains of new rows to the file (what kill -9 can lose)
_FIRST_ROWS = 4096      # rows preallocated when the run does not say how many it will record


class RowBuffer:
    """Rows of named channels (SI) in a preallocated buffer: what the cycle records into, the
    run's result read from (``hil.runtime`` keeps a run that writes no file in one).

    Parameters
    ----------
    channels : list of str
        The columns, in order.
    rows : int
        The rows the run will record, preallocated (a longer run grows the buffer, outside
        real time); 0: a first block of 4096.
    """

    def __init__(self, channels: list[str], rows: int = 0):
        self.names = list(channels)
        self._t_index = self.names.index("t") if "t" in self.names else None
        self._data = np.zeros((int(rows) if rows and rows > 0 else _FIRST_ROWS, len(self.names)))
        self._lock = threading.Lock()        # the buffer's growth against a drain reading it
        self.rows = 0

    @property
    def last_t(self) -> float:
        """The record time of the last row (NaN before the first)."""
        n = self.rows
        return float(self._data[n - 1, self._t_index]) if n and self._t_index is not None else float("nan")

    def write_row(self, values) -> None:
        """One row: a value (SI) for every channel, in their order (real-time: one store into the
        preallocated buffer)."""
        i = self.rows
        if i == self._data.shape[0]:         # a longer run than announced (not real-time then)
            with self._lock:
                self._data = np.concatenate([self._data, np.zeros_like(self._data)])
        self._data[i] = values
        self.rows = i + 1

    def append(self, **values: float) -> None:
        """One row: a value (SI) for every channel, by name."""
        self.write_row([values[n] for n in self.names])

    def _put(self, columns: dict[str, np.ndarray]) -> None:
        """Many rows at once (not real-time)."""
        cols = [np.asarray(columns[n], float) for n in self.names]
        n = len(cols[0]) if cols else 0
        with self._lock:
            need = self.rows + n
            if need > self._data.shape[0]:
                self._data = np.concatenate([self._data[:self.rows], np.zeros((need - self.rows, len(self.names)))])
            for i, c in enumerate(cols):
                self._data[self.rows:need, i] = c
            self.rows = need

    def channels(self) -> dict[str, np.ndarray]:
        """The recorded channels (SI), from memory: one array per channel, a row per write."""
        data = self._data[:self.rows]
        return {n: data[:, i].copy() for i, n in enumerate(self.names)}

    def close(self, status: str = "complete", reason: str = "", extra: dict | None = None) -> None:
        """Nothing to close in memory (the recorder's interface)."""


class Recorder(RowBuffer):
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
    rows : int
        The rows the run will record, preallocated (a longer run grows the buffer, outside
        real time); 0: a first block of 4096.
    drain_every : float or None
        Seconds between the drains of new rows to the file (None: no thread; rows reach the
        file when the record closes).
    """

    def __init__(self, path: str | Path, channels: list[str], meta: dict | None = None,
                 status_every: float | None = STATUS_EVERY, rows: int = 0,
                 drain_every: float | None = DRAIN_EVERY):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        super().__init__(channels, rows)
        kinds = [CHANNELS.get(n, "dimensionless") for n in self.names]
        self._factors = [float(UNITS[WRITE_UNIT[k]][1]) for k in kinds]
        self._io_lock = threading.Lock()     # one writer of the file at a time (drain, extend, close)
        self._written = 0                    # rows in the file
        # O_NOFOLLOW: a symbolic link planted at the record's name is refused, not followed;
        # unbuffered: every write() goes to the file at once (the page cache survives kill -9)
        self._fh = open_new(self.path, binary=True)
        head = "".join(f"# {k} = {_one_line(v)}\n" for k, v in (meta or {}).items())
        head += ",".join(header_name(n, k) for n, k in zip(self.names, kinds)) + "\n"
        self._write(head.encode("utf-8"))
        self.status = "running"
        self.reason = ""
        self._status_lock = threading.Lock()
        self._write_status()
        self._drain = None
        if drain_every is not None and drain_every > 0:
            self._drain = _Drain(self, float(drain_every), status_every)
            self._drain.start()

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
            # what the file holds (a row recorded is in it within a drain interval): after a kill,
            # the status and the record agree
            n = self._written
            info = {"file": self.path.name, "status": self.status, "rows": n, "reason": self.reason,
                    "time": time.strftime("%Y-%m-%dT%H:%M:%S"), "pid": os.getpid()}
            if n and self._t_index is not None:
                info["t_s"] = float(self._data[n - 1, self._t_index])
            if extra:
                info.update(extra)
            # a fresh temporary name in the folder, renamed over the status (not a fixed .json.tmp)
            write_atomic(self.status_path, json.dumps(info, indent=2), sync=sync)

    def extend(self, columns: dict[str, np.ndarray]) -> None:
        """Many rows at once (a simulated run recorded in one go), written to the file at once."""
        self._put(columns)
        self.drain()

    def drain(self) -> None:
        """The rows recorded since the last drain, to the file (not real-time: the drain thread,
        :meth:`extend` and :meth:`close` call it)."""
        with self._io_lock:
            if self._fh.closed:
                return
            with self._lock:
                n = self.rows
                block = self._data[self._written:n]
                if not block.shape[0]:
                    return
                block = block.copy()
            self._write(format_rows(list(block.T), self._factors).encode("ascii"))
            self._written = n

    def flush(self) -> None:
        """Every row recorded so far, to the file now (the drain thread does it every 10 ms)."""
        self.drain()

    def close(self, status: str = "complete", reason: str = "", extra: dict | None = None) -> None:
        """Close the record with its status and reason, every row drained to the file first.
        Once closed, a later call changes neither (the first to close a run that stopped is the
        one that knows why: the cycle loop), but its ``extra`` (loop statistics, the trip
        record, where the run started) is added."""
        if self._drain is not None:
            self._drain.finish()
            self._drain = None
        if self._fh.closed:
            if extra:
                self._write_status(extra)
            return
        try:
            self.drain()
            os.fsync(self._fh.fileno())       # the end of the run: on the disk, not only in the cache
        except OSError as exc:                # a full disk, a removed folder: the status says what is missing
            reason = (f"{reason}; " if reason else "") + \
                f"{self.rows - self._written} row(s) not written to {self.path.name}: {exc}"
        finally:
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


class _Drain(threading.Thread):
    """Outside the cycle: drains a running record's new rows to the file every ``every`` seconds,
    and rewrites its status every ``status_every`` seconds while rows come in (without fsync: the
    page cache survives the process)."""

    def __init__(self, rec: Recorder, every: float, status_every: float | None):
        super().__init__(name=f"record {rec.path.name}", daemon=True)
        self.rec = rec
        self.every = every
        self.status_every = status_every
        self._done = threading.Event()

    def run(self) -> None:
        reported = self.rec.rows
        next_status = time.monotonic() + (self.status_every or 0.0)
        while not self._done.wait(self.every):
            try:
                self.rec.drain()
            except Exception:         # a full disk, a removed folder: the record goes on, the end tells
                continue
            if not self.status_every or time.monotonic() < next_status:
                continue
            next_status = time.monotonic() + self.status_every
            rows = self.rec.rows
            if rows == reported:
                continue
            try:
                self.rec._write_status(sync=False)
            except Exception:
                continue
            reported = rows

    def finish(self) -> None:
        self._done.set()
        if self is not threading.current_thread():
            self.join()


def _one_line(value) -> str:
    """A metadata value on its comment line (a line break in it would end the comment)."""
    return " ".join(str(value).splitlines())
