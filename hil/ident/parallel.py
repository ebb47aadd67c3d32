"""Fitting many candidates (hil.ident.fit.evaluate), in worker processes.

The replay and its residuals reach the workers by fork, as the arguments of the pool's
initializer (:func:`_start_worker`: a forked process inherits them, nothing large is pickled),
which keeps them for the worker process's tasks; the parent process holds no module state. A
worker sends its Candidate back without its config, which the parent rebuilds from the fitted
parameters. Without fork, or with one job, the candidates are fitted here one after the other. A
candidate that cannot be fitted (ValueError) gives None.
"""
from __future__ import annotations

import multiprocessing as mp

from hil.ident.fit import evaluate
from hil.plant_config import candidate, configure

__all__ = ["evaluate_many"]


def _safe_eval(replay, res0, name, max_nfev, start=None, n_starts=2):
    try:
        return evaluate(replay, name, res0, max_nfev, start, n_starts)
    except ValueError:
        return None


# the replay and its residuals in a worker process (set there by _start_worker; empty in the parent)
_worker_inputs: dict = {}


def _start_worker(replay, res0) -> None:
    """The pool's initializer, in each worker process: keep what the worker's tasks evaluate."""
    _worker_inputs.update(replay=replay, res0=res0)


def _work(args):
    c = _safe_eval(_worker_inputs["replay"], _worker_inputs["res0"], *args)
    if c is not None:
        c.cfg = None            # configs stay in the parent (rebuilt there)
    return c


def evaluate_many(replay, work, res0, jobs, progress):
    """Evaluate the (name, max_nfev, start, n_starts) items, in ``jobs`` processes."""
    from hil.ident.progress import expect
    expect(progress, len(work))
    if jobs > 1 and len(work) > 1:
        try:
            ctx = mp.get_context("fork")
        except ValueError:
            ctx = None
        if ctx is not None:
            out = []
            with ctx.Pool(min(jobs, len(work)), initializer=_start_worker, initargs=(replay, res0)) as pool:
                for c in pool.imap(_work, work):
                    if progress:
                        progress(c.effect if c else "?")
                    if c is not None:
                        c.cfg = configure(candidate(c.effect, replay.cfg), replay.cfg, c.params)
                    out.append(c)
            return out
    out = []
    for item in work:
        if progress:
            progress(item[0])
        out.append(_safe_eval(replay, res0, *item))
    return out
