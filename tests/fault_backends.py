"""The test doubles of a drive that goes wrong, shared by the runtime and backend tests: the
embedded plant in torque mode (the host closes both loops, one exchange per velocity cycle) whose
feedback goes wrong from one velocity cycle on, either as the fault rule of drivers.base asks
(reported in ``Feedback.fault``) or by raising :class:`BackendFault` from ``read_feedback`` (a
backend that breaks the rule: the loop still ends the run ``fault``)."""
from drivers.base import Backend, BackendFault, Fault
from drivers.sim import SimulatedPlant
from hil.errors import StopKind
from hil.plant_config import plant_from_config


class FaultyPlant(Backend):
    """``at``: the first velocity cycle (1-based count of ``read_feedback`` calls) that goes wrong;
    ``reason``: what it says; ``kind``: the kind of stop it says (None: none, the default of where
    it stops the run); ``raises``: raise BackendFault instead of reporting it; ``stop_fails``: the
    controlled stop raises BackendFault too (the link is gone). ``stopped``: the controlled stop was
    commanded."""
    name = "faulty"
    closes = "none"
    simulated = True

    def __init__(self, cfg, at: int, reason: str = "drive fault: overcurrent", raises: bool = False,
                 kind: StopKind | None = StopKind.DRIVE_FAULT, stop_fails: bool = False):
        self.sim = SimulatedPlant(cfg, plant_from_config(cfg), closes="none")
        self.cycle_time = self.sim.cycle_time
        self.at, self.reason, self.raises, self.kind = at, reason, raises, kind
        self.cycles, self.stopped, self.stop_fails = 0, False, stop_fails

    def open(self):
        self.sim.home_at(0.0)

    def enable(self):
        self.sim.enable()

    def read_feedback(self):
        self.cycles += 1
        fb = self.sim.read_feedback()
        if self.cycles >= self.at:
            if self.raises:
                raise BackendFault(self.reason, self.kind)
            fb.set_fault(Fault.of(self.kind), self.reason)
        return fb

    def write_setpoint(self, sp):
        self.sim.write_setpoint(sp)

    def sync(self):
        self.sim.sync()

    def quick_stop(self):
        self.stopped = True
        if self.stop_fails:
            raise BackendFault("lost communication: no answer to the quick stop", StopKind.LINK)
        self.sim.disable()

    def disable(self):
        self.sim.disable()

    def close(self):
        pass
