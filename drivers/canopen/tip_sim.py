"""A simulated tool-tip sensor on its own CANopen node: a CiA 406-like absolute linear encoder
(drivers/canopen/eds/tip_encoder_cia406.eds) on the simulated drive's bus, its position value
0x6004 the plant's tip mass, sent in its TPDO1 on every SYNC (the drive calls
:meth:`TipSensorSim.on_sync`, real-time). Its mapping is read once after an SDO write (codec).
"""
from __future__ import annotations

import struct

import canopen

from drivers.canopen import eds as eds_files
from drivers.canopen.codec import pdo_plan, store, stored_bytes
from drivers.errors import ConfigError

__all__ = ["TipSensorSim"]


class TipSensorSim:
    """A tool-tip sensor on its own CANopen node: a CiA 406-like absolute linear encoder
    (drivers/canopen/eds/tip_encoder_cia406.eds) on the drive's bus. Position value 0x6004 = the plant's tip mass
    in steps of 0x6005.1 nm, plus the preset 0x6003 (written at homing: the value the sensor
    shows there); TPDO1 (0x6004) on every SYNC while OPERATIONAL, sent before the drive's TPDOs in
    the same SYNC (in lockstep, the host's SDO barrier covers it too). It answers SDO and NMT
    (canopen's LocalNode); its heartbeat (0x1017) is not produced."""

    def __init__(self, drive, node_id: int, eds: str | None = None):
        if node_id == drive.node_id:
            raise ConfigError(f"{drive.cfg.source}: canopen.tip_node_id: {node_id} is the drive's node id")
        self.drive = drive
        self.node_id = node_id
        self.node = canopen.LocalNode(node_id, eds_files.load(drive.cfg, "canopen.tip_eds", node_id, eds))
        self.node.add_write_callback(self._on_sdo_write)
        drive.network.add_node(self.node)
        self._plan = None            # (step m, COB-ID or None, mapping), cached until an SDO write
        self.offset = 0.0            # m, set by the preset
        self.missing = 0
        self.sent = 0
        self._last_tip = 0.0
        self.node.nmt.state = "PRE-OPERATIONAL"
        drive.network.send_message(0x700 + node_id, [0])        # boot-up

    def _step(self) -> float:
        return max(1, self.node.sdo[0x6005][1].raw) * 1e-9

    def _on_sdo_write(self, index, subindex, od, data):
        self._plan = None
        if index == 0x6003:              # preset: the present position shows this value from now on
            preset = struct.unpack("<i", data)[0]
            self.offset = preset * self._step() - self._last_tip
            self.node.sdo[0x6004].raw = preset

    def on_sync(self, x_tip: float) -> None:
        self._last_tip = x_tip
        if self._plan is None:
            self._plan = (self._step(), *pdo_plan(self.node, 0x1800, 0x1A00, 0))
        step, cob, entries = self._plan
        value = int(round((x_tip + self.offset) / step))
        store(self.node, 0x6004, 0, "i", max(-2 ** 31, min(2 ** 31 - 1, value)))
        if self.node.nmt.state != "OPERATIONAL" or cob is None:
            return
        if self.missing > 0:
            self.missing -= 1
            self.drive.log.append((self.drive.syncs, "tip sensor TPDO withheld"))
            return
        data = b"".join(stored_bytes(self.node, index, sub)[:nbytes] for index, sub, nbytes, _ in entries)
        self.sent += 1
        self.drive.network.send_message(cob, data)
