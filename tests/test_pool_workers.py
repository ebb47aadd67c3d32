"""Pool workers end with their parent (issue 49, finding 5): after ``kill -9`` of a fleet run, its
pool's workers stayed alive 23 minutes, each on its task. A process that owns a pool with
:func:`hil.pool.die_with_parent` as the initializer is killed; its workers are gone within a few
watch periods."""
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from hil.pool import WATCH_PERIOD

OWNER = textwrap.dedent("""
    import multiprocessing, os, sys, time
    from concurrent.futures import ProcessPoolExecutor
    from hil.pool import die_with_parent

    def task(_):
        time.sleep(120)                  # a long record

    pool = ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("fork"), initializer=die_with_parent,
                               initargs=(os.getpid(),))
    futs = [pool.submit(task, i) for i in range(2)]
    time.sleep(1.0)
    print(" ".join(str(p) for p in pool._processes), flush=True)
    time.sleep(120)
""")


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split()[2] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_workers_of_a_killed_owner_end_within_a_few_watch_periods():
    owner = subprocess.Popen([sys.executable, "-c", OWNER], stdout=subprocess.PIPE, text=True)
    try:
        workers = [int(p) for p in owner.stdout.readline().split()]
        assert len(workers) == 2 and all(_alive(p) for p in workers)
        os.kill(owner.pid, signal.SIGKILL)
        owner.wait(10)
        deadline = time.monotonic() + 10 * WATCH_PERIOD
        while time.monotonic() < deadline and any(_alive(p) for p in workers):
            time.sleep(0.1)
        assert not any(_alive(p) for p in workers)
    finally:
        if owner.poll() is None:
            owner.kill()
