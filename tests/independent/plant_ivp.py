"""A second, independent simulator of the paper's bench, for test records (issue 24, item 6).

Written again from the paper (Eq. 1-3: the n-dof lumped-mass chain M x'' + C x' + K x = f, the
force {f, 0, ..., 0} on the motor's reflected mass; Eq. 11: friction on the motor; Eq. 15-16: the
sine-square velocity profile) and from the drive's description in drivers/control.py's docstring, not
from the project's kernel: it shares no code with ``hil`` (only the config reader may be used to
fill :class:`Bench`, :func:`bench_from_config`). Where the project's kernel discretizes the chain
exactly over a velocity period (a matrix exponential) and decides dry friction by time stepping,
this module integrates the equations of motion with ``scipy.integrate.solve_ivp`` (an adaptive
Runge-Kutta pair) and treats stick-slip as a hybrid system with events (a velocity zero crossing;
the break-away force reached). A kernel error, or a convention the kernel and the replay share,
therefore cannot agree with this simulator by construction.

The drive, as a drive steps it:

* position loop every ``tp``, tick k at t_k = k tp: v_ref = kv (x_cmd[k] - x_fb) + ffv (x_cmd[k+1] -
  x_cmd[k]) / tp, x_fb the table (or motor) position at t_k; the motor speed reference is
  w_ref = v_ref 2 pi / pitch, held until the next tick;
* velocity loop every ``tv``: e = w_ref - w_motor; the integral takes e tv unless the last output
  was limited; u = kp (e + I / ti), limited to +-u_max, held over the period (zero-order hold);
* the torque command u reaches the motor ``delay`` seconds late (an exact transport delay: the
  applied torque switches inside a period when the delay is not a whole number of periods) and
  through the current loop: ideal (``current_tc`` 0) or a first-order lag di/dt = (u - i) / tc,
  integrated with the chain.

Logged at each position tick, as a drive logs them: the positions at t_k (before the tick's output
acts), the command x_cmd[k], and the torque ``"command"`` (the controller's output at the tick,
before the delay and the current loop) or ``"actual"`` (the motor's current at t_k, after them).

Units: SI inside (m, kg, N, s; motor torques N m, rotary damping N m s/rad). Hidden effects
(:class:`Hidden`) use the catalogue's names and meanings (sim_plant/effects.py): Coulomb
friction per direction, extra viscous friction per direction, backlash of total width ``gap`` in
the motor-table link (inside the gap neither spring nor damper carries force), a compliant mode
(an extra mass on a spring-damper at the tool tip, which becomes the tip), torque ripple of any
period along the travel (pitch / orders per revolution), an actuator delay, a current loop's lag,
a constant force on a chosen mass (default the table, where gravity on an inclined axis acts),
and changed masses, stiffnesses and dampings (:class:`Bench` itself).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

__all__ = ["Bench", "Hidden", "bench_from_config", "simulate", "sine_square_move", "command_sequence", "measure",
           "two_mass_frequency"]

RTOL = 1e-9
ATOL_X = 1e-12        # m
ATOL_V = 1e-10        # m/s
CHATTER_V = 1e-8      # m/s: a speed this small, changing direction 50 times in one interval, is a chatter


@dataclass(frozen=True)
class Bench:
    """The bench and its drive, SI. ``m``: masses motor (reflected), table, ...; ``k``, ``c``:
    the links between neighbours; ``viscous``: N m s/rad on the motor (Eq. 11)."""
    m: tuple
    k: tuple
    c: tuple
    pitch: float
    viscous: float
    tp: float
    tv: float
    kv: float
    ffv: float
    kp: float
    ti: float
    u_max: float
    table: int = 1
    tip: int = -1
    feedback: str = "table"      # table | motor

    @property
    def r(self) -> float:
        """N on the motor's mass per N m of motor torque (and rad/s per m/s): 2 pi / pitch."""
        return 2.0 * math.pi / self.pitch

    def changed(self, **kw) -> "Bench":
        return dataclasses.replace(self, **kw)


