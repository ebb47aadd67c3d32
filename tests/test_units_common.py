"""The common units read without pint (hil.units._COMMON_UNITS) read exactly as pint reads them.

pint is the authority: every entry, in every spelling the fast path takes, over numbers written as
people write them and over seeded random ones, must give the float pint gives; so must every
display factor and every shipped config. A spelling the table lacks, or a unit of another
dimension, still goes to pint (its messages)."""
from __future__ import annotations

import random
import subprocess
import sys
from pathlib import Path

import pytest

import hil.units as U
from hil.config import load
from hil.errors import HilError

ROOT = Path(__file__).resolve().parents[1]


def _numbers(seed: int, n: int) -> list[str]:
    rng = random.Random(seed)
    out = ["0", "1", "-3", "+2", "100", "7000", "0.5", ".5", "5.", "1e3", "-2.5e-4", "16789", "3.7060e4", "335.57"]
    for _ in range(n):
        digits = rng.randint(1, 7)
        m = rng.randint(1, 10 ** digits - 1)
        out.append(f"{'-' if rng.random() < 0.3 else ''}{m}e{rng.randint(-9, 9)}")
        out.append(f"{m / 10 ** rng.randint(0, digits)}")
    return out


def _texts():
    for i, (unit, (kind, _)) in enumerate(U._COMMON_UNITS.items()):
        for number in _numbers(i, 40):          # seeded: the same numbers on every run
            for space in ("", " "):
                if unit == "1/s" and not space:      # "501/s" is 501 per second: "/s"'s case
                    continue
                yield number + space + unit, kind


def test_every_common_unit_reads_as_pint_reads_it(monkeypatch):
    texts = list(_texts())
    fast = [U.parse(t, k) for t, k in texts]
    monkeypatch.setattr(U, "_COMMON_UNITS", {})
    slow = [U.parse(t, k) for t, k in texts]
    wrong = [(t, a, b) for (t, _), a, b in zip(texts, fast, slow) if a != b]
    assert not wrong, wrong[:5]
    assert len(texts) > 3000


def test_every_display_factor_is_pints(monkeypatch):
    """Every rung of the display ladders, and every common unit asked for by name (fmt's ``unit``;
    "/s" alone pint cannot take as a target unit, so it has no factor of pint's to match)."""
    wanted = [(kind, unit) for kind, ladder in U.DISPLAY_UNITS.items() for _, unit, _ in ladder]
    wanted += [(kind, unit) for unit, (kind, _) in U._COMMON_UNITS.items() if unit != "/s"]
    U._factor.cache_clear()
    fast = [U._factor(*w) for w in wanted]
    monkeypatch.setattr(U, "_COMMON_UNITS", {})
    U._factor.cache_clear()
    try:
        assert fast == [U._factor(*w) for w in wanted]
    finally:
        U._factor.cache_clear()


@pytest.mark.parametrize("path", sorted((ROOT / "config").glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_config_reads_as_with_pint(path, monkeypatch):
    def read():
        try:
            cfg = load(path)
        except HilError as exc:         # a file of another form (the components' sheet): the same line
            return str(exc)
        return {k: cfg.get(k) for k in cfg.keys()}
    fast = read()
    monkeypatch.setattr(U, "_COMMON_UNITS", {})
    assert fast == read()


@pytest.mark.parametrize("text, kind", [("10 mm", "time"), ("5 Hz", "length"), ("3 N", "torque")])
def test_a_common_unit_of_another_dimension_still_gets_pints_message(text, kind):
    with pytest.raises(U.UnitError, match="expected"):
        U.parse(text, kind)


@pytest.mark.parametrize("text, kind, si", [("501/s", "frequency", 501.0), ("50 1/s", "loop_gain", 50.0),
                                            ("7000mm/min", "speed", 7000 / 60000), ("8.5e-4 kg*m^2", "inertia", 8.5e-4),
                                            ("\u221210 mm", "length", -0.01), ("2 Nm", "torque", 2.0)])
def test_the_spellings_that_could_split_two_ways(text, kind, si):
    assert U.parse(text, kind) == pytest.approx(si, rel=1e-15)


def test_a_shipped_config_and_its_text_need_no_pint():
    """The point of the table: `hil model` and every command that reads a shipped config start
    without importing pint (0.25 s)."""
    code = ("import sys; from hil.config import load; from hil.units import fmt; "
            "cfg = load('config/paper_bench.toml'); fmt(cfg['plant.k1'], 'stiffness'); fmt(1e-5, 'length'); "
            "print('pint' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "False", out.stderr
