"""Compiled pieces of the plant used inside the simulation loops: the plant step (exact
zero-order hold over one velocity period), dry friction on the motor (time-stepping, with
stiction), the force terms of plant effects and the encoders' readings.

The effects' forces are held over the step from their values at its start, except a backlash's:
it switches within a step where the link enters or leaves its gap, and held it lags the contact
(on the nominal move with a 20 um gap the table was 0.7 um and the tip 1.6 um off an independent
integration, tests/independent/test_plant_ivp.py). The step takes the mean of its values at the
step's start and at the end of the step predicted with the start's (a trapezoid, one prediction):
13 nm and 28 nm.

Most terms are forces on the masses. One adds to the dry friction's level instead
(``LOAD_FRICTION``: a ball screw's friction growing with the axial force the nut carries,
mu |F_link|, F_link = k (x_i - x_i+1) + c (v_i - v_i+1) the link's spring and damper force), so
that it sticks and slides with the motor's Coulomb friction (:func:`friction_force`): the effect
forces return that extra level, 0 without such a term (then the friction is the plant's alone).

Effects reach the compiled loop as rows of a small table: a code and up to ``N_EFFECT_PARAMS``
numbers. The Python side of each effect (sim_plant.effects) writes its rows into
``Plant.effects``; :func:`effect_table` turns them into the arrays the loops take. The codes and
the layout of their rows are :mod:`sim_plant.terms` (plain numbers, re-exported here: an effect
writes its rows without importing numba); this module is the only place that acts on them.

A term may act on a reading instead of a force: ``ENCODER_ERROR`` (an encoder's interpolation
error, sim_plant.effects.encoder) changes what an encoder reads, :func:`reading` (and the
motor's speed derived from it, :func:`reading_speed`), which drivers.control's feedback stages call
with the table's encoder rows alone (:func:`encoder_rows`); a plant without them passes None,
which the compiled loops leave out: it reads the true positions, bit for bit and at no cost.

The stages here are inlined into the loops that call them (numba's ``inline="always"``), and those
loops are compiled with :func:`njit_cycle`: a cycle allocates nothing, so it needs no reference
counting, and with it each inlined stage took a reference to every array it was given and gave it
back, each velocity step (atomic operations that numba could not pair across the loop over the
effect table: some 14 arrays, taken and given back, in 60 % of the time of a torque ripple's run
under perf).

numba keys a cached compiled function by the stamp of its own source file alone (numba issue 1833):
the loops of drivers.control, hil.simulate and drivers.sim inline the stages of this module and
of drivers.control, so a checkout where those changed and the callers did not (a branch switched, a
stage edited) would load the loops compiled with the old stages, and give other numbers, silently.
The same holds for this module's own functions and the codes of sim_plant.terms, which they take
as constants when compiled.
:func:`drop_stale_compiled_loops` keeps a hash of the inlined sources beside the package's cache
and, where it differs, removes the callers' cached loops before numba looks (they compile anew).
"""
from __future__ import annotations

import glob
import hashlib
import math
import os
from pathlib import Path

import numpy as np
from numba import njit

from sim_plant.plant import Plant
from sim_plant.terms import (
    BACKLASH,
    CONSTANT_FORCE,
    ENCODER_ERROR,
    FEEDBACK_DELAY,
    FORCE_ALONG_TRAVEL,
    LEAD_ERROR_LINEAR,
    LOAD_FRICTION,
    MOTOR_ENCODER,
    N_EFFECT_PARAMS,
    PITCH_ERROR,
    STIFFNESS_ALONG_TRAVEL,
    TABLE_ENCODER,
    TIME_DELAY,
    TORQUE_RIPPLE,
    VISCOUS_ASYMMETRIC,
)

__all__ = ["N_EFFECT_PARAMS", "CONSTANT_FORCE", "BACKLASH", "PITCH_ERROR", "TORQUE_RIPPLE", "VISCOUS_ASYMMETRIC",
           "TIME_DELAY", "FEEDBACK_DELAY", "STIFFNESS_ALONG_TRAVEL", "LEAD_ERROR_LINEAR", "FORCE_ALONG_TRAVEL",
           "ENCODER_ERROR", "MOTOR_ENCODER", "TABLE_ENCODER", "encoder_error", "encoder_rows", "reading",
           "reading_speed", "LOAD_FRICTION", "dry_friction",
           "empty_effects", "effect_table", "time_delay", "feedback_delay", "link_compliance", "effect_forces",
           "effect_forces_at", "friction_force", "plant_step", "state_size", "mass_token", "njit_cycle",
           "drop_stale_compiled_loops"]