@dataclass(frozen=True)
class Hidden:
    """The effects a record holds that the nominal model lacks (catalogue names in brackets)."""
    coulomb_pos: float = 0.0             # N m moving in +x [coulomb_friction, asymmetric_friction]
    coulomb_neg: float = 0.0             # N m moving in -x
    viscous_pos: float = 0.0             # extra N m s/rad moving in +x [viscous_friction, asymmetric_friction]
    viscous_neg: float = 0.0
    gap: float = 0.0                     # total play of the motor-table link, m [backlash]
    mode: tuple | None = None            # (mass kg, frequency Hz, damping ratio) at the tip [compliant_mode]
    ripple: tuple = ()                   # ((amplitude N m, period m, phase rad), ...) [torque_ripple]
    delay: float = 0.0                   # s, command to motor [actuator_delay]
    current_tc: float = 0.0              # s, current loop's time constant (0: ideal)
    force: float = 0.0                   # N, constant [constant_force]
    force_mass: int = 1                  # the mass it acts on (0 motor, 1 table, ...)
    notes: dict = field(default_factory=dict)


def bench_from_config(cfg) -> Bench:
    """A :class:`Bench` from a loaded project config (values in SI; a rotary 2- or 3-mass chain)."""
    n = 1
    while f"plant.m{n + 1}" in cfg:
        n += 1
    return Bench(m=tuple(cfg[f"plant.m{i}"] for i in range(1, n + 1)),
                 k=tuple(cfg[f"plant.k{i}"] for i in range(1, n)), c=tuple(cfg[f"plant.c{i}"] for i in range(1, n)),
                 pitch=cfg["plant.pitch"], viscous=cfg.get("friction.viscous", 0.0),
                 tp=cfg["control.position_period"], tv=cfg["control.velocity_period"], kv=cfg["control.kv"],
                 ffv=cfg.get("control.ffv", 1.0), kp=cfg["control.kp"], ti=cfg.get("control.ti", math.inf),
                 u_max=cfg["control.output_limit"],
                 feedback=cfg.get("control.position_feedback", "table"))


# --- the command ---------------------------------------------------------------------------------

def sine_square_move(t, stroke: float, v_max: float, a_max: float):
    """Position at times ``t`` (from the move's start) of a sine-square move (Eq. 15-16): ramps of
    T_r = pi v / (2 a_max) with v = v_max sin^2(pi t / (2 T_r)), whose integral is
    v (t / 2 - T_r / (2 pi) sin(pi t / T_r)); a stroke too short for v_max lowers the speed (same
    ramp time). Returns (positions, duration)."""
    d, s = abs(stroke), math.copysign(1.0, stroke)
    t_r = math.pi * v_max / (2.0 * a_max)
    v = v_max if v_max * t_r <= d else d / t_r
    t_c = (d - v * t_r) / v
    T = 2.0 * t_r + t_c
    t = np.clip(np.asarray(t, float), 0.0, T)

    def ramp(tau):
        return v * (0.5 * tau - t_r / (2.0 * math.pi) * np.sin(math.pi * tau / t_r))
    x = np.where(t < t_r, ramp(t), np.where(t < t_r + t_c, ramp(t_r) + v * (t - t_r),
                                            d - ramp(np.clip(T - t, 0.0, None))))
    return s * x, T


def scattered(bench: Bench, rng, scatter: float):
    """A night of a healthy axis: (``bench`` with every mass, stiffness and damping times
    1 + ``scatter`` N(0, 1), drawn from ``rng`` in that order, and the function that scatters any
    other value the same way, from the same ``rng``)."""
    def night(v):
        return v * (1.0 + scatter * rng.standard_normal())
    return bench.changed(m=tuple(night(v) for v in bench.m), k=tuple(night(v) for v in bench.k),
                         c=tuple(night(v) for v in bench.c)), night


