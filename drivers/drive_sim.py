"""A simulated CiA 402 servo drive on a CAN bus: a ``canopen`` LocalNode with the object dictionary
of config/cia402_generic.eds, answering SDO (canopen's server), NMT (canopen's NMT slave), SYNC,
PDO, heartbeat and EMCY. Its shaft is the sim_plant model (drivers.sim.SimulatedPlant), advanced
one cycle per SYNC, closing in the drive the loops the mode of operation gives it (CSP: both,
CSV: velocity, CST: none).

Time: ``lockstep=True`` (the tests, the in-process benchmarks) makes the drive's clock the SYNC
count, heartbeats included, so that runs are deterministic; ``lockstep=False`` (a separate
process, ``hil drive-sim``) produces heartbeats on the wall clock, and keeps the shaft moving on
its own clock when SYNCs stop (the link died: the drive-side guards must stop it).

Drive-side guards (set by the host over SDO at start-up): heartbeat consumer 0x1016 with the
abort-connection option 0x6007, following-error window 0x6065/0x6066, software position limits
0x607D, max torque 0x6072.

Fault injection (:meth:`DriveSim.inject`): ``emcy`` (a drive fault: EMCY + FAULT state),
``heartbeat_loss``, ``frozen_encoder``, ``late_pdo``, ``missing_pdo``, ``following_error``.
"""
from __future__ import annotations

import math
import struct
import threading
import time
from pathlib import Path

import canopen
import numpy as np

from hil.control import new_velocity_state, velocity_law

from . import cia402
from .sim import SimulatedPlant

__all__ = ["DriveSim", "DEFAULT_EDS", "EMCY_CODES", "FAULTS"]

DEFAULT_EDS = str(Path(__file__).resolve().parent.parent / "config" / "cia402_generic.eds")

# EMCY codes the simulated drive sends (CiA 301 / CiA 402)
EMCY_CODES = {
    0x2310: "continuous overcurrent",
    0x3210: "DC link overvoltage",
    0x4310: "drive overtemperature",
    0x7305: "incremental encoder 1 broken",
    0x8130: "life guard / heartbeat error (host heartbeat lost)",
    0x8611: "following error (drive-side window 0x6065)",
    0x8612: "reference limit (software position limit 0x607D)",
    0x8100: "communication error",
}
FAULTS = ("emcy", "heartbeat_loss", "frozen_encoder", "late_pdo", "missing_pdo", "following_error")

_FMT = {1: "b", 2: "h", 4: "i"}          # signed by default; unsigned objects fixed below
_UNSIGNED = {0x6040, 0x6041, 0x603F, 0x1001}


