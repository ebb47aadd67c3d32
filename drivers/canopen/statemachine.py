"""The host's side of the CiA 402 power state machine and homing, over SDO, on the tables of
drivers.canopen.cia402: the way up to OPERATION ENABLED, waiting for a quick stop (or fault
reaction) to end while the SYNC goes on, SHUTDOWN, fault reset, and homing methods 35/37.

Not real-time, all of it: it runs before the cycle (enable, homing) or after it (the stop, the
shutdown), on canopen's notifier thread (the link's cyclic phase ended first). ``backend`` is the
:class:`~drivers.canopen.backend.CanopenBackend` whose node, link and SYNC it uses.
"""
from __future__ import annotations

import math
import time

import canopen

from drivers.canopen import cia402
from drivers.canopen.link import one_line
from drivers.errors import BackendFault

__all__ = ["DriveStateMachine", "fault_text"]

_STOPPING = ("QUICK STOP ACTIVE", "FAULT REACTION ACTIVE")


def fault_text(emcy_log, error_code: int) -> str:
    """What the drive's fault is: its last EMCY, else its error code 0x603F."""
    if emcy_log:
        e = emcy_log[-1]
        return f"EMCY {e['code']} {e['text']}"
    return f"error code 0x{error_code:04X} {cia402.emcy_text(error_code)}" if error_code else "no EMCY"


