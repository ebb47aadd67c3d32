"""A simulated drive loads every compiled function of its cycle before it serves (issue 27's
benchmark met it): the CANopen drive starts disabled, its plant coasts, and a coasting cycle first
compiled inside ``serve`` (seconds on a fresh install, with no numba cache) held up the greeting
of the first socketcand client past its 2 s (``canopen.connect_timeout``).

Each check runs in a fresh interpreter, where nothing is loaded yet: after the drive's
construction, every dispatcher of the plant's cycle has its compiled code (numba's own record of
it, ``Dispatcher.signatures``), and the plant's state is as before the warm-up. And a whole ``hil
move`` on each real-axis path (host and simulated drive in one process) loads nothing compiled
after its first cycle has begun: the drive's first feedback loaded ``quantize`` inside the cycle
before (a compilation there on a fresh install, with the loop's watchdog running)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

CYCLE = ("drive_cycle", "coast_cycle", "torque_cycle", "drive_feedback")

PROBE = r"""
import json, sys
import numpy as np
from hil import config
import drivers.control as control
import drivers.sim as sim
from hil.plant_config import plant_from_config
kind = sys.argv[1]
cfg = config.load("paper_bench_canopen.toml" if kind == "canopen" else "serial_ascii_example.toml")
if kind == "canopen":
    import can
    from drivers.canopen.drive_sim import DriveSim
    drive = DriveSim(cfg, plant_from_config(cfg), bus=can.Bus(interface="virtual", channel="warm_up_probe"), lockstep=True)
    plant = drive.plant
elif kind == "serial":
    from drivers.serial.drive_sim import _Drive
    plant = _Drive(cfg, plant_from_config(cfg)).plant
else:
    import copy
    from drivers.base import Setpoint
    # a plant in motion (enabled, a setpoint ahead, its loops' state filled), and its twin
    plant = sim.SimulatedPlant(cfg, plant_from_config(cfg), closes=kind)
    plant.home_at(0.01)
    plant.enable()
    for k in range(40):
        plant.write_setpoint(Setpoint(position=0.01 + 1e-6 * k * k, speed=0.05 * k, output=0.02 * k))
        plant.sync()
    twin = copy.deepcopy(plant)
    objects = {k: id(v) for k, v in vars(plant).items() if isinstance(v, np.ndarray)}
    plant.warm_up()
    def equal(a, b):
        if isinstance(a, np.ndarray):
            return np.array_equal(a, b, equal_nan=True)
        return a == b or (a != a and b != b)
    kept = all(equal(v, vars(twin)[k]) for k, v in vars(plant).items()
               if isinstance(v, (np.ndarray, float, int, bool, type(None), Setpoint)))
    kept = kept and all(id(vars(plant)[k]) == i for k, i in objects.items())
    # and the next cycles are the twin's, bit for bit
    for k in range(40, 80):
        for p in (plant, twin):
            p.write_setpoint(Setpoint(position=0.01 + 1e-6 * k * k, speed=0.05 * k, output=0.02 * k))
            p.sync()
    fa, fb = vars(plant.read_feedback()), vars(twin.read_feedback())
    kept = kept and np.array_equal(plant.x, twin.x) and all(equal(fa[k], fb[k]) for k in fa)
    print(json.dumps({"same": bool(kept)}))
