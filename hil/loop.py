"""The fixed-rate loop: one cycle per backend exchange, on a real-time or a simulated clock.

Each cycle (:meth:`ControlLoop._tick`): read the feedback, run the loops the backend does not
close (drivers.control's stages: profile and position law, velocity law, output delay), record (every
position tick), let the supervisor check, write the setpoint, end the cycle (``backend.sync()``),
wait for the next deadline. In steady state the cycle allocates nothing that stays: its state,
setpoint, output delay and the clock's lateness are preallocated.

* :class:`RealTimeClock`: absolute deadlines t0 + k T (no drift). The wait gives the interpreter
  lock away: the backend's ``receive_until`` (where it has one: the loop's own thread takes the
  answer from the bus in a blocking receive with a timeout) or a sleep, with the thread's timer
  slack at 1 ns (Linux: the default 50 us would add itself to every wake-up), until ``spin``
  before the deadline (5 % of the period, at most 200 us), then spins; it records every cycle's lateness and counts overruns
  (a cycle that starts a whole period late).
* :class:`LoopCpu`: the loop's thread pinned to one CPU while a run lasts (``runtime.loop_cpu``),
  as a drive engineer places it on a real-time PC; the scope's server goes on the other CPUs.
* :class:`SimulatedClock`: no waiting; time is the cycle count times the period.

The loop's hooks: a ``recorder`` (one row per position tick), a ``scope`` (a
:class:`hil.scope.ring.ScopeRing`: the same row, written in place into a preallocated ring the live
scope's server reads without a lock; trips and the run's end as its events), a ``supervisor`` (checked every
position tick) and an :class:`Injection` (an excitation added in every cycle to the torque or to
the speed reference, and one row per cycle of what the loop did with it: hil.frf measures
frequency responses through it).

Real-time: the methods marked "(real-time)" run inside the cycle, between reading the feedback
and ending the cycle; they, and the hooks they call, must be short and must not block.

How a run ends follows the fault rule of :mod:`drivers.base`: a ``Feedback.fault`` trips the
supervisor (at a position tick through its check, between ticks here), a trip commands the
configured controlled stop in the same cycle and ends the run ``tripped``; a
:class:`~hil.errors.BackendFault` raised in the cycle ends it ``fault`` (latched in the supervisor
like a trip), Ctrl-C ``aborted``, each after the same controlled stop, which never raises (what
fails is logged: the link may be gone). The result carries the kind of stop
(:class:`hil.errors.StopKind`, decided where the stop is: the supervisor's rule, the backend's
fault), and so the command's exit code (STOP_EXIT_CODES).
"""
from __future__ import annotations

import gc
import logging
import math
import os
import threading
import time
import warnings
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from drivers.base import Backend, BackendFault, Feedback, Setpoint, fault_kind
from drivers.control import (
    injected_velocity_cycle,
    measured_speed,
    new_velocity_state,
    position_law,
    position_tick,
    velocity_cycle,
    velocity_law,
)
from drivers.rt import CpuLatencyRequest, fine_timer_slack
from hil.errors import ConfigError, RunStatus, StopKind
from hil.scope.ring import ScopeRing

__all__ = ["RealTimeClock", "SimulatedClock", "ControlLoop", "LoopResult", "TickResult", "Injection",
           "CYCLE_CHANNELS", "LoopCpu", "check_loop_cpu", "cpu_list"]


class TickResult(IntEnum):
    """What a position tick of the cycle returns (as Ruckig's ``Result``: the real-time path
    compares no strings and raises nothing of its own): ``OK``, the run goes on; ``TRIPPED``, a
    supervisor rule or a fault the backend reported stopped it (the controlled stop commanded,
    the reason in ``ControlLoop.trip_reason``, its kind in ``ControlLoop.trip_kind``)."""
    OK = 0
    TRIPPED = 1

# wake-ups whose lateness a real-time clock keeps by default (2 min at 1 kHz; a run asks for its own count)
LATENESS_SAMPLES = 1 << 17

# what an Injection records every cycle, one column each
CYCLE_CHANNELS = ("r", "u", "u_ctrl", "e", "w", "w_ref_pos", "w_ref", "x_motor", "x_table", "x_tip")

log = logging.getLogger(__name__)