class DriveStateMachine:
    """The drive's power state, read and commanded over SDO."""

    def __init__(self, backend):
        self.be = backend

    def state(self, tries: int = 3) -> str:
        """The CiA 402 state from the statusword 0x6041 (an upload). Read again, at most ``tries``
        times, on an answer that is not the upload's: every client on the drive's one SDO server
        channel hears every answer (CiA 301 allows one client; ``hil status`` beside a running move
        is a second), so a download answer of the other client's can arrive first ("Unexpected
        response 0x60"). A read has no effect to repeat."""
        self.be.link.stop_cycling()
        for _ in range(tries - 1):
            try:
                return cia402.state_from_statusword(self.be.node.sdo[0x6041].raw)
            except canopen.SdoCommunicationError:
                time.sleep(0.005)
        return cia402.state_from_statusword(self.be.node.sdo[0x6041].raw)

    def enable(self) -> None:
        """Up to OPERATION ENABLED (at most 12 steps), or BackendFault: a drive in FAULT (``hil
        reset`` first) or one stuck on the way."""
        sdo = self.be.node.sdo
        for _ in range(12):
            st = self.state()
            if st == "OPERATION ENABLED":
                return
            cmd = cia402.NEXT_TO_ENABLE[st]
            if cmd == "FAULT RESET":
                raise BackendFault(f"drive in FAULT ({self.be.fault_text()}); run 'hil reset' first")
            if cmd is not None:
                sdo[0x6040].raw = cia402.COMMANDS[cmd]
            else:
                time.sleep(0.01)
        raise BackendFault(f"drive did not reach OPERATION ENABLED (stuck in {self.state()})")

    def wait_stopped(self, cw: int, max_cycles: int | None = None) -> str:
        """Keep the SYNC going (the drive's clock in lockstep) until the drive has finished its
        quick stop or fault reaction; its state is read over SDO (TPDOs may be what failed). A
        drive still in OPERATION ENABLED did not get the RPDO: the stop (controlword ``cw``) is
        commanded again over SDO. Returns the state it ended in, or "unreachable"."""
        be = self.be
        s = be.settings
        limit = max_cycles or int(math.ceil(s.stop_timeout / s.cycle_time))
        be.link.stop_cycling()
        sdo, st, errors = be.node.sdo, "unknown", 0
        for _ in range(limit):
            be.send_sync()
            if not s.lockstep:
                time.sleep(s.cycle_time)
            try:
                st = cia402.state_from_statusword(sdo[0x6041].raw)
                if st == "OPERATION ENABLED":
                    be.events.append(f"cycle {be.syncs}: stop repeated over SDO")
                    sdo[0x6040].raw = cw
                    continue
            except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
                errors += 1
                be.events.append(f"cycle {be.syncs}: no SDO answer while stopping ({one_line(exc)})")
                if errors >= 3:
                    be.events.append("drive unreachable: the drive-side guards (0x1016/0x6007) stop it")
                    return "unreachable"
                continue
            if st not in _STOPPING:
                return st
        return st

    def shutdown(self, stopping: bool, cw: int, stopped: str) -> str:
        """Let a quick stop (or fault reaction) finish where ``stopping``, then SHUTDOWN (READY TO
        SWITCH ON: no torque) unless the drive was found unreachable (``stopped``, the state an
        earlier stop ended in). Returns the state the stop ended in."""
        be = self.be
        try:
            if stopping:
                stopped = self.wait_stopped(cw)
            if stopped != "unreachable":
                st = self.state()
                if st in ("OPERATION ENABLED", "SWITCHED ON", "QUICK STOP ACTIVE"):
                    be.node.sdo[0x6040].raw = cia402.COMMANDS["SHUTDOWN"]
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
            be.events.append(f"disable: {one_line(exc)}")
        return stopped

    def fault_reset(self) -> str:
        self.be.link.stop_cycling()
        sdo = self.be.node.sdo
        sdo[0x6040].raw = 0x00
        sdo[0x6040].raw = cia402.COMMANDS["FAULT RESET"]
        sdo[0x6040].raw = 0x00
        return self.state()

    def home(self, offset: float, method: int, timeout: float) -> dict:
        """Homing mode (6), method 37 (or 35): the present position becomes ``offset`` (m, 0x607C).
        Enables the drive, starts homing (controlword bit 4), waits for homing attained
        (statusword bit 12), shuts down and returns to the configured mode."""
        be = self.be
        s = be.settings
        sdo = be.node.sdo
        sdo[0x6098].raw = int(method)
        sdo[0x607C].raw = int(round(offset * s.counts_per_m))
        sdo[0x6060].raw = cia402.HOMING_MODE
        ok, err = False, False
        try:
            be.enable()
            be.link.stop_cycling()              # homing runs over SDO
            sdo[0x6040].raw = cia402.COMMANDS["ENABLE OPERATION"] | 0x10
            ok, err = self._wait_homed(timeout)
            sdo[0x6040].raw = cia402.COMMANDS["ENABLE OPERATION"]
        finally:
            be.disable()
            sdo[0x6060].raw = cia402.MODES[s.mode]
        pos = sdo[0x6064].raw / s.counts_per_m
        if err or not ok:
            raise BackendFault(f"homing method {method} {'failed (statusword bit 13)' if err else 'timed out'}")
        out = {"homed": True, "method": method, "position_m": pos}
        if be.tip_node is not None:         # the axis at rest: the tip sensor shows the homed position too
            be.tip_node.sdo[0x6003].raw = int(round(pos / be.tip_step))
            out["tip_m"] = be.tip_node.sdo[0x6004].raw * be.tip_step
        return out

    def _wait_homed(self, timeout: float) -> tuple[bool, bool]:
        """(homing attained, homing error) once either shows, SYNCs going meanwhile; both False
        after ``timeout``."""
        be = self.be
        sdo = be.node.sdo
        bits = cia402.SW_BITS
        ok, err = False, False
        t_end = time.perf_counter() + timeout
        while time.perf_counter() < t_end:
            sw = sdo[0x6041].raw
            err = bool(sw & (1 << bits["following_error"]))
            ok = bool(sw & (1 << bits["setpoint_acknowledge"]) and sw & (1 << bits["target_reached"]))
            if ok or err:
                break
            be.send_sync()
            if not be.settings.lockstep:
                time.sleep(be.settings.cycle_time)
        return ok, err
