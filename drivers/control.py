"""The cascade control law, written once: the compiled simulator and the real-time loop both call
these functions (numba-compiled, callable from Python too).

Reference order (the project's; see the runtime issue):

* Position loop every Tp, tick k at t_k = k Tp: read the table position x2;
  v_ref = Kv (x_cmd[k] - x2) + FFV (x_cmd[k+1] - x_cmd[k]) / Tp; w_ref = v_ref 2 pi / p, held
  until the next tick. The feed-forward is the interpolator's velocity for the coming period.
* Velocity loop every Tv, aligned with the position ticks: e = w_ref - w_motor;
  I = I + e Tv unless the previous output saturated (conditional-integration anti-windup);
  u = Kp (e + I / Ti) (+ acceleration feed-forward); u limited to +-u_max and held over the step.

Between the law and the plant sit the loop terms, built once by :func:`loop_terms` for every
loop that runs the law on the simulated plant: the output delay (the controller's computation
delay plus the plant's transport delay, in velocity periods, interpolated linearly between held
outputs when it is not a whole number), the delay of the position loop's feedback (in velocity
periods: the feedback position is sampled every velocity period into a history, and the position
loop reads it that many periods old, interpolated linearly in the same way), the current loop's
first-order lag, the effect table of the plant step, and the encoders' interpolation errors (its
``ENCODER_ERROR`` rows, sim_plant.kernel.reading, which the feedback stages :func:`encoders`,
:func:`feedback_reading`, :func:`motor_feedback` read; None without: compiled away).

The controller's settings and state are small float arrays (index constants below) so that the
same functions run inside compiled loops without Python objects.

The cycle, stage by stage (read feedback, profile and position law, velocity law, write command,
the plant over one velocity period), is written here once and composed by the three loops that
run it: the compiled loop (hil.simulate), the host's cycle loop (hil.loop) and the simulated
backend (drivers.sim). Its records are arrays named by fields, each built from one list:
the settings :class:`P`, the loop's state :data:`S` (:data:`LOOP_STATE`) and the loop terms
:data:`T` (:data:`LOOP_TERMS`, :attr:`LoopTerms.array`). The stages are real-time (no allocation,
bounded time); the builders (:func:`controller_from_config`, :func:`loop_terms`, the buffers of
:class:`LoopTerms`) are not.
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass, replace
from enum import IntEnum

import numpy as np
from numba import njit

from sim_plant.kernel import (
    MOTOR_ENCODER,
    TABLE_ENCODER,
    dry_friction,
    effect_table,
    encoder_rows,
    feedback_delay,
    plant_step,
    reading,
    reading_speed,
    time_delay,
)
from sim_plant.plant import Plant

__all__ = ["ControllerSettings", "controller_from_config", "position_law", "velocity_law",
           "new_velocity_state", "measured_speed", "pi_law", "filter_path", "filter_sections", "quantize", "delay_line", "history_push", "history_read", "LoopTerms",
           "loop_terms",
           "lag_alpha", "P", "S", "T", "LOOP_STATE", "LOOP_TERMS", "velocity_step", "encoders", "feedback_position",
           "feedback_reading", "motor_feedback",
           "position_tick", "delay_ring", "Terms", "terms_of", "speed_feedback", "velocity_cycle", "injected_velocity_cycle", "actuate", "plant_period",
           "plant_cycle"]


class P(IntEnum):
    """Indices into the settings array (IntEnum: numba reads them as constants)."""
    TP = 0
    TV = 1
    KV = 2
    FFV = 3
    KP = 4
    TI = 5
    ULIM = 6
    SPEED_SCALE = 7
    ACC_FF = 8
    N_TAPS = 9
    TAPS = 10            # taps follow, newest sample first (at most MAX_TAPS)
    MAX_TAPS = 8
    N_TQ = 18            # filter sections on the torque setpoint (drivers.filters), then 5 numbers each
    TQ = 19
    N_SP = 39            # filter sections on the speed feedback, then 5 numbers each
    SP = 40
    SIZE = 60


def _named_indices(name: str, fields: tuple, doc: str, sizes: dict | None = None) -> type[IntEnum]:
    """An IntEnum of the indices of ``fields`` (upper case) in a float array, one slot each unless
    ``sizes`` gives a field more, and ``SIZE``: one list names a record's fields once (numba reads
    the members as constants)."""
    members, at = {}, 0
    for f in fields:
        members[f.upper()] = at
        at += (sizes or {}).get(f, 1)
    members["SIZE"] = at
    enum = IntEnum(name, members)
    enum.__doc__ = doc
    enum.__module__ = __name__
    return enum


#: the loop's state, one float each; ``hist``: the speed filter's motor positions, newest first;
#: ``tq_z``, ``sp_z``: the two states of each filter section on the torque and on the speed path
LOOP_STATE = ("integral", "saturated", "qf_prev", "have_prev", "w_ref", "a_cmd", "hist", "tq_z", "sp_z")
_MAX_SOS = 4              # drivers.filters.MAX_SECTIONS
S = _named_indices("S", LOOP_STATE, "Indices into the loop's state array (:func:`new_velocity_state`): the "
                   "velocity PI's integral and anti-windup flag, the speed filter, the position tick's speed "
                   "reference and commanded acceleration, the filter sections' states.",
                   {"hist": int(P.MAX_TAPS), "tq_z": 2 * _MAX_SOS, "sp_z": 2 * _MAX_SOS})

#: the terms between the law and the plant of one loop, as numbers (:attr:`LoopTerms.array`)
LOOP_TERMS = ("substeps", "force_gain", "lag_alpha", "delayed", "delay_int", "delay_frac", "feedback_late",
              "feedback_int", "feedback_frac", "feedback_motor", "feedback_mass", "feedback_res", "res_motor",
              "res_table", "table", "tip", "dry")
T = _named_indices("T", LOOP_TERMS, "Indices into the loop terms' array (:attr:`LoopTerms.array`): velocity "
                   "steps per position tick, force per output, the current loop's step factor, the output "
                   "delay (flag, whole periods, fraction), the feedback delay (the same), the position "
                   "feedback (on the motor: flag; its mass and resolution), the encoders' resolutions, the table and tip masses, "
                   "dry friction present (flags 1.0 / 0.0).")
_STATE_SIZE = int(S.SIZE)

#: the loop terms as the compiled stages read them, by name (``t.lag_alpha``): a tuple of floats, a
#: value, so that compiled loops keep it in registers (:func:`terms_of` builds it from the array)
Terms = namedtuple("Terms", LOOP_TERMS)


@dataclass(frozen=True)
class ControllerSettings:
    """Settings of the cascade (SI; speeds of the velocity loop in controller units: rad/s of the
    motor for a rotary drive, m/s for a linear actuator)."""
    position_period: float
    velocity_period: float
    kv: float
    ffv: float
    kp: float
    ti: float
    output_limit: float
    speed_scale: float
    acc_ff: float = 0.0                  # output per (m/s^2) of commanded acceleration
    position_feedback: str = "table"     # table | motor
    velocity_feedback: str = "motor_speed"   # motor_speed | position_difference
    velocity_filter: tuple = (1.0,)
    output_delay: int = 0                # velocity periods
    # second-order sections (b0, b1, b2, a1, a2) at the velocity period (drivers.filters)
    torque_filters: tuple = ()
    speed_filters: tuple = ()

    @property
    def substeps(self) -> int:
        return int(round(self.position_period / self.velocity_period))

    def speed_filter(self) -> np.ndarray | None:
        """The speed filter's taps where the velocity loop reads the filtered motor positions
        (``position_difference``), None where it reads the motor's speed (the compiled loops then
        leave the filter out; :func:`speed_feedback`)."""
        taps = self.as_array()
        return taps[P.TAPS:P.TAPS + int(taps[P.N_TAPS])].copy() if taps[P.N_TAPS] > 0.0 else None

    def as_array(self) -> np.ndarray:
        if len(self.velocity_filter) > P.MAX_TAPS:
            raise ValueError(f"control.velocity_filter: at most {P.MAX_TAPS} taps, got {len(self.velocity_filter)}")
        a = np.zeros(P.SIZE)
        a[P.TP], a[P.TV], a[P.KV], a[P.FFV] = self.position_period, self.velocity_period, self.kv, self.ffv
        a[P.KP], a[P.TI], a[P.ULIM] = self.kp, self.ti, self.output_limit
        a[P.SPEED_SCALE], a[P.ACC_FF] = self.speed_scale, self.acc_ff
        taps = self.velocity_filter if self.velocity_feedback == "position_difference" else ()
        a[P.N_TAPS] = len(taps)
        a[P.TAPS:P.TAPS + len(taps)] = taps
        for n_at, at, secs in ((P.N_TQ, P.TQ, self.torque_filters), (P.N_SP, P.SP, self.speed_filters)):
            if len(secs) > _MAX_SOS:
                raise ValueError(f"control.filters: at most {_MAX_SOS} sections on a path, got {len(secs)}")
            a[n_at] = len(secs)
            for i, sec in enumerate(secs):
                a[at + 5 * i:at + 5 * i + 5] = sec
        return a


def controller_from_config(cfg, plant) -> ControllerSettings:
    """Controller settings of a config for a plant (the plant gives the speed and force scales)."""
    # acceleration feed-forward: a fraction of the total reflected inertia, as controller output
    acc_ff = cfg.get("control.acc_ff", 0.0) * plant.total_mass / plant.force_gain
    return ControllerSettings(
        position_period=cfg["control.position_period"], velocity_period=cfg["control.velocity_period"],
        kv=cfg["control.kv"], ffv=cfg.get("control.ffv", 1.0), kp=cfg["control.kp"],
        ti=cfg.get("control.ti", math.inf), output_limit=cfg["control.output_limit"],
        speed_scale=plant.speed_scale, acc_ff=acc_ff,
        position_feedback=cfg.get("control.position_feedback", "table"),
        velocity_feedback=cfg.get("control.velocity_feedback", "motor_speed"),
        velocity_filter=tuple(cfg.get("control.velocity_filter", [1.0])),
        output_delay=int(cfg.get("control.output_delay", 0)),
        **filter_sections(cfg.get("control.filters") or (), cfg["control.velocity_period"]))


def filter_sections(specs, tv: float) -> dict:
    """``torque_filters`` and ``speed_filters`` of :class:`ControllerSettings` from the config's
    ``control.filters`` (dicts of SI values, or :class:`drivers.filters.FilterSpec`), designed at
    the velocity period ``tv`` (not real-time)."""
    from drivers.filters import FilterSpec, sections

    def spec(d):          # the config's entry: the depth in dB
        d = dict(d)
        if "depth" in d:
            d["depth"] = 10.0 ** (d["depth"] / 20.0)
        for k in ("b", "a"):
            if k in d:
                d[k] = tuple(d[k])
        return FilterSpec(**d)
    specs = [s if isinstance(s, FilterSpec) else spec(s) for s in specs]
    return {"torque_filters": sections(specs, tv, "torque"), "speed_filters": sections(specs, tv, "speed")}


@njit(cache=True, inline="always")
def position_law(p, x_cmd_k, x_cmd_next, x_feedback):
    """Speed reference of the velocity loop (controller units) at a position tick."""
    v_ref = p[P.KV] * (x_cmd_k - x_feedback) + p[P.FFV] * (x_cmd_next - x_cmd_k) / p[P.TP]
    return v_ref * p[P.SPEED_SCALE]


@njit(cache=True, inline="always")
def new_velocity_state():
    """A fresh loop state (:data:`S`): at rest, nothing integrated (not real-time: allocates)."""
    return np.zeros(_STATE_SIZE)


@njit(cache=True, inline="always")
def measured_speed(p, s, v_motor, x_motor):
    """Read feedback (real-time): the speed the velocity loop sees: the motor's speed, or the
    backward difference of the FIR-filtered motor position (then the history in ``s`` advances)."""
    n = int(p[P.N_TAPS])
    if n == 0:
        return filter_path(p, s, P.N_SP, P.SP, S.SP_Z, v_motor * p[P.SPEED_SCALE])
    for i in range(n - 1, 0, -1):
        s[S.HIST + i] = s[S.HIST + i - 1]
    s[S.HIST] = x_motor
    if s[S.HAVE_PREV] == 0.0:       # first sample: fill the history, no speed yet
        for i in range(1, n):
            s[S.HIST + i] = x_motor
    qf = 0.0
    for i in range(n):
        qf += p[P.TAPS + i] * s[S.HIST + i]
    w = 0.0
    if s[S.HAVE_PREV] != 0.0:
        w = (qf - s[S.QF_PREV]) / p[P.TV] * p[P.SPEED_SCALE]
    s[S.QF_PREV] = qf
    s[S.HAVE_PREV] = 1.0
    return filter_path(p, s, P.N_SP, P.SP, S.SP_Z, w)


@njit(cache=True, inline="always")
def filter_path(p, s, n_at, at, z_at, x):
    """The filter sections on one path (real-time): ``p[n_at]`` sections of 5 numbers from
    ``p[at]``, their states from ``s[z_at]`` (transposed direct form II); ``x`` through them all.
    No section: ``x`` itself (the loop does not run)."""
    n = int(p[n_at])
    for i in range(n):
        c, z = at + 5 * i, z_at + 2 * i
        y = p[c] * x + s[z]
        s[z] = p[c + 1] * x - p[c + 3] * y + s[z + 1]
        s[z + 1] = p[c + 2] * x - p[c + 4] * y
        x = y
    return x


@njit(cache=True, inline="always")
def pi_law(kp, ti, tv, limit, integral, saturated, w_ref, w_meas, feed_forward):
    """The velocity PI on scalars: returns (output, integral, saturated). The reference order:
    e = w_ref - w; I = I + e Tv unless the previous output saturated; u = Kp (e + I / Ti) + ff,
    limited to +-limit. (Scalars, so that compiled loops keep the state in registers.)"""
    e = w_ref - w_meas
    if not saturated:
        integral += e * tv
    u = kp * (e + integral / ti) + feed_forward
    if u > limit:
        return limit, integral, True
    if u < -limit:
        return -limit, integral, True
    return u, integral, False


@njit(cache=True, inline="always")
def velocity_step(p, s, w_ref, w_meas, feed_forward):
    """Velocity law (real-time): one step of the PI on the settings ``p`` and the state ``s``,
    ``feed_forward`` added; the (limited) controller output, torque or command."""
    u, s[S.INTEGRAL], sat = pi_law(p[P.KP], p[P.TI], p[P.TV], p[P.ULIM], s[S.INTEGRAL], s[S.SATURATED] != 0.0,
                                   w_ref, w_meas, feed_forward)
    s[S.SATURATED] = 1.0 if sat else 0.0
    if p[P.N_TQ] > 0.0:          # the torque setpoint's filters, limited again after them
        lim = p[P.ULIM]
        u = min(max(filter_path(p, s, P.N_TQ, P.TQ, S.TQ_Z, u), -lim), lim)
    return u


@njit(cache=True, inline="always")
def velocity_law(p, s, w_ref, w_meas, a_cmd):
    """Velocity law (real-time): :func:`velocity_step` with the acceleration feed-forward of the
    commanded acceleration ``a_cmd``."""
    return velocity_step(p, s, w_ref, w_meas, p[P.ACC_FF] * a_cmd)


@njit(cache=True, inline="always")
def quantize(x, q):
    if q > 0.0:
        return q * math.floor(x / q + 0.5)
    return x


@njit(cache=True, inline="always")
def delay_line(ubuf, u, d_int, d_frac):
    """Push the output ``u`` into ``ubuf`` (newest first) and return the delayed output: the
    outputs ``d_int`` and ``d_int + 1`` periods old, interpolated linearly by ``d_frac``."""
    for i in range(d_int + 1, 0, -1):
        ubuf[i] = ubuf[i - 1]
    ubuf[0] = u
    return (1.0 - d_frac) * ubuf[d_int] + d_frac * ubuf[d_int + 1]


@njit(cache=True, inline="always")
def history_push(hbuf, value):
    """Push ``value`` into the ring buffer ``hbuf`` (its last entry holds the index of the newest
    sample); the first push fills it (before the start the axis was at rest)."""
    m = hbuf.shape[0] - 1
    h = int(hbuf[m])
    if h < 0:
        for i in range(m):
            hbuf[i] = value
        hbuf[m] = 0.0
        return
    h += 1
    if h >= m:
        h = 0
    hbuf[h] = value
    hbuf[m] = h


@njit(cache=True, inline="always")
def history_read(hbuf, d_int, d_frac):
    """The value ``d_int + d_frac`` pushes old (0: the newest), linear between the samples."""
    m = hbuf.shape[0] - 1
    i0 = int(hbuf[m]) - d_int
    if i0 < 0:
        i0 += m
    i1 = i0 - 1
    if i1 < 0:
        i1 += m
    return (1.0 - d_frac) * hbuf[i0] + d_frac * hbuf[i1]


# --- the cycle, stage by stage ------------------------------------------------------------------
# As LinuxCNC's control.c names its stages: read feedback, supervise, profile, position law,
# velocity law, write command, record; and on the simulated plant, the plant over one velocity
# period. The compiled loop (hil.simulate), the host's cycle loop (hil.loop) and the simulated
# backend (drivers.sim) compose these, so that each stage is written once. Their records are
# named by fields: the settings ``p`` (an array, :class:`P`), the loop's state ``s`` (an array,
# :data:`S`), the loop terms ``t`` (a :data:`Terms` record, of the array :data:`T` names); the
# plant is its discretized matrices ``Ad``, ``Bd``, the friction tuple ``fric`` and the effect table
# ``codes``, ``eparams`` (``codes`` None without effects: compiled away). All are real-time: no
# allocation, bounded time.

@njit(cache=True, inline="always")
def terms_of(a):
    """The loop terms' array (:attr:`LoopTerms.array`, :data:`T`) as the :data:`Terms` record the
    stages take (real-time: a value, no allocation). Entry points called from Python take the
    array, which numba passes fastest, and build the record here."""
    return Terms(a[T.SUBSTEPS], a[T.FORCE_GAIN], a[T.LAG_ALPHA], a[T.DELAYED], a[T.DELAY_INT], a[T.DELAY_FRAC],
                 a[T.FEEDBACK_LATE], a[T.FEEDBACK_INT], a[T.FEEDBACK_FRAC], a[T.FEEDBACK_MOTOR], a[T.FEEDBACK_MASS],
                 a[T.FEEDBACK_RES], a[T.RES_MOTOR], a[T.RES_TABLE], a[T.TABLE], a[T.TIP], a[T.DRY])


@njit(cache=True, inline="always")
def encoders(t, x, enc=None):
    """Read feedback (real-time): the motor and table encoders on the plant state ``x``, as they
    read (an encoder's interpolation error of the rows ``enc``, :attr:`LoopTerms.enc`:
    sim_plant.kernel.reading; None: none, compiled away), quantized."""
    return (quantize(reading(enc, MOTOR_ENCODER, x[0]), t.res_motor),
            quantize(reading(enc, TABLE_ENCODER, x[int(t.table)]), t.res_table))


@njit(cache=True, inline="always")
def feedback_reading(t, x, enc=None):
    """Read feedback (real-time): the position loop's encoder as it reads now (its interpolation
    error where ``enc`` has one), quantized."""
    which = MOTOR_ENCODER if t.feedback_motor != 0.0 else TABLE_ENCODER
    return quantize(reading(enc, which, x[int(t.feedback_mass)]), t.feedback_res)


@njit(cache=True, inline="always")
def feedback_position(t, x, hbuf, enc=None):
    """Read feedback (real-time): the position the position loop closes on, as it arrives: the
    feedback encoder now (:func:`feedback_reading`), or with a feedback delay its history ``hbuf``
    read that many periods old."""
    if hbuf is not None and t.feedback_late != 0.0:     # None: compiled away
        return history_read(hbuf, int(t.feedback_int), t.feedback_frac)
    return feedback_reading(t, x, enc)


@njit(cache=True, inline="always")
def motor_feedback(p, t, x, enc=None):
    """Read feedback (real-time): the motor encoder's reading (quantized) and the motor's speed
    (m/s) as the drive derives it from that encoder (sim_plant.kernel.reading_speed: the
    error's change over one velocity period where ``enc`` has a motor-encoder error; the plant's
    speed otherwise)."""
    n = x.shape[0] // 2
    return (quantize(reading(enc, MOTOR_ENCODER, x[0]), t.res_motor),
            reading_speed(enc, x[0], x[n], p[P.TV]))


@njit(cache=True, inline="always")
def speed_feedback(p, s, speed_filter, v_motor, x_motor):
    """Read feedback (real-time): :func:`measured_speed`, decided when the loop is compiled:
    ``speed_filter`` (:meth:`ControllerSettings.speed_filter`) None reads the motor's speed and
    compiles the filter away (the compiled loops' hot path), an array the filtered positions."""
    if speed_filter is not None:
        return measured_speed(p, s, v_motor, x_motor)
    return filter_path(p, s, P.N_SP, P.SP, S.SP_Z, v_motor * p[P.SPEED_SCALE])


@njit(cache=True, inline="always")
def position_tick(p, s, x_cmd, k, x_feedback):
    """Profile and position law at position tick ``k`` (real-time). ``x_cmd``: the command at every
    tick and at the one after the last. Keeps the interpolator's acceleration (for the
    feed-forward) and the speed reference in the state ``s`` until the next tick; returns the
    speed reference."""
    tp = p[P.TP]
    if k > 0:
        s[S.A_CMD] = (x_cmd[k + 1] - 2.0 * x_cmd[k] + x_cmd[k - 1]) / (tp * tp)
    else:
        s[S.A_CMD] = (x_cmd[k + 1] - x_cmd[k]) / (tp * tp)
    s[S.W_REF] = position_law(p, x_cmd[k], x_cmd[k + 1], x_feedback)
    return s[S.W_REF]


@njit(cache=True, inline="always")
def delay_ring(ring, u):
    """Write command (real-time): ``u`` in, the output ``len(ring) - 1`` cycles old out (zero
    before the first ones): a ring of whole periods, its last slot the index of the oldest."""
    m = ring.shape[0] - 1
    if m == 0:
        return u
    i = int(ring[m])
    out = ring[i]
    ring[i] = u
    i += 1
    ring[m] = 0.0 if i == m else float(i)
    return out


@njit(cache=True, inline="always")
def velocity_cycle(p, s, ring, v_motor, x_motor):
    """The host's velocity-loop cycle (real-time): read the speed, the velocity law on the tick's
    speed reference and feed-forward (kept in ``s`` by :func:`position_tick`), the output delay
    (``ring``, :func:`delay_ring`); returns the output to send."""
    w = measured_speed(p, s, v_motor, x_motor)
    return delay_ring(ring, velocity_step(p, s, s[S.W_REF], w, p[P.ACC_FF] * s[S.A_CMD]))


@njit(cache=True, inline="always")
def injected_velocity_cycle(p, s, ring, v_motor, x_motor, r, into_torque, data, i):
    """:func:`velocity_cycle` with an excitation ``r`` added to the output (``into_torque``; the sum
    limited) or to the speed reference (real-time). Row ``i`` of ``data`` takes what the cycle did,
    the columns of hil.loop.CYCLE_CHANNELS up to the encoders (r, u, u_ctrl, e, w, w_ref_pos,
    w_ref)."""
    w = measured_speed(p, s, v_motor, x_motor)
    w_pos = s[S.W_REF]
    w_ref = w_pos + (0.0 if into_torque else r)
    uc = velocity_step(p, s, w_ref, w, p[P.ACC_FF] * s[S.A_CMD])
    lim = p[P.ULIM]
    u = min(max(uc + (r if into_torque else 0.0), -lim), lim)
    data[i, 0], data[i, 1], data[i, 2], data[i, 3], data[i, 4], data[i, 5], data[i, 6] = \
        r, u, uc, w_ref - w, w, w_pos, w_ref
    return delay_ring(ring, u)


@njit(cache=True, inline="always")
def actuate(t, ubuf, u, u_act):
    """Write command (real-time): the output through the delay (where the terms have one) and the
    current loop's first-order lag; returns the current loop's new output ``u_act``."""
    if ubuf is not None and t.delayed != 0.0:           # None: compiled away
        u = delay_line(ubuf, u, int(t.delay_int), t.delay_frac)
    return u_act + t.lag_alpha * (u - u_act)


@njit(cache=True, inline="always")
def plant_period(Ad, Bd, fric, codes, eparams, t, x, f, x_new, hbuf, u_act, fext=None, masses=None, enc=None):
    """The plant over one velocity period (real-time): the state ``x`` advanced in place under the
    actuator's output ``u_act`` (and external forces ``fext``, None: compiled away); the position
    loop's feedback history ``hbuf`` takes the new reading (through the encoders' errors ``enc``)
    where the terms have a feedback delay. ``masses``: the chain's size for the compiler
    (sim_plant.kernel.mass_token), or None."""
    plant_step(Ad, Bd, x, u_act * t.force_gain, fric, t.dry != 0.0, codes, eparams, f, x_new, fext, masses)
    if hbuf is not None and t.feedback_late != 0.0:     # None: compiled away
        history_push(hbuf, feedback_reading(t, x, enc))


@njit(cache=True, inline="always")
def plant_cycle(Ad, Bd, fric, codes, eparams, t, x, f, x_new, ubuf, hbuf, u, u_act, enc=None):
    """Write command and plant (real-time): :func:`actuate`, then :func:`plant_period`; returns
    the current loop's output ``u_act``."""
    u_act = actuate(t, ubuf, u, u_act)
    plant_period(Ad, Bd, fric, codes, eparams, t, x, f, x_new, hbuf, u_act, None, enc=enc)
    return u_act


def lag_alpha(plant: Plant, ctrl: ControllerSettings) -> float:
    """The current loop's first-order lag as a step factor over one velocity period (1: ideal)."""
    tc = plant.current_loop_time_constant
    return 1.0 if tc <= 0 else float(1.0 - np.exp(-ctrl.velocity_period / tc))


@dataclass(frozen=True, eq=False)
class LoopTerms:
    """The terms between the control law and the plant step of one plant and controller.

    ``codes``, ``params``: the effect table (:func:`sim_plant.kernel.effect_table`; ``codes`` is
    None without effects, which the compiled loops leave out). ``delay``: velocity periods from
    the law's output to the current loop. ``lag_alpha``: the current loop's step factor.
    ``feedback_delay``: velocity periods by which the position loop's feedback is late. ``enc``:
    the table's ``ENCODER_ERROR`` rows (sim_plant.kernel.encoder_rows), which the feedback
    stages read; None without (compiled away)."""
    codes: np.ndarray | None
    params: np.ndarray
    delay: float
    lag_alpha: float
    feedback_delay: float = 0.0
    array: np.ndarray | None = None
    enc: np.ndarray | None = None

    def with_array(self, plant: Plant, ctrl: ControllerSettings) -> LoopTerms:
        """These terms with :attr:`array`: their numbers and the plant's and controller's that the
        cycle's stages read, named by :data:`T` (not real-time)."""
        t = np.zeros(T.SIZE)
        motor_fb = ctrl.position_feedback == "motor"
        t[T.SUBSTEPS], t[T.FORCE_GAIN], t[T.LAG_ALPHA] = ctrl.substeps, plant.force_gain, self.lag_alpha
        t[T.DELAYED] = 1.0 if self.delay > 0.0 else 0.0
        t[T.DELAY_INT], t[T.DELAY_FRAC] = self.delay_parts
        t[T.FEEDBACK_LATE] = 1.0 if self.feedback_delay > 0.0 else 0.0
        t[T.FEEDBACK_INT], t[T.FEEDBACK_FRAC] = self.feedback_parts
        t[T.FEEDBACK_MOTOR], t[T.FEEDBACK_MASS] = (1.0, 0) if motor_fb else (0.0, plant.table)
        t[T.FEEDBACK_RES] = plant.motor_resolution if motor_fb else plant.table_resolution
        t[T.RES_MOTOR], t[T.RES_TABLE] = plant.motor_resolution, plant.table_resolution
        t[T.TABLE], t[T.TIP], t[T.DRY] = plant.table, plant.tip, 1.0 if dry_friction(plant) else 0.0
        return replace(self, array=t)

    @property
    def feedback_parts(self) -> tuple[int, float]:
        """The feedback delay as whole velocity periods and the fraction beyond them."""
        d_int = int(math.floor(self.feedback_delay))
        return d_int, self.feedback_delay - d_int

    def feedback_buffer(self) -> np.ndarray | None:
        """A fresh history of the feedback position for :func:`history_push` /
        :func:`history_read`, or None without a feedback delay (not real-time)."""
        if self.feedback_delay <= 0.0:
            return None
        h = np.zeros(self.feedback_parts[0] + 3)
        h[-1] = -1.0          # empty: the first push fills it
        return h

    def feedback_history(self) -> np.ndarray:
        """:meth:`feedback_buffer`, or a two-element empty history (which the stages never read)
        without a feedback delay (not real-time)."""
        h = self.feedback_buffer()
        return h if h is not None else np.array([0.0, -1.0])

    @property
    def delay_parts(self) -> tuple[int, float]:
        """The delay as whole periods and the fraction interpolated beyond them (as the compiled
        loop splits it)."""
        d_int = int(math.floor(self.delay))
        return d_int, self.delay - d_int

    def delay_buffer(self) -> np.ndarray | None:
        """A fresh buffer of held outputs for :func:`delay_line`, or None without a delay (not
        real-time)."""
        return np.zeros(self.delay_parts[0] + 2) if self.delay > 0.0 else None

    def output_buffer(self) -> np.ndarray:
        """:meth:`delay_buffer`, or a buffer the stages never read without a delay (not
        real-time)."""
        return np.zeros(self.delay_parts[0] + 2)


def loop_terms(plant: Plant, ctrl: ControllerSettings, with_output_delay: bool = True) -> LoopTerms:
    """The loop terms of ``plant`` under ``ctrl``.

    Parameters
    ----------
    plant : sim_plant.plant.Plant
        The plant: its effect rows (transport and feedback delays included) and current-loop time
        constant.
    ctrl : ControllerSettings
        The controller: velocity period and output delay.
    with_output_delay : bool
        Whether the delay includes the controller's ``output_delay``; False where the caller's
        controller applies it itself (the host's loop, hil.loop) and only the plant's transport
        delay is left to the plant side.

    Returns
    -------
    LoopTerms
    """
    codes, params = effect_table(plant)
    delay = time_delay(plant) / ctrl.velocity_period
    if with_output_delay:
        delay = float(ctrl.output_delay) + delay
    terms = LoopTerms(codes, params, delay, lag_alpha(plant, ctrl), feedback_delay(plant) / ctrl.velocity_period,
                      enc=encoder_rows(codes, params))
    return terms.with_array(plant, ctrl)