# the sources whose stages other files' compiled loops inline, and those loops' cache files (numba's
# in-tree cache: <folder>/__pycache__/<module>.<function>-<line>.py<ver>.nbi / .nbc), from the folder
# that holds the three packages (the clone's root, or site-packages)
# (the kernel's own loops among them: they take the codes of sim_plant/terms.py as constants)
INLINED_SOURCES = ("sim_plant/kernel.py", "sim_plant/terms.py", "drivers/control.py")
INLINING_CACHES = ("drivers/__pycache__/control.", "hil/__pycache__/simulate.", "drivers/__pycache__/sim.",
                   "sim_plant/__pycache__/kernel.")
SOURCES_STAMP = "sim_plant/__pycache__/numba-inlined-sources.sha256"


def drop_stale_compiled_loops(root: Path | None = None) -> list[str]:
    """Remove the cached compiled loops of :data:`INLINING_CACHES` where the sources they inline
    (:data:`INLINED_SOURCES`) are not those they were compiled from (the module's definitions): a
    hash of the sources is kept in ``SOURCES_STAMP``. Returns
    the files removed. Nothing where the package's folder cannot be written: numba then caches in
    the user's cache folder (or ``NUMBA_CACHE_DIR``, always, where it is set), which this does not
    look into. Nor does it stop a process started before the edit from saving loops compiled with
    the old stages after this has run (numba's index of the caller's unchanged file accepts them).
    ``root``: the folder that holds sim_plant/, drivers/ and hil/."""
    root = Path(__file__).resolve().parents[1] if root is None else Path(root)
    try:
        digest = hashlib.sha256(b"".join(f.encode() + b"\0" + (root / f).read_bytes() + b"\0"
                                         for f in INLINED_SOURCES)).hexdigest()
        stamp = root / SOURCES_STAMP
        if stamp.is_file() and stamp.read_text().strip() == digest:
            return []
        gone = []
        for prefix in INLINING_CACHES:
            for f in sorted(glob.glob(glob.escape(str(root / prefix)) + "*.nb[ic]")):
                os.remove(f)
                gone.append(f)
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(digest + "\n")
        return gone
    except OSError:
        return []


drop_stale_compiled_loops()


def _without_refcount() -> dict:
    """numba's option that compiles a function without its reference counting (NRT), where this
    numba has it (``_nrt``, numba.core.cpu.CPUTargetOptions); none otherwise: the same numbers, slower."""
    try:
        from numba.core.cpu import CPUTargetOptions
    except ImportError:         # pragma: no cover - a numba that moved its options
        return {}
    return {"_nrt": False} if hasattr(CPUTargetOptions, "_nrt") else {}


_CYCLE_OPTIONS = _without_refcount()


def njit_cycle(fn):
    """Compile ``fn``, a loop of cycles that allocates nothing (its state and work arrays passed in),
    without reference counting (the module's note): ``njit(cache=True)`` where numba has no such
    option. Where it has, an allocation in ``fn`` fails to compile."""
    return njit(cache=True, **_CYCLE_OPTIONS)(fn)



def empty_effects():
    return np.zeros(0, np.int64), np.zeros((0, N_EFFECT_PARAMS))


def effect_table(plant: Plant):
    """The effects' kernel terms as arrays: (codes, params), or (None, params) when there are
    none, so that the compiled loop is specialised without the effect branch (it is the
    simulator's hot path)."""
    if not plant.effects:
        return None, empty_effects()[1]
    codes = np.array([c for c, _ in plant.effects], np.int64)
    params = np.zeros((len(plant.effects), N_EFFECT_PARAMS))
    for i, (_, q) in enumerate(plant.effects):
        params[i, :len(q)] = q
    return codes, params


def encoder_rows(codes, params):
    """The ``ENCODER_ERROR`` rows of an effect table (:func:`effect_table`), or None where it has
    none (the compiled readings then leave the encoders' errors out)."""
    if codes is None or not np.any(codes == ENCODER_ERROR):
        return None
    return np.ascontiguousarray(params[codes == ENCODER_ERROR])


