"""The ``[canopen]`` configuration section (the keys as data; the reference in the docs is generated
from :data:`SECTION`) and :class:`CanopenSettings`, what the backend reads of a configuration, read
and checked once when the backend is built: nothing in the cycle looks a key up by its name.

Mistakes are :class:`~hil.errors.ConfigError` naming the key and the file. The speed scale (rad/s
of the motor per m/s of the load) comes from the screw's pitch, as hil.plant_config sets it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import can

from hil.config import Field, register_section
from hil.drivers.canopen import cia402
from hil.drivers.canopen.codec import SYNC_OVERFLOW
from hil.errors import ConfigError

__all__ = ["SECTION", "CanopenSettings"]

SECTION = {
    "canopen.interface": Field("str", "python-can interface (socketcan, pcan, kvaser, slcan, socketcand, virtual...)",
                               default="virtual"),
    "canopen.channel": Field("str", "python-can channel (can0, /dev/ttyACM0, a virtual channel name...)",
                             default="hil"),
    "canopen.bitrate": Field("int", "CAN bit rate (bit/s)", default=1000000, nonnegative=True),
    "canopen.host": Field("str", "socketcand server address (127.0.0.1 only for the simulated drive)",
                          default="127.0.0.1"),
    "canopen.port": Field("int", "socketcand server port", default=29536, nonnegative=True),
    "canopen.node_id": Field("int", "the drive's node id (1..127)", default=1, positive=True, maximum=127),
    "canopen.host_node_id": Field("int", "the node id of the host's heartbeat (1..127)", default=127, positive=True,
                                  maximum=127),
    "canopen.eds": Field("str", "object dictionary of the drive (EDS); default hil/drivers/canopen/eds/cia402_generic.eds",
                         default=""),
    "canopen.mode": Field("str", "mode of operation: csp (the drive closes both loops), csv (velocity), cst "
                          "(torque: the host closes both)", default="csp", choices=("csp", "csv", "cst")),
    "canopen.counts_per_rev": Field("int", "motor encoder counts per motor revolution (0x608F)", default=1048576,
                                    positive=True),
    "canopen.gear_motor_revs": Field("int", "gear ratio: motor revolutions (0x6091.1)", default=1, positive=True),
    "canopen.gear_shaft_revs": Field("int", "gear ratio: screw revolutions (0x6091.2)", default=1, positive=True),
    "canopen.rated_torque": Field("torque", "motor rated torque (0x6076); torques go in per mille of it",
                                  default=10.0, positive=True),
    "canopen.tip_sensor": Field("bool", "the drive sends a tool-tip position 0x60E4.2 (a second encoder input)",
                                default=True),
    "canopen.tip_node_id": Field("int", "node id of a separate tool-tip sensor (CiA 406-like encoder, position "
                                 "0x6004 in TPDO1 on every SYNC); 0: none (the tip is the drive's 0x60E4.2 "
                                 "where canopen.tip_sensor, else not measured)", default=0, nonnegative=True,
                                 maximum=127),
    "canopen.tip_eds": Field("str", "object dictionary of the tip sensor node; default "
                             "hil/drivers/canopen/eds/tip_encoder_cia406.eds", default=""),
    "canopen.heartbeat": Field("time", "drive's heartbeat producer time (0x1017)", default=0.1, positive=True),
    "canopen.heartbeat_timeout": Field("time", "host: the drive's heartbeat is lost after this", default=0.35,
                                       positive=True),
    "canopen.host_heartbeat": Field("time", "host's heartbeat period", default=0.1, positive=True),
    "canopen.drive_heartbeat_timeout": Field("time", "drive: the host's heartbeat is lost after this (0x1016)",
                                             default=0.35, positive=True),
    "canopen.abort_option": Field("int", "0x6007, the drive's action when the host's heartbeat or SYNC is lost: "
                                  "0 none, 1 fault, 2 disable voltage, 3 quick stop", default=3, nonnegative=True,
                                  maximum=3),
    "canopen.sync_timeout": Field("time", "drive: the SYNC is lost after this long without one (SYNC consumer: "
                                  "0x1006 x the loss limit 0x2003 in cycles, rounded up); then 0x6007 acts; 0: off",
                                  default=0.1, nonnegative=True),
    "canopen.quick_stop_deceleration": Field("acceleration", "drive: quick-stop deceleration (0x6085); default: "
                                             "what the drive derives (the simulated drive: 80 % of what "
                                             "the torque limit gives the axis)", default=None, positive=True),
    "canopen.following_error_window": Field("length", "drive-side following-error window (0x6065) on the motor "
                                            "position; default 1.5 x limits.following_error_table", default=None,
                                            positive=True),
    "canopen.following_error_timeout": Field("time", "drive-side following-error time out (0x6066)",
                                             default=0.01, nonnegative=True),
    "canopen.pdo_timeout": Field("time", "lockstep: how long the SDO barrier after a SYNC may take before the "
                                 "drive counts as gone (a loaded machine: generous)", default=5.0, positive=True),
    "canopen.pdo_miss_limit": Field("int", "consecutive cycles without TPDO before 'lost communication'",
                                    default=2, positive=True),
    "canopen.lockstep": Field("bool", "drive time advances with SYNC only (a simulated drive in this process)",
                              default=False),
    "canopen.switch_interval": Field("time", "real-time runs: the interpreter's thread switch interval at most this "
                                     "(process-wide; Python's default 5 ms delays the receive threads)",
                                     default=1e-4, positive=True),
    "canopen.connect_timeout": Field("time", "socketcand: how long the server may take to accept and greet",
                                     default=2.0, positive=True),
    "canopen.sdo_timeout": Field("time", "SDO response timeout", default=0.5, positive=True),
    "canopen.stop_timeout": Field("time", "how long the host keeps the SYNC going while the drive finishes a "
                                  "quick stop", default=2.0, positive=True),
}


def _lookup(key: str):
    return SECTION.get(key)


register_section("canopen", _lookup, lambda: list(SECTION))


@dataclass(frozen=True)
class CanopenSettings:
    """What the backend uses of a configuration, the keyword overrides of the backend applied.
    Built once (not real-time); read in the cycle as plain attributes."""

    mode: str                   # csp, csv or cst (canopen.mode)
    closes: str                 # the loops the drive closes (hil.drivers.base)
    cycle_time: float           # s: the SYNC period (the velocity period in cst, else the position period)
    lockstep: bool              # the drive's time advances with the SYNC only
    interface: str
    channel: str
    node_id: int
    host_id: int                # the node id of the host's heartbeat
    counts_per_m: float         # motor encoder counts per metre of the load
    rated: float                # N m: the rated torque, the unit of 0x6071/0x6077 (per mille)
    speed_scale: float          # controller speed units per m/s (rad/s per m/s on a rotary axis, else 1)
    tip_id: int                 # the tool-tip sensor's node (0: none)
    tip: bool                   # the drive sends the tip as 0x60E4.2 (no tip node)
    sync_loss_cycles: int       # the drive's SYNC consumer, in cycles (0: off)
    pdo_miss_limit: int
    heartbeat_timeout: float
    host_heartbeat: float
    pdo_timeout: float
    stop_timeout: float
    stop_how: str               # supervisor.stop: quick_stop or disable
    switch_interval: float

    @classmethod
    def from_config(cls, cfg, has_bus: bool = False, interface: str | None = None, channel: str | None = None,
                    mode: str | None = None, lockstep: bool | None = None,
                    node_id: int | None = None) -> "CanopenSettings":
        """The settings of ``cfg`` (``has_bus``: the caller brings its own python-can bus, so the
        interface is not checked); the keywords override the config's keys."""
        mode = mode or cfg.get("canopen.mode", "csp")
        if mode not in cia402.MODES:
            raise ConfigError(f"{cfg.source}: canopen.mode: expected one of {', '.join(cia402.MODES)}, "
                              f"got {mode!r}")
        tv, tp = cfg["control.velocity_period"], cfg["control.position_period"]
        if mode == "cst" and tv > 1e-3 + 1e-12:
            raise ConfigError(f"{cfg.source}: canopen.mode cst: the host's velocity loop must run at 1 ms or "
                              f"faster with its own gains (control.velocity_period is {tv * 1e3:g} ms): the "
                              f"velocity PI sampled at the position period is unstable")
        cycle_time = tv if mode == "cst" else tp
        interface = interface or cfg.get("canopen.interface", "virtual")
        if not has_bus and interface not in can.VALID_INTERFACES:
            raise ConfigError(f"{cfg.source}: canopen.interface: unknown python-can interface {interface!r} "
                              f"(known: {', '.join(sorted(can.VALID_INTERFACES))})")
        node_id = node_id or int(cfg.get("canopen.node_id", 1))
        pitch = cfg.get("plant.pitch") or 1.0
        counts_per_m = (cfg.get("canopen.counts_per_rev", 1048576) * cfg.get("canopen.gear_motor_revs", 1)
                        / cfg.get("canopen.gear_shaft_revs", 1) / pitch)
        tip_id = int(cfg.get("canopen.tip_node_id", 0) or 0)
        sync_timeout = float(cfg.get("canopen.sync_timeout", 0.1))
        sync_loss_cycles = int(math.ceil(sync_timeout / cycle_time - 1e-9)) if sync_timeout > 0 else 0
        if sync_loss_cycles > SYNC_OVERFLOW // 2:
            raise ConfigError(f"{cfg.source}: canopen.sync_timeout: {sync_timeout * 1e3:g} ms is "
                              f"{sync_loss_cycles} cycles; expected at most {SYNC_OVERFLOW // 2} (half the "
                              f"SYNC counter's range, so that the drive can tell a stale SYNC from a fresh one)")
        if tip_id and tip_id == node_id:
            raise ConfigError(f"{cfg.source}: canopen.tip_node_id: {tip_id} is the drive's node id")
        return cls(
            mode=mode, closes=cia402.MODE_CLOSES[mode], cycle_time=cycle_time,
            lockstep=bool(cfg.get("canopen.lockstep", False) if lockstep is None else lockstep),
            interface=interface, channel=channel or cfg.get("canopen.channel", "hil"), node_id=node_id,
            host_id=int(cfg.get("canopen.host_node_id", 127)), counts_per_m=counts_per_m,
            rated=float(cfg.get("canopen.rated_torque", 10.0)), speed_scale=speed_scale(cfg), tip_id=tip_id,
            tip=bool(cfg.get("canopen.tip_sensor", True)) and not tip_id, sync_loss_cycles=sync_loss_cycles,
            pdo_miss_limit=int(cfg.get("canopen.pdo_miss_limit", 2)),
            heartbeat_timeout=cfg.get("canopen.heartbeat_timeout", 0.35),
            host_heartbeat=cfg.get("canopen.host_heartbeat", 0.1),
            pdo_timeout=float(cfg.get("canopen.pdo_timeout", 5.0)),
            stop_timeout=cfg.get("canopen.stop_timeout", 2.0),
            stop_how=cfg.get("supervisor.stop", "quick_stop"),
            switch_interval=float(cfg.get("canopen.switch_interval", 1e-4)))


def speed_scale(cfg) -> float:
    """Controller speed units per m/s of the load: 2 pi / pitch (rad/s per m/s) on a rotary axis,
    1 on a linear one (hil.plant_config's rule, without building the plant)."""
    return 2.0 * math.pi / cfg["plant.pitch"] if cfg.rotary else 1.0