def cpu_list(cpus) -> str:
    """CPU numbers as Linux writes them (``0-3,6``)."""
    out, run = [], []
    for c in sorted(cpus):
        if run and c == run[-1] + 1:
            run.append(c)
            continue
        if run:
            out.append(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]))
        run = [c]
    if run:
        out.append(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]))
    return ",".join(out)


def check_loop_cpu(cpu: int | None, key: str = "runtime.loop_cpu") -> int | None:
    """``cpu`` if the loop's thread can be pinned to it (not real-time: before anything moves).

    None: no pinning asked. A CPU this process may not use (not in its affinity mask, e.g. no such
    CPU): :class:`~hil.errors.ConfigError` naming ``key``. A system without thread affinity
    (``os.sched_setaffinity``: Linux only): a warning, and None (the loop runs on any CPU)."""
    if cpu is None:
        return None
    if not hasattr(os, "sched_setaffinity"):
        warnings.warn(f"{key} {cpu}: this system cannot pin a thread to a CPU; the loop runs on any CPU",
                      RuntimeWarning, stacklevel=2)
        return None
    allowed = os.sched_getaffinity(0)
    if cpu not in allowed:
        raise ConfigError(f"{key} {cpu}: no such CPU for this process (it may run on CPU {cpu_list(allowed)})")
    return int(cpu)


class LoopCpu:
    """The calling thread (the loop's) pinned to one CPU between :meth:`hold` and :meth:`release`
    (Linux ``sched_setaffinity`` on the thread's native id; not real-time: before and after the
    cycle). ``cpu``: checked by :func:`check_loop_cpu`; None: nothing is done. ``release`` gives
    the thread back the CPUs it had."""

    def __init__(self, cpu: int | None):
        self.cpu = cpu
        self._before = None          # (thread id, its CPUs before the run)

    def hold(self) -> None:
        if self.cpu is None or self._before is not None:
            return
        tid = threading.get_native_id()
        try:
            before = os.sched_getaffinity(tid)
            os.sched_setaffinity(tid, {self.cpu})
        except OSError as exc:       # taken offline since the check: the run goes on, unpinned
            warnings.warn(f"runtime.loop_cpu {self.cpu}: the loop's thread could not be pinned ({exc.strerror}); "
                          f"it runs on any CPU", RuntimeWarning, stacklevel=2)
            return
        self._before = (tid, before)

    def release(self) -> None:
        before, self._before = self._before, None
        if before is not None:
            try:
                os.sched_setaffinity(*before)
            except OSError:          # CPUs taken offline meanwhile: keep the one it has
                pass


class SimulatedClock:
    """Runs as fast as the computer can."""
    real_time = False

    def __init__(self, period: float):
        self.period = period
        self.k = 0
        self.lateness = np.zeros(0)        # no waiting, nothing late
        self.overruns = 0

    def start(self, cycles: int | None = None) -> None:
        """The first cycle (not real-time); ``cycles``: how many the run has (unused here)."""
        self.k = 0

    def wait(self) -> float:
        """End of the cycle (real-time)."""
        self.k += 1
        return 0.0

    @property
    def now(self) -> float:
        return self.k * self.period