def time_delay(plant: Plant) -> float:
    """The plant's transport delay (s): the sum of its ``TIME_DELAY`` rows."""
    return float(sum(q[0] for c, q in plant.effects if c == TIME_DELAY))


def feedback_delay(plant: Plant) -> float:
    """The delay of the position loop's feedback (s): the sum of the plant's ``FEEDBACK_DELAY`` rows."""
    return float(sum(q[0] for c, q in plant.effects if c == FEEDBACK_DELAY))


def dry_friction(plant: Plant) -> bool:
    """Whether the plant step decides dry friction on the motor: the plant's own levels, or a
    ``LOAD_FRICTION`` row (a level that only the link's force gives)."""
    return plant.friction.active or any(c == LOAD_FRICTION for c, _ in plant.effects)


@njit(cache=True, inline="always")
def link_compliance(q, x_nut):
    """Compliance (m/N) of a ``STIFFNESS_ALONG_TRAVEL`` row with the nut at ``x_nut``: the quadratic
    through the compliances at x_start, midway and x_end (linear when the midway value is their mean:
    a screw held at one end, Eq. 20 EA/L in series with fixed compliances). Outside that stretch it
    is extrapolated, never below a tenth of the smaller end value."""
    s = (x_nut - q[2]) / (q[3] - q[2])
    comp = q[4] * (2.0 * s - 1.0) * (s - 1.0) + q[5] * 4.0 * s * (1.0 - s) + q[6] * s * (2.0 * s - 1.0)
    floor = 0.1 * min(q[4], q[6])
    return comp if comp > floor else floor


@njit(cache=True, inline="always")
def backlash_correction(q, x, xo, v, vo):
    """A :data:`BACKLASH` row's force on link i's far mass (the near one takes its opposite): the
    linear chain already applies k (x_i - x_i+1); a dead zone of +-gap removes that force inside
    the gap and shifts it outside, correction = k (dz(d) - d), and inside the gap the link's damper
    carries no force either."""
    i = int(q[0])
    gap, k = q[1], q[2]
    d = x[xo + i] - x[xo + i + 1]
    if d > gap:
        dz = d - gap
    elif d < -gap:
        dz = d + gap
    else:
        dz = 0.0
    corr = k * (dz - d)
    if dz == 0.0:
        corr -= q[3] * (v[vo + i] - v[vo + i + 1])
    return corr


# inlined into the plant step: the call with its array arguments cost about as much per step as the forces
# (issue 26: a backlash run 97 -> 70 ns per velocity step; the rest was reference counting, njit_cycle:
# 194 -> 32 ns); a plant without effects compiles it away
@njit(cache=True, inline="always")
def effect_forces_at(codes, params, x, xo, v, vo, f):
    """Add the forces of the effect terms at state (x, v) to ``f`` (one entry per mass), the
    positions read from ``x`` at offset ``xo``, the velocities from ``v`` at ``vo``: the plant step
    passes its state vector twice, unsliced (real-time: no array views per step). Returns what the
    terms add to the level of the dry friction on the motor (N; 0.0 without ``LOAD_FRICTION``)."""
    extra_level = 0.0
    for r in range(codes.shape[0]):
        c = codes[r]
        q = params[r]
        if c == CONSTANT_FORCE:
            f[int(q[0])] += q[1]
        elif c == BACKLASH:
            i = int(q[0])
            corr = backlash_correction(q, x, xo, v, vo)
            f[i] -= corr
            f[i + 1] += corr
        elif c == PITCH_ERROR:
            # the nut sits at x1 + e(x1): the link sees k (x1 + e - x2)
            i = int(q[0])
            e = q[1] * math.sin(2.0 * math.pi * x[xo + i] / q[2] + q[3])
            f[i] -= q[4] * e
            f[i + 1] += q[4] * e
        elif c == TORQUE_RIPPLE:
            f[0] += q[0] * math.sin(2.0 * math.pi * x[xo] / q[1] + q[2])
        elif c == STIFFNESS_ALONG_TRAVEL:
            # the chain applies k (x_i - x_i+1) with its constant k; the link's k(x_nut) adds the difference
            i = int(q[0])
            corr = (1.0 / link_compliance(q, x[xo + i + 1]) - q[1]) * (x[xo + i] - x[xo + i + 1])
            f[i] -= corr
            f[i + 1] += corr
        elif c == LEAD_ERROR_LINEAR:
            # the nut sits at x1 + eps (x1 - x_ref) (a screw grown by its strain): the link sees k (x1 + e - x2)
            i = int(q[0])
            e = q[1] * (x[xo + i] - q[2])
            f[i] -= q[3] * e
            f[i + 1] += q[3] * e
        elif c == FORCE_ALONG_TRAVEL:
            i = int(q[0])
            f[i] += q[1] + q[2] * x[xo + i]
        elif c == VISCOUS_ASYMMETRIC:
            i = int(q[0])
            if v[vo + i] > 0.0:
                f[i] -= q[1] * v[vo + i]
            else:
                f[i] -= q[2] * v[vo + i]
        elif c == LOAD_FRICTION:
            # no force here: the level joins the motor's dry friction, which decides sticking (friction_force)
            i = int(q[0])
            extra_level += q[1] * abs(q[2] * (x[xo + i] - x[xo + i + 1]) + q[3] * (v[vo + i] - v[vo + i + 1]))
    return extra_level


