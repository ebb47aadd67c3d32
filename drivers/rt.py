"""Small helpers for the threads that keep a wall-clock cycle (the host's loop, a simulated drive's
cycle): nothing here blocks or allocates in a cycle."""
from __future__ import annotations

__all__ = ["fine_timer_slack"]

PR_SET_TIMERSLACK = 29          # linux/prctl.h


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