class RealTimeClock:
    """Absolute deadlines; the wait gives the interpreter lock away until ``spin`` before the
    deadline (``idle(t_end)``: a blocking wait until ``t_end``, the backend's receive; else a
    sleep), then spins.

    ``spin`` (s): the part of the wait spent spinning (holding the lock); default 5 % of the
    period, at most 200 us. Measured with benchmarks/bench_canopen_timing.py (``--spin``, socketcand,
    SCHED_FIFO, 2-core VM): at 1 kHz p50 / p99 lateness 48 / 104 us without spin, 0 / 41 us with
    50 us, 0 / 15 us with 200 us; at 250 Hz 27-30 / 91-94 us with 50 us, 0 / 0-7 us with 200 us;
    the answers missed do not change with it. A timed wait ends on time at the median but now and
    then a few hundred microseconds late (the virtual machine's wake-ups): the spin covers that
    for a twentieth of a core.

    ``cpu_latency`` (s): with a priority, the CPUs' wake-up latency asked of the kernel while the
    loop runs (``runtime.cpu_latency``, :class:`drivers.rt.CpuLatencyRequest`; default 0: idle
    CPUs poll; None or inf: no request)."""
    real_time = True

    def __init__(self, period: float, spin: float | None = None, priority: int = 0, idle=None,
                 cpu_latency: float | None = 0.0):
        self.period = period
        self.spin = min(200e-6, 0.05 * period) if spin is None else spin
        self.idle = idle
        self.priority = int(priority)
        self.cpu_latency = CpuLatencyRequest(cpu_latency if self.priority > 0 else None)
        self.k = 0
        self.t0 = 0.0
        self._late = np.zeros(LATENESS_SAMPLES)    # every wake-up's lateness, preallocated (see wait)
        self._cycles = 0
        self._late_max = 0.0
        self.overruns = 0
        self._policy = None

    @property
    def lateness(self) -> np.ndarray:
        """The lateness of every wake-up of the last run (s), up to the buffer's size (the first ones)."""
        return self._late[:min(self._cycles, self._late.size)]

    def start(self, cycles: int | None = None) -> None:
        """Start the run's clock (not real-time): the real-time scheduling asked for, the lateness
        buffer ready for ``cycles`` wake-ups (default: the size it has, :data:`LATENESS_SAMPLES`
        at first)."""
        if cycles is not None and cycles != self._late.size:
            self._late = np.zeros(max(int(cycles), 1))
        self._cycles = 0
        self._late_max = 0.0
        if self.priority > 0 and hasattr(os, "sched_setscheduler"):
            # a fixed real-time priority for the loop's thread (Linux, CAP_SYS_NICE): the OS no
            # longer preempts the cycle for ordinary work; the loop sleeps most of each period
            # every thread of the process: the loop waits on the GIL for the bus's receive threads,
            # and a receive thread preempted by ordinary work would stall the loop (priority inversion)
            try:
                tids = [int(t) for t in os.listdir("/proc/self/task")] if os.path.isdir("/proc/self/task") else [0]
                self._policy = [(t, os.sched_getscheduler(t), os.sched_getparam(t)) for t in tids]
                for t in tids:
                    os.sched_setscheduler(t, os.SCHED_FIFO, os.sched_param(self.priority))
            except (PermissionError, OSError) as exc:
                self.stop()
                warnings.warn(f"runtime.priority {self.priority}: real-time scheduling refused ({exc}); "
                              f"running with normal priority", RuntimeWarning, stacklevel=2)
            # idle CPUs kept from deep (halting) idle states: the wake-up on the drive's answer or on
            # the deadline does not wait for a halted (virtual) CPU to be woken
            refused = self.cpu_latency.hold()
            if refused:
                warnings.warn(f"runtime.cpu_latency: the wake-up latency request was refused ({refused}); "
                              f"idle CPUs may sleep deeper", RuntimeWarning, stacklevel=2)
        fine_timer_slack()
        self.t0 = time.perf_counter()
        self.k = 0

    def stop(self) -> None:
        """Back to the thread's former scheduling (and the CPUs' idle states; not real-time)."""
        self.cpu_latency.release()
        for tid, policy, param in self._policy or ():
            try:
                os.sched_setscheduler(tid, policy, param)
            except OSError:       # a thread that has ended meanwhile
                pass
        self._policy = None

    def wait(self) -> float:
        """Wait for the next deadline; returns how late this wake-up is (s) (real-time)."""
        self.k += 1
        deadline = self.t0 + self.k * self.period
        if self.idle is not None:
            self.idle(deadline - self.spin)          # blocking, the lock given away
        remaining = deadline - time.perf_counter()
        if remaining > self.spin:
            time.sleep(remaining - self.spin)
        while time.perf_counter() < deadline:
            pass
        late = time.perf_counter() - deadline
        if self._cycles < self._late.size:         # bounded: past its size only the count and maximum go on
            self._late[self._cycles] = late
        self._cycles += 1
        if late > self._late_max:
            self._late_max = late
        if late > self.period:
            self.overruns += 1
            # skip the missed deadlines rather than running a burst of cycles to catch up
            self.k += int(late // self.period)
        return late

    @property
    def now(self) -> float:
        return time.perf_counter() - self.t0

    def stats(self) -> dict:
        """Lateness figures of the last run (not real-time)."""
        lat = self.lateness if self._cycles else np.zeros(1)
        return {"cycles": self._cycles, "lateness_p50_us": float(np.percentile(lat, 50) * 1e6),
                "lateness_p99_us": float(np.percentile(lat, 99) * 1e6),
                "lateness_max_us": float(max(lat.max(), self._late_max) * 1e6), "overruns": self.overruns}


class Injection:
    """The injection hook of :class:`ControlLoop`: an excitation added in every cycle, and a record
    of every cycle.

    Parameters
    ----------
    signal : array_like
        One value per cycle (velocity period) of the run, from its first cycle; at least as many
        as the run has cycles.
    into : {"torque", "velocity"}
        ``"torque"``: added to the velocity controller's output (output units), the sum limited to
        the output limit; ``"velocity"``: added to the speed reference of the velocity loop
        (controller speed units).

    After the run ``data`` holds one row per cycle, columns :data:`CYCLE_CHANNELS`: the excitation
    ``r``, the output ``u`` (before the computation delay), the controller's output ``u_ctrl`` and
    input ``e``, the measured speed ``w``, the position loop's speed reference ``w_ref_pos``, the
    velocity loop's ``w_ref``, the encoders as read (``x_tip`` NaN where the tip is not measured).
    The host must run the velocity loop (a backend with ``closes == "none"``)."""

    def __init__(self, signal, into: str = "torque"):
        if into not in ("torque", "velocity"):
            raise ValueError(f"injection into {into!r}: torque or velocity")
        self.signal = np.asarray(signal, float)
        self.into = into
        self.data = np.zeros((self.signal.size, len(CYCLE_CHANNELS)))


@dataclass
class LoopResult:
    ticks: int
    status: RunStatus
    reason: str = ""
    clock: dict = field(default_factory=dict)
    stop: StopKind = StopKind.COMPLETE     # how it ended: the command's exit code
    # the controlled stop commanded when the run ended early: {"how", "ok", "error"}; None: none was
    controlled_stop: dict | None = None


class ControlLoop:
    """Runs a command (positions on the position clock) on a backend.

    ``supervisor``: an object with ``check(t, feedback, x_cmd) -> str | None`` (a trip reason);
    a trip or a backend fault ends the run with the controlled stop (``supervisor.stop``:
    ``backend.quick_stop()`` or ``backend.disable()``) commanded in the same cycle.
    ``injection``: an :class:`Injection` (the host must close the velocity loop). ``progress``: called with the fraction of the run done every 1000 position
    ticks (inside the cycle: keep it short). ``scope``: a :class:`~hil.scope.ring.ScopeRing` the
    cycle writes every position tick's row into (it changes nothing of what the loop computes).
    ``loop_cpu``: the CPU the thread that runs the cycle is pinned to while :meth:`run` lasts
    (``runtime.loop_cpu``; checked here, before the drive is enabled: :func:`check_loop_cpu`).

    The cycle's stages (:meth:`_tick`), as drivers.control writes them once for every loop: read
    feedback, supervise, profile and position law, velocity law, write command, record. What the
    cycle keeps is preallocated here: the loop's state and output delay (drivers.control's arrays), one
    :class:`~drivers.base.Setpoint` written in place, the supervisor's methods looked up once.

    Real-time: :meth:`run`'s cycle and the methods it calls there (``_tick``, ``_command``,
    ``_supervise``, ``_record``, ``_stop``, ``_event``, the clock's ``wait``); :meth:`__init__` does
    the slow preparation before the drive is enabled."""

    def __init__(self, backend: Backend, ctrl, clock=None, recorder=None, supervisor=None, rotary: bool = True,
                 priority: int = 0, injection: Injection | None = None, progress=None,
                 cpu_latency: float | None = 0.0, scope: ScopeRing | None = None, loop_cpu: int | None = None):
        self.backend = backend
        self.scope = scope
        self.loop_cpu = LoopCpu(check_loop_cpu(loop_cpu))
        self.ctrl = ctrl
        self.p = ctrl.as_array()
        period = backend.cycle_time
        self.clock = clock or (SimulatedClock(period) if backend.simulated else
                               RealTimeClock(period, priority=priority, idle=getattr(backend, "receive_until", None),
                                             cpu_latency=cpu_latency))
        self.recorder = recorder
        self.supervisor = supervisor
        self.rotary = rotary
        if injection is not None and backend.closes != "none":
            raise ValueError(f"backend {backend.name}: an injection needs the host to close the velocity loop "
                             f"(closes='none'), this one closes {backend.closes!r}")
        self.injection = injection
        self.progress = progress
        # what the backend closes, bound once (the cycle compares no strings)
        self._closes_both = backend.closes == "both"
        self._closes_velocity = backend.closes == "velocity"
        self._inject_torque = injection is not None and injection.into == "torque"
        if backend.closes == "none":
            self.per_tick = ctrl.substeps          # cycles per position tick
        else:
            self.per_tick = 1
        self._ring = np.zeros(int(ctrl.output_delay) + 1)     # outputs still in the computation delay
        self._s = new_velocity_state()
        self._w_ref = 0.0
        self.trip_kind = StopKind.TRIP
        self.trip_reason = ""
        self._setpoint = Setpoint()
        self._cmds: list[float] = []      # the run's commands, as a list (run)
        self._motor_feedback = ctrl.position_feedback == "motor"
        self._record_order = None if recorder is None else _record_order(recorder.names, rotary)
        self._record_stale = recorder is not None and "stale" in recorder.names
        _warm_up(self.p)
        if self.clock.real_time:
            gc.collect()
            gc.freeze()

    @property
    def supervisor(self):
        return self._supervisor

    @supervisor.setter
    def supervisor(self, sup) -> None:
        """The supervisor and its methods, looked up here once rather than in every cycle (not
        real-time)."""
        self._supervisor = sup
        self._check = None if sup is None else sup.check
        self._check_setpoint = getattr(sup, "check_setpoint", None)
        self._latch = getattr(sup, "trip", None)
        self._stop_how = getattr(sup, "stop", "quick_stop")
        self._stop_disables = self._stop_how == "disable"

    def _record(self, k: int, x_cmd: float, v_cmd: float, fb: Feedback, output: float) -> None:
        """Record: one row of the recorder at position tick ``k``, in the recorder's column order
        (real-time: one tuple, no dictionaries), and the scope's row (in place, no allocation)."""
        scope = self.scope
        if scope is not None:
            t = k * self.ctrl.position_period
            scope.write(t, x_cmd, fb.x_motor, fb.x_table, fb.x_tip, x_cmd - fb.x_table,
                        x_cmd - (fb.x_tip if not math.isnan(fb.x_tip) else fb.x_table), output, fb.v_motor)
        if self.recorder is None:
            return
        tip = fb.x_tip if not math.isnan(fb.x_tip) else fb.x_table
        if self._record_stale:
            row = (k * self.ctrl.position_period, x_cmd, v_cmd, fb.x_motor, fb.x_table, tip, output,
                   x_cmd - fb.x_table, x_cmd - tip, 1.0 if fb.stale else 0.0)
        else:
            row = (k * self.ctrl.position_period, x_cmd, v_cmd, fb.x_motor, fb.x_table, tip, output,
                   x_cmd - fb.x_table, x_cmd - tip)
        order = self._record_order
        self.recorder.write_row(row if order is None else [row[i] for i in order])

    def run(self, x_cmd, x_after: float | None = None) -> LoopResult:
        """Run ``len(x_cmd)`` position ticks (not real-time itself: it prepares, then runs the cycle).
        ``x_after``: the command at the tick after the last (the last tick's feed-forward moves
        toward it); default: the last position, held."""
        x_cmd = np.asarray(x_cmd, float)
        cmd = np.append(x_cmd, x_cmd[-1] if x_after is None else x_after)
        # the cycle's own reads of the command from a list: an element of an array is a new numpy
        # scalar every time, an element of a list is the float already there (nothing built per cycle)
        self._cmds = cmd.tolist()
        K = x_cmd.size
        if self.injection is not None and self.injection.signal.size < K * self.per_tick:
            raise ValueError(f"injection: {self.injection.signal.size} values for {K * self.per_tick} cycles")
        self._s = new_velocity_state()
        self._stopped = None              # the controlled stop, once one is commanded (_stop)
        # no garbage-collection pauses inside the cycle on hardware (collected in __init__,
        # before the drive was enabled: a collection can take longer than a drive's watchdog)
        gc_was_on = gc.isenabled()
        if self.clock.real_time:
            gc.disable()
        self.loop_cpu.hold()
        self.clock.start(K * self.per_tick)
        k = 0
        status, reason, kind = RunStatus.COMPLETE, "", StopKind.COMPLETE
        try:
            for k in range(K):
                if self._tick(k, cmd) is TickResult.TRIPPED:
                    return self._end(k, RunStatus.TRIPPED, self.trip_reason, self.trip_kind)
                if self.progress is not None and k % 1000 == 0:
                    try:
                        self.progress((k + 1) / K)
                    except OSError:          # its reader went away (a closed pipe): the motion goes on
                        self.progress = None
        except BackendFault as exc:
            status, reason, kind = RunStatus.FAULT, exc.reason, fault_kind(exc.kind, StopKind.LINK)
            self._stop_after(k, "fault", reason)
            if self._latch is not None:        # latched like a trip: motion refused until 'hil reset'
                self._latch(k * self.ctrl.position_period, reason, None, kind)
        except KeyboardInterrupt:
            status, reason = RunStatus.ABORTED, "interrupted (Ctrl-C)"
            self._stop_after(k, "aborted", reason)
            raise
        except Exception as exc:
            status, reason = RunStatus.ABORTED, f"{type(exc).__name__}: {exc}"
            self._stop_after(k, "aborted", reason)
            raise
        finally:
            if hasattr(self.clock, "stop"):
                self.clock.stop()
            self.loop_cpu.release()
            if self.clock.real_time:
                gc.unfreeze()
                if gc_was_on:
                    gc.enable()
            if self.recorder is not None and status is not RunStatus.COMPLETE:
                self.recorder.close(status, reason)
        if status is RunStatus.COMPLETE:
            self._event(K - 1, "complete", "")
        return self._end(K, status, reason, kind)

    def _tick(self, k: int, cmd: np.ndarray) -> TickResult:
        """Position tick ``k``: its ``per_tick`` cycles, stage by stage (real-time). Returns
        ``TRIPPED`` on a trip (the controlled stop commanded, the event written, the reason in
        ``trip_reason``, its kind in ``trip_kind``), ``OK`` while all is well."""
        b = self.backend
        cmds = self._cmds
        v_cmd = (cmds[k + 1] - cmds[k]) / self.ctrl.position_period
        for j in range(self.per_tick):
            fb = b.read_feedback()                                  # read feedback
            if fb.fault and (self._check is None or j != 0):
                # supervise: the supervisor checks once a tick, a fault between ticks trips it here, the same way
                reason = fb.fault_line
                if self._latch is None:
                    raise BackendFault(reason, fb.fault_kind)
                self.trip_kind = fault_kind(fb.fault_kind, StopKind.TRIP)
                self.trip_reason = reason
                self._latch(k * self.ctrl.position_period, reason, fb, self.trip_kind)
                self._stop_after(k, "trip", reason)
                return TickResult.TRIPPED
            out = self._command(k, j, cmd, fb)                      # profile, position law, velocity law
            if j == 0:
                self._record(k, cmds[k], v_cmd, fb, out)            # record
                trip = self._supervise(k, fb)                       # supervise, before the setpoint goes out
                if trip:
                    self._stop_after(k, "trip", trip)
                    self.trip_kind = getattr(self.supervisor, "trip_kind", None) or StopKind.TRIP
                    self.trip_reason = trip
                    return TickResult.TRIPPED
            b.write_setpoint(self._setpoint)                        # write command
            b.sync()
            self.clock.wait()
        return TickResult.OK

    def _command(self, k: int, j: int, cmd: np.ndarray, fb: Feedback) -> float:
        """Profile, position law and velocity law of cycle ``j`` of tick ``k`` (drivers.control's
        stages, as far as the backend does not close the loops itself): writes this cycle's
        setpoint in place; returns the output to record (real-time)."""
        sp = self._setpoint
        if self._closes_both:
            sp.position = self._cmds[k + 1]
            return fb.output
        if j == 0:
            xfb = fb.x_motor if self._motor_feedback else fb.x_table
            if not math.isnan(fb.x_feedback):      # the feedback arrives late
                xfb = fb.x_feedback
            self._w_ref = position_tick(self.p, self._s, cmd, k, xfb)
        if self._closes_velocity:
            sp.speed = self._w_ref
            return fb.output
        inj = self.injection
        if inj is None:
            u = velocity_cycle(self.p, self._s, self._ring, fb.v_motor, fb.x_motor)
        else:
            i = k * self.per_tick + j
            u = injected_velocity_cycle(self.p, self._s, self._ring, fb.v_motor, fb.x_motor, inj.signal[i],
                                        self._inject_torque, inj.data, i)
            inj.data[i, 7], inj.data[i, 8], inj.data[i, 9] = fb.x_motor, fb.x_table, fb.x_tip
        sp.output = u
        return u

    def _supervise(self, k: int, fb: Feedback):
        """Supervise at position tick ``k``: the supervisor's check of the feedback, and of the
        setpoint about to go out (the command of tick ``k + 1`` on a position-mode drive); the trip's reason or
        None (real-time)."""
        if self._check is None:
            return None
        t = k * self.ctrl.position_period
        trip = self._check(t, fb, self._cmds[k])
        if not trip and self._check_setpoint is not None:
            trip = self._check_setpoint(t, self._cmds[k + 1])
        return trip

    def _stop_after(self, k: int, kind: str, reason: str) -> None:
        """The controlled stop, and the scope's event of how the run ends (real-time)."""
        self._stop(self.backend)
        self._event(k, kind, reason)

    def _event(self, k: int, kind: str, reason: str) -> None:
        """An event of the scope at position tick ``k`` (real-time; nothing without a scope)."""
        if self.scope is not None:
            self.scope.event(k * self.ctrl.position_period, kind, reason)

    def _stop(self, backend: Backend) -> None:
        """The controlled stop the configuration asks for (supervisor.stop: quick_stop or disable);
        never raises: the link may be gone, and the drive-side guards stop the axis then
        (real-time)."""
        how = self._stop_how
        self._stopped = {"how": how, "ok": True, "error": ""}
        try:
            if self._stop_disables:
                backend.disable()
            else:
                backend.quick_stop()
        except Exception as exc:
            log.warning("%s backend: the controlled stop (%s) failed: %s", backend.name, how, exc)
            self._stopped = {"how": how, "ok": False, "error": f"{type(exc).__name__}: {exc}"}

    def _end(self, ticks: int, status: RunStatus, reason: str, kind: StopKind) -> LoopResult:
        """The run's result (not real-time: after the cycle)."""
        clock = self.clock.stats() if hasattr(self.clock, "stats") else {}
        return LoopResult(ticks, status, reason, clock, kind, self._stopped)


# the columns _record fills, in the order of hil.runtime.record_channels
# "stale" (1 where the cycle's answer did not come in, Feedback.stale) only where the recorder has it
RECORD_ROW = ("t", "x_cmd", "v_cmd", "x_motor", "x_table", "x_tip", "output", "e_table", "e_tip", "stale")


def _record_order(names, rotary: bool) -> list[int] | None:
    """Where each of the recorder's columns ``names`` is in :data:`RECORD_ROW` (None: the same
    order); the controller's output is ``torque`` on a rotary axis, ``command`` on a linear one
    (not real-time)."""
    row = [("torque" if rotary else "command") if n == "output" else n for n in RECORD_ROW]
    unknown = [n for n in names if n not in row]
    if unknown:
        raise ValueError(f"recorder channels {unknown}: the loop records only {row}")
    order = [row.index(n) for n in names]
    return None if order == list(range(len(order))) else order


def _warm_up(p) -> None:
    """Load the compiled control law before the first cycle (it takes a fraction of a second the
    first time, which would otherwise land inside the first cycle and trip a drive's watchdog;
    not real-time)."""
    s = new_velocity_state()
    position_law(p, 0.0, 0.0, 0.0)
    measured_speed(p, s, 0.0, 0.0)
    velocity_law(p, new_velocity_state(), 0.0, 0.0, 0.0)
    s = new_velocity_state()
    position_tick(p, s, np.zeros(2), 0, 0.0)
    velocity_cycle(p, s, np.zeros(1), 0.0, 0.0)
    injected_velocity_cycle(p, s, np.zeros(1), 0.0, 0.0, 0.0, True, np.zeros((1, len(CYCLE_CHANNELS))), 0)
