"""Which torque a record holds, where its config does not say (issue 24, item 2).

A drive logs either its torque (force) command at the sample, before the actuator's delay and
current loop, or the measured current, after them (config ``measurement.torque`` on a rotary
axis, ``measurement.force`` on a linear one; :func:`hil.ident.synth.torque_sampling`). The two
coincide where the model has neither a delay nor a current-loop lag. Where the record does not
say, :func:`diagnose_both` runs the diagnosis as the record is taken to be (the current) and,
where the choice can matter (a delay or a lag in the start model or in the model found, or a
chain that ends above the noise floor), again with the command sampled; the one whose model
ends nearer the noise floor (the sum over channels of (error / floor)^2) is the record's.
"""
from __future__ import annotations

__all__ = ["sampling_key", "sampling_matters", "diagnose_both", "sampling_text"]

# keys whose non-zero value makes the command and the current differ at the sample
_DELAY_KEYS = ("effects.actuator_delay.delay", "effects.time_delay.delay", "actuator.current_loop_time_constant",
               "control.output_delay")


def sampling_key(cfg) -> str:
    return "measurement.torque" if cfg.rotary else "measurement.force"


def sampling_matters(cfg) -> bool:
    """Whether the command and the current differ at the sample under ``cfg``'s model (a delay or a
    lag: the keys above, and the parameters of the effects that say so, ``Effect.lags_the_torque``)."""
    from sim_plant.effects import CATALOGUE
    lagging = tuple(f"effects.{n}.{p.name}" for n, e in CATALOGUE.items() if e.lags_the_torque for p in e.fitted_params)
    return any((cfg.get(k) or 0) > 0 for k in _DELAY_KEYS + lagging)


def _distance(d) -> float:
    """How far the diagnosis's model ends from the noise floor: sum of (error / floor)^2."""
    return float(sum(r * r for r in d["final"]["above_floor"].values()))


def diagnose_both(run, cfg, replay_of, has_force: bool):
    """The chain's diagnosis ``run(replay)`` of the record as ``cfg`` says it holds its torque, or,
    where ``cfg`` does not say and ``has_force``, of both samplings where the choice can matter.

    ``replay_of(cfg)``: the record replayed through a config. Returns (diagnosis, the config it
    used, the ``torque_sampling`` entry of the JSON or None where the config says)."""
    key = sampling_key(cfg)
    if cfg.get(key) is not None or not has_force:
        return run(replay_of(cfg)), cfg, None
    d = run(replay_of(cfg))
    entry = {"key": key, "said": False, "record": "either", "above_floor": {"actual": _distance(d)}}
    ended_above = not d["final"]["at_noise_floor"]
    if not (sampling_matters(cfg) or sampling_matters(d["config"]) or ended_above):
        return d, cfg, entry          # no delay, no lag, at the floor: command and current are one
    alt_cfg = cfg.with_values({key: "command"})
    d2 = run(replay_of(alt_cfg))
    entry["above_floor"]["command"] = _distance(d2)
    if not (sampling_matters(d["config"]) or sampling_matters(d2["config"]) or sampling_matters(cfg)):
        return d, cfg, entry          # neither model has a delay or a lag: the two cannot be told apart
    if entry["above_floor"]["command"] < entry["above_floor"]["actual"]:
        entry["record"] = "command"
        return d2, alt_cfg, entry
    entry["record"] = "actual"
    return d, cfg, entry


def sampling_text(entry) -> list[str]:
    """The finding in words; nothing where the two samplings are one."""
    if not entry or entry["record"] == "either":
        return []         # (the model has no delay or lag: the command and the current are one at the sample)
    a = entry["above_floor"]
    name = entry["key"].split(".")[1]
    other = "actual" if entry["record"] == "command" else "command"
    what = ("the command at the sample, before the actuator's delay and current loop" if entry["record"] == "command"
            else "the current, after the actuator's delay and current loop")
    return [f"{name} channel: the record holds {what} ({entry['key']} = \"{entry['record']}\": the model ends "
            f"{a[entry['record']]:.3g} against {a[other]:.3g} as {other}, in (error / noise floor)^2 summed over "
            f"channels); say so in the config"]
