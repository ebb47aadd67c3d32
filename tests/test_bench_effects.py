"""Effects real benches show (issue 25, item 4): the controller's own settings as default
candidates of the diagnosis ("someone changed them on the drive"), with bounds from the sampled
loops' physics, found on records made with another setting at two strengths and on the maxon
LinA actuator's record (../shared/data, skipped where absent)."""
import math
from pathlib import Path

import pytest

from hil.closed_loop import loop_stability
from hil.config import load
from hil.ident import Replay, candidate_names, diagnose, synthesize
from hil.io.importers import parse_mapping, read_any
from hil.io.measurement import Measurement
from hil.plant_config import candidate, control_bounds, plant_from_config

ROOT = Path(__file__).resolve().parents[1]
CFG = load(str(ROOT / "config" / "paper_bench.toml"))
LINA = load(str(ROOT / "config" / "lina.toml"))
DATA = ROOT.parent / "shared" / "data"
LINA_RECORD = DATA / "maxon-linear-actuator-lina" / "pp-square-wave-10mm-0.5Hz.txt"
LINA_MAP = "data[:,0]=t[ms],data[:,2]=x_cmd[mm],data[:,3]=x_motor[mm]"   # the docs' map: column 2 the demand
CONTROL = ["parameter:control.kv", "parameter:control.ffv", "parameter:control.kp", "parameter:control.ti"]


# --- the controller's settings among the default candidates ----------------------------------------

def test_controller_settings_are_default_candidates_of_a_closed_loop_record():
    names = candidate_names(CFG, plant_from_config(CFG))
    assert all(n in names for n in CONTROL)
    # an open-loop record replays the recorded actuator: the loops never run, no controller setting
    assert not any(n.startswith("parameter:control.") for n in candidate_names(CFG, plant_from_config(CFG),
                                                                                open_loop=True))


def test_several_records_open_loop_or_not():
    """Several records at once (hil.ident.records.Records, what --validate and repetitions give):
    open loop only when every record is; the chain asked it of the joined records and failed."""
    import numpy as np

    from hil.ident.diagnosis import is_open_loop
    from hil.ident.records import Records
    ch, _ = synthesize(CFG, duration=1.0, seed=1, open_loop=True, inputs={"u_add": lambda t: 0.5 * np.sin(7 * t)})
    op = Replay(Measurement(ch, source="open"), CFG, open_loop=True)
    ch, _ = synthesize(CFG, duration=1.0, seed=1)
    cl = Replay(Measurement(ch, source="closed"), CFG)
    assert is_open_loop(op) and not is_open_loop(cl)
    assert is_open_loop(Records([op, op])) and not is_open_loop(Records([cl, cl]))


def test_a_setting_the_config_lacks_is_no_candidate_and_a_filter_is_one():
    # Ti = inf is a P loop (nothing to re-identify); the current loop's lag where the config gives it
    cfg = CFG.with_values({"control.ti": math.inf, "actuator.current_loop_time_constant": 0.5e-3})
    names = candidate_names(cfg, plant_from_config(cfg))
    assert "parameter:control.ti" not in names
    assert "parameter:actuator.current_loop_time_constant" in names
    assert "parameter:actuator.current_loop_time_constant" not in candidate_names(CFG, plant_from_config(CFG))
    # a feed-forward of 0 is a setting too (the maxon workbook's)
    assert "parameter:control.ffv" in candidate_names(LINA, plant_from_config(LINA))


def test_bounds_of_the_gains_are_the_sampled_loops_stability_limits():
    tp, tv = CFG["control.position_period"], CFG["control.velocity_period"]
    assert control_bounds("control.kv", CFG) == (0.0, pytest.approx(2.0 / tp))
    assert control_bounds("control.ffv", CFG) == (0.0, 1.2)
    assert control_bounds("control.ti", CFG) == (tv, 3600.0)
    r = 2 * math.pi / CFG["plant.pitch"]
    mass = CFG["plant.m1"] + CFG["plant.m2"] + CFG["plant.m3"]
    assert control_bounds("control.kp", CFG)[1] == pytest.approx(2 * mass / (r * r * tv))
    # each an upper limit of the real loop (its lags only lower it): the model's lifted loop, a
    # second method, is unstable at the bound and stable at the config's value
    for key in ("control.kv", "control.kp"):
        hi = control_bounds(key, CFG)[1]
        assert loop_stability(CFG)[0]
        assert not loop_stability(CFG.with_values({key: hi}))[0], key
    # the fit's parameter carries them
    p = candidate("parameter:control.kv", CFG).params[0]
    assert (p.lower, p.upper, p.guess) == (0.0, pytest.approx(2.0 / tp), CFG["control.kv"])
    assert candidate("parameter:control.ffv", LINA).params[0].guess == 1.0    # from 0: the start is 1


