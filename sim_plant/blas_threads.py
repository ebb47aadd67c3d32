"""One BLAS thread for the small matrices of the plant (the discretization's matrix exponential).

scipy's ``expm`` of the chain's 10 x 10 Van Loan block costs about 12 us on one OpenBLAS thread
and 8 ms of CPU (18 ms wall) with OpenBLAS's default of one thread per core on a loaded two-core
machine (issue 26: 389 discretizations, 3 s of CPU in one ``hil diagnose``): the threads are woken
and waited for, and a matrix that small gives them nothing to share. :func:`one_blas_thread` runs a
block with OpenBLAS's count set to 1 and puts it back after; the arithmetic of a 10 x 10 product or
solve is the one thread's either way (the same bits: tests/test_speed_identity.py).

The diagnosis (hil.ident's ``diagnose`` and ``diagnose_chain``, hil fleet's records) runs on one
thread too: OpenBLAS's threads spun on its thin products (a Jacobian's columns, and then scipy's
position periodogram, a 1500 x 1500 product, since compiled: hil.ident.residual) for a quarter of
its CPU time and gave no wall time back, and in a pool that fills the cores (hil fleet, hil
diagnose --jobs) that CPU is the other workers'. One thread also makes long dot products the same
sums on every machine, whatever its cores (two threads add the halves of each in another order).

The OpenBLAS libraries are the ones loaded in this process (numpy's and scipy's wheels bundle
their own; their symbols carry a prefix, ``scipy_openblas_...``), found once from
``/proc/self/maps`` (Linux) or scipy's bundled library folder, and used through ``ctypes`` where
they export ``openblas_set_num_threads_local`` (OpenBLAS 0.3.27 and later). Anywhere else (MKL,
Accelerate, an older OpenBLAS) the block runs as it is.

Despite its name, that setting is the whole process's in OpenBLAS's pthreads builds (the wheels'):
set in one thread, every thread sees it. The diagnosis fits on several threads at once
(hil.ident.parallel), so one thread's block ending must not give the others their BLAS threads
back in the middle of a fit (a long dot product summed in halves: other bits). The blocks are
therefore counted, process-wide: the first to enter sets 1, the last to leave restores the count
it found. A thread outside any block while another is inside runs on one BLAS thread too.
"""
from __future__ import annotations

import ctypes
import glob
import os
import threading
from contextlib import contextmanager

__all__ = ["one_blas_thread", "blas_thread_setters"]

_SETTERS: list | None = None


def _loaded_openblas() -> list[str]:
    """Paths of the OpenBLAS libraries loaded in this process."""
    paths: list[str] = []
    try:
        with open("/proc/self/maps") as maps:
            for line in maps:
                path = line.rsplit(" ", 1)[-1].strip()
                if "openblas" in os.path.basename(path).lower() and path not in paths:
                    paths.append(path)
    except OSError:
        pass
    if not paths:
        try:
            import scipy
            base = os.path.dirname(os.path.dirname(scipy.__file__))
            for pattern in ("scipy.libs/*openblas*", "scipy/.dylibs/*openblas*"):
                paths += glob.glob(os.path.join(base, pattern))
        except ImportError:         # pragma: no cover - scipy is a dependency
            pass
    return paths


def blas_thread_setters() -> list:
    """The ``openblas_set_num_threads_local`` function of each loaded OpenBLAS (found once)."""
    global _SETTERS
    if _SETTERS is None:
        found = []
        for path in _loaded_openblas():
            try:
                fn = ctypes.CDLL(path).openblas_set_num_threads_local
            except (OSError, AttributeError):
                continue
            fn.restype, fn.argtypes = ctypes.c_int, [ctypes.c_int]
            found.append(fn)
        _SETTERS = found
    return _SETTERS


# the blocks inside one_blas_thread now (every thread's), and the counts the first one found
_BLOCKS = {"depth": 0, "saved": []}
_LOCK = threading.Lock()


def _new_lock_in_child() -> None:
    # a fork while another thread held the lock would leave it held in the child forever
    global _LOCK
    _LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_new_lock_in_child)


@contextmanager
def one_blas_thread():
    """Run the block on one OpenBLAS thread; the count is restored when the last block of any
    thread ends (the module's note: the setting is the process's)."""
    setters = blas_thread_setters()
    with _LOCK:
        if _BLOCKS["depth"] == 0:
            _BLOCKS["saved"] = [fn(1) for fn in setters]
        _BLOCKS["depth"] += 1
    try:
        yield
    finally:
        with _LOCK:
            _BLOCKS["depth"] -= 1
            if _BLOCKS["depth"] == 0:
                for fn, n in zip(setters, _BLOCKS["saved"]):
                    fn(n)
