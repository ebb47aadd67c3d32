"""The first run of an installation compiles the simulator (numba, some 10-60 s): it says so, once,
and a run that loads the compiled loops from numba's cache says nothing."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap

PROBE = textwrap.dedent('''
    import io, sys
    sys.path.insert(0, sys.argv[1])
    from hil.commands import progress
    progress._OWN_PACKAGES = ("probe_mod",)
    said = io.StringIO()
    progress.announce_compiles(said)
    import probe_mod
    probe_mod.f(1.0)
    probe_mod.g(1.0)
    print(said.getvalue().count(progress.COMPILE_NOTICE))
''')


def test_the_first_compile_says_so_once_and_a_cached_run_says_nothing(tmp_path):
    (tmp_path / "probe_mod.py").write_text(
        "from numba import njit\n\n@njit(cache=True)\ndef f(x):\n    return x + 1.0\n\n"
        "@njit(cache=True)\ndef g(x):\n    return x * 2.0\n", encoding="utf-8")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    runs = [subprocess.run([sys.executable, "-c", PROBE, str(tmp_path)], env=env, capture_output=True,
                           text=True, timeout=120) for _ in range(2)]
    assert [r.stdout.strip() for r in runs] == ["1", "0"], [r.stderr[-2000:] for r in runs]
