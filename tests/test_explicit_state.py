"""Explicit state (issue 28, item 7): what the forked fitting workers evaluate is handed to them,
not left in a module of the parent process."""
import multiprocessing as mp

import pytest

from hil.ident import parallel


class _Replay:
    """A stand-in that no fit can use: the workers fail on it at once."""


@pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="the workers are forked")
def test_the_parent_keeps_no_replay_after_the_workers_failed():
    """The workers raise (a replay they cannot fit, an error other than ValueError); the parent's
    modules hold nothing of the run afterwards (before: the replay stayed in parallel._WORK when
    the pool raised, until the next run)."""
    replay = _Replay()
    with pytest.raises(Exception):
        parallel.evaluate_many(replay, [("coulomb_friction", 1), ("backlash", 1)], None, 2, None)
    held = [name for name, value in vars(parallel).items()
            if isinstance(value, dict) and any(v is replay for v in value.values())]
    assert held == []