def _fmt(index: int, bits: int) -> str:
    f = _FMT[bits // 8]
    return f.upper() if index in _UNSIGNED else f


class DriveSim:
    """``DriveSim(cfg, bus=bus)`` on an existing python-can bus, or ``interface=``/``channel=``."""

    def __init__(self, cfg, bus=None, interface: str | None = None, channel: str | None = None,
                 node_id: int | None = None, eds: str | None = None, lockstep: bool = True, bitrate: int = 1000000):
        self.cfg = cfg
        self.node_id = node_id or int(cfg.get("canopen.node_id", 1))
        self.lockstep = lockstep
        self.lock = threading.RLock()
        self._own_bus = bus is None
        self.network = canopen.Network(bus)
        if bus is None:
            self.network.connect(interface=interface or cfg.get("canopen.interface", "virtual"),
                                 channel=channel or cfg.get("canopen.channel", "hil"), bitrate=bitrate)
        else:
            self.network.connect()
        eds = eds or cfg.get("canopen.eds") or DEFAULT_EDS
        self.node = canopen.LocalNode(self.node_id, canopen.import_od(eds, self.node_id))
        # heartbeats are produced here (on the SYNC clock in lockstep, else the wall clock)
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.node.add_write_callback(self._on_sdo_write)
        self.network.add_node(self.node)
        self.network.subscribe(0x80, self._on_sync)
        for n in range(4):
            self.network.subscribe(0x200 + 0x100 * n + self.node_id, self._on_rpdo)
        self.host_id = 0
        self.network.subscribe(0x700 + int(cfg.get("canopen.host_node_id", 127)), self._on_host_heartbeat)
        # drive state
        self.state = "SWITCH ON DISABLED"
        self.cw = 0
        self.mode = "csp"
        self.plant: SimulatedPlant | None = None
        self._make_plant("csp")
        self.time = 0.0
        self.syncs = 0
        self.rx: dict[tuple[int, int], int] = {}
        self.target_position = 0
        self.target_velocity = 0
        self.target_torque = 0
        self.last_host_heartbeat = 0.0
        self.host_heartbeat_seen = False
        self._next_hb = 0.0
        self.emcy_sent: list[tuple[float, int]] = []
        self.log: list[tuple[int, str]] = []          # (sync count, event)
        self.quick_stop_at: int | None = None         # sync count when the quick stop was received
        self.fault_code = 0
        self._qs_state = new_velocity_state()
        self._fe_count = 0
        self._home_offset = 0.0
        # injected faults
        self.inject_state: dict[str, float] = {}
        self._frozen: tuple | None = None
        self._missing = 0
        self._late = 0.0
        self._fe_offset = 0.0
        self._hb_dead = False
        self._last_sync_wall = time.perf_counter()
        self._stop = threading.Event()
        self._idle_thread = None
        self.node.sdo[0x6041].raw = cia402.statusword_for(self.state)
        self.node.nmt.state = "PRE-OPERATIONAL"
        self.network.send_message(0x700 + self.node_id, [0])        # boot-up
        if not lockstep:
            self._idle_thread = threading.Thread(target=self._idle_loop, daemon=True)
            self._idle_thread.start()

    # -- plant ----------------------------------------------------------------------------------
    def _make_plant(self, mode: str) -> None:
        closes = cia402.MODE_CLOSES[mode]
        new = SimulatedPlant(self.cfg, closes=closes)
        if self.plant is not None:
            new.x[:] = self.plant.x
            new._u_act = self.plant._u_act
            new._prev_position = self.plant.x[0]
        new.open()
        self.plant = new
        self.mode = mode
        self.period = new.cycle_time

    def home_at(self, position: float) -> None:
        with self.lock:
            self.plant.home_at(position)

    # scaling (the same as the host's: from the drive's own 0x608F/0x6091/0x6092)
    def _scales(self):
        d = self.node
        cpr = d.sdo[0x608F][1].raw / max(d.sdo[0x608F][2].raw, 1)
        gear = d.sdo[0x6091][1].raw / max(d.sdo[0x6091][2].raw, 1)
        feed = d.sdo[0x6092][1].raw * 1e-6 / max(d.sdo[0x6092][2].raw, 1)      # um per shaft rev
        return cpr * gear / feed, d.sdo[0x6076].raw * 1e-3                         # counts per m, rated N m

    # -- bus callbacks ---------------------------------------------------------------------------
    def _on_sdo_write(self, index, subindex, od, data):
        with self.lock:
            if index == 0x6040:
                self._controlword(struct.unpack("<H", data)[0])
            elif index == 0x6060:
                code = struct.unpack("<b", data)[0]
                for name, c in cia402.MODES.items():
                    if c == code and name != self.mode:
                        self._make_plant(name)
            elif index == 0x1016 and subindex == 1:
                self.last_host_heartbeat = self.time

    def _controlword(self, cw: int) -> None:
        prev, self.cw = self.cw, cw
        old = self.state
        new = cia402.next_state(old, cw, prev)
        if new == old:
            return
        if new == "QUICK STOP ACTIVE":
            self.quick_stop_at = self.syncs
            self._qs_state = new_velocity_state()
        if new == "OPERATION ENABLED":
            self.plant._prev_position = None
            self.plant._s = new_velocity_state()
            self.last_host_heartbeat = self.time
            self._fe_count = 0
        if old == "FAULT":
            self.fault_code = 0
            self.node.sdo[0x603F].raw = 0
            self.node.emcy.reset()
        self._set_state(new)

    def _set_state(self, new: str) -> None:
        self.log.append((self.syncs, f"{self.state} -> {new}"))
        self.state = new
        self.plant.enabled = new == "OPERATION ENABLED"
        self.node.sdo[0x6041].raw = cia402.statusword_for(new)

    def _on_rpdo(self, can_id, data, timestamp):
        n = ((can_id - self.node_id) - 0x200) // 0x100
        with self.lock:
            if self.node.nmt.state != "OPERATIONAL":
                return
            off = 0
            mapping = self.node.sdo[0x1600 + n]
            for k in range(1, mapping[0].raw + 1):
                entry = mapping[k].raw
                index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
                value = struct.unpack_from("<" + _fmt(index, bits), data, off)[0]
                off += bits // 8
                if index == 0x6040:
                    self._controlword(value)          # the controlword acts on receipt
                else:
                    self.rx[(index, sub)] = value     # targets act at the next SYNC

    def _on_host_heartbeat(self, can_id, data, timestamp):
        with self.lock:
            self.last_host_heartbeat = self.time if self.lockstep else time.perf_counter()
            self.host_heartbeat_seen = True

    def _on_sync(self, can_id, data, timestamp):
        with self.lock:
            self._last_sync_wall = time.perf_counter()
            self._cycle(from_sync=True)

    def _idle_loop(self):
        """Wall-clock mode: the shaft keeps moving when SYNCs stop (3 periods without one)."""
        while not self._stop.wait(self.period):
            with self.lock:
                if time.perf_counter() - self._last_sync_wall > 3 * self.period:
                    self._cycle(from_sync=False)
                self._heartbeat_wall()

    def _heartbeat_wall(self):
        ms = self.node.sdo[0x1017].raw
        if ms and not self._hb_dead and time.perf_counter() >= self._next_hb:
            self._next_hb = time.perf_counter() + ms * 1e-3
            self.network.send_message(0x700 + self.node_id, [self.node.nmt._state])

    def advance(self, cycles: int) -> None:
        """Let ``cycles`` periods pass without a SYNC (the link is dead; lockstep tests)."""
        for _ in range(cycles):
            with self.lock:
                self._cycle(from_sync=False)

    # -- one drive cycle -------------------------------------------------------------------------
    def _cycle(self, from_sync: bool) -> None:
        self.syncs += 1
        self.time += self.period
        cpm, rated = self._scales()
        pl = self.plant
        operational = self.node.nmt.state == "OPERATIONAL"
        # heartbeat consumer (0x1016) and the abort-connection option (0x6007)
        hb = self.node.sdo[0x1016][1].raw
        timeout = (hb & 0xFFFF) * 1e-3
        now_hb = self.time if self.lockstep else time.perf_counter()
        if timeout > 0 and self.state == "OPERATION ENABLED" and now_hb - self.last_host_heartbeat > timeout:
            self._abort_connection()
        # targets latched at SYNC, clamped to the software limits
        lo, hi = self.node.sdo[0x607D][1].raw, self.node.sdo[0x607D][2].raw
        if (0x607A, 0) in self.rx:
            self.target_position = min(max(self.rx[(0x607A, 0)], lo), hi)
        if (0x60FF, 0) in self.rx:
            self.target_velocity = self.rx[(0x60FF, 0)]
        if (0x6071, 0) in self.rx:
            self.target_torque = self.rx[(0x6071, 0)]
        tmax = self.node.sdo[0x6072].raw * 1e-3 * rated
        if self.state == "OPERATION ENABLED":
            if self.mode == "csp":
                pl.write_setpoint(_sp(position=self.target_position / cpm - self._home_offset))
            elif self.mode == "csv":
                pl.write_setpoint(_sp(speed=self.target_velocity / cpm * pl.ctrl.speed_scale))
            else:
                u = self.target_torque * 1e-3 * rated
                pl.write_setpoint(_sp(output=max(-tmax, min(tmax, u))))
            pl.sync()
        elif self.state == "QUICK STOP ACTIVE":
            self._quick_stop_step(tmax)
            if abs(pl.x[pl.plant.n]) < 1e-4:
                self._set_state("SWITCH ON DISABLED")      # quick stop option 2: stop, then disable
        else:
            pl.enabled = False
            pl.sync()
        if self._fe_offset:
            pl.x[: pl.plant.n] += 0.0                      # the load does not move: offset on the reading
        actual = self._actual(cpm, rated)
        # drive-side guards
        if self.state == "OPERATION ENABLED":
            if not (lo <= actual["pos"] <= hi):
                self.fault(0x8612)
            win = self.node.sdo[0x6065].raw
            if self.mode == "csp" and win != 0xFFFFFFFF and abs(self.target_position - actual["pos"]) > win:
                self._fe_count += 1
                if self._fe_count * self.period * 1e3 > self.node.sdo[0x6066].raw:
                    self.fault(0x8611)
            else:
                self._fe_count = 0
        # heartbeat on the drive's clock (lockstep)
        if self.lockstep:
            ms = self.node.sdo[0x1017].raw
            if ms and not self._hb_dead and self.time + 1e-12 >= self._next_hb:
                self._next_hb = self.time + ms * 1e-3
                self.network.send_message(0x700 + self.node_id, [self.node.nmt._state])
        if from_sync and operational:
            self._send_tpdos(actual)

    def _quick_stop_step(self, tmax: float) -> None:
        """The drive's own velocity loop to zero speed at full torque (quick stop option 2)."""
        pl = self.plant
        n = pl.plant.n
        steps = max(1, int(round(self.period / pl.ctrl.velocity_period)))
        for _ in range(steps):
            w = pl.x[n] * pl.ctrl.speed_scale
            u = velocity_law(pl._p, self._qs_state, 0.0, w, 0.0)
            pl._step(max(-tmax, min(tmax, u)))

    def _actual(self, cpm: float, rated: float) -> dict:
        pl = self.plant
        n, p = pl.plant.n, pl.plant
        fb = pl.read_feedback()
        x_motor, x_table, x_tip = fb.x_motor, fb.x_table, fb.x_tip
        if math.isnan(x_tip):
            x_tip = x_table
        x_motor += self._home_offset
        x_table += self._home_offset + self._fe_offset
        x_tip += self._home_offset + self._fe_offset
        if self._frozen is not None:
            x_motor, x_table, x_tip, v = self._frozen
        else:
            v = pl.x[n]
        act = {"pos": int(round(x_motor * cpm)), "vel": int(round(v * cpm)),
               "torque": int(round(pl._u_act / rated * 1e3)) if self.state == "OPERATION ENABLED" else 0,
               "table": int(round(x_table * 1e9)), "tip": int(round(x_tip * 1e9)), "v": v,
               "x": (x_motor, x_table, x_tip)}
        d = self.node
        d.sdo[0x6064].raw = act["pos"]
        d.sdo[0x606C].raw = act["vel"]
        d.sdo[0x6077].raw = max(-32768, min(32767, act["torque"]))
        d.sdo[0x60E4][1].raw = act["table"]
        d.sdo[0x60E4][2].raw = act["tip"]
        return act

    def _send_tpdos(self, actual) -> None:
        if self._missing > 0:
            self._missing -= 1
            self.log.append((self.syncs, "TPDO withheld"))
            return
        frames = []
        for n in range(4):
            comm, mapping = self.node.sdo[0x1800 + n], self.node.sdo[0x1A00 + n]
            cob = comm[1].raw
            if cob & 0x80000000 or mapping[0].raw == 0:
                continue
            data = b""
            for k in range(1, mapping[0].raw + 1):
                entry = mapping[k].raw
                index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
                value = self.node.get_data(index, sub)
                data += value[: bits // 8]
            frames.append((cob & 0x7FF, data))
        if self._late > 0:
            delay = self._late
            self._late = 0.0
            self.log.append((self.syncs, f"TPDO late by {delay * 1e3:g} ms"))
            threading.Timer(delay, lambda: [self.network.send_message(c, d) for c, d in frames]).start()
            return
        for cob, data in frames:
            self.network.send_message(cob, data)

    # -- faults ------------------------------------------------------------------------------------
    def fault(self, code: int = 0x2310, data: bytes = b"") -> None:
        """The drive faults: EMCY, error register, 0x603F, FAULT state (the shaft coasts, disabled)."""
        with self.lock:
            if self.state in ("FAULT", "FAULT REACTION ACTIVE"):
                return
            self.fault_code = code
            self.node.sdo[0x603F].raw = code
            self.node.sdo[0x1001].raw = 0x01 | (0x10 if code & 0xFF00 == 0x8100 else 0)
            self.node.emcy.send(code, self.node.sdo[0x1001].raw, data)
            self.emcy_sent.append((self.time, code))
            self._set_state("FAULT REACTION ACTIVE")
            self._set_state("FAULT")

    def _abort_connection(self) -> None:
        option = self.node.sdo[0x6007].raw
        self.log.append((self.syncs, f"host heartbeat lost, abort connection option {option}"))
        if option == 1:
            self.fault(0x8130)
        elif option == 2:
            self.node.emcy.send(0x8130, 0x11, b"")
            self._set_state("SWITCH ON DISABLED")
        elif option == 3:
            self.node.emcy.send(0x8130, 0x11, b"")
            self.quick_stop_at = self.syncs
            self._qs_state = new_velocity_state()
            self._set_state("QUICK STOP ACTIVE")

    def inject(self, fault: str, value: float | int | None = None) -> None:
        """Inject a fault: emcy [code], heartbeat_loss, frozen_encoder, late_pdo [seconds],
        missing_pdo [count], following_error [metres of offset on the position reading]."""
        with self.lock:
            self.log.append((self.syncs, f"inject {fault} {value if value is not None else ''}".strip()))
            if fault == "emcy":
                self.fault(int(value or 0x2310))
            elif fault == "heartbeat_loss":
                self._hb_dead = True
                self.node.nmt.stop_heartbeat()
            elif fault == "frozen_encoder":
                cpm, rated = self._scales()
                a = self._actual(cpm, rated)
                self._frozen = (*a["x"], a["v"])
            elif fault == "late_pdo":
                self._late = float(value or 0.05)
            elif fault == "missing_pdo":
                self._missing = int(value or 1)
            elif fault == "following_error":
                self._fe_offset = float(value if value is not None else 0.01)
            else:
                raise ValueError(f"unknown fault {fault!r} (known: {', '.join(FAULTS)})")

    def clear_injections(self) -> None:
        with self.lock:
            self._frozen, self._missing, self._late, self._fe_offset = None, 0, 0.0, 0.0
            self._hb_dead = False

    def close(self) -> None:
        self._stop.set()
        if self._idle_thread is not None:
            self._idle_thread.join(1.0)
        self.node.nmt.stop_heartbeat()
        try:
            self.network.disconnect()
        except Exception:
            pass


def _sp(position=0.0, speed=0.0, output=0.0):
    from .base import Setpoint
    return Setpoint(position=position, speed=speed, output=output)
