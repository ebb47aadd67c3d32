"""A record replayed through a config's model (:class:`Replay`).

The measured command x_cmd, interpolated on the position-loop period, drives the model with the
same loops, starting from the first measured position of the feedback channel; the simulated
channels are read back on the measured sample times (sample for sample when the record was taken
at the loop's period, else by linear interpolation), and the residual of each channel is
r = y_measured - y_simulated (SI units).

Channels: the positions x_motor, x_table, x_tip (m) in the record, and the force channel of the
axis: torque (N m) on a rotary axis, force (N) or command (V) on a linear one.
``force_to_load`` = 2 pi / pitch turns a motor torque into a load force (1 otherwise). With
The force channel is sampled as the record holds it (config ``measurement.torque`` /
``measurement.force``, :func:`hil.ident.synth.torque_sampling`): the drive's command at the
sample, before the actuator's delay and current loop, or the current after them. With
``align``, each channel is shifted by the lag (samples, at most 200) that maximises the
cross-correlation of its derivative with the simulated one, found once on the replay's config.
``objective`` holds the channels' weights (hil.ident.objective), from the residual under the
replay's config; ``noise`` their noise floors (hil.ident.noise: a figure given in the config or
the file header, the quantization, the settled standstills), the record's, kept by
:meth:`Replay.with_config`; ``noise_sources`` says where each came from.

Artefacts of the recording (``channel_skew``, ``tip_skew``, ``force_offset``, ``position_offset``:
sim_plant.effects.RecordEffect) act on the simulated channels read back, not in the loop. The
last :data:`SIM_CACHE_SIZE` simulations are kept by the loop's key (every value of the config that
the loop reads; :class:`SimulationCache`, shared by the replays of one record), so that fitting such
an artefact, or simulating a config again, costs no simulation.

Measured inputs besides the command enter the one compiled loop (hil.simulate), each held from
its sample over the velocity periods that follow it (:func:`hil.simulate.per_velocity_period`):
``u_add``, a command added after the controller (in the controller's units: N m on a rotary
axis, V on a linear one; a channel in N is divided by the drive's force gain), and
``f_ext_table``, ``f_ext_tip``, external forces on those masses. When the config's
``measurement.output_includes_u_add`` is false the recorded force channel is the controller's own
output, and the simulated one is compared less u_add. ``open_loop``: the actuator's recorded
command (torque on a rotary axis, command or force on a linear one) is the whole input, there is
no loop, and that channel is an input, not compared; the replay's record then holds the measured
feedback position as ``x_cmd`` (the motion that happened, for the motion phases and the fits'
scales), the loop never reads it.
"""
from __future__ import annotations

import logging
import math
import threading
from collections import OrderedDict

import numpy as np

from drivers.control import controller_from_config
from hil.errors import UserError
from hil.ident.noise import record_noise
from hil.ident.objective import Objective, batched
from hil.ident.residual import xcorr
from hil.ident.synth import extend_command, torque_sampling
from hil.plant_config import plant_from_config, record_effects
from hil.simulate import external_forces, per_velocity_period, simulate, simulate_many

logger = logging.getLogger(__name__)

__all__ = ["Replay", "SimulationCache", "SIM_CACHE_SIZE", "POSITION_CHANNELS", "UNITS", "angle_axis",
           "channel_units"]

POSITION_CHANNELS = ("x_motor", "x_table", "x_tip")
_FORCE = ("torque", "force", "command")
#: what a config's model may raise in a replay (the fits cost it as a failed evaluation)
_MODEL_ERRORS = (ValueError, ZeroDivisionError, FloatingPointError)
#: loop configs whose simulated channels a record's replays keep (SimulationCache)
SIM_CACHE_SIZE = 16
#: ticks of command past a head's last sample that its simulation gets (Replay.head_costs): the
#: position tick reads the command ahead for its feed-forward
HEAD_LOOKAHEAD = 4
#: samples a head needs at least (Replay.head_costs)
HEAD_MIN = 64
UNITS = {"x_motor": "m", "x_table": "m", "x_tip": "m", "x_motor-x_table": "m", "torque": "N*m", "force": "N",
         "command": "V", "e_table": "m", "e_tip": "m"}


