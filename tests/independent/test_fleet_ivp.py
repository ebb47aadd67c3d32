"""A fleet from the independent simulator (issue 26's goal): ``hil fleet run`` on records this
project's kernel did not make.

Four axes of the paper bench, six nights, every record the same test move (as a nightly check
repeats one program); from night to night every plant parameter (each mass, stiffness and
damping), the Coulomb level (1.5 N m) and the backlash (4 um) scattered by 1 % (temperature and
load). One axis's backlash grows by 6 um from one night (a worn nut), another's friction rises by
0.5 N m from a later night (failing lubrication). Exactly those two axes must be flagged, each in
its own effect and on the date of its change; the steady axes not at all.

The records come from plant_ivp (its own integrator, stick-slip as a hybrid system, its own
controller), written in the measurement format; nothing of ``hil`` makes them."""
import datetime as dt
import hashlib
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from contextlib import redirect_stdout
from io import StringIO
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plant_ivp as ivp  # noqa: E402

from hil.cli import main  # noqa: E402
from hil.config import load  # noqa: E402
from hil.io.measurement import write  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CFG_PATH = ROOT / "config" / "paper_bench.toml"
BENCH = ivp.bench_from_config(load(CFG_PATH))
AXES = ["X1", "X2", "X3", "X4"]
NIGHTS = 6
SCATTER = 0.01
GAP, LEVEL = 4e-6, 1.5              # m (total play), N m


def _dates():
    return [(dt.date(2026, 3, 2) + dt.timedelta(days=i)).isoformat() for i in range(NIGHTS)]


def _record(args):
    """One night of one axis: (file name, true gap, true level)."""
    out, axis, date, drift, salt = args
    seed = int.from_bytes(hashlib.sha256(f"{axis}|{date}|{salt}".encode()).digest()[:4], "little")
    bench, night = ivp.scattered(BENCH, np.random.default_rng(seed), SCATTER)
    gap, level = GAP, LEVEL
    if drift and date >= drift[1]:
        gap, level = (gap + drift[2], level) if drift[0] == "backlash.gap" else (gap, level + drift[2])
    gap, level = night(gap), night(level)
    x = ivp.command_sequence(2.0, BENCH.tp, seed=0)
    ch = ivp.measure(ivp.simulate(bench, x, ivp.Hidden(coulomb_pos=level, coulomb_neg=level, gap=gap)),
                     seed % 100000)
    name = f"{axis}_{date}.csv"
    write(Path(out) / name, ch, {"sample_period": f"{BENCH.tp:g} s", "source": "plant_ivp"})
    return name, gap, level


def _fleet(folder: Path, drifts: dict, salt: str):
    folder.mkdir(parents=True)
    work = [(str(folder), a, d, drifts.get(a), salt) for a in AXES for d in _dates()]
    with ProcessPoolExecutor(2) as pool:
        return list(pool.map(_record, work))


def _run(records: Path, out: Path) -> dict:
    buf = StringIO()
    with redirect_stdout(buf):
        rc = main(["fleet", "run", str(records), "--config", str(CFG_PATH), "--track", "backlash,coulomb_friction",
                   "--candidates", "backlash,coulomb_friction,viscous_friction", "--max-steps", "2",
                   "--out", str(out), "--json"])
    assert rc == 0
    return json.loads(buf.getvalue())


# X2's backlash grows by 6 um from the fourth night, X3's friction by 0.5 N m from the fifth
DRIFTS = {"X2": ("backlash.gap", 3, 6e-6), "X3": ("coulomb_friction.level", 4, 0.5)}


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    work = tmp_path_factory.mktemp("fleet-ivp")
    dates = _dates()
    drifts = {a: (p, dates[i], step) for a, (p, i, step) in DRIFTS.items()}
    _fleet(work / "records", drifts, "a")
    run = _run(work / "records", work / "out")
    assert run["records"] == len(AXES) * NIGHTS and run["errors"] == []
    return drifts, {a["axis"]: a for a in run["axes"]}


def _flags(axes, effect):
    return {a: [f["since"] for f in ax["flags"] if f["parameter"].startswith(effect + ".")]
            for a, ax in axes.items() if any(f["parameter"].startswith(effect + ".") for f in ax["flags"])}


@pytest.mark.slow
def test_the_rising_friction_is_flagged_on_its_axis_alone_on_its_date(fleet):
    drifts, axes = fleet
    assert _flags(axes, "coulomb_friction") == {"X3": [drifts["X3"][1]]}


@pytest.mark.slow
def test_the_growing_backlash_is_flagged_on_its_axis_alone_on_its_date(fleet):
    drifts, axes = fleet
    assert _flags(axes, "backlash") == {"X2": [drifts["X2"][1]]}
