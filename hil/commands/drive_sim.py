"""``hil drive-sim``: the simulated CiA 402 drive (drivers.canopen.drive_sim) as a separate process, reachable
from other processes over python-can's socketcand interface on 127.0.0.1."""
from __future__ import annotations

import os
import signal
import sys
import threading

from hil.errors import UserError
from hil.io.jsonout import dumps

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
Faults to inject (repeatable): KIND[=VALUE]@SECONDS after the start, e.g. --fault emcy=0x2310@20,
--fault heartbeat_loss@30. Kinds: emcy, heartbeat_loss, frozen_encoder, late_pdo (seconds),
missing_pdo (count), following_error (metres), tip_missing_pdo (count; with a tip sensor node).

--set canopen.tip_node_id=2 (here and on the host) adds a tool-tip sensor on its own node: a
CiA 406-like linear encoder (drivers/canopen/eds/tip_encoder_cia406.eds) sending the tip mass's position in
its TPDO1 on every SYNC.
"""


def add_arguments(p) -> None:
    from hil.commands.move import add_common
    add_common(p, backend=False)
    p.add_argument("--interface", default="socketcand", choices=("socketcand", "slcan"),
                   help="transport for other processes: socketcand (a server on 127.0.0.1; default). "
                        "slcan is not built in this version")
    p.add_argument("--channel", default="can0", help="the socketcand bus name clients open (default can0)")
    p.add_argument("--port", type=int, help="TCP port on 127.0.0.1 (default: the config's canopen.port, 29536)")
    p.add_argument("--fault", action="append", default=[], metavar="KIND[=VALUE]@SECONDS",
                   help="inject a fault that many seconds after the start (repeatable)")
    p.add_argument("--seconds", type=float, default=0.0, help="stop after this long (default: until Ctrl-C)")
    p.add_argument("--switch-interval", type=float, default=1e-4, metavar="S",
                   help="the interpreter's thread switch interval (default 100 us: a fault timer's thread gives the "
                        "interpreter back to the drive's soon; Python's own default is 5 ms)")
    p.add_argument("--priority", type=int, default=0, metavar="N",
                   help="SCHED_FIFO priority 1..99 of the drive's thread (Linux, CAP_SYS_NICE; default 0: normal "
                        "scheduling): a drive is a real-time device; on a loaded machine the scheduler otherwise "
                        "holds its answer back by milliseconds now and then")
    p.add_argument("--json", action="store_true", help="print the connection settings as one JSON line, and at the "
                   "end the drive's SYNC-to-answer times")


def parse_fault(text: str):
    from drivers.canopen.drive_sim import FAULTS
    kind, _, at = text.partition("@")
    kind, _, value = kind.partition("=")
    if kind not in FAULTS:
        raise UserError(f"--fault {text!r}: unknown kind {kind!r} (known: {', '.join(FAULTS)})")
    try:
        t = float(at) if at else 0.0
        v = (int(value, 0) if kind in ("emcy", "missing_pdo", "tip_missing_pdo") else float(value)) if value else None
    except ValueError:
        raise UserError(f"--fault {text!r}: expected KIND[=VALUE]@SECONDS") from None
    return kind, v, t


def run(args) -> int:
    from drivers.canopen.drive_sim import DriveSim, SocketcandServerBus
    from hil.commands.move import load_config
    cfg = load_config(args)
    if args.interface == "slcan":
        raise UserError("--interface slcan is not built in this version; use --interface socketcand")
    faults = [parse_fault(f) for f in args.fault]
    if args.switch_interval and args.switch_interval > 0:
        sys.setswitchinterval(args.switch_interval)
    port = args.port if args.port is not None else int(cfg.get("canopen.port", 29536))
    try:
        bus = SocketcandServerBus(host="127.0.0.1", port=port, channel=args.channel)
    except OSError as exc:
        raise UserError(f"cannot serve on 127.0.0.1:{port} ({exc}); choose another --port") from None
    try:
        sim = DriveSim(cfg, bus=bus, lockstep=False, thread=False)    # a mistake in the config (the EDS): ConfigError
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
    for kind, value, at in faults:
        threading.Timer(at, sim.inject, args=(kind, value)).start()
    if args.priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.priority))
        except (AttributeError, PermissionError, OSError) as exc:
            print(f"hil drive-sim: --priority {args.priority}: real-time scheduling refused ({exc}); running with "
                  f"normal priority", file=sys.stderr, flush=True)
    def _terminate(signum, frame):      # SIGTERM ends the drive as Ctrl-C does (a parent that stops it)
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _terminate)
    try:
        sim.serve(args.seconds)          # the drive's one thread: this one
    except KeyboardInterrupt:
        pass
    finally:
        sim.close()
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
