"""Standard errors a user can trust (issue 49, finding 3): a fit claimed kv = 1.00 +- 0.21 1/s where
the truth was 230 of its standard errors away. A serially correlated residual counts n / tau
independent samples (tau against the closed form of an AR(1) process, and the coverage of the
errors over many noise draws, against the white formula's); a parameter at its bound or in a
near-singular direction claims none; ``hil fit`` says where the fitted model still misses the
record, so a value that takes up what the model lacks is never given as a measurement."""
import json

import numpy as np
import pytest
from conftest import CONFIG
from scipy.optimize import least_squares

from hil.cli import main
from hil.ident.fit import correlation_time, standard_errors

BENCH = str(CONFIG / "paper_bench.toml")


def _ar1(phi: float, n: int, rng) -> np.ndarray:
    e = rng.standard_normal(n)
    x = np.empty(n)
    x[0] = e[0] / np.sqrt(1 - phi * phi)
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.9, 0.97])
def test_the_correlation_time_of_an_ar1_process_is_its_closed_form(phi):
    """tau = (1 + phi) / (1 - phi) for x_k = phi x_(k-1) + e_k."""
    rng = np.random.default_rng(1)
    taus = [correlation_time(_ar1(phi, 20000, rng)) for _ in range(5)]
    assert np.mean(taus) == pytest.approx((1 + phi) / (1 - phi), rel=0.15)


def test_the_errors_cover_the_truth_where_the_white_formula_does_not():
    """A line fitted to a record with AR(1) noise (phi 0.95): over 300 draws the slope lies within
    2 standard errors of the truth about 95 % of the time; the white formula's errors, about
    sqrt(tau) = 6 times smaller, cover it far less often."""
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 1.0, 2000)
    inside, inside_white = 0, 0
    draws = 300
    for _ in range(draws):
        y = 1.0 + 2.0 * t + 0.01 * _ar1(0.95, t.size, rng)
        sol = least_squares(lambda z: z[0] + z[1] * t - y, [0.0, 0.0])
        se = standard_errors(sol, 1.0)[1]
        se_white = standard_errors(sol, 1.0, correlated=False)[1]
        inside += abs(sol.x[1] - 2.0) < 2 * se
        inside_white += abs(sol.x[1] - 2.0) < 2 * se_white
    assert 0.88 <= inside / draws <= 0.995
    assert inside_white / draws < 0.5


def test_no_error_at_a_bound_or_in_a_near_singular_direction():
    t = np.linspace(0.0, 1.0, 500)
    y = 2.0 * t + 0.01 * np.random.default_rng(3).standard_normal(t.size)
    at_bound = least_squares(lambda z: z[0] * t - y, [0.5], bounds=([0.0], [1.0]))
    assert at_bound.x[0] == pytest.approx(1.0) and np.isnan(standard_errors(at_bound, 1.0)[0])
    twins = least_squares(lambda z: (z[0] + z[1]) * t - y, [0.3, 0.4])      # only the sum is seen
    assert np.all(np.isnan(standard_errors(twins, 1.0)))
    # nearly twins: no error claimed alone, and the pair still named as confounded
    near = least_squares(lambda z: z[0] * t + z[1] * (t + 1e-8 * t * t) - y, [0.3, 0.4])
    from hil.ident.fit import confounded_pairs
    assert np.all(np.isnan(standard_errors(near, 1.0)))
    ((a, b, r),) = confounded_pairs(near, ["a", "b"])
    assert (a, b) == ("a", "b") and r < -0.99


@pytest.fixture(scope="module")
def friction_record(tmp_path_factory):
    d = tmp_path_factory.mktemp("honest")
    rec = d / "cf.csv"
    assert main(["synth", "--config", BENCH, "--effect", "coulomb_friction", "--param", "level=2Nm", "--duration",
                 "6s", "--seed", "4", "--out", str(rec)]) == 0
    return rec


def test_a_gain_fitted_for_a_missing_friction_is_said_to_miss_the_record(friction_record, tmp_path, capsys):
    """The red team's case: the record holds the config's own kv and a Coulomb friction the model
    lacks; a fit of kv alone moves it. The fit says that its model misses the record (the value
    takes up the friction) in the text and the JSON, and its error is no longer a tenth of the
    change it claims."""
    capsys.readouterr()
    assert main(["fit", str(friction_record), "--config", BENCH, "--add", "parameter:control.kv", "--out",
                 str(tmp_path / "kv.toml"), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    kv = got["fitted"]["control.kv"]
    assert got["misfit"] is not None and got["misfit"]["above_floor"] > 3
    assert abs(kv["value"] - 50.0) < 4 * kv["stderr"]
    assert main(["fit", str(friction_record), "--config", BENCH, "--add", "parameter:control.kv", "--out",
                 str(tmp_path / "kv2.toml")]) == 0
    assert "values take up what the model still lacks" in capsys.readouterr().out


def test_the_right_effect_is_fitted_within_its_error_and_reaches_the_floor(friction_record, tmp_path, capsys):
    capsys.readouterr()
    assert main(["fit", str(friction_record), "--config", BENCH, "--add", "coulomb_friction", "--out",
                 str(tmp_path / "cf.toml"), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    level = got["fitted"]["effects.coulomb_friction.level"]
    assert got["misfit"] is None
    assert abs(level["value"] - 2.0) < 3 * level["stderr"] and level["stderr"] < 0.01
