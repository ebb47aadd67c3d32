"""``hil scope RECORD.csv``: replay a record into the live scope's page (issue 27); and the
``--scope`` options every command that moves an axis shares (:func:`add_scope_options`,
:func:`scope_for`)."""
from __future__ import annotations

from contextlib import contextmanager

HELP = "replay a record into the live scope: a local web page (127.0.0.1, a per-run token)"
DESCRIPTION = """Serve the live scope's page on 127.0.0.1 and replay a record into it at --speed times
real time: positions (mm), following errors (um), torque or force, motor speed (mm/s, the
derivative of x_motor), the run's end and its trip reason. The URL, with the run's token, is
printed on stderr; a request without the token is refused. The page stays up after the replay
until Ctrl-C, or for --hold.

The same page watches a run live: --scope on move, jog, home, sweep --backend and frf.

example:
  hil scope out/move/move.csv --speed 0.5
"""


def add_arguments(p) -> None:
    p.add_argument("record", metavar="RECORD", help="a record in the measurement format (e.g. out/move/move.csv)")
    p.add_argument("--speed", metavar="FACTOR", default="1.0",
                   help="seconds of the record per second of wall time (default 1.0: real time)")
    p.add_argument("--port", metavar="PORT", type=int, default=0, help="port on 127.0.0.1 (default: any free one)")
    p.add_argument("--hold", metavar="TIME", help="serve this long after the replay, then end (default: until Ctrl-C)")


def add_scope_options(p) -> None:
    """``--scope``, ``--scope-port``, ``--scope-hold`` of the commands that move an axis."""
    p.add_argument("--scope", action="store_true",
                   help="serve the live scope of the run on 127.0.0.1 (the URL with its token on stderr)")
    p.add_argument("--scope-port", metavar="PORT", type=int, default=0,
                   help="the scope's port on 127.0.0.1 (default: any free one)")
    p.add_argument("--scope-hold", metavar="TIME", default="0s",
                   help="keep the scope's page up this long after the run (default 0s; Ctrl-C ends it early)")


@contextmanager
def scope_for(args, cfg, command: str):
    """The run's scope: with ``--scope``, a ring buffer for the run and its server (the URL on
    stderr), held ``--scope-hold`` after the run however it ends; without it, None (nothing started).

    ``with scope_for(args, cfg, "jog") as ring: run_trajectory(..., scope=ring)``."""
    if not getattr(args, "scope", False):
        yield None
        return
    from hil.loop import check_loop_cpu
    held = check_scope_options(args)
    loop_cpu = check_loop_cpu(cfg.get("runtime.loop_cpu"))     # one line before anything starts
    # the server in its own process: it never holds this process's interpreter lock, which the cycle needs;
    # niced, and on the CPUs other than the loop's where runtime.loop_cpu pins it
    server = start_scope(None, args.scope_port, f"hil {command}: {cfg.get('meta.name') or cfg.source}",
                         "N m" if cfg.rotary else "N", command, loop_cpu=loop_cpu)
    try:
        yield server.ring
    finally:
        hold(server, held)


def check_scope_options(args) -> float | None:
    """``--scope-port`` and ``--scope-hold`` checked (one line, exit 2), before anything moves;
    returns the hold time (s)."""
    from hil.errors import UserError
    if not 0 <= args.scope_port <= 65535:
        raise UserError(f"--scope-port {args.scope_port}: expected a port, 0 (any free one) to 65535")
    return parse_hold(args.scope_hold, "--scope-hold")


def parse_hold(text, option: str) -> float | None:
    from hil.units import parse_bounded
    return None if text is None else parse_bounded(text, "time", option, nonnegative=True, maximum=86400.0)


def start_scope(ring, port: int, title: str, output_unit: str, command: str, option: str = "--scope-port",
                loop_cpu: int | None = None):
    """Start the scope's server and say where it is on stderr; returns the server. ``ring``: a
    ring to serve in a thread of this process (a replay: no cycle to disturb); None: a server in
    its own process with a ring of its own (``server.ring``), for a run (hil.scope.server.ScopeProcess),
    off ``loop_cpu`` (the loop's CPU, checked)."""
    import sys

    from hil.errors import UserError
    from hil.scope.server import ScopeProcess, ScopeServer
    if not 0 <= port <= 65535:
        raise UserError(f"{option} {port}: expected a port, 0 (any free one) to 65535")
    if ring is None:
        server = ScopeProcess(port=port, title=title, output_unit=output_unit, loop_cpu=loop_cpu)
    else:
        server = ScopeServer(ring, port=port, title=title, output_unit=output_unit)
    url = server.start()
    print(f"hil {command}: scope at {url}", file=sys.stderr, flush=True)
    return server


def hold(server, seconds: float | None) -> None:
    """Keep serving ``seconds`` (None: until Ctrl-C), then stop the server."""
    import time
    try:
        if seconds is None:
            while True:
                time.sleep(3600)
        elif seconds > 0:
            time.sleep(seconds)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()


def run(args) -> int:
    import math

    from hil.errors import UserError
    from hil.io.measurement import read
    from hil.io.record_status import status_of
    from hil.scope.ring import ScopeRing, feed
    held = parse_hold(args.hold, "--hold")
    try:
        speed = float(args.speed)
    except ValueError:
        speed = math.nan
    if not (math.isfinite(speed) and speed > 0):
        raise UserError(f"--speed {args.speed}: expected a positive number (1.0: real time)")
    meas = read(args.record)
    missing = [n for n in ("x_cmd", "x_motor", "x_table", "e_table", "e_tip") if n not in meas]
    if missing:
        raise UserError(f"{args.record}: no column {', '.join(missing)}: hil scope replays a run's record (hil move)")
    ch = dict(meas.channels)
    ch.setdefault("x_tip", ch["x_table"])
    st = status_of(args.record) or {}
    ring = ScopeRing(capacity=max(1 << 16, len(meas) + 2))
    server = start_scope(ring, args.port, f"hil scope: {args.record}", "N m" if "torque" in ch else "N", "scope",
                         "--port")
    try:
        feed(ring, ch, status=st.get("status", "complete"), reason=st.get("reason", ""), pace=speed)
    except KeyboardInterrupt:
        server.stop()
        return 130
    hold(server, held)
    return 0
