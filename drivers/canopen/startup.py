"""Start-up of a CiA 402 drive and a tool-tip sensor node over SDO (not real-time): the mode of
operation, scaling, limits, the drive-side guards and the PDO mapping the cycle uses.

Drive-side guards set here, so that the drive stops itself when the host or the link dies:
heartbeat consumer 0x1016 (the host produces a heartbeat) with abort-connection option 0x6007,
the SYNC consumer (0x1006 x the loss limit 0x2003 where the dictionary has it), following-error
window 0x6065/0x6066, software position limits 0x607D, max torque 0x6072, max motor speed
0x6080. Each function takes the node's SDO client and the settings; none keeps state.
"""
from __future__ import annotations

import math
import struct
import time

import canopen

from drivers.canopen import cia402
from drivers.canopen.codec import RPDO_TARGET, SYNC_ECHO, SYNC_OVERFLOW, TIP_PROFILE, TPDO_MAPS, struct_code
from drivers.errors import BackendFault, ConfigError, StopKind

__all__ = ["PdoLayout", "configure_drive", "configure_tip", "map_pdo", "sdo_retry"]


class PdoLayout:
    """What the mapping gives the cycle: the RPDO's ``struct`` (controlword + target), the TPDOs
    (COB-ID -> ``[(index, sub, bits)]``) and whether the last one carries the SYNC echo."""

    def __init__(self, rpdo: struct.Struct, tpdo: dict, echo: bool):
        self.rpdo, self.tpdo, self.echo = rpdo, tpdo, echo


def sdo_retry(fn, what: str, where: str, tries: int = 5):
    """``fn()`` retried while the SDO does not answer (a drive still booting); then BackendFault
    saying ``what`` does not answer on the bus ``where``."""
    for i in range(tries):
        try:
            return fn()
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError):
            if i == tries - 1:
                raise BackendFault(f"{what} does not answer SDO on {where}", StopKind.LINK)
            time.sleep(0.05)


def configure_tip(sdo, cfg, tip_id: int, tip_cob: int, where: str) -> float:
    """The tool-tip sensor node: its profile (CiA 406), its measuring step, TPDO1 = position value
    0x6004 on every SYNC. Returns the measuring step (m)."""
    try:
        devtype = sdo_retry(lambda: sdo[0x1000].raw, f"tip sensor node {tip_id}", where)
    except BackendFault:
        raise BackendFault(f"tip sensor node {tip_id} does not answer SDO on {where} (canopen.tip_node_id)",
                           StopKind.LINK) from None
    if devtype & 0xFFFF != TIP_PROFILE:
        raise ConfigError(f"{cfg.source}: canopen.tip_node_id: node {tip_id} is not an encoder "
                          f"(device type 0x{devtype:08X}, profile {devtype & 0xFFFF}, expected {TIP_PROFILE})")
    step = sdo[0x6005][1].raw * 1e-9
    if not step > 0:
        raise BackendFault(f"tip sensor node {tip_id}: measuring step 0x6005.1 is 0")
    sdo[0x1800][1].raw = tip_cob | 0x80000000
    sdo[0x1A00][0].raw = 0
    sdo[0x1A00][1].raw = (0x6004 << 16) | 32
    sdo[0x1A00][0].raw = 1
    sdo[0x1800][2].raw = 1
    sdo[0x1800][1].raw = tip_cob
    return step


def configure_drive(node, cfg, s) -> PdoLayout:
    """SDO configuration of the drive ``node`` with the settings ``s``
    (drivers.canopen.section.CanopenSettings): mode, scaling, limits, drive-side guards, PDO
    mapping."""
    _set_scaling_and_limits(node.sdo, cfg, s)
    _set_guards(node.sdo, cfg, s)
    return _map_pdos(node, s)


def _set_scaling_and_limits(sdo, cfg, s) -> None:
    cpm = s.counts_per_m
    sdo[0x6060].raw = cia402.MODES[s.mode]
    sdo[0x608F][1].raw = int(cfg.get("canopen.counts_per_rev", 1048576))
    sdo[0x608F][2].raw = 1
    sdo[0x6091][1].raw = int(cfg.get("canopen.gear_motor_revs", 1))
    sdo[0x6091][2].raw = int(cfg.get("canopen.gear_shaft_revs", 1))
    sdo[0x6092][1].raw = int(round((cfg.get("plant.pitch") or 1.0) * 1e6))      # um per screw revolution
    sdo[0x6092][2].raw = 1
    sdo[0x6076].raw = int(round(s.rated * 1e3))                                  # mN m
    torque = cfg.get("limits.torque") or cfg["control.output_limit"]
    sdo[0x6072].raw = min(0xFFFF, int(round(torque / s.rated * 1e3)))
    speed_rpm = cfg["limits.speed"] * cpm / cfg.get("canopen.counts_per_rev", 1048576) * 60
    sdo[0x6080].raw = int(math.ceil(speed_rpm * 1.2))
    sdo[0x607D][1].raw = int(math.floor(cfg["limits.travel_min"] * cpm))
    sdo[0x607D][2].raw = int(math.ceil(cfg["limits.travel_max"] * cpm))


