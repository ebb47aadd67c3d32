"""The one cycle (drivers.control's stages, issue 28): its records named by fields, the host's cycle
without allocation in steady state, the runtime on the backend contract alone."""
from __future__ import annotations

import gc
import tracemalloc

import numpy as np
import pytest

from drivers.base import Backend
from drivers.control import (
    LOOP_STATE,
    LOOP_TERMS,
    S,
    T,
    Terms,
    controller_from_config,
    delay_ring,
    loop_terms,
    terms_of,
)
from drivers.sim import SimulatedPlant
from hil.io.recorder import Recorder
from hil.loop import ControlLoop, RealTimeClock
from hil.plant_config import plant_from_config
from hil.profiles import MoveSpec, Trajectory
from hil.runtime import record_channels, run_trajectory
from hil.supervisor import Supervisor


def test_the_records_are_named_from_one_list():
    """Every field of the state and terms lists has its own slot, in the list's order, and SIZE
    covers them (the speed filter's history P.MAX_TAPS slots, each filter path's states two per
    section)."""
    sizes = {"hist": 8, "tq_z": 8, "sp_z": 8}
    assert [S[f.upper()] for f in LOOP_STATE] == list(np.cumsum([0] + [sizes.get(f, 1) for f in LOOP_STATE]))[:-1]
    assert [T[f.upper()] for f in LOOP_TERMS] == list(range(len(LOOP_TERMS)))
    assert S.SIZE == S.SP_Z + 8 and T.SIZE == len(LOOP_TERMS)


