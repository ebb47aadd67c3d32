"""Explicit state (issue 28, item 7): what the forked fitting workers evaluate is handed to them,
not left in a module of the parent process."""
import multiprocessing as mp

import pytest

from hil.ident import parallel


class _Replay:
    """A stand-in that no fit can use: the workers fail on it at once."""


@pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="the workers are forked")
def test_the_parent_keeps_no_replay_after_the_workers_failed():
    """The workers raise (a replay they cannot fit, an error other than ValueError); the parent's
    modules hold nothing of the run afterwards (before: the replay stayed in parallel._WORK when
    the pool raised, until the next run)."""
    replay = _Replay()
    with pytest.raises(Exception):
        parallel.evaluate_many(replay, [("coulomb_friction", 1), ("backlash", 1)], None, 2, None)
    held = [name for name, value in vars(parallel).items()
            if isinstance(value, dict) and any(v is replay for v in value.values())]
    assert held == []


def test_the_schema_sections_are_listed_not_registered_on_import():
    """hil.config knows the [supervisor], [noise] and [effects.*] keys itself (an explicit table):
    reading them imports neither hil.supervisor nor hil.plant_config (before: found by importing
    those modules from their names as strings, which registered the sections as a side effect).
    The backends' sections are listed the same way: reading a [canopen] or [serial] key, or a
    "did you mean" over them, imports no backend (before: drivers.canopen.backend and
    drivers.serial.backend imported by name to register their sections): only the sections' own
    light schema modules beside the backends (drivers/*/schema.py), the drive's errors and the
    package's contract."""
    import subprocess
    import sys
    code = ("import sys; from hil import config\n"
            "assert config.field_for('supervisor.stop').default == 'quick_stop'\n"
            "assert config.field_for('noise.x_table').kind == 'length'\n"
            "assert config.field_for('effects.backlash.gap').kind == 'length'\n"
            "assert config.field_for('effects.coulomb_friction.level').kind_for({'actuator.type': 'linear'}) == 'force'\n"
            "assert config.field_for('supervisor.nonsense') is None\n"
            "assert config.field_for('canopen.heartbeat_timeout').kind == 'time'\n"
            "assert config.field_for('canopen.mode').choices == ('csp', 'csv', 'cst')\n"
            "assert config.field_for('serial.baudrate').default == 115200\n"
            "assert config.field_for('serial.commands.read').kind == 'str'\n"
            "assert config.field_for('serial.nonsense') is None and config.field_for('canopen.nonsense') is None\n"
            "assert config.did_you_mean('canopen.nodeid') == \"; did you mean 'canopen.node_id'?\"\n"
            "assert config.did_you_mean('serial.baudrat') == \"; did you mean 'serial.baudrate'?\"\n"
            "light = {'drivers', 'drivers.base', 'drivers.errors', 'drivers.schema', 'drivers.canopen',"
            " 'drivers.canopen.schema', 'drivers.serial', 'drivers.serial.schema'}\n"
            "print(sorted(m for m in ('hil.supervisor', 'hil.plant_config') if m in sys.modules)"
            " + sorted(m for m in sys.modules if m.startswith('drivers') and m not in light))\n"
            "print(sorted(config.SECTION_NAMES))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[0] == "[]", out
    assert out[1] == str(sorted(["canopen", "effects", "noise", "serial", "supervisor"]))
