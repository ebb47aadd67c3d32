"""The fixed-rate loop: one cycle per backend exchange, on a real-time or a simulated clock.

Each cycle: read the feedback, run the loops the backend does not close (hil.control's law),
write the setpoint, record (every position tick), let the supervisor check, end the cycle
(``backend.sync()``), wait for the next deadline.

* :class:`RealTimeClock`: absolute deadlines t0 + k T (no drift). The wait gives the interpreter
  lock away: the backend's ``receive_until`` (where it has one: the loop's own thread takes the
  answer from the bus in a blocking receive with a timeout) or a sleep, with the thread's timer
  slack at 1 ns (Linux: the default 50 us would add itself to every wake-up), until ``spin``
  before the deadline (5 % of the period, at most 200 us), then spins; it records every cycle's lateness and counts overruns
  (a cycle that starts a whole period late).
* :class:`SimulatedClock`: no waiting; time is the cycle count times the period.

The loop's hooks: a ``recorder`` (one row per position tick), a ``scope`` (a
:class:`hil.scope.ring.ScopeRing`: the same row, written in place into a preallocated ring the live
scope's server reads without a lock; trips and the run's end as its events), a ``supervisor`` (checked every
position tick) and an :class:`Injection` (an excitation added in every cycle to the torque or to
the speed reference, and one row per cycle of what the loop did with it: hil.frf measures
frequency responses through it).

Real-time: the methods marked "(real-time)" run inside the cycle, between reading the feedback
and ending the cycle; they, and the hooks they call, must be short and must not block.

How a run ends follows the fault rule of :mod:`hil.drivers.base`: a ``Feedback.fault`` trips the
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
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from hil.control import measured_speed, new_velocity_state, position_law, velocity_law
from hil.drivers.base import Backend, BackendFault, Feedback, Setpoint, fault_kind
from hil.drivers.rt import CpuLatencyRequest, fine_timer_slack
from hil.errors import RunStatus, StopKind
from hil.scope.ring import ScopeRing

__all__ = ["RealTimeClock", "SimulatedClock", "ControlLoop", "LoopResult", "Injection", "CYCLE_CHANNELS"]

# what an Injection records every cycle, one column each
CYCLE_CHANNELS = ("r", "u", "u_ctrl", "e", "w", "w_ref_pos", "w_ref", "x_motor", "x_table", "x_tip")

log = logging.getLogger(__name__)


class SimulatedClock:
    """Runs as fast as the computer can."""
    real_time = False

    def __init__(self, period: float):
        self.period = period
        self.k = 0
        self.lateness: list[float] = []
        self.overruns = 0

    def start(self) -> None:
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
    loop runs (``runtime.cpu_latency``, :class:`hil.drivers.rt.CpuLatencyRequest`; default 0: idle
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
        self.lateness: list[float] = []
        self.overruns = 0
        self._policy = None

    def start(self) -> None:
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
        """Back to the thread's former scheduling (and the CPUs' idle states)."""
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
        self.lateness.append(late)
        if late > self.period:
            self.overruns += 1
            # skip the missed deadlines rather than running a burst of cycles to catch up
            self.k += int(late // self.period)
        return late

    @property
    def now(self) -> float:
        return time.perf_counter() - self.t0

    def stats(self) -> dict:
        lat = np.array(self.lateness) if self.lateness else np.zeros(1)
        return {"cycles": len(self.lateness), "lateness_p50_us": float(np.percentile(lat, 50) * 1e6),
                "lateness_p99_us": float(np.percentile(lat, 99) * 1e6), "lateness_max_us": float(lat.max() * 1e6),
                "overruns": self.overruns}


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


class ControlLoop:
    """Runs a command (positions on the position clock) on a backend.

    ``supervisor``: an object with ``check(t, feedback, x_cmd) -> str | None`` (a trip reason);
    a trip or a backend fault ends the run with the controlled stop (``supervisor.stop``:
    ``backend.quick_stop()`` or ``backend.disable()``) commanded in the same cycle.
    ``injection``: an :class:`Injection` (the host must close the velocity loop). ``progress``: called with the fraction of the run done every 1000 position
    ticks (inside the cycle: keep it short). ``scope``: a :class:`~hil.scope.ring.ScopeRing` the
    cycle writes every position tick's row into (it changes nothing of what the loop computes).

    Real-time: :meth:`run`'s cycle and the methods it calls there (``_inject``, ``_record``,
    ``_stop``, the clock's ``wait``); :meth:`__init__` does the slow preparation before the drive
    is enabled."""

    def __init__(self, backend: Backend, ctrl, clock=None, recorder=None, supervisor=None, rotary: bool = True,
                 priority: int = 0, injection: Injection | None = None, progress=None,
                 cpu_latency: float | None = 0.0, scope: ScopeRing | None = None):
        self.backend = backend
        self.scope = scope
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
        if backend.closes == "none":
            self.per_tick = ctrl.substeps          # cycles per position tick
        else:
            self.per_tick = 1
        self._delay = [0.0] * int(ctrl.output_delay)     # outputs still in the computation delay
        self._record_order = None if recorder is None else _record_order(recorder.names, rotary)
        self._record_stale = recorder is not None and "stale" in recorder.names
        _warm_up(self.p)
        if self.clock.real_time:
            gc.collect()
            gc.freeze()

    def _record(self, k: int, x_cmd: float, v_cmd: float, fb: Feedback, output: float) -> None:
        """One row of the recorder at position tick ``k``, in the recorder's column order
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

    def _inject(self, i: int, s, w_pos: float, w: float, a_cmd: float, fb: Feedback) -> float:
        """The velocity-loop step of cycle ``i`` with the excitation added; records the cycle
        (real-time). Returns the output before the computation delay."""
        inj = self.injection
        r = inj.signal[i]
        w_ref = w_pos + (r if inj.into == "velocity" else 0.0)
        uc = velocity_law(self.p, s, w_ref, w, a_cmd)
        lim = self.ctrl.output_limit
        u = min(max(uc + (r if inj.into == "torque" else 0.0), -lim), lim)
        inj.data[i] = (r, u, uc, w_ref - w, w, w_pos, w_ref, fb.x_motor, fb.x_table, fb.x_tip)
        return u

    def run(self, x_cmd, x_after: float | None = None) -> LoopResult:
        """Run ``len(x_cmd)`` position ticks. ``x_after``: the command at the tick after the last
        (the last tick's feed-forward moves toward it); default: the last position, held."""
        x_cmd = np.asarray(x_cmd, float)
        cmd = np.append(x_cmd, x_cmd[-1] if x_after is None else x_after)
        K = x_cmd.size
        if self.injection is not None and self.injection.signal.size < K * self.per_tick:
            raise ValueError(f"injection: {self.injection.signal.size} values for {K * self.per_tick} cycles")
        b, p = self.backend, self.p
        s = new_velocity_state()
        # no garbage-collection pauses inside the cycle on hardware (collected in __init__,
        # before the drive was enabled: a collection can take longer than a drive's watchdog)
        gc_was_on = gc.isenabled()
        if self.clock.real_time:
            gc.disable()
        self.clock.start()
        k = 0
        status, reason, kind = RunStatus.COMPLETE, "", StopKind.COMPLETE
        try:
            for k in range(K):
                tp = self.ctrl.position_period
                v_cmd = (cmd[k + 1] - cmd[k]) / tp
                # the interpolator's acceleration (for the acceleration feed-forward), as in the simulator
                a_cmd = (cmd[k + 1] - 2.0 * cmd[k] + (cmd[k - 1] if k > 0 else cmd[k])) / tp ** 2
                for j in range(self.per_tick):
                    fb = b.read_feedback()
                    if fb.fault and (self.supervisor is None or j != 0):
                        # the supervisor checks once a tick: a fault between ticks trips it here, the same way
                        latch = getattr(self.supervisor, "trip", None)
                        if latch is None:
                            raise BackendFault(fb.fault, fb.fault_kind)
                        kind = fault_kind(fb.fault_kind, StopKind.TRIP)
                        latch(k * self.ctrl.position_period, fb.fault, fb, kind)
                        self._stop(b)
                        self._event(k, "trip", fb.fault)
                        return self._end(k, RunStatus.TRIPPED, fb.fault, kind)
                    # the setpoint of this cycle (from the loops the backend does not close)
                    if b.closes == "both":
                        sp, out = Setpoint(position=cmd[k + 1]), fb.output
                    else:
                        if j == 0:
                            xfb = fb.x_motor if self.ctrl.position_feedback == "motor" else fb.x_table
                            if not math.isnan(fb.x_feedback):      # the feedback arrives late
                                xfb = fb.x_feedback
                            w_ref = position_law(p, cmd[k], cmd[k + 1], xfb)
                        if b.closes == "velocity":
                            sp, out = Setpoint(speed=w_ref), fb.output
                        else:
                            w = measured_speed(p, s, fb.v_motor, fb.x_motor)
                            if self.injection is None:
                                u = velocity_law(p, s, w_ref, w, a_cmd)
                            else:
                                u = self._inject(k * self.per_tick + j, s, w_ref, w, a_cmd, fb)
                            self._delay.insert(0, u)
                            u = self._delay.pop()
                            sp, out = Setpoint(output=u), u
                    if j == 0:
                        self._record(k, cmd[k], v_cmd, fb, out)
                        # checked before the setpoint goes out: a trip stops the axis in this cycle
                        if self.supervisor is not None:
                            trip = self.supervisor.check(k * self.ctrl.position_period, fb, cmd[k])
                            # and the setpoint about to go out (cmd[k + 1] on a position-mode drive)
                            check_next = getattr(self.supervisor, "check_setpoint", None)
                            if not trip and check_next is not None:
                                trip = check_next(k * self.ctrl.position_period, cmd[k + 1])
                            if trip:
                                self._stop(b)
                                self._event(k, "trip", trip)
                                kind = getattr(self.supervisor, "trip_kind", None) or StopKind.TRIP
                                return self._end(k, RunStatus.TRIPPED, trip, kind)
                    b.write_setpoint(sp)
                    b.sync()
                    self.clock.wait()
                if self.progress is not None and k % 1000 == 0:
                    try:
                        self.progress((k + 1) / K)
                    except OSError:          # its reader went away (a closed pipe): the motion goes on
                        self.progress = None
        except BackendFault as exc:
            self._stop(b)
            status, reason, kind = RunStatus.FAULT, exc.reason, fault_kind(exc.kind, StopKind.LINK)
            self._event(k, "fault", reason)
            latch = getattr(self.supervisor, "trip", None)
            if latch is not None:        # latched like a trip: motion refused until 'hil reset'
                latch(k * self.ctrl.position_period, reason, None, kind)
        except KeyboardInterrupt:
            self._stop(b)
            status, reason = RunStatus.ABORTED, "interrupted (Ctrl-C)"
            self._event(k, "aborted", reason)
            raise
        except Exception as exc:
            self._stop(b)
            status, reason = RunStatus.ABORTED, f"{type(exc).__name__}: {exc}"
            self._event(k, "aborted", reason)
            raise
        finally:
            if hasattr(self.clock, "stop"):
                self.clock.stop()
            if self.clock.real_time:
                gc.unfreeze()
                if gc_was_on:
                    gc.enable()
            if self.recorder is not None and status != "complete":
                self.recorder.close(status, reason)
        if status == "complete":
            self._event(K - 1, "complete", "")
        return self._end(K, status, reason, kind)

    def _event(self, k: int, kind: str, reason: str) -> None:
        """An event of the scope at position tick ``k`` (real-time; nothing without a scope)."""
        if self.scope is not None:
            self.scope.event(k * self.ctrl.position_period, kind, reason)

    def _stop(self, backend: Backend) -> None:
        """The controlled stop the configuration asks for (supervisor.stop: quick_stop or disable);
        never raises: the link may be gone, and the drive-side guards stop the axis then
        (real-time)."""
        how = getattr(self.supervisor, "stop", "quick_stop")
        try:
            if how == "disable":
                backend.disable()
            else:
                backend.quick_stop()
        except Exception as exc:
            log.warning("%s backend: the controlled stop (%s) failed: %s", backend.name, how, exc)

    def _end(self, ticks: int, status: RunStatus, reason: str, kind: StopKind) -> LoopResult:
        clock = self.clock.stats() if hasattr(self.clock, "stats") else {}
        return LoopResult(ticks, status, reason, clock, kind)


