"""A simulated ASCII serial drive on a pseudo-terminal, in a process of its own.

It speaks the command set of the config's ``[serial]`` section (commands recognised from their
templates, replies rendered from their patterns: literal text and named groups) and its shaft is
the sim_plant model (:class:`drivers.sim.SimulatedPlant`, ``closes="both"`` in position mode,
``"velocity"`` in velocity mode).

Time: with ``advance="setpoint"`` (the default) the plant advances one cycle (one position
period) per setpoint received, so that a host loop may run as fast as the link permits; with
``advance="wall"`` it advances with the wall clock, one cycle per elapsed position period, as a
real drive on its own clock does.

The watchdog (the drive's protection against a silent host, as the CiA 402 abort-connection
option is a CANopen drive's) runs on the wall clock. Its time is a drive parameter (``watchdog``
of :func:`serve`, ``hil serial-sim --watchdog``; 0: off), which the host's ``watchdog`` command
(``WD {ms}``) sets at start-up. When no valid command arrived for that long while enabled, the
drive performs its quick stop (its own velocity loop to standstill at full torque, then
disabled) and reports fault 1; ``clear_fault`` and ``enable`` are needed before it takes a
setpoint again. The watchdog is checked before anything received is read: a drive that stood
frozen (its process stopped, as by ``kill -STOP``) finds the host silent for the whole freeze
when it resumes, stops, and discards every byte that was queued on the line meanwhile, unread. A
drive on an ASCII line has no sequence number or time stamp to tell a stale command from a
fresh one: what arrived while it could not look is stale. With ``advance="setpoint"`` the quick
stop runs to standstill at once (no setpoints advance the plant's clock any more).

Fault injection (:meth:`SimulatedSerialDrive.inject`, or ``hil serial-sim --fault``): after
``after`` further commands (of operation ``op`` if given), the next ``count`` commands get, instead
of their execution and reply:

=============  ==============================================================================
``timeout``     no reply
``partial``     the first half of the reply, no line ending
``garbled``     the reply with random bytes in it
``checksum``    the reply with a wrong checksum
``unexpected``  a well-formed line that is not the reply (``HELLO``)
``refuse``      the error reply (code 9)
``drive_fault`` the drive faults (code 2, disabled): executes, and reports it in ``read``
``vanish``      the port disappears (the process closes the pseudo-terminal and ends)
``late``        the reply, 50 ms late (a drive that no longer keeps up)
``frozen_encoder`` executes; from then on every ``read`` reports the positions of this moment
=============  ==============================================================================

The drive notes what fired and when (command count, wall clock), and when the host's stop
(``quick_stop`` or ``disable``) arrived after it: :meth:`SimulatedSerialDrive.state` gives both,
for the reaction times of the fault matrix (tests/test_faults.py).

Fault codes in ``read``: 0 none, 1 watchdog, 2 drive fault (injected), 3 command while disabled.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import re
import select
import time
import tty

import numpy as np

from drivers.base import Setpoint
from drivers.errors import ConfigError
from drivers.serial.protocol import CommandSet, ReplyError, command_pattern, render_reply
from drivers.sim import SimulatedPlant

__all__ = ["SimulatedSerialDrive", "serve", "FAULTS", "parse_fault"]

FAULTS = ("timeout", "partial", "garbled", "checksum", "unexpected", "refuse", "drive_fault", "vanish", "late",
          "frozen_encoder")
LATE = 0.05          # s: how late a ``late`` reply comes
STANDSTILL = 1e-4    # m/s: the quick stop is complete below this motor speed (as the CANopen drive's)


_FAULT = re.compile(r"(?P<kind>[a-z_]+)(?:@(?P<after>[0-9]+))?(?:x(?P<count>[0-9]+))?(?::(?P<op>[A-Za-z0-9_]+))?")


def parse_fault(text: str) -> dict:
    """``kind[@after][xcount][:op]``, e.g. ``timeout@100x3:set_position``: ``after`` exchanges
    first (0 or more), ``count`` times (1 or more), on the operation ``op`` only (any: none).
    Anything else is a ValueError naming the grammar (``timeout@1x-1`` read a count of -1)."""
    m = _FAULT.fullmatch(text.strip())
    if m is None:
        raise ValueError(f"{text!r}: expected KIND[@AFTER][xCOUNT][:OP], e.g. timeout@100x3:set_position "
                         f"(AFTER 0 or more, COUNT 1 or more)")
    kind, after, count = m["kind"], int(m["after"] or 0), int(m["count"] or 1)
    if kind not in FAULTS:
        raise ValueError(f"unknown fault {kind!r} (known: {', '.join(FAULTS)})")
    if count < 1:
        raise ValueError(f"{text!r}: a count of at least 1, e.g. {kind}x1")
    return {"kind": kind, "after": after, "count": count, "op": m["op"]}


class _Drive:
    def __init__(self, cfg, plant, advance: str = "setpoint", seed: int = 1, watchdog: float = 0.0):
        self.cs = CommandSet.from_config(cfg)
        mode = cfg.get("serial.mode", "position")
        self.plant = SimulatedPlant(cfg, plant, closes="both" if mode == "position" else "velocity")
        self.plant.open()
        # the quick stop's torque: the drive's limit
        self.tmax = float(cfg.get("limits.torque") or cfg["control.output_limit"])
        self._warm_up()
        self.k_pos = float(cfg.get("serial.scale_position", 1e6))
        self.k_speed = float(cfg.get("serial.scale_speed", self.k_pos))
        self.k_out = float(cfg.get("serial.scale_output", 1.0))
        self.period = self.plant.cycle_time
        self.advance = advance
        self.patterns = [(op, command_pattern(t)) for op, t in self.cs.commands.items()]
        self.enabled = False
        self.fault = 0
        self.watchdog = float(watchdog)       # s; the drive parameter, until the host's watchdog command
        self.stopping = False                 # the quick stop is running
        self.setpoints = 0                    # setpoints executed
        self.discarded = 0                    # bytes discarded unread after a freeze
        self.drain_pending = False
        self.watchdog_trip: dict | None = None    # when the watchdog tripped: wall clock, position, speed
        self.last_valid = time.perf_counter()
        self.t_next = time.perf_counter() + self.period
        self.faults: list[dict] = []
        self.rng = np.random.default_rng(seed)
        self.commands = 0
        self.vanish = False
        self.frozen: dict | None = None
        self.fired: list[dict] = []           # what fired: kind, command count, wall clock
        self.stopped: dict | None = None      # the host's first stop after a fault fired
        self.name = "SIMDRIVE"
        # self-check: every reply can be rendered and parses back
        try:
            self._reply("read", dict(x_motor=0, x_table=0, v_motor=0, output=0, fault=0))
        except ValueError as exc:
            raise ConfigError(f"{cfg.source}: serial.replies.read: the simulated drive cannot answer with it "
                              f"({exc})") from None

    def _warm_up(self) -> None:
        """Load the plant's compiled cycles before the first command (a first setpoint must not take
        100 ms): its control law, its coasting while disabled, the output steps of the quick stop
        (:meth:`_quick_stop_step`) and the feedback it reads (SimulatedPlant.warm_up, the state put
        back)."""
        self.plant.warm_up()

    # -- replies -------------------------------------------------------------------------------
    def _reply(self, op, values=None) -> bytes:
        text = render_reply(self.cs.replies[op], values or {})
        return self.cs.frame(text)

    def _error(self, code: int) -> bytes:
        if "error" in self.cs.replies:
            return self._reply("error", {"code": code})
        return self.cs.frame("?")

    def _feedback(self) -> dict:
        if self.frozen is not None:
            return dict(self.frozen, fault=self.fault)
        fb = self.plant.read_feedback()
        return dict(x_motor=round(fb.x_motor * self.k_pos), x_table=round(fb.x_table * self.k_pos),
                    v_motor=round(fb.v_motor * self.k_pos), output=round(fb.output * self.k_out),
                    fault=self.fault)

    # -- one command line --------------------------------------------------------------------------
    def handle(self, line: bytes) -> bytes | None:
        self.commands += 1
        try:
            text = self.cs.unframe(line)
        except ReplyError:
            return self._error(1)
        for op, pat in self.patterns:
            m = pat.fullmatch(text)
            if m:
                break
        else:
            return self._error(1)
        vals = {k: int(v) for k, v in m.groupdict().items()}
        if op in ("quick_stop", "disable") and self.fired and self.stopped is None:
            self.stopped = {"op": op, "command": self.commands, "t": time.perf_counter()}
        f = self._due(op)
        if f is not None:
            if not f.get("noted"):
                f["noted"] = True
                self.fired.append({"kind": f["kind"], "command": self.commands, "t": time.perf_counter()})
            return self._inject(f, op, vals)
        self.last_valid = time.perf_counter()
        return self.execute(op, vals)

    def _due(self, op):
        for f in self.faults:
            if f["op"] and f["op"] != op:
                continue
            if f["after"] > 0:
                f["after"] -= 1
                return None
            f["count"] -= 1
            if f["count"] <= 0:
                self.faults.remove(f)
            return f
        return None

    def _inject(self, f, op, vals) -> bytes | None:
        kind = f["kind"]
        if kind == "timeout":
            return None
        if kind == "vanish":
            self.vanish = True
            return None
        if kind == "drive_fault":
            self.fault, self.enabled = 2, False
            self.plant.disable()
            return self.execute(op, vals)
        if kind == "refuse":
            return self._error(9)
        if kind == "late":
            reply = self.execute(op, vals)
            time.sleep(LATE)
            return reply
        if kind == "frozen_encoder":
            if self.frozen is None:
                self.frozen = {k: v for k, v in self._feedback().items() if k != "fault"}
            self.last_valid = time.perf_counter()
            return self.execute(op, vals)
        if kind == "unexpected":
            return self.cs.frame("HELLO")
        good = self._render_for(op, vals)
        if kind == "partial":
            return good[:max(1, len(good) // 2)].replace(self.cs.line_ending, b"")
        if kind == "checksum":
            body = good[:-len(self.cs.line_ending)]
            if self.cs.checksum == "none":
                return body + b"#" + self.cs.line_ending
            last = body[-1:]
            return body[:-1] + (b"0" if last != b"0" else b"1") + self.cs.line_ending
        if kind == "garbled":
            b = bytearray(good)
            for i in self.rng.integers(0, max(1, len(b) - 1), size=max(1, len(b) // 4)):
                b[i] = int(self.rng.integers(0, 256))
            return bytes(b)
        return None

    def _render_for(self, op, vals) -> bytes:
        if op == "read":
            return self._reply("read", self._feedback())
        v = dict(vals)
        if vals:
            v["echo"] = next(iter(vals.values()))
        v.setdefault("name", self.name)
        return self._reply(op, v)

    def execute(self, op, vals) -> bytes:
        pl = self.plant
        if op == "read":
            return self._reply("read", self._feedback())
        if op == "identify":
            return self._reply(op, {"name": self.name})
        if op == "watchdog":
            self.watchdog = vals.get("ms", 0) / 1e3
            return self._reply(op, {"echo": vals.get("ms", 0)})
        if op == "clear_fault":
            self.fault = 0
            return self._reply(op, {})
        if op == "enable":
            if self.fault:
                return self._error(3)
            self.enabled, self.stopping = True, False
            pl.enable()
            pl.restart_interpolation()
            self.t_next = time.perf_counter() + self.period
            return self._reply(op, {})
        if op == "quick_stop":
            self.quick_stop()
            return self._reply(op, {})
        if op == "disable":
            self.enabled = self.stopping = False
            pl.disable()
            return self._reply(op, {})
        if op in ("set_position", "set_speed", "set_output"):
            if not self.enabled:
                return self._error(3)
            v = next(iter(vals.values()))
            self.setpoints += 1
            if op == "set_position":
                pl.write_setpoint(Setpoint(position=v / self.k_pos))
            elif op == "set_speed":
                pl.write_setpoint(Setpoint(speed=v / self.k_speed))
            else:
                pl.write_setpoint(Setpoint(output=v / self.k_out))
            if self.advance == "setpoint":
                pl.sync()
            return self._reply(op, {"echo": v})
        return self._error(1)

    # -- the quick stop and the watchdog ---------------------------------------------------------
    def quick_stop(self) -> None:
        """Stop on the drive's own velocity loop, torque limited, then disable (CiA 402 quick stop
        option 2); setpoints are refused from now on."""
        was_moving = self.enabled or self.stopping
        self.enabled = False
        if not was_moving:
            self.plant.disable()
            return
        self.stopping = True
        if self.advance == "setpoint":        # no setpoint will advance the clock: stop now
            for _ in range(int(10.0 / self.period) + 1):
                if not self.stopping:
                    break
                self._stop_cycle()

    def _quick_stop_step(self) -> None:
        """One position period of the quick stop: the velocity loop's proportional part to zero
        speed, torque limited. No integral part: the speed decays without reversing (an integral
        wound up while braking would drive the axis back past where the stop began)."""
        pl = self.plant
        n = pl.plant.n
        kp = pl.ctrl.kp
        for _ in range(pl.ctrl.substeps):
            u = -kp * pl.x[n] * pl.ctrl.speed_scale
            pl.step_output(max(-self.tmax, min(self.tmax, u)))

    def _stop_cycle(self) -> None:
        self._quick_stop_step()
        if abs(self.plant.x[self.plant.plant.n]) < STANDSTILL:
            self.stopping = False
            self.plant.disable()

    def check_watchdog(self, now: float | None = None) -> bool:
        """Trip (quick stop, fault 1) when the host has been silent longer than the watchdog time
        while the drive was enabled; True when it tripped now."""
        now = time.perf_counter() if now is None else now
        if self.enabled and self.watchdog > 0 and now - self.last_valid > self.watchdog:
            fb = self.plant.read_feedback()
            self.watchdog_trip = {"t": now, "silent": now - self.last_valid, "x": fb.x_table, "x_motor": fb.x_motor,
                                  "v": fb.v_motor, "setpoints": self.setpoints}
            self.fault = 1
            self.drain_pending = True         # what waits on the line is stale: the loop drops it
            self.quick_stop()
            return True
        return False

    def tick(self) -> None:
        now = time.perf_counter()
        self.check_watchdog(now)
        if self.advance == "wall":
            n = 0
            while now >= self.t_next and n < 100:
                if self.stopping:
                    self._stop_cycle()
                else:
                    self.plant.sync()
                self.t_next += self.period
                n += 1
            if now >= self.t_next:
                self.t_next = now + self.period


def _drain(fd: int) -> int:
    """Read and drop everything waiting on ``fd``; the number of bytes dropped."""
    n = 0
    while select.select([fd], [], [], 0)[0]:
        try:
            data = os.read(fd, 4096)
        except OSError:
            break
        if not data:
            break
        n += len(data)
    return n


def serve(cfg, plant, conn=None, faults=(), advance: str = "setpoint", announce=None, watchdog: float = 0.0) -> None:
    """Run the drive, its shaft the model ``plant``, on a new pseudo-terminal until ``conn`` says stop
    (or the port vanishes); ``announce(path)`` is told the slave's path; ``watchdog`` (s) is the
    drive's parameter until the host's watchdog command sets it."""
    drive = _Drive(cfg, plant, advance, watchdog=watchdog)
    drive.faults = [dict(f) for f in faults]
    master, slave = os.openpty()
    tty.setraw(slave)
    tty.setraw(master)
    os.set_blocking(master, False)      # a read never waits: the loop keeps its clock
    path = os.ttyname(slave)
    if conn is not None:
        conn.send(path)
    if announce is not None:
        announce(path)
    eol = drive.cs.line_ending
    buf = bytearray()
    watch = [master] + ([conn] if conn is not None else [])
    try:
        while True:
            r = select.select(watch, [], [], 0.0005)[0]
            # the watchdog first: after a freeze, what waits on the line was sent to a drive that
            # could not look; the drive stops and drops it unread
            drive.check_watchdog()
            if drive.drain_pending:        # tripped here, or in the last tick
                drive.drain_pending = False
                buf.clear()
                drive.discarded += _drain(master)
                r = [x for x in r if x is not master]
            if conn is not None and conn in r:
                try:
                    msg = conn.recv()
                except EOFError:
                    return
                if msg[0] == "stop":
                    return
                if msg[0] == "inject":
                    drive.faults.append(dict(msg[1]))
                if msg[0] == "state":
                    conn.send({"enabled": drive.enabled, "fault": drive.fault, "commands": drive.commands,
                               "x": float(drive.plant.x[0]), "v": float(drive.plant.x[drive.plant.plant.n]),
                               "fired": list(drive.fired), "stopped": drive.stopped,
                               "stopping": drive.stopping, "setpoints": drive.setpoints,
                               "discarded": drive.discarded, "watchdog_trip": drive.watchdog_trip,
                               "x_table": float(drive.plant.read_feedback().x_table)})
            if master in r:
                try:
                    data = os.read(master, 4096)
                except OSError:          # no slave open, or nothing after all: nothing to read
                    data = b""
                buf += data
                while True:
                    i = buf.find(eol)
                    if i < 0:
                        if len(buf) > 4096:
                            buf.clear()
                        break
                    line = bytes(buf[:i + len(eol)])
                    del buf[:i + len(eol)]
                    reply = drive.handle(line)
                    if drive.vanish:
                        return
                    if reply:
                        try:
                            os.write(master, reply)
                        except BlockingIOError:     # nobody reads the line: the reply is lost
                            pass
            drive.tick()
    finally:
        for fd in (master, slave):
            try:
                os.close(fd)
            except OSError:
                pass


def _child(cfg, plant, conn, faults, advance, watchdog):
    try:
        serve(cfg, plant, conn, faults, advance, watchdog=watchdog)
    except KeyboardInterrupt:
        pass


class SimulatedSerialDrive:
    """The simulated drive in a child process, its shaft the model ``plant``
    (``hil.plant_config.plant_from_config(cfg)``). ``port`` is the pseudo-terminal to open."""

    def __init__(self, cfg, plant, faults=(), advance: str = "setpoint", watchdog: float = 0.0):
        try:
            ctx = mp.get_context("fork")
        except ValueError:
            ctx = mp.get_context()
        self._conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_child, args=(cfg, plant, child, list(faults), advance, watchdog),
                                daemon=True)
        self.proc.start()
        if not self._conn.poll(60):
            self.proc.kill()
            raise RuntimeError("the simulated serial drive did not start")
        self.port = self._conn.recv()

    def inject(self, kind: str, count: int = 1, after: int = 0, op: str | None = None) -> None:
        if kind not in FAULTS:
            raise ValueError(f"unknown fault {kind!r}")
        self._conn.send(("inject", {"kind": kind, "count": count, "after": after, "op": op}))

    def state(self) -> dict:
        self._conn.send(("state",))
        return self._conn.recv() if self._conn.poll(5) else {}

    @property
    def alive(self) -> bool:
        return self.proc.is_alive()

    def stop(self) -> None:
        try:
            if self.proc.is_alive():
                self._conn.send(("stop",))
        except (OSError, BrokenPipeError):
            pass
        self.proc.join(5)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join(5)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
        return False

