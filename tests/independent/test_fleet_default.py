"""Issue 53's goal under the default options: ``hil fleet run`` as the fleet tutorial teaches, with
no ``--track``, ``--candidates`` or ``--max-steps``, on records this project's kernel did not make.

Three axes of the paper bench, four weekly nights (three of baseline and one after), every mass,
stiffness, damping and strength scattered by 1 % from night to night, a Coulomb friction of
0.3 N m and a backlash of 4 um on every axis. On the fourth night one axis's friction rises and
another's backlash grows, by strengths drawn (seeded) well beyond the scatter; the third axis stays
as it was. The drifting axes must be flagged in their own effect on that night, the steady one
not at all, and no record may end in an error."""
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
NIGHTS, SCATTER = 4, 0.01
_draw = np.random.default_rng(53)
# the drifts of the last night: the friction times 2.5..4, the backlash 5..9 um wider
DRIFT = {"V": ("coulomb_friction", float(_draw.uniform(2.5, 4.0))), "W": ("backlash", float(_draw.uniform(5e-6, 9e-6)))}
DATES = [(dt.date(2026, 9, 7) + dt.timedelta(days=7 * i)).isoformat() for i in range(NIGHTS)]


def write_night(out, axis: str, i: int, level: float, gap: float, **extra) -> None:
    """Axis ``axis``'s night ``i`` into ``out``: the bench scattered by :data:`SCATTER` (seeded by the
    axis and the date), a Coulomb friction ``level`` and a backlash ``gap`` each scattered as well,
    and any further hidden effect ``extra`` (plant_ivp.Hidden's fields)."""
    seed = int.from_bytes(hashlib.sha256(f"default|{axis}|{DATES[i]}".encode()).digest()[:4], "little")
    bench, night = ivp.scattered(BENCH, np.random.default_rng(seed), SCATTER)
    level, gap = night(level), night(gap)
    x = ivp.command_sequence(2.0, BENCH.tp, seed=0)
    hidden = ivp.Hidden(coulomb_pos=level, coulomb_neg=level, gap=gap, **extra)
    ch = ivp.measure(ivp.simulate(bench, x, hidden), seed % 100000)
    write(Path(out) / f"{axis}_{DATES[i]}.csv", ch, {"sample_period": f"{BENCH.tp:g} s", "source": "plant_ivp"})


def judged_fleet(work: Path, record, axes) -> dict:
    """Every night of ``axes`` written by ``record((folder, axis, night))`` (two processes), then
    ``hil fleet run`` on them with the default options: axis -> its judgement (no record in error)."""
    (work / "records").mkdir()
    with ProcessPoolExecutor(2) as pool:
        list(pool.map(record, [(str(work / "records"), a, i) for a in axes for i in range(NIGHTS)]))
    buf = StringIO()
    with redirect_stdout(buf):
        rc = main(["fleet", "run", str(work / "records"), "--config", str(CFG_PATH), "--out", str(work / "out"),
                   "--json"])
    assert rc == 0
    run = json.loads(buf.getvalue())
    assert run["records"] == len(axes) * NIGHTS and run["errors"] == []
    return {a["axis"]: a for a in run["axes"]}


def _record(args):
    out, axis, i = args
    level, gap = 0.3, 4e-6
    if i == NIGHTS - 1 and axis in DRIFT:
        effect, size = DRIFT[axis]
        level, gap = (level * size, gap) if effect == "coulomb_friction" else (level, gap + size)
    write_night(out, axis, i, level, gap)


@pytest.fixture(scope="module")
def axes(tmp_path_factory):
    return judged_fleet(tmp_path_factory.mktemp("fleet-default"), _record, "UVW")


def _flagged_effects(axis: dict) -> set[str]:
    return {f["parameter"].rsplit(".", 1)[0] if "." in f["parameter"].split(":")[-1] else f["parameter"]
            for f in axis["flags"]}


@pytest.mark.slow
def test_the_steady_axis_is_not_flagged(axes):
    # on its one night after the baseline the usual model leaves 2.9 x (table) and 4.8 x (tip) the
    # noise floor where the baseline's left 1.2-3.2 x; a pitch error of 0.6 um fitted there beside
    # it takes none of that away, so it is no finding (hil.fleet.summary._takes_the_rise)
    assert axes["U"]["flags"] == [] and axes["U"]["verdict"].startswith("ok"), axes["U"]["verdict"]


@pytest.mark.slow
@pytest.mark.parametrize("axis", sorted(DRIFT))
def test_a_drifting_axis_is_flagged_in_its_own_effect_on_its_night(axes, axis):
    effect = DRIFT[axis][0]
    got = axes[axis]
    assert _flagged_effects(got) == {effect}, got["verdict"]
    assert {f["since"] for f in got["flags"]} == {DATES[-1]}, got["verdict"]
