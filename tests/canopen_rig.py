"""The lockstep CANopen test rig shared by the CANopen and supervisor tests: the simulated CiA 402
drive and the host backend on one private python-can virtual channel."""
import itertools

import can

from drivers.canopen.backend import CanopenBackend
from drivers.canopen.drive_sim import DriveSim
from hil import config
from hil.plant_config import plant_from_config

_ids = itertools.count()


def channel(prefix: str) -> str:
    """A virtual channel of its own for each rig (tests must not hear each other's frames)."""
    return f"{prefix}{next(_ids)}"


def rig(mode="csp", prefix="co", **ov):
    over = {"canopen.lockstep": True}
    if mode == "cst":
        over["control.velocity_period"] = "1 ms"      # the host's velocity loop in torque mode
    over.update(ov)
    cfg = config.load("config/paper_bench_canopen.toml", over)
    ch = channel(prefix)
    sim = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel=ch), lockstep=True)
    be = CanopenBackend(cfg, bus=can.Bus(interface="virtual", channel=ch), mode=mode, lockstep=True)
    return cfg, sim, be