# --- a feed-forward changed on the drive, at two strengths -------------------------------------------

@pytest.mark.parametrize("ffv", [0.7, 0.9])
def test_diagnose_names_a_changed_feed_forward(ffv):
    """Records of the paper bench (ffv 1 in the config) made with another feed-forward: among the
    controller's default candidates, and a mass and a delay that also make the table lag, the
    diagnosis names the feed-forward with its value."""
    ch, truth = synthesize(CFG, "parameter:control.ffv", {"value": ffv}, duration=4.0, seed=5)
    rp = Replay(Measurement(ch, source=f"synth ffv {ffv}"), CFG)
    names = [n for n in candidate_names(CFG, rp.plant) if n.startswith("parameter:control.")]
    assert names, "no controller setting among the default candidates"
    d = diagnose(rp, names + ["mass_change", "feedback_delay"], jobs=1, max_nfev=20)
    assert d["verdict"] == "parameter:control.ffv"
    best = d["candidates"][0]
    assert best.params["value"] == pytest.approx(ffv, rel=0.03)
    assert best.error_after < 0.2 * best.error_before


# --- the maxon LinA actuator's record -------------------------------------------------------------

@pytest.mark.skipif(not LINA_RECORD.exists(), reason=f"{LINA_RECORD} absent (../shared/data)")
def test_linear_actuator_diagnosis_names_its_feed_forward():
    """The issue's goal: on the LinA record, whose start model has the workbook's feed-forward 0,
    diagnose names the feed-forward with its fitted value and the tracking error falls by 80 %."""
    meas = read_any(LINA_RECORD, parse_mapping(LINA_MAP))
    rp = Replay(meas, LINA)
    d = diagnose(rp, jobs=1)
    assert d["verdict"] == "parameter:control.ffv"
    best = next(c for c in d["candidates"] if c.effect == "parameter:control.ffv")
    assert best.channel == "x_motor"
    assert 0.9 < best.params["value"] < 1.1
    assert best.error_after <= 0.2 * best.error_before
    assert "control.ffv 0 -> 1" in best.evidence


# --- a flexible transmission at the drive ------------------------------------------------------------

EMPS = load(str(ROOT / "config" / "emps.toml"))


def _two_mass(share, f, zeta, total=None):
    """The EMPS axis as a true 2-mass chain (motor, link, load; the loops on the motor): masses,
    stiffness and damping of the 2-mass closed form f = sqrt(k (1/m1 + 1/m2)) / 2 pi."""
    total = total or EMPS["plant.m1"]
    m1, m2 = (1 - share) * total, share * total
    mu = m1 * m2 / total
    w = 2 * math.pi * f
    return EMPS.with_values({"plant.m1": m1, "plant.m2": m2, "plant.k1": mu * w * w, "plant.c1": 2 * zeta * mu * w})


def _modes(chain):
    import numpy as np
    ev = np.linalg.eigvals(np.linalg.solve(chain.M, chain.K)).real
    return sorted(float(np.sqrt(x) / (2 * math.pi)) for x in ev if x > 1e-9)


def test_ringing_after_the_edges_of_a_command():
    """A residual that rings at 21 Hz (damped, ratio 0.05) after each start and stop of ramp moves,
    with white noise between: the ring's frequency within the 1/16 Hz grid's half-bin and the
    window's, and the share of the energy in the 100 ms windows after the edges (closed form)."""
    import numpy as np

    from sim_plant.effects import edges, ringing
    dt = 1e-3
    t = np.arange(0, 8, dt)
    x = np.zeros_like(t)
    starts = [1.0, 3.0, 5.0]
    for t0 in starts:                      # a 0.5 s ramp up, held, then down after 1 s
        x += np.clip((t - t0) / 0.5, 0, 1) - np.clip((t - t0 - 1.0) / 0.5, 0, 1)
    found = edges(t, x)
    assert len(found) == 4 * len(starts)   # each ramp starts and ends: four steps of the acceleration per move
    r = 1e-3 * np.random.default_rng(0).standard_normal(t.size)
    w = 2 * math.pi * 21.0
    for i in found:
        tau = t[i:] - t[i]
        r[i:] += np.exp(-0.05 * w * tau) * np.sin(w * math.sqrt(1 - 0.05 ** 2) * tau)
    f, share = ringing(t, x, r)
    assert f == pytest.approx(21.0 * math.sqrt(1 - 0.05 ** 2), abs=0.5)
    # a ring exp(-zeta w t) sin(...) keeps 1 - exp(-2 zeta w T) of its energy in the window T
    assert share == pytest.approx(1 - math.exp(-2 * 0.05 * w * 0.1), abs=0.03)