def angle_axis(cfg) -> bool:
    """A motor without a screw: a rotary axis whose pitch is 2 pi m per revolution, the convention
    that makes the project's positions read as the motor's angle (1 m = 1 rad; config/hsm150.toml)."""
    return bool(cfg.rotary) and abs(float(cfg["plant.pitch"]) - 2 * math.pi) <= 1e-9 * 2 * math.pi


def channel_units(cfg) -> dict:
    """The SI unit of each replayed channel on this axis: positions in rad on an angle axis
    (:func:`angle_axis`), in m otherwise."""
    if not angle_axis(cfg):
        return dict(UNITS)
    return {c: ("rad" if u == "m" else u) for c, u in UNITS.items()}


class Replay:
    """A measurement replayed through a config's model: the simulated channels on the measured
    sample times, and their residuals."""

    def __init__(self, meas, cfg, channels=None, align: bool = False, noise: dict | None = None,
                 open_loop: bool = False, sims: "SimulationCache | None" = None):
        logger.debug("replaying %s through %s", getattr(meas, "source", "a record"), cfg.source)
        self.cfg = cfg
        self.units = channel_units(cfg)
        self.plant = plant_from_config(cfg)
        self.open_loop = open_loop
        self.drive_channel = _drive_channel(meas, cfg) if open_loop else None
        if open_loop:
            meas = _open_loop_view(meas, cfg)
        self.meas = meas
        self.align = align
        self.shifts: dict[str, int] = {}
        self._inputs: dict = {}
        t = meas.t
        self.sample_period = meas.sample_period
        tp = cfg["control.position_period"]
        n = int(math.floor((t[-1] - t[0]) / tp + 1e-9)) + 1
        self.t_sim = t[0] + np.arange(n) * tp
        self.x_cmd_sim = np.interp(self.t_sim, t, meas["x_cmd"])
        self.one_to_one = n == t.size and np.allclose(self.t_sim, t, atol=1e-6 * tp)
        avail = [c for c in POSITION_CHANNELS if c in meas]
        if "force" in meas and not cfg.rotary:
            avail.append("force")
        elif "command" in meas and not cfg.rotary:
            avail.append("command")
        elif "torque" in meas and cfg.rotary:
            avail.append("torque")
        if self.drive_channel in avail:         # the input of an open-loop run is not an output
            avail.remove(self.drive_channel)
        if channels:
            bad = [c for c in channels if c not in avail]
            if bad:
                raise UserError(f"{meas.source}: channel {bad[0]!r} is not in the record or not simulated "
                                f"(available: {', '.join(avail)})")
            avail = list(channels)
        if not avail:
            raise UserError(f"{meas.source}: no measured channel to compare (need one of x_motor, x_table, x_tip, "
                            f"torque, force)")
        self.channels = avail
        self.force_channel = next((c for c in avail if c in _FORCE and c != "command"), None)
        self.force_to_load = (2 * math.pi / cfg["plant.pitch"]) if (cfg.rotary and self.force_channel) else 1.0
        fb = "x_motor" if cfg.get("control.position_feedback") == "motor" else "x_table"
        first_pos = [c for c in (fb,) + POSITION_CHANNELS if c in meas]
        self.x0 = float(meas[first_pos[0]][0]) if first_pos else float(meas["x_cmd"][0])
        # the simulated channels of the last few loop configs, shared by the replays of this record
        # (with_config): a config simulated again, exactly, is served from it
        self._sims = sims if sims is not None else SimulationCache()
        res0 = self.residuals(cfg, first=True)
        rms = {c: float(np.sqrt(np.mean(res0[c] ** 2))) for c in self.channels}
        # the record's noise floor (hil.ident.noise): a property of the record, kept by with_config
        self.noise_sources = noise or record_noise(meas, cfg, res0)
        self.noise = {c: self.noise_sources[c]["rms"] for c in self.channels}
        self.objective = Objective(self, {c: 1.0 / max(rms[c], self.noise[c], 1e-15) for c in self.channels},
                                   sum(res0[c].size for c in self.channels))
        self.base_residuals = res0

    def with_config(self, cfg) -> "Replay":
        # (an open-loop replay's meas is its view of the record: the new one starts from the record)
        return Replay(self._source_meas, cfg, self.channels, self.align, self.noise_sources, open_loop=self.open_loop,
                      sims=self._sims)

    @property
    def _source_meas(self):
        return getattr(self.meas, "open_loop_source", self.meas)

    def input_notes(self) -> list[str]:
        """What drives the replay besides the command, in words (the report and the JSON say it)."""
        m, out = self.meas, []
        if self.open_loop:
            out.append(f"open loop: the recorded {self.drive_channel} drives the plant, no position loop; "
                       f"the positions are compared")
        if "u_add" in m:
            inc = self.cfg.get("measurement.output_includes_u_add", True)
            out.append(f"u_add [{(m.units or {}).get('u_add') or 'controller units'}] added after the controller; "
                       f"the recorded controller output {'includes' if inc else 'excludes'} it "
                       f"(measurement.output_includes_u_add = {'true' if inc else 'false'})")
        for c, where in (("f_ext_table", "the table"), ("f_ext_tip", "the tool tip")):
            if c in m:
                out.append(f"{c}: a measured external force on {where}")
        return out

    def inputs(self, plant, ctrl) -> dict:
        """The record's measured inputs on the loop's clock (keyword arguments of hil.simulate.simulate)."""
        tv, n_sub = ctrl.velocity_period, ctrl.substeps
        key = (tv, n_sub, plant.force_gain, plant.n, plant.table, plant.tip)
        if key in self._inputs:
            return self._inputs[key]
        m, t = self.meas, self.meas.t
        steps = (self.x_cmd_sim.size + 1) * n_sub
        out = {}
        if self.open_loop:
            y = _in_controller_units(m, self.drive_channel, plant, "--open-loop")
            out["open_loop"] = True
            out["u_add"] = per_velocity_period(t, y, t[0], tv, steps)
            if "u_add" in m:
                out["u_add"] = out["u_add"] + per_velocity_period(t, _in_controller_units(m, "u_add", plant, "u_add"),
                                                                  t[0], tv, steps)
        elif "u_add" in m:
            out["u_add"] = per_velocity_period(t, _in_controller_units(m, "u_add", plant, "u_add"), t[0], tv, steps)
        fe = external_forces(plant, t, m, tv, steps)
        if fe is not None:
            out["f_ext"] = fe
        # the first one kept, whichever thread made it: batches are grouped by its identity (_batches)
        return self._inputs.setdefault(key, out)

    def simulate(self, cfg=None):
        cfg = cfg or self.cfg
        plant = self.plant if cfg is self.cfg else plant_from_config(cfg)
        ctrl = controller_from_config(cfg, plant)
        # one extrapolated command sample past the end (synth.extend_command): a record that ends
        # mid-motion is replayed without a false torque spike at its last sample
        res = simulate(plant, ctrl, extend_command(self.x_cmd_sim), x0=self.x0, torque=torque_sampling(cfg),
                       **self.inputs(plant, ctrl))
        return _first(res, self.x_cmd_sim.size)

    def simulated(self, cfg=None) -> dict[str, np.ndarray]:
        """Simulated channels on the measurement's sample times, with the recording's artefacts."""
        cfg = cfg or self.cfg
        key = _loop_key(cfg)
        ch = self._sims.get(key)
        if ch is None:
            ch = self.simulate(cfg).channels()
            self._sims.put(key, ch)
        return self._on_samples(cfg, ch)

    def _on_samples(self, cfg, ch: dict, n: int | None = None) -> dict[str, np.ndarray]:
        """The loop's simulated channels ``ch`` of ``cfg`` on the measurement's sample times, with the
        recording's artefacts (``n``: on the first ``n`` samples alone, :meth:`head_costs`; the
        simulation covers them)."""
        out = {}
        t = self.meas.t if n is None else self.meas.t[:n]
        for c in self.channels + ["x_motor", "x_table", "x_tip"]:
            if c in ch:
                y = ch[c]
                out[c] = y[:t.size].copy() if self.one_to_one else np.interp(t, self.t_sim[:y.size], y)
        if "u_add" in self.meas and not self.open_loop and not cfg.get("measurement.output_includes_u_add", True):
            # the record logged the controller's own output: the simulated one less the added command
            plant = self.plant if cfg is self.cfg else plant_from_config(cfg)
            u = _in_controller_units(self.meas, "u_add", plant, "u_add")[:t.size]
            for c in _FORCE:
                if c in out:
                    out[c] = out[c] - u * (plant.force_gain if c == "force" else 1.0)
        for eff, vals in record_effects(cfg):
            out = eff.apply_record(t, out, vals)
        return out

    def _loop(self, cfg) -> tuple:
        """(plant, controller) of a config's loop."""
        plant = self.plant if cfg is self.cfg else plant_from_config(cfg)
        return plant, controller_from_config(cfg, plant)

    def _batches(self, todo: dict) -> list:
        """The keys of ``todo`` ({key: (cfg, plant, ctrl)}) in groups whose loops share their inputs
        and torque sampling, so that each runs in one batch: [(torque sampling, [key, ...]), ...]."""
        groups: dict = {}
        for key, (cfg, plant, ctrl) in todo.items():
            groups.setdefault((id(self.inputs(plant, ctrl)), torque_sampling(cfg)), []).append(key)
        return [(torque, group) for (_, torque), group in groups.items()]

    def head_costs(self, cfgs: list, share: float) -> list | None:
        """Per config the weighted squared error (as ``sum(objective.vector(r) ** 2)``) of the record's
        first ``share`` of samples alone, a lower bound of its whole error: the loop simulated over
        those samples only (and :data:`HEAD_LOOKAHEAD` ticks of command past them, which the
        feed-forward reads), the same numbers as the first samples of :meth:`residuals_many`'s, the
        loop being causal. A config whose model raises gets None. None for all when the record
        cannot be cut so: a recording artefact in a config (they may read samples either side), or
        too few samples."""
        n = int(self.meas.t.size * share)
        if n < HEAD_MIN:
            return None
        ok = []
        for cfg in cfgs:
            try:
                if record_effects(cfg):
                    return None
                ok.append(True)
            except _MODEL_ERRORS:
                ok.append(False)
        # the loop's ticks that cover the first n samples, with one beyond (interpolation's neighbour)
        ticks = n if self.one_to_one else int(np.searchsorted(self.t_sim, self.meas.t[n - 1], side="right")) + 1
        if ticks + HEAD_LOOKAHEAD + 1 >= self.x_cmd_sim.size:
            return None
        cmd = extend_command(self.x_cmd_sim)[:ticks + HEAD_LOOKAHEAD]
        out: list = [None] * len(cfgs)
        todo = {}                       # index -> (cfg, plant, ctrl)
        for i, cfg in enumerate(cfgs):
            if not ok[i]:
                continue
            try:
                todo[i] = (cfg, *self._loop(cfg))
            except _MODEL_ERRORS:
                pass
        w = self.objective.weights
        for torque, group in self._batches(todo):
            runs = [group] if batched() else [[g] for g in group]
            for run in runs:
                loops = [todo[i] for i in run]
                try:
                    res = simulate_many([lp[1] for lp in loops], [lp[2] for lp in loops], cmd, x0=self.x0,
                                        torque=torque, **self.inputs(loops[0][1], loops[0][2]))
                except _MODEL_ERRORS:
                    continue
                for i, (cfg, _, _), r in zip(run, loops, res):
                    try:
                        sim = self._on_samples(cfg, _first(r, ticks).channels(), n)
                        res_i = self._residuals_of(cfg, sim, cut=n)
                        out[i] = float(np.sum(np.concatenate([res_i[c] * w[c] for c in w]) ** 2))
                    except _MODEL_ERRORS:
                        pass
        return out

    def residuals_many(self, cfgs: list) -> list:
        """:meth:`residuals` of several configs (a Jacobian's parameter sets, a grid of starts), the
        same numbers, their loops simulated in one compiled call where they share their structure
        (hil.simulate.simulate_many). Per config its residuals, or the ValueError,
        ZeroDivisionError or FloatingPointError that its model raised (the callers decide)."""
        keys = [_loop_key(c) for c in cfgs]
        sims = {}
        for key in keys:
            ch = sims.get(key) or self._sims.get(key)
            if ch is not None:
                sims[key] = ch
        errors: dict = {}
        todo = {}                       # loop key -> (cfg, plant, ctrl), the loops still to simulate
        for key, cfg in zip(keys, cfgs):
            if key in sims or key in todo or key in errors:
                continue
            try:
                todo[key] = (cfg, *self._loop(cfg))
            except _MODEL_ERRORS as e:
                errors[key] = e
        for torque, group in self._batches(todo):
            plants = [todo[k][1] for k in group]
            ctrls = [todo[k][2] for k in group]
            try:
                res = simulate_many(plants, ctrls, extend_command(self.x_cmd_sim), x0=self.x0, torque=torque,
                                    **self.inputs(plants[0], ctrls[0]))
            except _MODEL_ERRORS:
                res = [None] * len(group)        # one by one, so that each config gets its own error
            for key, r in zip(group, res):
                try:
                    sim = self.simulate(todo[key][0]) if r is None else _first(r, self.x_cmd_sim.size)
                    sims[key] = sim.channels()
                except _MODEL_ERRORS as e:
                    errors[key] = e
        out = []
        for key, cfg in zip(keys, cfgs):
            if key in errors:
                out.append(errors[key])
                continue
            self._sims.put(key, sims[key])
            try:
                out.append(self._residuals_of(cfg, self._on_samples(cfg, sims[key])))
            except _MODEL_ERRORS as e:
                out.append(e)
        return out

    def residuals(self, cfg=None, first: bool = False) -> dict[str, np.ndarray]:
        return self._residuals_of(cfg, self.simulated(cfg), first)

    def _residuals_of(self, cfg, sim: dict, first: bool = False, cut: int | None = None) -> dict[str, np.ndarray]:
        out = {}
        for c in self.channels:
            if c not in sim:        # e.g. a linear actuator's model against a rotary record's torque
                src = (cfg or self.cfg).source
                raise UserError(f"{src}: its model gives no {c!r} channel, which the record {self.meas.source} "
                                f"compares (a {'rotary' if (cfg or self.cfg).rotary else 'linear'} actuator gives "
                                f"{', '.join(sorted(k for k in sim if k != 't'))}): is it a model of this axis?")
            y = self.meas[c]
            if first and self.align:
                self.shifts[c] = _best_shift(y, sim[c])
            s = self.shifts.get(c, 0)
            if s:
                y = _shifted(y, s)
            out[c] = (y if cut is None else y[:cut]) - sim[c]
        return out

    def unit(self, chan) -> str:
        return self.units.get(chan, "")

    def primary_channel(self, res) -> str:
        return self.force_channel or max(self.channels, key=lambda c: float(np.mean(res[c] ** 2) * self.objective.weights[c] ** 2))