def test_loop_terms_array_holds_the_plant_and_controller_numbers(bench):
    cfg = bench.with_values({"effects.time_delay.delay": "0.15 ms", "effects.feedback_delay.delay": "1.3 ms",
                             "control.position_feedback": "motor"})
    sim = SimulatedPlant(cfg, plant_from_config(cfg))
    ctrl, pl = sim.ctrl, sim.plant
    t = loop_terms(pl, ctrl).array
    tv = ctrl.velocity_period
    assert t[T.SUBSTEPS] == round(ctrl.position_period / tv) and t[T.FORCE_GAIN] == pl.force_gain
    # 0.15 ms over a 62.5 us period: 2 whole periods and 0.4 of one
    assert t[T.DELAYED] == 1.0 and t[T.DELAY_INT] == 2 and t[T.DELAY_FRAC] == pytest.approx(0.15e-3 / tv - 2)
    assert t[T.FEEDBACK_LATE] == 1.0 and t[T.FEEDBACK_INT] == int(1.3e-3 // tv)
    assert t[T.FEEDBACK_MOTOR] == 1.0 and t[T.FEEDBACK_MASS] == 0 and t[T.FEEDBACK_RES] == pl.motor_resolution
    assert t[T.TABLE] == pl.table and t[T.TIP] == pl.tip


def test_the_terms_record_reads_the_array_by_name(bench):
    """The compiled stages' record of the loop terms holds every field of the array, by its name."""
    a = loop_terms(SimulatedPlant(bench, plant_from_config(bench)).plant, SimulatedPlant(bench, plant_from_config(bench)).ctrl).array + np.arange(T.SIZE) * 1e-3
    rec = terms_of(a)
    assert rec == Terms(*a) and rec._fields == LOOP_TERMS


@pytest.mark.parametrize("d", [0, 1, 3])
def test_delay_ring_is_a_whole_period_delay(d):
    """The host's output delay: the output d cycles old, zero before the first d (as a shift)."""
    u = np.random.default_rng(1).standard_normal(40)
    ring = np.zeros(d + 1)
    out = np.array([delay_ring(ring, v) for v in u])
    assert np.array_equal(out, np.concatenate([np.zeros(d), u[:u.size - d]]))


def test_the_clock_keeps_a_bounded_lateness_buffer():
    """A real-time clock's lateness goes into a preallocated buffer of the run's size; past it, the
    count and the maximum go on (no list grows)."""
    clock = RealTimeClock(20e-6, spin=0.0)
    clock.start(10)
    for _ in range(25):
        clock.wait()
    assert clock.lateness.size == 10 and clock.stats()["cycles"] == 25
    assert clock.stats()["lateness_max_us"] >= clock.lateness.max() * 1e6


class _Probe(RealTimeClock):
    """A real-time clock (its own bookkeeping as on hardware) that reads the traced memory at two
    cycles of the run. A full collection first: it empties the interpreter's free lists (of
    tuples, floats), which tracemalloc counts as allocated while they fill."""

    def __init__(self, period, at):
        super().__init__(period, spin=0.0)
        self.at = at
        self.cycles = 0
        self.memory = [0, 0]

    def wait(self):
        late = super().wait()
        self.cycles += 1
        if self.cycles in self.at:
            gc.collect()
            self.memory[self.at.index(self.cycles)] = tracemalloc.get_traced_memory()[0]
        return late


@pytest.mark.parametrize("closes, at", [("none", (4000, 5000)), ("velocity", (1000, 2000))])
def test_the_python_cycle_does_not_grow(bench, tmp_path, closes, at):
    """1 000 cycles of the host's loop in steady state (after the supervisor's bounded history has
    filled) on the simulated backend, with the recorder, the supervisor and the real-time clock's
    bookkeeping: the traced memory does not grow (a list per cycle would add ~30 kB)."""
    sim = SimulatedPlant(bench, plant_from_config(bench), closes=closes)
    sim.home_at(0.0)
    sim.enable()
    ctrl = controller_from_config(bench, sim.plant)
    ticks = at[1] // (ctrl.substeps if closes == "none" else 1) + 20
    traj = Trajectory()
    traj.move(MoveSpec(0.002, 0.02, a_max=1.0))
    _, x_cmd = traj.sample(ctrl.position_period, ticks * ctrl.position_period)
    x_cmd = x_cmd[:ticks]
    clock = _Probe(2e-6, at)
    sup = Supervisor(bench, real_time=False)
    # the recorder's drain thread left out (drain_every=None): its text of a batch of rows, held while
    # it writes, would be counted as the cycle's; the cycle itself only stores into the buffer
    with Recorder(tmp_path / "run.csv", record_channels(True), {}, status_every=None, drain_every=None) as rec:
        loop = ControlLoop(sim, ctrl, clock=clock, recorder=rec, supervisor=sup)
        tracemalloc.start()
        try:
            result = loop.run(x_cmd)
        finally:
            tracemalloc.stop()
    assert result.status == "complete", result.reason
    assert all(clock.memory)
    assert clock.memory[1] - clock.memory[0] < 1024, clock.memory


class _PeakProbe(RealTimeClock):
    """A real-time clock that reads, at the end of every cycle, the peak of the memory traced during
    it (tracemalloc's peak, reset at the start of each cycle): every allocation of the cycle counts,
    also one freed before the cycle ends. ``peaks`` is allocated once, so that the probe's own
    bookkeeping is the same every cycle (a tuple of two numbers: :meth:`own`)."""

    def __init__(self, period, first, n):
        super().__init__(period, spin=0.0)
        self.first, self.cycles = first, 0
        self.peaks = np.full(n, -1.0)
        self._base = 0

    def wait(self):
        late = super().wait()
        i = self.cycles - self.first
        if 0 <= i < self.peaks.size:
            self.peaks[i] = tracemalloc.get_traced_memory()[1] - self._base
        self.cycles += 1
        tracemalloc.reset_peak()
        self._base = tracemalloc.get_traced_memory()[0]
        return late

    def own(self, n: int = 2000) -> float:
        """The probe's own peak: cycles of nothing but its bookkeeping (the largest of ``n``)."""
        probe = _PeakProbe(self.period, 100, n)
        tracemalloc.start()
        try:
            for _ in range(n + 100):
                probe.wait()
        finally:
            tracemalloc.stop()
        return float(probe.peaks.max())


# a Python integer beyond the cached small ones (a tick counter): what a cycle may make, and nothing else
ONE_NUMBER = 32


@pytest.mark.parametrize("closes", ["none", "velocity"])
def test_the_host_cycle_builds_nothing(bench, tmp_path, closes):
    """Every allocation of the host's cycle, not only what stays (issue 48): 1 000 cycles in steady
    state on the simulated backend, with the recorder, the supervisor and the clock. Each cycle's
    peak of traced memory exceeds the probe's own by at most a Python integer; at most one cycle in
    the thousand by more (an interpreter's own block, a deque's). Before, every cycle built a
    Feedback (208 bytes) and read the command as numpy scalars."""
    sim = SimulatedPlant(bench, plant_from_config(bench), closes=closes)
    sim.home_at(0.0)
    sim.enable()
    ctrl = controller_from_config(bench, sim.plant)
    per_tick = ctrl.substeps if closes == "none" else 1
    first, n = 1000, 1000
    ticks = (first + n) // per_tick + 20
    traj = Trajectory()
    traj.move(MoveSpec(0.002, 0.02, a_max=1.0))
    _, x_cmd = traj.sample(ctrl.position_period, ticks * ctrl.position_period)
    clock = _PeakProbe(2e-6, first, n)
    own = clock.own()
    sup = Supervisor(bench, real_time=False)
    with Recorder(tmp_path / "run.csv", record_channels(True), {}, status_every=None, drain_every=None) as rec:
        loop = ControlLoop(sim, ctrl, clock=clock, recorder=rec, supervisor=sup)
        tracemalloc.start()
        try:
            result = loop.run(x_cmd[:ticks])
        finally:
            tracemalloc.stop()
    assert result.status == "complete", result.reason
    extra = clock.peaks - own
    assert clock.peaks.min() >= 0 and np.count_nonzero(extra > ONE_NUMBER) <= 1, \
        (own, sorted(set(extra[extra > ONE_NUMBER].tolist())))


class _Wrapped(Backend):
    """A backend that is not drivers.sim.SimulatedPlant but offers the same dry run through the
    contract; ``cycles``: how often the host exchanged with it."""
    name = "wrapped"
    closes = "none"
    simulated = True

    def __init__(self, cfg):
        self.sim = SimulatedPlant(cfg, plant_from_config(cfg))
        self.cycle_time = self.sim.cycle_time
        self.cycles = 0

    def open(self):
        pass

    def start_at(self, position):
        self.sim.start_at(position)

    def dry_run_model(self):
        return self.sim.dry_run_model()

    def enable(self):
        self.sim.enable()

    def read_feedback(self):
        self.cycles += 1
        return self.sim.read_feedback()

    def write_setpoint(self, sp):
        self.sim.write_setpoint(sp)

    def sync(self):
        self.sim.sync()

    def disable(self):
        self.sim.disable()

    def close(self):
        pass


def test_the_runtime_takes_the_dry_run_from_the_contract(bench):
    """The runtime asks the backend (dry_run_model, start_at), not its class: a backend wrapping the
    embedded plant gets the same compiled dry run, bit for bit, and no cycle is exchanged."""
    traj = Trajectory()
    traj.move(MoveSpec(0.005, 0.05, a_max=2.0))
    wrapped = _Wrapped(bench)
    rec = run_trajectory(bench, traj, backend=wrapped, settle=0.05)
    ref = run_trajectory(bench, traj, backend=SimulatedPlant(bench, plant_from_config(bench)), settle=0.05)
    assert wrapped.cycles == 0 and rec.status == ref.status == "complete"
    for name, values in ref.channels.items():
        assert np.array_equal(rec.channels[name], values), name