compiled = {name: len(getattr(sim, name).signatures) for name in %r}
compiled["quantize"] = len(control.quantize.signatures)
print(json.dumps(compiled))
""" % (CYCLE,)


def _probe(kind):
    out = subprocess.run([sys.executable, "-c", PROBE, kind], cwd=ROOT, capture_output=True, text=True, timeout=300,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert out.returncode == 0, out.stderr[-2000:]
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


@pytest.mark.parametrize("kind", ["canopen", "serial"])
def test_a_drive_simulator_loads_its_whole_cycle_before_it_serves(kind):
    (compiled,) = _probe(kind)
    assert all(compiled.values()), f"not loaded before the first cycle: {[k for k, v in compiled.items() if not v]}"


# what each arrangement's cycle calls (drivers.sim.SimulatedPlant.sync, advance, read_feedback)
CALLS = {"none": {"coast_cycle", "torque_cycle", "quantize"},
         "velocity": {"drive_cycle", "coast_cycle", "torque_cycle", "quantize"},
         "both": {"drive_cycle", "coast_cycle", "torque_cycle", "drive_feedback", "quantize"}}


@pytest.mark.slow
@pytest.mark.realtime
@pytest.mark.parametrize("closes", sorted(CALLS))
def test_the_warm_up_leaves_the_state_as_it_was(closes):
    state, compiled = _probe(closes)
    assert state["same"]
    assert {k for k, v in compiled.items() if v} == CALLS[closes]


# a whole move, the set of compiled functions taken at the loop's first tick and at the end
MOVE_PROBE = r"""
import contextlib, io, json, os, sys, tempfile
from pathlib import Path
os.environ["HIL_STATE_DIR"] = tempfile.mkdtemp()
from numba.core.registry import CPUDispatcher
import hil.loop as L
from hil import config
from hil.cli import main
from hil.plant_config import plant_from_config

def dispatchers():
    out = {}
    for name, mod in list(sys.modules.items()):
        if name.split(".")[0] in ("hil", "drivers", "sim_plant"):
            for obj in list(vars(mod).values()):
                if isinstance(obj, CPUDispatcher):
                    out[obj.py_func.__module__ + "." + obj.py_func.__name__] = len(obj.signatures)
    return out

first = {}
tick = L.ControlLoop._tick
def first_tick(self, k, cmd):
    if k == 0 and not first:
        first.update(dispatchers())
    return tick(self, k, cmd)
L.ControlLoop._tick = first_tick
out = Path(tempfile.mkdtemp())
if sys.argv[1] == "canopen":
    import can
    from drivers.canopen.drive_sim import DriveSim
    sets = {"canopen.lockstep": True, "canopen.interface": "virtual", "canopen.channel": "warm_up_move"}
    cfg = config.load("config/paper_bench_canopen.toml", sets)
    sim = DriveSim(cfg, plant_from_config(cfg),
                   bus=can.Bus(interface="virtual", channel="warm_up_move"), lockstep=True)
    argv = ["--config", "config/paper_bench_canopen.toml", "--backend", "canopen", "--stroke", "20mm",
            "--feed", "6000mm/min", "--amax", "2m/s^2", "--dwell", "0.3s"]
    argv += sum((["--set", f"{k}={str(v).lower() if isinstance(v, bool) else v}"] for k, v in sets.items()), [])
    with contextlib.redirect_stdout(io.StringIO()):
        rc = main(["move", *argv, "--out", str(out)])
    sim.close()
else:
    from drivers.serial.drive_sim import SimulatedSerialDrive
    cfg = config.load("config/serial_ascii_example.toml")
    with SimulatedSerialDrive(cfg, plant_from_config(cfg)) as drive, \
            contextlib.redirect_stdout(io.StringIO()):
        rc = main(["move", "--config", "config/serial_ascii_example.toml", "--backend", "serial", "--set",
                   f'serial.port="{drive.port}"', "--stroke", "10mm", "--feed", "7000mm/min", "--tacc", "200ms",
                   "--dwell", "0.3s", "--out", str(out)])
end = dispatchers()
print(json.dumps({"rc": rc, "ticked": bool(first),
                  "loaded_in_cycle": sorted(k for k, v in end.items() if v > first.get(k, 0))}))
"""


@pytest.mark.slow
@pytest.mark.realtime
@pytest.mark.parametrize("backend", ["canopen", "serial"])
def test_nothing_compiled_is_loaded_once_the_loop_runs(backend):
    out = subprocess.run([sys.executable, "-c", MOVE_PROBE, backend], cwd=ROOT, capture_output=True, text=True,
                         timeout=300, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["rc"] == 0 and got["ticked"]
    assert got["loaded_in_cycle"] == []