class SimulationCache:
    """The simulated channels (:meth:`hil.simulate.SimulationResult.channels`) of the last
    :data:`SIM_CACHE_SIZE` loop configs of one record, by the loop's key (:func:`_loop_key`: every
    value of the config that the simulation reads), least recently used out first. The kernel is
    deterministic, so a hit is the simulation's own arrays; the replays of one record share it
    (:meth:`Replay.with_config`: the record, its command and its inputs are the same, and the
    start and the loop's clock are the config's). Treat the arrays as read-only."""

    def __init__(self, size: int | None = None):
        self.size = SIM_CACHE_SIZE if size is None else int(size)
        self._items: OrderedDict = OrderedDict()
        # candidates fitted on threads share it (hil.ident.parallel): a lookup and its move to the
        # end, an insertion and its evictions, each whole
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def get(self, key):
        """The channels of ``key``, or None."""
        with self._lock:
            ch = self._items.get(key)
            if ch is None:
                self.misses += 1
                return None
            self.hits += 1
            self._items.move_to_end(key)
            return ch

    def put(self, key, channels: dict) -> None:
        with self._lock:
            self._items[key] = channels
            self._items.move_to_end(key)
            while len(self._items) > self.size:
                self._items.popitem(last=False)

    def __len__(self) -> int:
        return len(self._items)


