"""Linear-time analysis (issue 18, item 5): the windowed cross-correlation equals np.correlate's
full one on the window, ``hil compare`` shows progress on long records and stops on Ctrl-C within
a second (timings themselves: benchmarks/bench_compare.py)."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import CONFIG, ROOT

from hil.ident.residual import xcorr


@pytest.mark.parametrize("n,maxlag", [(2, 1), (7, 3), (50, 200), (1000, 200), (5000, 1), (20000, 200),
                                      (20000, 3000), (4096, 4095)])
def test_xcorr_equals_the_full_correlation(n, maxlag):
    rng = np.random.default_rng(n + maxlag)
    a = rng.normal(size=n)
    b = np.roll(a, 7) + 0.3 * rng.normal(size=n)
    lags, c = xcorr(a, b, maxlag)
    A, B = (a - a.mean()) / a.std(), (b - b.mean()) / b.std()
    m = min(maxlag, n - 1)
    ref = np.correlate(A, B, mode="full")[n - 1 - m:n + m] / n
    assert np.array_equal(lags, np.arange(-m, m + 1))
    assert np.max(np.abs(c - ref)) < 1e-12
    if n > 100 and m >= 7:
        assert lags[np.argmax(c)] == -7


def _long_record(tmp_path, rows):
    from hil.config import load
    from hil.ident.synth import synthesize
    from hil.io.measurement import write
    ch, _ = synthesize(load(CONFIG / "paper_bench.toml"), None, duration=rows * 4e-3, seed=2)
    return write(tmp_path / "long.csv", ch)


@pytest.mark.slow
@pytest.mark.realtime
def test_compare_shows_progress_and_stops_on_ctrl_c_within_a_second(tmp_path):
    rec = _long_record(tmp_path, 150_000)
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    p = subprocess.Popen([sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main())", "compare",
                          str(rec), "--config", str(CONFIG / "paper_bench.toml"), "--out", str(tmp_path / "o")],
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = p.stderr.readline()
        assert "replaying 150000 samples" in line
        time.sleep(0.3)                        # inside the compiled replay or the analysis
        t0 = time.perf_counter()
        p.send_signal(signal.SIGINT)
        p.wait(timeout=10)
        assert time.perf_counter() - t0 < 1.0
        assert p.returncode in (-signal.SIGINT, 130)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert not (Path(tmp_path) / "o" / "report.html").exists()