# the columns _record fills, in the order of hil.runtime.record_channels
# "stale" (1 where the cycle's answer did not come in, Feedback.stale) only where the recorder has it
RECORD_ROW = ("t", "x_cmd", "v_cmd", "x_motor", "x_table", "x_tip", "output", "e_table", "e_tip", "stale")


def _record_order(names, rotary: bool) -> list[int] | None:
    """Where each of the recorder's columns ``names`` is in :data:`RECORD_ROW` (None: the same
    order); the controller's output is ``torque`` on a rotary axis, ``command`` on a linear one."""
    row = [("torque" if rotary else "command") if n == "output" else n for n in RECORD_ROW]
    unknown = [n for n in names if n not in row]
    if unknown:
        raise ValueError(f"recorder channels {unknown}: the loop records only {row}")
    order = [row.index(n) for n in names]
    return None if order == list(range(len(order))) else order


def _warm_up(p) -> None:
    """Load the compiled control law before the first cycle (it takes a fraction of a second the
    first time, which would otherwise land inside the first cycle and trip a drive's watchdog)."""
    s = new_velocity_state()
    position_law(p, 0.0, 0.0, 0.0)
    measured_speed(p, s, 0.0, 0.0)
    velocity_law(p, new_velocity_state(), 0.0, 0.0, 0.0)