def command_sequence(duration: float, tp: float, seed: int, travel: float = 0.08, v_max: float = 0.2,
                     a_max: float = 6.0) -> np.ndarray:
    """A varied command on the tick clock (one more sample than ticks, for the last tick's
    feed-forward): sine-square moves of 2..50 mm at 5 mm/s..``v_max`` with accelerations from
    ``a_max`` down, dwells of 0..0.5 s, both directions, within [0, travel]; seeded."""
    rng = np.random.default_rng(seed)
    n = int(round(duration / tp)) + 1
    t_grid = np.arange(n) * tp
    x = np.zeros(n)
    t0, pos = 0.15, 0.0
    while t0 < duration:
        stroke = rng.uniform(0.002, 0.05)
        if pos + stroke > travel or (pos - stroke >= 0.0 and rng.random() < 0.5):
            stroke = -stroke
        v = rng.uniform(0.005, v_max)
        a = rng.uniform(0.3 * a_max, a_max)
        _, T = sine_square_move(0.0, stroke, v, a)
        sel = t_grid >= t0
        dx, _ = sine_square_move(t_grid[sel] - t0, stroke, v, a)
        x[sel] = pos + dx
        pos += stroke
        t0 += T + (rng.uniform(0.0, 0.5) if rng.random() < 0.7 else 0.0)
    return x


# --- the plant ----------------------------------------------------------------------------------

class _Plant:
    """The chain's equations of motion with the hidden effects, state [x (n), v (n), current]."""

    def __init__(self, bench: Bench, hid: Hidden):
        m, k, c = list(bench.m), list(bench.k), list(bench.c)
        tip = bench.tip % len(m)
        if hid.mode is not None:
            mm, f, z = hid.mode
            w = 2.0 * math.pi * f
            m.append(mm)
            k.append(mm * w * w)
            c.append(2.0 * z * mm * w)
            tip = len(m) - 1
            # (the mode hangs on the last mass of the chain, the old tip)
        self.m, self.k, self.c = np.array(m, float), np.array(k, float), np.array(c, float)
        self.n = len(m)
        self.tip, self.table = tip, bench.table
        r = bench.r
        self.r = r
        self.cv = bench.viscous * r * r
        self.cv_pos, self.cv_neg = hid.viscous_pos * r * r, hid.viscous_neg * r * r
        self.fc_pos, self.fc_neg = hid.coulomb_pos * r, hid.coulomb_neg * r
        self.dry = self.fc_pos > 0.0 or self.fc_neg > 0.0
        self.half_gap = 0.5 * hid.gap
        self.ripple = [(a * r, p, ph) for a, p, ph in hid.ripple]
        self.force, self.force_mass = hid.force, hid.force_mass
        self.tc = hid.current_tc
        self._matrices()
        self.K_full, self.C_full = self.KM * self.m[:, None], self.CM * self.m[:, None]
        self.nonlinear = bool(self.half_gap > 0.0 or self.cv_pos or self.cv_neg or self.ripple or self.force)

    def _matrices(self):
        """Stiffness and damping matrices of the chain (Eq. 1: M x'' + C x' + K x = f) with the
        motor's viscous friction on the motor's mass; divided by the masses."""
        n = self.n
        K, C = np.zeros((n, n)), np.zeros((n, n))
        for i in range(n - 1):
            for M, val in ((K, self.k[i]), (C, self.c[i])):
                M[i, i] += val
                M[i + 1, i + 1] += val
                M[i, i + 1] -= val
                M[i + 1, i] -= val
        C[0, 0] += self.cv
        self.minv = 1.0 / self.m
        self.KM = K * self.minv[:, None]
        self.CM = C * self.minv[:, None]

    def forces(self, y, torque):
        """Forces on every mass (N) except dry friction, for state ``y`` and motor torque."""
        n = self.n
        x, v = y[:n], y[n:2 * n]
        f = -(self.K_full @ x) - (self.C_full @ v)
        f[0] += torque * self.r
        return f + self.extra(x, v)

    def extra(self, x, v):
        """The hidden effects' forces beyond the linear chain (N per mass)."""
        n = self.n
        f = np.zeros(n)
        if self.half_gap > 0.0:
            # the chain applies k d + c dv on link 1; inside the gap neither acts, outside k (d -+ h)
            h, d, dv = self.half_gap, x[0] - x[1], v[0] - v[1]
            corr = -(self.k[0] * d + self.c[0] * dv) if abs(d) <= h else -self.k[0] * math.copysign(h, d)
            f[0] -= corr
            f[1] += corr
        if self.cv_pos or self.cv_neg:
            f[0] -= (self.cv_pos if v[0] > 0.0 else self.cv_neg) * v[0]
        for a, p, ph in self.ripple:
            f[0] += a * math.sin(2.0 * math.pi * x[0] / p + ph)
        if self.force:
            f[self.force_mass] += self.force
        return f

    def rhs(self, mode, u_cmd):
        """The right-hand side in a friction ``mode``: +1 / -1 sliding, 0 stuck, None no dry
        friction; ``u_cmd``: the (delayed) torque command over the interval."""
        n, tc = self.n, self.tc

        KM, CM, minv, r = self.KM, self.CM, self.minv, self.r
        fc = self.fc_pos if mode == 1 else (-self.fc_neg if mode == -1 else 0.0)

        def f(t, y):
            x, v = y[:n], y[n:2 * n]
            torque = y[2 * n] if tc > 0.0 else u_cmd
            dy = np.empty_like(y)
            dy[:n] = v
            a = -(KM @ x) - (CM @ v)
            a[0] += (torque * r - fc) * minv[0]
            if self.nonlinear:
                a += self.extra(x, v) * minv
            dy[n:2 * n] = a
            if mode == 0:
                dy[0] = 0.0
                dy[n] = 0.0
            if tc > 0.0:
                dy[2 * n] = (u_cmd - y[2 * n]) / tc
            return dy
        return f

    def drive_force(self, y, u_cmd):
        """The force on the motor's mass without dry friction (decides sticking)."""
        torque = y[2 * self.n] if self.tc > 0.0 else u_cmd
        return self.forces(y, torque)[0]

    def mode_at_rest(self, y, u_cmd):
        f = self.drive_force(y, u_cmd)
        if f > self.fc_pos:
            return 1
        if f < -self.fc_neg:
            return -1
        return 0