@njit(cache=True)
def effect_forces(codes, params, x, v, f):
    """Add the forces of the effect terms at state (x, v) to ``f`` (one entry per mass)."""
    effect_forces_at(codes, params, x, 0, v, 0, f)


@njit(cache=True, inline="always")
def encoder_error(q, x):
    """The interpolation error (m) of one ``ENCODER_ERROR`` row ``q`` at the true position ``x``:
    a1 sin(2 pi x / P + phi1) + a2 sin(4 pi x / P + phi2)."""
    th = 2.0 * math.pi * x / q[1]
    return q[2] * math.sin(th + q[3]) + q[4] * math.sin(2.0 * th + q[5])


@njit(cache=True, inline="always")
def reading(enc, encoder, x):
    """What ``encoder`` (:data:`MOTOR_ENCODER`, :data:`TABLE_ENCODER`) reads at the true position
    ``x``, before its quantization: x plus the error of each of its rows among the ``ENCODER_ERROR``
    rows ``enc`` (:func:`encoder_rows`). ``x`` itself, unchanged, where it has none (``enc`` None:
    compiled away)."""
    r = x
    if enc is not None:
        for i in range(enc.shape[0]):
            if int(enc[i, 0]) == encoder:
                r += encoder_error(enc[i], x)
    return r


@njit(cache=True, inline="always")
def reading_speed(enc, x, v, tv):
    """The motor's speed (m/s) as the drive derives it from the motor encoder, at the true position
    ``x`` and speed ``v``: v plus the change of the encoder's error over one velocity period ``tv``
    at that speed, (e(x) - e(x - v tv)) / tv (v e'(x) where a period of the error takes many
    velocity periods; the backward difference of the readings at constant speed, exactly). ``v``
    itself, unchanged, without a motor-encoder row among ``enc`` (None: compiled away)."""
    r = v
    if enc is not None:
        for i in range(enc.shape[0]):
            if int(enc[i, 0]) == MOTOR_ENCODER:
                r += (encoder_error(enc[i], x) - encoder_error(enc[i], x - v * tv)) / tv
    return r


@njit(cache=True, inline="always")
def friction_force(fric, v_start, v_free, b, extra_level=0.0):
    """Dry friction force on mass 1 over one step, and whether the motor sticks (time-stepping treatment of Coulomb friction).

    ``v_free``: mass 1's velocity at the end of the step without dry friction; ``b``: the
    velocity change per newton over the step. If the force that brings the motor to rest within
    the step lies inside the friction level, that force is applied (the motor sticks, exactly);
    otherwise the full level acts against the motion. This keeps a stuck axis stuck while the
    torque stays below the level, instead of creeping as a smoothed sign() would.

    fric = [sliding +, sliding -, break-away +, break-away -, Stribeck velocity]; ``extra_level``
    (N, >= 0): added to the level in both directions, at rest and sliding (a load-dependent
    friction, :data:`LOAD_FRICTION`; a literal 0.0 where the plant has no effects compiles away)."""
    f_stop = -v_free / b
    # level in the direction the motor would move
    if f_stop > 0.0:          # it would move in -x
        slide, stat = fric[1], fric[3]
    else:
        slide, stat = fric[0], fric[2]
    vs = fric[4]
    if v_start == 0.0:
        level = stat          # at rest: break-away level
    elif vs > 0.0:
        level = slide + (stat - slide) * math.exp(-(v_start / vs) ** 2)
    else:
        level = slide
    if extra_level > 0.0:
        level += extra_level
    if abs(f_stop) <= level:
        return f_stop, True
    return (level if f_stop > 0.0 else -level), False


