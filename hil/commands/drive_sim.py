"""``hil drive-sim``: the simulated CiA 402 drive (drivers.canopen.drive_sim) as a separate process, reachable
from other processes over python-can's socketcand interface on 127.0.0.1."""
from __future__ import annotations

import math
import os
import signal
import sys
import time

from hil.errors import UserError
from hil.io.jsonout import JsonKey, dumps

HELP = "run the simulated CiA 402 drive on a socketcand server on 127.0.0.1 (for --backend canopen)"
DESCRIPTION = """Run the simulated CiA 402 servo drive (the config's plant as its shaft, the object
dictionary of drivers/canopen/eds/cia402_generic.eds) until Ctrl-C, reachable from any other process through
python-can's socketcand interface: this process is a small socketcand server (raw mode) on
127.0.0.1 only. Run the host against it in another shell:

  hil drive-sim --config config/paper_bench_canopen.toml
  hil move  --config config/paper_bench_canopen.toml --backend canopen \\
      --set canopen.interface=socketcand --set canopen.channel=can0 \\
      --stroke 20mm --feed 6000mm/min --amax 2m/s^2 --dwell 0.3s

The drive runs on the wall clock, as a drive: one thread (this process's main thread, --priority
N: SCHED_FIFO) takes each frame off the bus itself and answers a SYNC at once, on that thread:
one drive cycle (the plant advanced by the compiled step of drivers.sim; the targets of the last
RPDO) and its TPDOs written in one segment. Answer time, SYNC taken off the bus to the TPDOs
written: under 0.5 ms (at 250 Hz p50 0.24 ms, p99 0.34-0.41 ms; at 1 kHz p50 0.09 ms, p99
0.16-0.18 ms; a 2-core machine at load average 2 to 5, --priority 50); with --json the last
line gives the run's own figures. On its
own clock when the SYNCs stop (the drive-side guards, heartbeat consumer 0x1016 with 0x6007, stop
the axis then).
Faults to inject (repeatable): KIND[=VALUE]@SECONDS, SECONDS of the drive's clock after it is
first enabled (OPERATION ENABLED: the host's move has begun), e.g. --fault emcy=0x2310@0.2 fires
0.2 s into the first move. Kinds: emcy, heartbeat_loss, frozen_encoder, late_pdo (seconds),
missing_pdo (count), following_error (metres), tip_missing_pdo (count; with a tip sensor node),
freeze (seconds, 0.5 by default: the drive's thread stalls, the host's frames queue, and it
finds that backlog when it carries on), kill (the drive is gone: no answer, no heartbeat, ever).

--set canopen.tip_node_id=2 (here and on the host) adds a tool-tip sensor on its own node: a
CiA 406-like linear encoder (drivers/canopen/eds/tip_encoder_cia406.eds) sending the tip mass's position in
its TPDO1 on every SYNC.

Ctrl-C (or SIGTERM) stops it; ``kill -USR1 PID`` prints every thread's stack on stderr and lets it
run on (a drive that seems hung).
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints): two JSON lines, the connection settings when the drive
# is up, the answer times when it stops
_LAST = "the last line, when the drive stops"
JSON_NOTE = ("Two lines: the first, as soon as the drive is up, says where to connect; the last, when it stops, "
             "how soon it answered each SYNC.")
JSON_KEYS = {
    "interface": JsonKey("", "`socketcand` (python-can's interface for the host)"),
    "host": JsonKey("", "127.0.0.1"),
    "port": JsonKey("", "the TCP port served (--port 0: the free one taken)"),
    "channel": JsonKey("", "the bus name clients open"),
    "node_id": JsonKey("", "the drive's node id"),
    "tip_node_id": JsonKey("", "the tip sensor's node id (null: none)"),
    "syncs": JsonKey("", "SYNCs answered", when=_LAST),
    "answer_p50_us": JsonKey("us", "median time from a SYNC taken off the bus to its TPDOs written",
                             when=_LAST + ", after a SYNC"),
    "answer_p99_us": JsonKey("us", "99th percentile of that time", when=_LAST + ", after a SYNC"),
    "answer_max_us": JsonKey("us", "largest", when=_LAST + ", after a SYNC"),
}


def add_arguments(p) -> None:
    from hil.commands.move import add_common
    add_common(p, backend=False, can=False)
    # only what works: the socketcand server (a serial slcan adapter would need hardware on both ends)
    p.add_argument("-i", "--interface", default="socketcand", choices=("socketcand",), metavar="NAME",
                   help="transport for other processes: socketcand (a server on 127.0.0.1; the only one)")
    p.add_argument("-c", "--channel", default="can0", metavar="NAME",
                   help="the socketcand bus name clients open (default can0)")
    p.add_argument("--port", type=int, metavar="PORT",
                   help="TCP port on 127.0.0.1 (default: the config's canopen.port, 29536)")
    p.add_argument("--fault", action="append", default=[], metavar="KIND[=VALUE]@SECONDS",
                   help="inject a fault that many seconds after the start (repeatable)")
    p.add_argument("--seconds", default=None, metavar="TIME",
                   help="stop after this long, e.g. 30s or 2min, more than 0 (default: until Ctrl-C)")
    p.add_argument("--switch-interval", default="100us", metavar="TIME",
                   help="the interpreter's thread switch interval (default 100 us: a fault timer's thread gives the "
                        "interpreter back to the drive's soon; Python's own default is 5 ms)")
    p.add_argument("--priority", type=int, default=0, metavar="N",
                   help="SCHED_FIFO priority 1..99 of the drive's thread (Linux, CAP_SYS_NICE; default 0: normal "
                        "scheduling): a drive is a real-time device; on a loaded machine the scheduler otherwise "
                        "holds its answer back by milliseconds now and then")
    p.add_argument("--cpu-latency", default="0us", metavar="TIME",
                   help="with --priority: the CPUs' wake-up latency held while the drive runs (Linux PM QoS "
                        "/dev/cpu_dma_latency, as runtime.cpu_latency; default 0 us: idle CPUs poll; inf: no request)")
    p.add_argument("--json", action="store_true", help="print the connection settings as one JSON line, and at the "
                   "end the drive's SYNC-to-answer times")


# the drive's log entries hil drive-sim prints as they happen
GUARD_EVENTS = ("stalled", "abort connection", "quick stop ended", "ignored")

FAULT_KINDS = ("emcy", "heartbeat_loss", "frozen_encoder", "late_pdo", "missing_pdo", "following_error",
               "tip_missing_pdo", "freeze", "kill")


# the VALUE each kind takes: (least, largest, what it is); kinds not named take none
COUNTED = ("emcy", "missing_pdo", "tip_missing_pdo")
FAULT_VALUES = {"emcy": (0x1000, 0xFFFF, "an EMCY error code"), "late_pdo": (0.0, 10.0, "seconds"),
                "missing_pdo": (1, 10 ** 6, "a count"), "tip_missing_pdo": (1, 10 ** 6, "a count"),
                "following_error": (-1.0, 1.0, "metres"), "freeze": (0.0, 60.0, "seconds")}
MAX_FAULT_TIME = 1e5          # s: SECONDS after the drive was enabled (a day and more)


def parse_fault(text: str):
    """``KIND[=VALUE]@SECONDS`` -> (kind, value, seconds)."""
    kind, _, at = text.partition("@")
    kind, _, value = kind.partition("=")
    if kind not in FAULT_KINDS:
        raise UserError(f"--fault {text!r}: unknown kind {kind!r} (known: {', '.join(FAULT_KINDS)})")
    try:
        t = float(at) if at else 0.0
        v = (int(value, 0) if kind in COUNTED else float(value)) if value else None
    except ValueError:
        raise UserError(f"--fault {text!r}: expected KIND[=VALUE]@SECONDS") from None
    if not (math.isfinite(t) and 0 <= t <= MAX_FAULT_TIME):
        raise UserError(f"--fault {text!r}: SECONDS must be a number 0..{MAX_FAULT_TIME:g}, got {at!r}")
    if v is not None:
        lo, hi, what = FAULT_VALUES.get(kind, (None, None, ""))
        if lo is None:
            raise UserError(f"--fault {text!r}: {kind} takes no VALUE")
        if not (math.isfinite(v) and lo <= v <= hi):
            raise UserError(f"--fault {text!r}: {kind}'s VALUE must be {what} {lo:g}..{hi:g}, got {value!r}")
    return kind, v, t


class FaultSchedule:
    """The faults of ``--fault``, each injected once, SECONDS of the drive's clock (``sim.time``:
    one period per cycle, SYNC or not) after the drive first reached OPERATION ENABLED, so that
    ``@0.2`` fires 0.2 s into the first move whenever it is started. :meth:`poll` is called every
    drive cycle or so (a thread in ``hil drive-sim``; the tests call it from the drive's cycle).

    Two faults are the simulated drive's as a whole: ``freeze`` (VALUE seconds, default 0.5: it
    answers nothing, no TPDO, no heartbeat, as a drive whose processor stalls, then carries on) and
    ``kill`` (it is gone: nothing, ever; the host's lost answers and the drive-side guards act)."""

    def __init__(self, faults):
        self.pending = sorted(faults, key=lambda f: f[2])
        self.enabled_at: float | None = None
        self.fired: list[tuple[str, float]] = []
        self._thaw: float | None = None
        self.killed = False

    def poll(self, sim) -> None:
        if self.enabled_at is None:
            if sim.state != "OPERATION ENABLED":
                return
            self.enabled_at = sim.time
        now = sim.time - self.enabled_at
        if self._thaw is not None and now >= self._thaw:
            sim.clear_injections()
            self._thaw = None
        while self.pending and now + 1e-9 >= self.pending[0][2]:
            kind, value, _ = self.pending.pop(0)
            self.fired.append((kind, now))
            if kind == "freeze":
                seconds = 0.5 if value is None else float(value)
                if not sim.lockstep:
                    # the drive's thread stalls (as under SIGSTOP): it reads and sends nothing, the
                    # host's frames queue, and it finds that backlog when it carries on
                    sim.stall(seconds)
                    continue
                # lockstep (the drive's clock is the SYNC count, it cannot stall): no answer for a
                # while, every TPDO withheld, the heartbeat stopped
                sim.inject("missing_pdo", 10 ** 9)
                sim.inject("heartbeat_loss")
                self._thaw = now + seconds
            elif kind == "kill":
                self.killed = True
                self.kill(sim)
            else:
                sim.inject(kind, value)

    @staticmethod
    def kill(sim) -> None:
        """The drive is gone: it hears nothing (SYNC, RPDO, SDO, the host's heartbeat) and sends
        nothing (TPDO, heartbeat, SDO answers) from now on."""
        sim.inject("heartbeat_loss")
        sim._stop.set()                         # its own clock (wall-clock mode) stops too
        n = sim.node_id
        ids = [0x80, 0x600 + n, 0x700 + int(sim.cfg.get("canopen.host_node_id", 127))]
        ids += [0x200 + 0x100 * k + n for k in range(4)]
        for cob in ids:
            if cob in sim.network.subscribers:
                sim.network.unsubscribe(cob)

    @property
    def done(self) -> bool:
        return not self.pending and self._thaw is None


def run(args) -> int:
    from drivers.canopen.drive_sim import DriveSim, SocketcandServerBus
    from hil.commands.move import load_config
    from hil.plant_config import plant_from_config
    cfg = load_config(args)
    faults = [parse_fault(f) for f in args.fault]
    if any(k == "tip_missing_pdo" for k, _, _ in faults) and not int(cfg.get("canopen.tip_node_id", 0) or 0):
        raise UserError("--fault tip_missing_pdo: the simulated drive has no tip sensor node "
                        "(--set canopen.tip_node_id=2)")
    from drivers.rt import CpuLatencyRequest
    from hil.units import parse_bounded, parse_option
    # given, a positive time (0 s ran until Ctrl-C, as if not given); not given: 0, until Ctrl-C
    args.seconds = 0.0 if args.seconds is None else parse_bounded(args.seconds, "time", "--seconds", positive=True)
    args.switch_interval = parse_bounded(args.switch_interval, "time", "--switch-interval", nonnegative=True)
    cpu_latency = parse_option(args.cpu_latency, "time", "--cpu-latency")
    if not cpu_latency >= 0:
        raise UserError(f"--cpu-latency {args.cpu_latency}: expected a time >= 0 (or inf: no request)")
    if args.switch_interval > 0:
        sys.setswitchinterval(args.switch_interval)
    port = args.port if args.port is not None else int(cfg.get("canopen.port", 29536))
    if not 0 <= port <= 65535:
        raise UserError(f"--port {port}: expected a TCP port 0..65535 (0: a free one)")
    try:
        bus = SocketcandServerBus(host="127.0.0.1", port=port, channel=args.channel)
    except OSError as exc:
        raise UserError(f"cannot serve on 127.0.0.1:{port} ({exc}); choose another --port") from None
    try:
        sim = DriveSim(cfg, plant_from_config(cfg), bus=bus, lockstep=False, thread=False)    # a mistake in the config (the EDS): ConfigError
    except BaseException:
        bus.shutdown()
        raise
    info = {"interface": "socketcand", "host": "127.0.0.1", "port": bus.port, "channel": args.channel,
            "node_id": sim.node_id, "tip_node_id": sim.tip_sensor.node_id if sim.tip_sensor else None}
    sets = (f"--set canopen.interface=socketcand --set canopen.channel={args.channel} "
            f"--set canopen.port={bus.port}")
    if args.json:
        print(dumps(info), flush=True)
    else:
        tip = f", tip sensor node {sim.tip_sensor.node_id}" if sim.tip_sensor else ""
        print(f"simulated CiA 402 drive, node {sim.node_id}{tip}, on socketcand 127.0.0.1:{bus.port} "
              f"channel {args.channel}", flush=True)
        print(f"host: hil move --config {cfg.source} --backend canopen {sets} ...; Ctrl-C to stop",
              file=sys.stderr, flush=True)
    schedule = FaultSchedule(faults)

    seen = [0]

    def on_duty(drive):                 # once a period, on the drive's thread (its lock held)
        before = len(schedule.fired)
        schedule.poll(drive)
        for kind, at in schedule.fired[before:]:
            print(f"drive-sim: {kind} injected {at:.3f} s after the drive was enabled", file=sys.stderr, flush=True)
        # what the drive-side guards did (a stall, a lost heartbeat or SYNC, the end of a quick stop)
        for _, event in drive.log[seen[0]:]:
            if any(w in event for w in GUARD_EVENTS):
                print(f"drive-sim: {event}", file=sys.stderr, flush=True)
        seen[0] = len(drive.log)

    latency = CpuLatencyRequest(None)
    if args.priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.priority))
        except (AttributeError, PermissionError, OSError) as exc:
            print(f"hil drive-sim: --priority {args.priority}: real-time scheduling refused ({exc}); running with "
                  f"normal priority", file=sys.stderr, flush=True)
        latency = CpuLatencyRequest(cpu_latency)
        refused = latency.hold()
        if refused:
            print(f"hil drive-sim: --cpu-latency: the wake-up latency request was refused ({refused})",
                  file=sys.stderr, flush=True)

    def _terminate(signum, frame):      # SIGTERM ends the drive as Ctrl-C does (a parent that stops it)
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _terminate)
    if hasattr(signal, "SIGUSR1"):      # kill -USR1 PID: every thread's stack on stderr, for a drive that seems hung
        import faulthandler
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    t0 = time.monotonic()
    try:
        sim.serve(args.seconds, on_duty=on_duty)    # the drive's one thread: this one
        # a killed drive is silent, not gone: the server stays, nothing answers, until the end
        while schedule.killed and (not args.seconds or time.monotonic() - t0 < args.seconds):
            time.sleep(0.05)
    except KeyboardInterrupt:
        pass
    except OSError as exc:            # the server's socket failed under it: one line, not a traceback
        raise UserError(f"drive-sim: the socketcand server failed ({exc})") from None
    finally:
        try:
            sim.close()
        except Exception:
            pass
        bus.shutdown()
        latency.release()
        if args.json:                    # how soon the drive answered each SYNC
            print(dumps(answer_stats(sim.answer_times)), flush=True)
    return 0


def answer_stats(times) -> dict:
    """The drive's SYNC-to-answer times (SYNC taken off the bus -> its TPDOs written), in us."""
    import numpy as np
    a = np.asarray(times, float) * 1e6
    if not a.size:
        return {"syncs": 0}
    return {"syncs": int(a.size), "answer_p50_us": float(np.percentile(a, 50)),
            "answer_p99_us": float(np.percentile(a, 99)), "answer_max_us": float(a.max())}