def _advance(pl: _Plant, y, mode, t0, t1, u_cmd):
    """Integrate from t0 to t1 with the torque command ``u_cmd`` held; returns (y, mode)."""
    n = pl.n
    atol = np.concatenate([np.full(n, ATOL_X), np.full(n, ATOL_V), [1e-9] * (y.size - 2 * n)])
    t = t0
    guard = 0
    while t < t1 - 1e-15:
        guard += 1
        if guard > 50 and abs(y[n]) <= CHATTER_V:
            # the motor at rest on a force discontinuity (the backlash's edge with the drive force
            # at the friction level: a step either way sticks it again); Filippov's limit of the
            # chatter is the motor held, here for the rest of the interval (at most one velocity
            # period, a force within the level's tolerance of the events)
            y = y.copy()
            y[n] = 0.0
            sol = solve_ivp(pl.rhs(0, u_cmd), (t, t1), y, method="RK45", rtol=RTOL, atol=atol, first_step=t1 - t)
            if sol.status < 0:
                raise RuntimeError(sol.message)
            y, t, mode = sol.y[:, -1].copy(), t1, 0
            break
        if guard > 50:
            raise RuntimeError("stick-slip: too many mode changes in one interval")
        if mode == 0:            # the torque jumps at the period's start: it may break away at once
            mode = pl.mode_at_rest(y, u_cmd)
        events = []
        if mode in (1, -1):
            def stop(t, y, s=mode):
                return y[n]
            stop.terminal, stop.direction = True, -mode
            events = [stop]
        elif mode == 0:
            def go_pos(t, y):
                return pl.drive_force(y, u_cmd) - pl.fc_pos

            def go_neg(t, y):
                return -pl.drive_force(y, u_cmd) - pl.fc_neg
            go_pos.terminal = go_neg.terminal = True
            go_pos.direction = go_neg.direction = 1
            events = [go_pos, go_neg]
        sol = solve_ivp(pl.rhs(mode, u_cmd), (t, t1), y, method="RK45", rtol=RTOL, atol=atol,
                        events=events or None, first_step=t1 - t)
        if sol.status < 0:
            raise RuntimeError(sol.message)
        y = sol.y[:, -1].copy()
        t = sol.t[-1]
        if sol.status == 1:          # an event ended the interval early
            if mode in (1, -1):
                y[n] = 0.0
                mode = pl.mode_at_rest(y, u_cmd)
            else:
                mode = 1 if sol.t_events[0].size else -1
    if mode == 0:
        y[n] = 0.0
    return y, mode


# --- the closed loop ----------------------------------------------------------------------------