def _drive_channel(meas, cfg) -> str:
    """The channel that drives an open-loop run: the torque on a rotary axis, the command (else
    the force) on a linear one."""
    order = ("torque",) if cfg.rotary else ("command", "force")
    for c in order:
        if c in meas:
            return c
    raise UserError(f"{meas.source}: --open-loop: no {' or '.join(order)} channel to drive the "
                    f"{'rotary' if cfg.rotary else 'linear'} axis (map the actuator's command to it)")


def _in_controller_units(meas, chan: str, plant, what: str) -> np.ndarray:
    """A recorded actuator channel in the controller's output units (N m on a rotary axis, V on a
    linear one): a force (N on mass 1) is divided by the plant's force gain."""
    from hil.io.measurement import UNITS as MUNITS
    unit = (getattr(meas, "units", {}) or {}).get(chan, "")
    kind = MUNITS[unit][0] if unit in MUNITS else {"torque": "torque", "force": "force",
                                                   "command": "voltage"}.get(chan, "")
    y = np.asarray(meas[chan], float)
    rotary = plant.pitch is not None
    if kind == "force":
        return y / plant.force_gain
    if kind in ("", "dimensionless") or (kind == "torque" and rotary) or (kind == "voltage" and not rotary):
        return y
    raise UserError(f"{meas.source}: {what}: channel {chan!r} is a {kind}, the {'rotary' if rotary else 'linear'} "
                    f"axis's controller outputs a {'torque' if rotary else 'command (V)'} (or give a force in N)")


