"""What the CANopen backend reads of the ``[canopen]`` configuration section: :class:`CanopenSettings`,
read and checked once when the backend is built: nothing in the cycle looks a key up by its name.
The section's keys are data beside it (:data:`SECTION`, :mod:`drivers.canopen.schema`); hil.config
lists and validates them with the other sections, and the reference in the docs is generated from it.

Mistakes are :class:`~hil.errors.ConfigError` naming the key and the file. The speed scale (rad/s
of the motor per m/s of the load) comes from the screw's pitch, as hil.plant_config sets it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import can

from drivers.canopen import cia402
from drivers.canopen.codec import SYNC_OVERFLOW
from drivers.canopen.schema import SECTION
from drivers.errors import ConfigError

__all__ = ["SECTION", "CanopenSettings"]

@dataclass(frozen=True)
class CanopenSettings:
    """What the backend uses of a configuration, the keyword overrides of the backend applied.
    Built once (not real-time); read in the cycle as plain attributes."""

    mode: str                   # csp, csv or cst (canopen.mode)
    closes: str                 # the loops the drive closes (drivers.base)
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
