"""Time to diagnose a 12 s record (4 ms samples) against the whole catalogue."""
import time

from hil.compare import Replay
from hil.config import load
from hil.identify import diagnose
from hil.measurement import Measurement
from hil.synth import synthesize

cfg = load("config/paper_bench.toml")
ch, _ = synthesize(cfg, "coulomb_friction", duration=12.0, seed=1)
rp = Replay(Measurement(ch, source="bench"), cfg)
diagnose(rp, ["coulomb_friction"], jobs=1)          # compile
t0 = time.perf_counter()
d = diagnose(rp)
print(f"diagnose 12 s record, {len(d['candidates'])} candidates: {time.perf_counter() - t0:.1f} s, verdict {d['verdict']}")