def _open_loop_view(meas, cfg):
    """The record as an open-loop replay sees it: ``x_cmd`` is the measured feedback position."""
    import copy
    fb = "x_motor" if cfg.get("control.position_feedback") == "motor" else "x_table"
    pos = next((c for c in (fb,) + POSITION_CHANNELS if c in meas), None)
    if pos is None:
        raise UserError(f"{meas.source}: --open-loop: no measured position (x_motor, x_table or x_tip) to compare")
    view = copy.copy(meas)
    view.channels = dict(meas.channels)
    view.channels["x_cmd"] = np.asarray(meas[pos], float).copy()
    view.open_loop_source = meas
    return view


def config_key(cfg, keep=None):
    """Every value of the config (the loop's and the recording's artefacts), or those whose key
    ``keep(key)`` accepts: equal keys, equal residuals."""
    return tuple(sorted((k, repr(v)) for k, v in cfg.values.items() if keep is None or keep(k)))


def _loop_key(cfg):
    """What the simulation depends on: the config's values less the recording's artefacts."""
    from sim_plant.effects import CATALOGUE, RecordEffect

    def physics(k):
        parts = k.split(".")
        return not (len(parts) >= 2 and parts[0] in ("effects", "measurement")
                    and isinstance(CATALOGUE.get(parts[1]), RecordEffect))
    return config_key(cfg, physics)


def _first(res, n: int):
    """The SimulationResult ``res`` cut to its first ``n`` records."""
    import dataclasses
    cut = {f.name: getattr(res, f.name)[:n] for f in dataclasses.fields(res)
           if isinstance(getattr(res, f.name), np.ndarray)}
    return dataclasses.replace(res, **cut)


def _shifted(y, s):
    return np.concatenate([y[s:], np.full(s, y[-1])]) if s > 0 else np.concatenate([np.full(-s, y[0]), y[:s]])


def _best_shift(y, yhat, maxlag: int = 200) -> int:
    """Samples by which ``y`` lags ``yhat`` (cross-correlation of their derivatives)."""
    a, b = np.diff(y), np.diff(yhat)
    maxlag = min(maxlag, a.size // 4)
    lags, c = xcorr(a, b, maxlag)
    return int(lags[np.argmax(c)])
