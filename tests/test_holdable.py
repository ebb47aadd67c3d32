"""One bound for each parameter, shared by the fit and the config (issue 53): a feedback delay
fitted at 0.75 us on a record without one could not be written (the config takes a time of 0 or
at least 1 us), and with ``--track feedback_delay`` every record of a fleet ended in that error. A
fitted value below the smallest magnitude its key takes is 0 where the key takes 0 (zero within
any timer's resolution), else that smallest magnitude; every other value is written as fitted."""
import math

import pytest
from conftest import CONFIG
from hypothesis import given, settings
from hypothesis import strategies as st

from hil import config
from hil.config import TIME_RANGE
from hil.plant_config import candidate, configure, holdable

CFG = config.load(CONFIG / "paper_bench.toml")


@pytest.mark.parametrize("fitted, written", [(7.5e-7, 0.0), (-3e-7, 0.0), (1e-6, 1e-6), (2.5e-4, 2.5e-4), (0.0, 0.0)])
def test_a_delay_below_a_microsecond_is_written_as_none(fitted, written):
    out = configure(candidate("feedback_delay", CFG), CFG, {"delay": fitted})
    assert out.get("effects.feedback_delay.delay") == written


@settings(max_examples=100, deadline=None, derandomize=True)
@given(value=st.floats(min_value=-1.0, max_value=1.0, allow_nan=False))
def test_every_time_the_fit_gives_is_one_the_config_holds(value):
    key = "effects.actuator_delay.delay"
    held = holdable(key, value, CFG.values)
    assert held == 0.0 or abs(held) >= TIME_RANGE[0]
    assert held == value or (abs(value) < TIME_RANGE[0] and held == 0.0)
    assert math.copysign(1.0, held) == math.copysign(1.0, value) or held == 0.0
