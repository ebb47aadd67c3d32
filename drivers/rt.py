"""Small helpers for the threads that keep a wall-clock cycle (the host's loop, a simulated drive's
cycle): nothing here blocks or allocates in a cycle.

- :func:`fine_timer_slack`: a timed wait ends at its time, not up to 50 us later.
- :class:`CpuLatencyRequest`: the CPUs kept out of idle states deeper than a wake-up latency
  while a cycle runs (Linux PM QoS, ``/dev/cpu_dma_latency``; what ``cyclictest`` does by
  default). An idle CPU that halts takes its idle state's exit latency to wake; a virtual CPU
  that halts is handed back to the hypervisor and wakes when the host schedules it again, now and
  then milliseconds later. A request of 0 us keeps idle CPUs polling: every wake-up (the drive's
  answer, the next deadline) costs microseconds, for the price of CPUs that never sleep while the
  loop runs.
- :class:`SampleBuffer`: the last samples of a per-cycle figure (a latency) in a buffer allocated
  once: appending in the cycle allocates nothing, however long the run.
"""
from __future__ import annotations

import math
import os
import struct

import numpy as np

__all__ = ["fine_timer_slack", "CpuLatencyRequest", "CPU_DMA_LATENCY", "SampleBuffer"]

PR_SET_TIMERSLACK = 29          # linux/prctl.h
CPU_DMA_LATENCY = "/dev/cpu_dma_latency"


def fine_timer_slack() -> bool:
    """The calling thread's timer slack at 1 ns (Linux ``prctl(PR_SET_TIMERSLACK)``): a timed wait
    (sleep, ``select``, a lock acquired with a timeout) then ends at its time, not up to the
    default 50 us later. Returns whether it was set (False off Linux)."""
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_TIMERSLACK, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


class CpuLatencyRequest:
    """A PM QoS request on the CPUs' wake-up latency, held while the file stays open (not real-time:
    made before the cycle starts, released after it ends).

    Parameters
    ----------
    latency : float
        The largest wake-up latency allowed, s (0: idle CPUs poll); ``inf`` or None: no request.
    path : str
        The PM QoS device (Linux ``/dev/cpu_dma_latency``; writable by root, or by a user a udev
        rule or ``chmod`` allows).

    :meth:`hold` returns None when the request holds (or none was asked), else the reason it was
    refused (no such device, no permission), for the caller to warn with; :meth:`release` is safe
    to call twice, and the kernel drops the request when the process ends however it ends.
    """

    def __init__(self, latency: float | None = 0.0, path: str = CPU_DMA_LATENCY):
        self.latency = latency
        self.path = path
        self._fd: int | None = None
        self.refused: str | None = None     # why the last hold() was refused
        self.was_held = False               # whether a request has held (for figures after release)

    @property
    def held(self) -> bool:
        return self._fd is not None

    def hold(self) -> str | None:
        if self._fd is not None or self.latency is None or not math.isfinite(self.latency):
            return None
        us = max(0, int(round(self.latency * 1e6)))
        try:
            fd = os.open(self.path, os.O_WRONLY)
        except OSError as exc:
            self.refused = f"{self.path}: {exc.strerror}"
            return self.refused
        try:
            os.write(fd, struct.pack("=i", us))          # the kernel's format: a 32-bit integer, us
        except OSError as exc:
            os.close(fd)
            self.refused = f"{self.path}: {exc.strerror}"
            return self.refused
        self._fd, self.refused, self.was_held = fd, None, True
        return None

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            try:
                os.close(fd)
            except OSError:
                pass


class SampleBuffer:
    """The last ``capacity`` samples of a figure measured once a cycle, in a float array allocated
    once (a ring): :meth:`append` is real-time (no allocation), ``total`` counts every sample
    appended. Reads like the list it replaces: ``len``, truth, iteration and ``numpy.asarray``
    give the samples held, oldest first (not real-time: a copy)."""

    def __init__(self, capacity: int = 1 << 16):
        self._data = np.zeros(int(capacity))
        self.capacity = int(capacity)
        self.total = 0

    def append(self, value: float) -> None:
        self._data[self.total % self.capacity] = value
        self.total += 1

    def clear(self) -> None:
        self.total = 0

    def __len__(self) -> int:
        return min(self.total, self.capacity)

    def __bool__(self) -> bool:
        return self.total > 0

    def values(self) -> np.ndarray:
        """The samples held, oldest first (a copy)."""
        if self.total <= self.capacity:
            return self._data[:self.total].copy()
        i = self.total % self.capacity
        return np.concatenate((self._data[i:], self._data[:i]))

    def __array__(self, dtype=None, copy=None):
        v = self.values()
        return v if dtype is None else v.astype(dtype)

    def __iter__(self):
        return iter(self.values().tolist())

    def __getitem__(self, index):
        return self.values().tolist()[index]