def simulate(bench: Bench, x_cmd, hidden: Hidden | None = None, torque: str = "actual", x0: float | None = None):
    """The closed loop on the command ``x_cmd`` (one sample per tick plus the one after the last
    tick). Returns the channels at the ticks (SI): t, x_cmd, x_motor, x_table, x_tip, torque
    (``torque``: "command" or "actual", see the module docstring) and both torques as
    torque_command / torque_actual."""
    if torque not in ("command", "actual"):
        raise ValueError(f"torque: 'command' or 'actual', got {torque!r}")
    hid = hidden or Hidden()
    pl = _Plant(bench, hid)
    x_cmd = np.asarray(x_cmd, float)
    K = x_cmd.size - 1
    n_sub = int(round(bench.tp / bench.tv))
    n = pl.n
    y = np.zeros(2 * n + (1 if pl.tc > 0.0 else 0))
    y[:n] = x_cmd[0] if x0 is None else x0
    mode = (0 if pl.dry else None)
    fb = 0 if bench.feedback == "motor" else pl.table
    integral, limited = 0.0, False
    queue = [(-math.inf, 0.0)]          # (time the command takes effect, command), oldest first
    out = {c: np.zeros(K) for c in ("t", "x_cmd", "x_motor", "x_table", "x_tip", "torque_command", "torque_actual")}
    for kk in range(K):
        tk = kk * bench.tp
        w_ref = (bench.kv * (x_cmd[kk] - y[fb]) + bench.ffv * (x_cmd[kk + 1] - x_cmd[kk]) / bench.tp) * pl.r
        for j in range(n_sub):
            t0 = tk + j * bench.tv
            e = w_ref - y[n] * pl.r
            if not limited:
                integral += e * bench.tv
            u = bench.kp * (e + integral / bench.ti)
            limited = abs(u) > bench.u_max
            u = max(-bench.u_max, min(bench.u_max, u))
            queue.append((t0 + hid.delay, u))
            if j == 0:
                applied = _applied(queue, t0)
                out["t"][kk], out["x_cmd"][kk] = tk, x_cmd[kk]
                out["x_motor"][kk], out["x_table"][kk], out["x_tip"][kk] = y[0], y[pl.table], y[pl.tip]
                out["torque_command"][kk] = u
                out["torque_actual"][kk] = y[2 * n] if pl.tc > 0.0 else applied
            # the plant over the period, split where a delayed command takes effect
            t1 = t0 + bench.tv
            cuts = [tq for tq, _ in queue if t0 < tq < t1 - 1e-12]
            a = t0
            for b in cuts + [t1]:
                y, mode = _advance(pl, y, mode, a, b, _applied(queue, a))
                a = b
            while len(queue) > 1 and queue[1][0] <= t1:
                queue.pop(0)
    out["torque"] = out["torque_" + torque].copy()
    return out


def _applied(queue, t):
    """The command in effect at time t: the newest whose time has come."""
    u = queue[0][1]
    for tq, uq in queue:
        if tq <= t + 1e-12:
            u = uq
        else:
            break
    return u


def measure(ch: dict, seed: int, resolution: float = 0.5e-6, position_noise: float = 0.1e-6,
            force_noise: float | None = None) -> dict:
    """The channels as a record holds them: encoder noise and quantization on the positions, a
    noise of 1 % of the torque's RMS on the torque (or ``force_noise`` N m)."""
    rng = np.random.default_rng(seed + 7919)
    out = {"t": ch["t"].copy(), "x_cmd": ch["x_cmd"].copy()}
    for c in ("x_motor", "x_table", "x_tip"):
        y = ch[c] + rng.normal(0.0, position_noise, ch[c].size)
        out[c] = resolution * np.floor(y / resolution + 0.5) if resolution > 0 else y
    y = ch["torque"]
    sd = 0.01 * float(np.sqrt(np.mean(y * y))) + 1e-9 if force_noise is None else force_noise
    out["torque"] = y + rng.normal(0.0, sd, y.size)
    return out


def two_mass_frequency(m1: float, m2: float, k: float) -> float:
    """Natural frequency (Hz) of two free masses on a spring: sqrt(k (m1 + m2) / (m1 m2)) / 2 pi."""
    return math.sqrt(k * (m1 + m2) / (m1 * m2)) / (2.0 * math.pi)