def _set_guards(sdo, cfg, s) -> None:
    cpm = s.counts_per_m
    fe = cfg.get("canopen.following_error_window") or (
        1.5 * cfg["limits.following_error_table"] if "limits.following_error_table" in cfg else None)
    sdo[0x6065].raw = 0xFFFFFFFF if fe is None else int(round(fe * cpm))
    sdo[0x6066].raw = int(round(cfg.get("canopen.following_error_timeout", 0.01) * 1e3))
    sdo[0x605A].raw = 2
    sdo[0x6007].raw = int(cfg.get("canopen.abort_option", 3))
    qs_dec = cfg.get("canopen.quick_stop_deceleration")
    if qs_dec is not None:
        sdo[0x6085].raw = max(1, min(0xFFFFFFFE, int(round(qs_dec * cpm))))
    sdo[0x1016][1].raw = (s.host_id << 16) | int(round(cfg.get("canopen.drive_heartbeat_timeout", 0.35) * 1e3))
    sdo[0x1017].raw = int(round(cfg.get("canopen.heartbeat", 0.1) * 1e3))
    sdo[0x1006].raw = int(round(s.cycle_time * 1e6))
    us = s.cycle_time * 1e6
    if abs(us / 1000 - round(us / 1000)) < 1e-9 and us / 1000 <= 255:
        sdo[0x60C2][1].raw, sdo[0x60C2][2].raw = int(round(us / 1000)), -3
    else:
        sdo[0x60C2][1].raw, sdo[0x60C2][2].raw = min(255, int(round(us / 100))), -4


def _map_pdos(node, s) -> PdoLayout:
    """PDO mapping (disable, map, enable): RPDO1 = controlword + the mode's target; the TPDOs of
    :data:`TPDO_MAPS` less what the drive lacks (the tip input, the SYNC echo)."""
    sdo = node.sdo
    rmap = [(0x6040, 0, 16), RPDO_TARGET[s.mode]]
    rpdo = struct.Struct("<" + "".join(struct_code(i, b) for i, _, b in rmap))
    map_pdo(sdo, s.node_id, 0x1400, 0x1600, 0x200, 0, rmap)
    echo = SYNC_ECHO in node.object_dictionary
    tmaps = [list(m) for m in TPDO_MAPS]
    if not s.tip:
        tmaps[2] = [e for e in tmaps[2] if e[0] != 0x60E4]
    if not echo:
        tmaps[2] = [e for e in tmaps[2] if e[0] != SYNC_ECHO]
    else:
        sdo[0x1019].raw = SYNC_OVERFLOW
    if 0x2003 in node.object_dictionary:
        # the SYNC consumer: a drive-specific object (this EDS's 0x2003); on another drive the
        # manufacturer's own (docs/guide/canopen.md)
        sdo[0x2003].raw = s.sync_loss_cycles
    tmaps = [m for m in tmaps if m]
    tpdo = {}
    for n in range(4):
        entries = tmaps[n] if n < len(tmaps) else []
        map_pdo(sdo, s.node_id, 0x1800, 0x1A00, 0x180, n, entries)
        if entries:
            tpdo[0x180 + 0x100 * n + s.node_id] = entries
    return PdoLayout(rpdo, tpdo, echo)


def map_pdo(sdo, node_id: int, comm_base: int, map_base: int, cob_base: int, n: int, entries) -> None:
    """Map PDO ``n`` (disabled while it is mapped; left disabled when ``entries`` is empty),
    synchronous: sent (or applied) on every SYNC."""
    cob = cob_base + 0x100 * n + node_id
    sdo[comm_base + n][1].raw = cob | 0x80000000
    sdo[map_base + n][0].raw = 0
    for k, (index, sub, bits) in enumerate(entries, 1):
        sdo[map_base + n][k].raw = (index << 16) | (sub << 8) | bits
    sdo[map_base + n][0].raw = len(entries)
    sdo[comm_base + n][2].raw = 1                          # synchronous, every SYNC
    if entries:
        sdo[comm_base + n][1].raw = cob