@njit(cache=True, inline="always")
def state_size(Ad, masses):
    """The plant state's length 2 n: ``Ad``'s, or twice the length of the tuple ``masses`` (one
    entry per mass, :func:`mass_token`), which numba knows when it compiles (None: ``Ad``'s)."""
    if masses is None:
        return Ad.shape[0]
    return 2 * len(masses)


def mass_token(n: int) -> tuple:
    """A tuple of ``n`` zeros: passed as ``masses`` to the compiled loops, its length (a constant
    of its numba type) specialises them on the chain's size, so that the loops over the state
    unroll. The arithmetic and its order are the same as with the size read from the matrix (the
    same bits); only the loop's bookkeeping goes (issue 26)."""
    return (0,) * int(n)


@njit(cache=True, inline="always")
def plant_step(Ad, Bd, x, f_drive, fric, dry, codes, eparams, f, x_new, fext=None, masses=None):
    """Advance the plant state ``x`` in place over one step: x+ = Ad x + Bd f, where f holds the
    drive force on mass 1, the effects' forces, external forces ``fext`` (one per mass, N, held
    over the step: a measured cutting force; None: compiled away; they need ``codes``, an empty
    table when there are no effects) and the dry friction on the motor (which needs the free
    motion of the step to decide between sticking and sliding; its level the plant's ``fric``
    plus what the effects add, :data:`LOAD_FRICTION`; ``dry``: :func:`dry_friction`). ``masses``:
    None, or :func:`mass_token` of the chain's size, which the loop is then compiled for.

    Written for speed (this is the simulator's inner loop): one pass over Ad, the friction decided
    from mass 1's free velocity alone, the other force columns only when effects exist."""
    nn = state_size(Ad, masses)
    n = nn // 2
    f0 = f_drive
    extra_level = 0.0                  # the effects' addition to the dry friction's level
    effects = codes is not None        # None (no effects): numba compiles the branch away
    if effects:
        for i in range(n):
            f[i] = 0.0
        extra_level = effect_forces_at(codes, eparams, x, 0, x, n, f)
        if fext is not None:
            for i in range(n):
                f[i] += fext[i]
        f[0] += f_drive
        f0 = f[0]
    stuck = False
    if dry:
        v_free = Bd[n, 0] * f0
        for c in range(nn):
            v_free += Ad[n, c] * x[c]
        if effects:
            for c in range(1, n):
                v_free += Bd[n, c] * f[c]
        ff, stuck = friction_force(fric, x[n], v_free, Bd[n, 0], extra_level)
        f0 += ff
    for r in range(nn):
        acc = Bd[r, 0] * f0
        for c in range(nn):
            acc += Ad[r, c] * x[c]
        x_new[r] = acc
    if effects:
        for r in range(nn):
            for c in range(1, n):
                x_new[r] += Bd[r, c] * f[c]
        # a backlash's force switches within a step where the link enters or leaves its gap; held
        # over the step from its start it lags the contact by up to a step (0.7 um on the table
        # against an independent integration): the mean of its values at the step's two ends
        # (trapezoid, from the step predicted with the start's) follows the contact
        for row in range(codes.shape[0]):
            if codes[row] == BACKLASH:
                q = eparams[row]
                i = int(q[0])
                half = 0.5 * (backlash_correction(q, x_new, 0, x_new, n) - backlash_correction(q, x, 0, x, n))
                if half != 0.0:
                    for r in range(nn):
                        x_new[r] += Bd[r, i + 1] * half - Bd[r, i] * half
    for r in range(nn):
        x[r] = x_new[r]
    if stuck:
        x[n] = 0.0       # exactly at rest, not a round-off away from it