def test_flexible_transmission_splits_a_rigid_axis_at_its_closed_form_resonance():
    eff = candidate("flexible_transmission")
    rigid = plant_from_config(EMPS)
    pl = eff.apply(rigid, {"load_share": 0.3, "frequency": 21.0, "damping_ratio": 0.05})
    assert pl.n == 2 and (pl.table, pl.tip) == (1, 1)
    m1, m2 = pl.chain.m
    assert (m1 + m2, m2 / (m1 + m2)) == (pytest.approx(rigid.chain.m[0]), pytest.approx(0.3))
    k = pl.chain.k[0]
    assert _modes(pl.chain) == [pytest.approx(math.sqrt(k * (1 / m1 + 1 / m2)) / (2 * math.pi))]
    assert _modes(pl.chain)[0] == pytest.approx(21.0)
    # the same as the config's own 2-mass chain
    two = plant_from_config(_two_mass(0.3, 21.0, 0.05))
    assert pl.chain.k == pytest.approx(two.chain.k) and pl.chain.c == pytest.approx(two.chain.c)
    assert pl.chain.c_ground == pytest.approx(two.chain.c_ground)


def test_flexible_transmission_inserts_its_link_at_the_drive_of_a_chain():
    eff = candidate("flexible_transmission")
    cfg = CFG.with_values({"effects.backlash.gap": 1e-5})
    chain0 = plant_from_config(CFG)
    base = plant_from_config(cfg)
    pl = eff.apply(base, {"load_share": 0.5, "frequency": 300.0, "damping_ratio": 0.05})
    assert pl.n == chain0.n + 1 and (pl.table, pl.tip) == (base.table + 1, base.tip + 1)
    assert pl.chain.m[0] + pl.chain.m[1] == pytest.approx(chain0.chain.m[0])
    assert pl.chain.m[2:] == chain0.chain.m[1:] and pl.chain.k[1:] == chain0.chain.k
    # the backlash stays in the screw's link (link 1 of the old chain, now link 2)
    (code, q), = base.effects
    assert [r for c, r in pl.effects if c == code][0][0] == q[0] + 1
    # the link: the motor against everything beyond it
    m_a, m_b = pl.chain.m[0], sum(pl.chain.m[1:])
    assert pl.chain.k[0] == pytest.approx((2 * math.pi * 300.0) ** 2 * m_a * m_b / (m_a + m_b))


@pytest.mark.parametrize("share,f,zeta", [(0.6, 21.0, 0.05), (0.3, 35.0, 0.1)])
def test_diagnose_finds_a_flexible_transmission_on_a_rigid_model(share, f, zeta):
    """Records of a true 2-mass EMPS axis (hil synth of a chain, not of the effect: only x_motor
    and the force recorded, as on the bench) replayed on the rigid model: the diagnosis names the
    flexible transmission, its resonance within 3 % of sqrt(k (1/m1 + 1/m2)) / 2 pi of the chain
    that made the record, its load share within 10 %."""
    two = _two_mass(share, f, zeta)
    ch, _ = synthesize(two, duration=6.0, seed=3, sample_period=1e-3)
    ch = {c: v for c, v in ch.items() if c not in ("x_table", "x_tip")}
    rp = Replay(Measurement(ch, source="2-mass EMPS"), EMPS)
    d = diagnose(rp, ["flexible_transmission", "compliant_mode", "mass_change", "parameter:plant.m1"], jobs=1,
                 max_nfev=30)
    assert d["verdict"] == "flexible_transmission"
    best = d["candidates"][0]
    k, m1, m2 = two["plant.k1"], two["plant.m1"], two["plant.m2"]
    assert best.params["frequency"] == pytest.approx(math.sqrt(k * (1 / m1 + 1 / m2)) / (2 * math.pi), rel=0.03)
    assert best.params["load_share"] == pytest.approx(share, rel=0.1)
    assert best.error_after < 0.2 * best.error_before
    assert "rings at" in best.evidence and "flexible transmission at the drive" in best.evidence
