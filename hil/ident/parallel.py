"""Fitting many candidates (hil.ident.fit.evaluate), in worker processes.

The replay and its residuals reach the workers by fork: a module-level dict that the
module-level worker reads, so nothing large is pickled and the worker is picklable by name. A
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


_WORK = {}


def _work(args):
    c = _safe_eval(_WORK["replay"], _WORK["res0"], *args)
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
            _WORK.update(replay=replay, res0=res0)
            out = []
            with ctx.Pool(min(jobs, len(work))) as pool:
                for c in pool.imap(_work, work):
                    if progress:
                        progress(c.effect if c else "?")
                    if c is not None:
                        c.cfg = configure(candidate(c.effect, replay.cfg), replay.cfg, c.params)
                    out.append(c)
            _WORK.clear()
            return out
    out = []
    for item in work:
        if progress:
            progress(item[0])
        out.append(_safe_eval(replay, res0, *item))
    return out
