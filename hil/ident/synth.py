"""Test data with a hidden effect (``hil synth``): measurement records of a richer plant.

The plant of a config plus one hidden effect (a catalogue effect with values, or a changed config
parameter) is driven through the config's loops by a varied move sequence: slow and fast moves,
short and long strokes, direct reversals and long dwells, sine-square velocity ramps. What is
recorded imitates a real bench: positions read through a 0.5 um linear encoder (quantization
after a small Gaussian sensor noise), torque or force with Gaussian noise, 4 ms sampling.
The quantization is applied to the record, not inside the loop, so that the clean record of a
config replays through that config to within the sensor noise. Artefacts of the recording
(``channel_skew``, ``tip_skew``) act on the recorded channels before the sensor noise, as the
replay applies them (hil.ident.replay).

Measured inputs besides the command (``inputs``, on the record's sample clock, held between
samples as the replay holds them): ``u_add``, a command added after the controller (controller
units: N m on a rotary axis, V on a linear one), recorded exactly (a known signal, as EMPS's
pulses); ``f_ext_table``, ``f_ext_tip``, external forces (N), recorded as applied too. With
``open_loop`` there is no loop: ``u_add`` is the actuator's whole command, written as the torque
(command) channel, and x_cmd is zero. :func:`pulse_train` makes EMPS-like pulses. The torque
(force) channel holds what the config's ``measurement.torque`` (``measurement.force``) says:
the drive's command at the sample, or the current after the actuator's delay and current loop
(the default, :func:`torque_sampling`).
"""
from __future__ import annotations

import math

import numpy as np

from hil.plant_config import candidate, configure, record_effects
from hil.simulate import simulate_config
from sim_plant.effects import CATALOGUE

__all__ = ["move_sequence", "synthesize", "pulse_train", "HIDDEN_DEFAULTS", "torque_sampling"]

# Values of the hidden effects for the paper bench (rotary: torques in N m on the motor): each
# catalogue effect's own (Effect.synth_strength), and a config parameter's
HIDDEN_DEFAULTS = {**{n: dict(e.synth_strength) for n, e in CATALOGUE.items() if e.synth_strength is not None},
                   "parameter:plant.c2": {"value": 40.0}}


def _ramp_move(x0, stroke, vmax, t_r, dt):
    """Positions of a sine-square move (ramps of t_r, cruise at vmax) sampled every dt."""
    d = abs(stroke)
    s = math.copysign(1.0, stroke)
    if vmax * t_r > d:              # too short to reach vmax: lower the speed
        vmax = d / t_r
    t_c = (d - vmax * t_r) / vmax
    T = 2 * t_r + t_c
    t = np.arange(1, int(math.ceil(T / dt)) + 1) * dt
    v = np.where(t < t_r, vmax * np.sin(np.pi * t / (2 * t_r)) ** 2,
                 np.where(t < t_r + t_c, vmax, vmax * np.sin(np.pi * np.clip(T - t, 0, None) / (2 * t_r)) ** 2))
    x = np.cumsum(v) * dt
    x *= d / x[-1]
    return x0 + s * x


def move_sequence(duration: float = 12.0, dt: float = 4e-3, seed: int = 0, travel: float = 0.08,
                  vmax: float = 0.2, amax: float = 6.0) -> np.ndarray:
    """A varied command on the dt clock: strokes 1..60 mm, speeds 5..vmax, ramps from amax down,
    dwells 0..0.6 s, some direct reversals; stays within [0, travel]."""
    rng = np.random.default_rng(seed)
    n = int(round(duration / dt))
    xs = [np.zeros(int(0.2 / dt))]
    x = 0.0
    while sum(a.size for a in xs) < n:
        stroke = rng.choice([1, 1, 1, 1, 2]) * rng.uniform(0.002, 0.03) * (1 if rng.random() < 0.3 else 2)
        if x + stroke > travel or (x - stroke >= 0 and rng.random() < 0.5):
            stroke = -stroke
        v = rng.uniform(0.005, vmax) if rng.random() < 0.7 else rng.uniform(0.002, 0.02)
        t_r = max(math.pi * v / (2 * rng.uniform(0.3 * amax, amax)), 2 * dt)
        seg = _ramp_move(x, stroke, v, t_r, dt)
        xs.append(seg)
        x = float(seg[-1])
        if rng.random() < 0.6:
            xs.append(np.full(int(rng.uniform(0.05, 0.6) / dt), x))
    return np.concatenate(xs)[:n]


def pulse_train(t, amplitude: float, period: float = 1.0, width: float = 0.2, start: float = 0.5) -> np.ndarray:
    """0 / ``amplitude`` pulses of ``width`` s every ``period`` s from ``start`` s, on the times ``t``."""
    # (a nanosecond's tolerance: the same train from times read back from a file, rounded)
    t = np.asarray(t, float) + 1e-9
    phase = np.mod(t - start, period)
    return np.where((t >= start) & (phase < width), float(amplitude), 0.0)


def torque_sampling(cfg) -> str:
    """Which controller output a record of ``cfg``'s axis holds (``measurement.torque`` on a rotary
    axis, ``measurement.force`` on a linear one): ``"command"``, the drive's output at the sample
    before the actuator's delay and current loop, or ``"actual"``, the current after them (the
    default: what a record that does not say was always taken to hold)."""
    return cfg.get("measurement.torque" if cfg.rotary else "measurement.force") or "actual"


