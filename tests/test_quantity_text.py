"""Quantities as copied from a datasheet, a PDF or a web page (issue 49, finding 1): the Unicode
minus sign and the dashes keep their sign, the non-breaking and thin spaces are spaces, and what
pint would read wrongly rather than not at all (a character it drops, a thousands separator, a
decimal comma) is one line naming the value, never a silent other number. A sign lost is motion
the wrong way: the command line, the config and ``--set`` are each checked end to end."""
import math

import pytest
from conftest import CONFIG
from hypothesis import given, settings
from hypothesis import strategies as st

from hil import config
from hil.cli import main
from hil.errors import UnitError
from hil.units import parse, parse_list, parse_option

MINUS_SIGNS = ["-", "\u2212", "\u2013", "\u2014", "\u2010", "\u2011", "\u2012", "\ufe63", "\uff0d"]
SPACES = ["", " ", "\u00a0", "\u202f", "\u2009", "\u2007", "\u200a", "\u2002", "\u2003"]
UNITS = [("mm", 1e-3), ("um", 1e-6), ("m", 1.0), ("µm", 1e-6)]


@settings(max_examples=200, deadline=None, derandomize=True)
@given(magnitude=st.floats(min_value=1e-3, max_value=1e4, allow_nan=False), minus=st.sampled_from(MINUS_SIGNS),
       space=st.sampled_from(SPACES), unit=st.sampled_from(UNITS))
def test_every_minus_sign_and_space_keeps_the_sign_and_the_value(magnitude, minus, space, unit):
    name, scale = unit
    text = f"{minus}{magnitude!r}{space}{name}"
    assert parse(text, "length", "--stroke") == pytest.approx(-magnitude * scale, rel=1e-12)
    assert parse_option(text, "length", "--stroke") == pytest.approx(-magnitude * scale, rel=1e-12)


@pytest.mark.parametrize("minus", MINUS_SIGNS[1:])
def test_a_minus_sign_in_the_exponent_and_before_a_bare_number(minus):
    assert parse(f"1e{minus}3 m", "length") == pytest.approx(1e-3)
    assert parse(f"{minus}33", "damping") == -33.0
    assert parse_list(f"{minus}60,{minus}80ms", "time") == pytest.approx([-0.06, -0.08])


@pytest.mark.parametrize("text, says", [
    ("1\u00a0000 mm", "digits separated by a space"), ("1 000 mm", "digits separated by a space"),
    ("1,5mm", "decimal comma; write a point ('1.5mm')"), ("1,000mm", "thousands separator ('1000mm')"),
    ("1 500/s", "digits separated by a space"), ("\u00ad10mm", "U+00AD SOFT HYPHEN"),
    ("\u20ac5 mm", "U+20AC"), ("\uff11\uff10mm", "U+FF11"), ("5 mm\u2044s", "U+2044")])
def test_what_pint_would_misread_is_one_line_naming_the_value(text, says):
    with pytest.raises(UnitError) as err:
        parse(text, "length", "limits.travel_max")
    message = str(err.value)
    assert "\n" not in message and message.startswith("limits.travel_max:") and says in message


@settings(max_examples=300, deadline=None, derandomize=True)
@given(text=st.text(alphabet=st.sampled_from(list("0123456789.e-+ mu/s,") + MINUS_SIGNS + SPACES[1:]
                                              + ["\u20ac", "\u00b7", "\u00b2", "\u200b", "\u00ad"]), max_size=14))
def test_no_text_reads_as_a_value_of_the_other_sign(text):
    """The fuzzer: whatever the text, a value comes back only with the sign the text shows (a minus
    of any spelling, leading): never a sign dropped, never a traceback."""
    try:
        v = parse(text, "length", "--stroke")
    except UnitError:
        return
    shown = text.strip().lstrip("\u200b\u00ad \u00a0\u202f\u2009\u2007\u200a\u2002\u2003")
    if v and math.isfinite(v) and shown[:1] in MINUS_SIGNS and shown[1:2] not in MINUS_SIGNS + ["+"]:
        assert v < 0, (text, v)


def test_what_pint_reads_beyond_ascii_still_reads():
    assert parse("2*\u03c0 rad/s", "angular_speed") == pytest.approx(2 * math.pi)
    assert parse("5 \u00c5", "length") == pytest.approx(5e-10)
    assert parse("50 1/s", "frequency") == 50.0 and parse("8.5e-4 kg*m\u00b2", "inertia") == pytest.approx(8.5e-4)


def test_the_config_and_set_keep_the_sign(tmp_path):
    text = (CONFIG / "paper_bench.toml").read_text(encoding="utf-8")
    assert 'travel_min = "-1 m"' in text
    path = tmp_path / "minus.toml"
    path.write_text(text.replace('travel_min = "-1 m"', 'travel_min = "\u221250 mm"', 1), encoding="utf-8")
    cfg = config.load(path, {"limits.travel_max": config.parse_assignment("limits.travel_max=\u22125mm")[1]})
    assert cfg.get("limits.travel_min") == pytest.approx(-0.05)
    assert cfg.get("limits.travel_max") == pytest.approx(-0.005)


def test_a_move_written_with_a_minus_sign_goes_the_way_it_says(tmp_path, capsys):
    """The red team's case: ``--stroke −10mm`` (U+2212) moved to +10 mm. It goes to -10 mm now."""
    out = tmp_path / "m"
    rc = main(["move", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "\u221210mm", "--feed",
               "7000mm/min", "--tacc", "200ms", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    last = (out / "move.csv").read_text().strip().splitlines()[-1].split(",")
    assert float(last[1]) == pytest.approx(-10.0)          # x_cmd [mm] at the end
    assert float(last[3]) == pytest.approx(-10.0, abs=0.01)


def test_set_with_a_minus_sign_is_checked_before_motion(capsys):
    rc = main(["move", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "10mm", "--feed", "7000mm/min",
               "--tacc", "200ms", "--set", "limits.travel_max=\u22125mm", "--check"])
    assert rc == 2
    assert "limits.travel_max -5.000 mm" in capsys.readouterr().err
