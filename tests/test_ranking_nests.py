"""A constant k1 is nested in a stiffness along the travel (k_start = k_end): on a record whose k1
drifted uniformly, the one parameter is named before the variation the record cannot see (the clean
records of ``bench_diagnose.py --matrix``, whose k1 drifts by up to 3 %, named
``stiffness_along_travel`` beside the other drifts)."""
import pytest

from hil.ident.diagnosis import _rank_single
from hil.ident.fit import Candidate
from hil.ident.scores import MIN_SCORE


def _cand(effect, score, tip):
    return Candidate(effect, {}, "x_tip", 2e-6, tip, score, "", significant=True, errors_after={"x_tip": tip})


@pytest.mark.parametrize("rich", ["stiffness_along_travel", "stiffness_along_travel_fixed_fixed"])
def test_constant_k1_first_when_the_variation_does_not_pay(rich):
    k1 = _cand("parameter:plant.k1", 56.0, 2.05e-7)
    along = _cand(rich, 56.0 + 0.5 * MIN_SCORE, 2.0e-7)
    assert [c.effect for c in _rank_single([along, k1])][0] == "parameter:plant.k1"


@pytest.mark.parametrize("rich", ["stiffness_along_travel", "stiffness_along_travel_fixed_fixed"])
def test_the_variation_first_when_it_pays(rich):
    k1 = _cand("parameter:plant.k1", 56.0, 4e-7)
    along = _cand(rich, 56.0 + 10 * MIN_SCORE, 1.5e-7)
    assert [c.effect for c in _rank_single([along, k1])][0] == rich