def extend_command(x_cmd):
    """``x_cmd`` with one more sample: the command of the tick after a record's last (its
    feed-forward needs it), extrapolated at constant acceleration (3 x[-1] - 3 x[-2] + x[-3];
    linearly from two samples). The held value where the record ends at rest, as before."""
    x = np.asarray(x_cmd, float)
    if x.size >= 3:
        nxt = 3.0 * x[-1] - 3.0 * x[-2] + x[-3]
    else:
        nxt = 2.0 * x[-1] - x[-2] if x.size == 2 else x[-1]
    return np.append(x, nxt)


def synthesize(cfg, effect: str | None = None, values: dict | None = None, *, duration: float = 12.0,
               sample_period: float = 4e-3, seed: int = 0, resolution: float = 0.5e-6,
               position_noise: float = 0.1e-6, force_noise: float | None = None, x_cmd=None,
               inputs: dict | None = None, open_loop: bool = False):
    """Channels (SI) of a record of ``cfg``'s plant with the hidden ``effect`` (None: clean).
    ``inputs``: measured inputs on the record's sample clock (``u_add``, ``f_ext_table``,
    ``f_ext_tip``; a function of the sample times is called with them); ``open_loop``: ``u_add``
    drives the plant alone. Returns (channels, truth) with the config of the richer plant in
    ``truth["config"]``."""
    rich = cfg
    if effect:
        eff = candidate(effect, cfg)
        # (an effect registered after this module was imported has its own in the catalogue)
        defaults = HIDDEN_DEFAULTS.get(effect) or getattr(eff, "synth_strength", None) or {}
        vals = dict(defaults) if values is None else dict(values)
        vals = {p.name: vals.get(p.name, p.guess) for p in eff.params}
        rich = configure(eff, cfg, vals)
    else:
        vals = {}
    tp = cfg["control.position_period"]
    ratio = sample_period / tp
    if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
        raise ValueError(f"sample period {sample_period:g} s must be a whole multiple of the position period {tp:g} s")
    k = int(round(ratio))
    if x_cmd is None:
        x_cmd = np.zeros(int(round(duration / tp))) if open_loop else move_sequence(duration, tp, seed)
    # the command goes on past the record's end (one sample, extrapolated at constant acceleration), as it did on
    # the machine: holding it would end the record with a one-sample torque spike (the last
    # tick's feed-forward falling to zero), an artefact of the record's end, not of the plant
    x_cmd = np.asarray(x_cmd, float)
    t_rec = np.arange((x_cmd.size + k - 1) // k) * sample_period
    ins = {c: np.asarray(v(t_rec) if callable(v) else v, float) for c, v in (inputs or {}).items()}
    if open_loop and "u_add" not in ins:
        raise ValueError("an open-loop record needs its actuator command (inputs['u_add'])")
    res = simulate_config(rich, extend_command(x_cmd), torque=torque_sampling(rich),
                          **_loop_inputs(rich, ins, t_rec, x_cmd.size + 1, open_loop))
    ch = {c: y[:x_cmd.size][::k] for c, y in res.channels().items()}
    if "u_add" in ins and not open_loop and not rich.get("measurement.output_includes_u_add", True):
        ch = dict(ch)             # the drive logged its controller's own output, without the pulses
        fg = res.meta["force_gain"]
        for c in ("torque", "command", "force"):
            if c in ch:
                ch[c] = ch[c] - ins["u_add"] * (fg if c == "force" else 1.0)
    for eff, v in record_effects(rich):          # the recording's artefacts (a skewed channel)
        ch = eff.apply_record(ch["t"], ch, v)
    rng = np.random.default_rng(seed + 1000)
    out = {"t": ch["t"].copy(), "x_cmd": ch["x_cmd"].copy()}
    for c in ("x_motor", "x_table", "x_tip"):
        y = ch[c] + rng.normal(0.0, position_noise, ch[c].size)
        out[c] = resolution * np.floor(y / resolution + 0.5) if resolution > 0 else y
    fch = "torque" if cfg.rotary else "force"
    y = ch[fch]
    if force_noise is None:
        force_noise = 0.01 * float(np.sqrt(np.mean(y * y))) + 1e-9
    if open_loop:
        # the actuator's command is the run's input, logged as it was sent
        out["x_cmd"] = np.zeros_like(out["t"])
        out["torque" if cfg.rotary else "command"] = ins["u_add"].copy()
    else:
        out[fch] = y + rng.normal(0.0, force_noise, y.size)
        if "u_add" in ins:
            out["u_add"] = ins["u_add"].copy()
    for c in ("f_ext_table", "f_ext_tip"):
        if c in ins:
            # as applied: a force sensor's noise, fed back into the replay, would excite the
            # lightly damped tip mode by itself (a record to test the loop's inputs, not the sensor)
            out[c] = ins[c].copy()
    truth = {"effect": effect or "none", "params": vals, "config": rich, "seed": seed,
             "resolution": resolution, "position_noise": position_noise, "force_noise": force_noise}
    return out, truth


def _loop_inputs(cfg, ins: dict, t_rec, ticks: int, open_loop: bool) -> dict:
    """The inputs on the loop's clock (hil.simulate.simulate's keywords), held from each sample
    as hil.ident.replay holds a record's."""
    from drivers.control import controller_from_config
    from hil.plant_config import plant_from_config
    from hil.simulate import external_forces, per_velocity_period
    if not ins and not open_loop:
        return {}
    plant = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant)
    steps = ticks * ctrl.substeps
    tv = ctrl.velocity_period
    out = {}
    if "u_add" in ins:
        out["u_add"] = per_velocity_period(t_rec, ins["u_add"], t_rec[0], tv, steps)
    if open_loop:
        out["open_loop"] = True
    fe = external_forces(plant, t_rec, ins, tv, steps)
    if fe is not None:
        out["f_ext"] = fe
    return out
