"""Issue 53's goal for drifts of presence, under the default options: an effect that was not there
appears on the last night (records of the independent simulator, as in test_fleet_default.py: the
paper bench, four weekly nights, every mass, stiffness, damping and strength scattered by 1 % from
night to night, a Coulomb friction of 0.3 N m and a backlash of 4 um on every axis).

Axis F gets a constant force on the table, axis L a delay from the command to the motor, each of a
strength drawn (seeded) well beyond the scatter. Each must be flagged on that night in the new
effect (or the catalogue effect that nests it or that this record cannot tell from it: a cable
carrier's force is a constant one with a slope; a current loop's lag of 1.5 ms looks like a delay),
and in nothing else: the usual effects beside it have not moved."""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from test_fleet_default import DATES, NIGHTS, judged_fleet, write_night  # noqa: E402

_draw = np.random.default_rng(5353)
APPEARS = {"F": dict(force=float(_draw.uniform(20.0, 40.0)), force_mass=1),
           "L": dict(delay=float(_draw.uniform(1.0e-3, 2.0e-3)))}
NAMES = {"F": {"constant_force", "cable_carrier"}, "L": {"actuator_delay", "feedback_delay", "current_loop_lag"}}


def _record(args):
    out, axis, i = args
    write_night(out, axis, i, 0.3, 4e-6, **(APPEARS[axis] if i == NIGHTS - 1 else {}))


@pytest.fixture(scope="module")
def axes(tmp_path_factory):
    return judged_fleet(tmp_path_factory.mktemp("fleet-presence"), _record, sorted(APPEARS))


@pytest.mark.slow
@pytest.mark.parametrize("axis", sorted(APPEARS))
def test_an_effect_that_appears_is_flagged_in_itself_alone_on_its_night(axes, axis):
    got = axes[axis]
    flagged = [f["parameter"] for f in got["flags"]]
    assert len(flagged) == 1 and flagged[0] in NAMES[axis], got["verdict"]
    assert got["flags"][0]["since"] == DATES[-1], got["verdict"]
