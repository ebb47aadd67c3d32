"""``hil frf``: measure the axis's frequency responses, set them against the model, tune."""
from __future__ import annotations

import math
from pathlib import Path

from hil.config import load, parse_assignment
from hil.errors import BackendError, BackendFault, RunStopped, UnitError, UserError
from hil.io.jsonout import JsonKey, dumps
from hil.io.safe_write import save_figure, write_atomic
from hil.supervisor import Supervisor, refuse_if_tripped
from hil.units import parse_angle_deg, parse_gain_db, parse_option

HELP = "measure frequency responses (TF1', TF2, TF3, velocity and position loops) against the model"
DESCRIPTION = """\
Excite the axis around a working point (a slow constant-speed move, so that friction keeps its
sign) with a periodic multisine, chirp or PRBS, added to the torque (controller output) or to
the speed reference of the velocity loop. Estimates, with coherence and uncertainty, averaged
over periods (the excitation as instrumental variable, no closed-loop bias):
  TF1' torque -> motor speed, TF2 table/motor, TF3 tip/table (where the tip is measured),
  torque -> tip speed, open and closed velocity loop, open and closed position loop.
Then: the modes fitted in the measurement beside the model's, one sentence per discrepancy
naming the parameter to change, margins and bandwidths, largest gains keeping the margins,
filter suggestions, acceleration feed-forward effect; a config diff (never applied).

  hil frf --config config/paper_bench.toml
  hil frf --config config/paper_bench.toml --sim-set plant.c2=40      # a plant unlike its model
  hil frf --config config/paper_bench.toml --input velocity --signal chirp --json

--set changes the config (the model and, on the simulated backend, the plant); --sim-set
changes only the simulated plant (to rehearse finding a wrong parameter).
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints). frf.json in --out holds the same, without plots and report.
JSON_KEYS = {
    "responses": JsonKey("", "per response (TF1p, TF2, TF3, tip, Lv, Tv, Lp, Tp, those measured): frequency_hz, "
                             "magnitude and magnitude_std (in its unit), phase_deg, coherence, derived, title, "
                             "unit (rad/s per N m, m/s per N m, or 1), model_magnitude, model_phase_deg"),
    "modes": JsonKey("", "one entry per fitted mode (entries modes[].*)"),
    "modes[].mode": JsonKey("", "the mode's number in the chain (2: the first elastic one)"),
    "modes[].response": JsonKey("", "the response it was fitted in"),
    "modes[].measured": JsonKey("Hz, 1", "fit of the measured peak: frequency_hz, damping_ratio, frequency_std_hz, "
                                         "damping_std, response"),
    "modes[].model": JsonKey("Hz, 1", "the same fit on the model's response: frequency_hz, damping_ratio"),
    "modes[].model_eigen": JsonKey("Hz, 1", "the model's eigenvalue: frequency_hz, damping_ratio"),
    "discrepancies": JsonKey("", "one sentence per discrepancy, naming the parameter to change"),
    "suggested_changes": JsonKey("SI", "config key -> [present value, suggested value] (never applied)"),
    "tuning": JsonKey("Hz, deg, dB", "velocity_loop and position_loop (crossover_hz, phase_margin_deg, "
                                     "gain_margin_db, phase_crossover_hz, bandwidth_hz, kp_max N*m*s/rad or kv_max "
                                     "1/s with at_kp_max/at_kv_max), filters (mode_hz, loop_gain_db, notch_hz, ...), "
                                     "acceleration_feed_forward (error_per_acc_now, error_per_acc_with_ff in "
                                     "m/(m/s^2), acc_ff_now), config_diff (text)"),
    "warnings": JsonKey("", "what limits the measurement (saturation, low coherence), one sentence each"),
    "excitation": JsonKey("s", "signal, input, period_s, periods, lines, saturated_periods, backend"),
    "plots": JsonKey("", "paths of the figures: bode_plant, bode_loops, coherence"),
    "report": JsonKey("", "path of report.html"),
}


def add_arguments(p) -> None:
    p.add_argument("--config", required=True, metavar="FILE", help="axis configuration (TOML)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config parameter (model and simulated plant), repeatable")
    p.add_argument("--sim-set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a parameter of the simulated plant only (the model keeps the config's)")
    p.add_argument("--backend", metavar="NAME", help="sim (default: the compiled loop) or another backend in torque mode")
    from hil.commands.canbus import add_can_options
    add_can_options(p)
    p.add_argument("--signal", choices=("multisine", "chirp", "prbs"), default="multisine")
    p.add_argument("--input", choices=("torque", "velocity"), default="torque",
                   help="where the excitation enters: the controller output or the speed reference")
    p.add_argument("--amplitude", metavar="QUANTITY", help="peak of the excitation: a torque (default 10%% of the output limit) "
                                       "or a speed (default 5 mm/s, or rad/s of the motor)")
    p.add_argument("--band", metavar="FMIN..FMAX", default="1Hz..200Hz", help="frequency band, e.g. 1Hz..200Hz")
    p.add_argument("--periods", metavar="N", type=int, default=6, help="averaged excitation periods (default 6)")
    p.add_argument("--period", metavar="TIME", default="2s", help="length of one excitation period (default 2 s)")
    p.add_argument("--settle", metavar="TIME", default="4s", help="least excitation time before averaging (default 4 s; "
                                                  "longer when the model has a slow mode)")
    p.add_argument("--speed", metavar="SPEED", default="10mm/s", help="speed of the working point (default 10 mm/s)")
    p.add_argument("--noise", metavar="QUANTITY", default="0 rad/s", help="simulated speed measurement noise, rms, in rad/s "
                                                "(simulated backend only; default 0)")
    p.add_argument("--pm", metavar="ANGLE", default="45deg",
                   help="phase margin to keep, e.g. 45deg or 0.785rad; a bare number in degrees (default 45deg)")
    p.add_argument("--gm", metavar="GAIN", default="6dB",
                   help="gain margin to keep, e.g. 6dB; a bare number in dB (default 6dB)")
    p.add_argument("--out", metavar="DIR", default="out/frf", help="folder for plots and data (default out/frf)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    from hil.commands.scope import add_scope_options
    add_scope_options(p)


def _band(text: str):
    parts = text.replace("...", "..").split("..")
    if len(parts) != 2:
        raise UserError(f"--band {text!r}: expected LOW..HIGH, e.g. 1Hz..200Hz")
    unit = "".join(ch for ch in parts[1] if ch.isalpha())
    lo = parts[0] if any(ch.isalpha() for ch in parts[0]) else parts[0] + unit
    return parse_option(lo, "frequency", "--band"), parse_option(parts[1], "frequency", "--band")


def settings_from_args(args, cfg, ctrl):
    from hil.frf import FrfSettings
    band = _band(args.band)
    if args.amplitude is None:
        amp = 0.1 * ctrl.output_limit if args.input == "torque" else 0.005 * ctrl.speed_scale
    elif args.input == "torque":
        kind = "torque" if cfg.rotary else "dimensionless"
        amp = parse_option(args.amplitude, kind, "--amplitude")
    else:
        try:
            amp = parse_option(args.amplitude, "angular_speed", "--amplitude")
        except UnitError:       # not a motor speed: a linear speed (or a bare number: asks for a unit)
            amp = parse_option(args.amplitude, "speed", "--amplitude") * ctrl.speed_scale
    if not amp > 0:
        raise UserError("--amplitude must be positive")
    if args.input == "torque" and amp >= ctrl.output_limit:
        raise UserError(f"--amplitude {amp:g} N m reaches the output limit {ctrl.output_limit:g}")
    if args.periods < 1:
        raise UserError("--periods must be at least 1")
    tv = ctrl.velocity_period
    if band[1] >= 0.5 / tv:
        raise UserError(f"--band: {band[1]:g} Hz is above the velocity loop's Nyquist frequency {0.5 / tv:g} Hz")
    if band[0] <= 0 or band[0] >= band[1]:
        raise UserError(f"--band {args.band}: needs 0 < low < high")
    period = parse_option(args.period, "time", "--period")
    if period * band[0] < 1 - 1e-9:
        period = 1.0 / band[0]
    return FrfSettings(signal=args.signal, input=args.input, amplitude=amp, band=band, periods=args.periods,
                       period=period, settle=parse_option(args.settle, "time", "--settle"),
                       speed=parse_option(args.speed, "speed", "--speed"),
                       noise_speed=parse_option(args.noise, "angular_speed", "--noise"))


def check_margins(pm_min: float, gm_min_db: float) -> None:
    """A margin to keep must be one: a gain margin > 0 dB (at or below 0 dB the loop is unstable:
    --gm -6dB suggested a kv that 'hil move' refuses) and a phase margin between 0 and 180 deg."""
    if not 0.0 < gm_min_db <= 60.0:
        raise UserError(f"--gm {gm_min_db:g} dB: expected a gain margin above 0 dB and at most 60 dB (at or below "
                        f"0 dB the loop is unstable), e.g. 6dB")
    if not 0.0 < pm_min < 180.0:
        raise UserError(f"--pm {pm_min:g} deg: expected a phase margin between 0 and 180 deg, e.g. 45deg")


# the gains the tuning help suggests: (key in tuning, its entry, config key)
_GAINS = (("velocity_loop", "kp_max", "control.kp"), ("position_loop", "kv_max", "control.kv"))


def keep_stable_gains(result, cfg_with) -> None:
    """Drop a suggested gain that the model's closed loop shows unstable, the check 'hil move'
    refuses such a loop with (hil.closed_loop.check_loop_stability), and say so in the warnings:
    the margins are read off the measured loops, the check is on the whole discrete loop.

    ``cfg_with(key, value)``: the configuration with one value changed (SI)."""
    from hil.closed_loop import UnstableLoopError, check_loop_stability
    tun = result.tuning
    for loop, entry, key in _GAINS:
        value = (tun.get(loop) or {}).get(entry)
        if value is None:
            continue
        try:
            check_loop_stability(cfg_with(key, value))
        except UnstableLoopError:
            tun[loop].pop(entry, None)
            tun[loop].pop("at_" + entry, None)
            tun["config_diff"] = "\n".join(line for line in tun.get("config_diff", "").split("\n")
                                           if not line.startswith(f"{key} = "))
            result.warnings.append(f"{key} {value:.4g}, the largest keeping the margins on the measured loop, is not "
                                   f"suggested: the model's closed loop is unstable with it ('hil move' would refuse it)")


def _check_travel(cfg, st, duration: float, x0: float) -> None:
    lo, hi = cfg.get("limits.travel_min", -math.inf), cfg.get("limits.travel_max", math.inf)
    end = x0 + st.speed * duration
    if not (lo <= min(x0, end) and max(x0, end) <= hi):
        raise UserError(f"the working-point move ends at {end * 1e3:.1f} mm, outside the travel "
                        f"{lo * 1e3:g}..{hi * 1e3:g} mm: lower --speed, --periods or --period")
    vmax = cfg.get("limits.speed", math.inf)
    if abs(st.speed) > vmax:
        raise UserError(f"--speed {st.speed:g} m/s exceeds limits.speed {vmax:g} m/s")


def _scope_feed(ring, rec, ctrl) -> None:
    """The compiled run's record (every velocity period) into the live scope, one row per position
    tick; the command is not in that record (NaN: no command, no following error shown)."""
    import numpy as np

    from hil.loop import CYCLE_CHANNELS
    from hil.scope.ring import feed
    d = rec.data[::ctrl.substeps]
    t = np.arange(d.shape[0]) * rec.dt * ctrl.substeps
    ch = {n: d[:, CYCLE_CHANNELS.index(n)] for n in ("x_motor", "x_table", "x_tip")}
    nan = np.full(t.size, np.nan)
    ch.update(t=t, x_cmd=nan, e_table=nan, e_tip=nan, torque=d[:, CYCLE_CHANNELS.index("u")])
    feed(ring, ch, pace=None)


def measure_axis(args, cfg, pm_min: float, gm_min_db: float, ring=None):
    """The measurement of ``hil frf`` on the backend ``args`` names (the simulated plant by
    default): the drive opened in torque mode, the supervisor armed, the travel checked from where
    the axis stands, the experiment, the drive shut down however it ends. Returns the
    :class:`~hil.frf.FrfResult`, its settings and the controller (not real-time; ``hil tune``
    calls it too)."""
    from drivers.control import controller_from_config
    from hil import frf
    from hil.backends import open_backend
    from hil.plant_config import plant_from_config
    overrides = dict(parse_assignment(s) for s in args.set)
    plant_model = plant_from_config(cfg)
    ctrl = controller_from_config(cfg, plant_model)
    st = settings_from_args(args, cfg, ctrl)
    if args.sim_set:
        cfg_true = load(args.config, dict(overrides, **dict(parse_assignment(s) for s in args.sim_set)))
    else:
        cfg_true = cfg
    plant_true = plant_from_config(cfg_true)
    settle = frf.settle_time(plant_model, st)
    duration = st.lead_in + math.ceil(settle / st.period + st.periods) * st.period + 1.0
    _check_travel(cfg, st, duration, 0.0)
    name = args.backend or cfg.get("backend.type", "sim")
    backend = None
    if name != "sim":
        if args.sim_set:
            raise UserError("--sim-set changes the simulated plant only; it has no meaning with --backend " + name)
        options = {"mode": "cst"} if name == "canopen" else {}     # the host closes both loops
        try:
            backend = open_backend(cfg, name, can_log=getattr(args, "can_log", None), **options)
        except (BackendError, BackendFault, TypeError, ValueError) as exc:
            raise UserError(str(exc)) from None
        if backend.closes != "none":
            raise UserError(f"backend {name}: frf closes both loops on the host and needs the drive in torque mode")
        supervisor = Supervisor(cfg)
        supervisor.arm()          # a latched trip refuses motion: one line, exit 2
        try:
            backend.open()
            # where the axis stands, before the drive is enabled: the experiment starts there, and
            # its travel is checked from there
            fb = backend.read_position()
            if fb is not None:
                _check_travel(cfg, st, duration, fb.x_table)
            backend.enable()
        except BackendFault as exc:
            backend.shutdown()
            raise UserError(f"backend {name}: {exc.reason}") from None
        except BaseException:
            backend.shutdown()
            raise
    else:
        refuse_if_tripped(cfg)
        supervisor = None
    from hil.commands.progress import shown
    progress = frf.stderr_progress if shown(args) else None      # on a terminal (stderr: --json too)
    try:
        result = frf.measure(plant_true, plant_model, ctrl, st, backend=backend, progress=progress,
                             pm_min=pm_min, gm_min_db=gm_min_db, supervisor=supervisor, scope=ring)
        if ring is not None and backend is None:   # the compiled run: its record into the scope at once
            _scope_feed(ring, result.record, ctrl)
    except RunStopped:
        raise                     # stopped in the middle: the exit code of how (hil.errors.STOP_EXIT_CODES)
    except (ValueError, RuntimeError) as exc:
        raise UserError(str(exc)) from None
    finally:
        if backend is not None:
            backend.shutdown()
    return result, st, ctrl


def run(args) -> int:
    from hil.commands.move import load_config
    pm_min, gm_min_db = parse_angle_deg(args.pm, "--pm"), parse_gain_db(args.gm, "--gm")
    check_margins(pm_min, gm_min_db)
    overrides = dict(parse_assignment(s) for s in args.set)
    cfg = load_config(args)            # --set, and -i/-c/-b or python-can's configuration for canopen
    from hil.commands.scope import check_scope_options, scope_for
    check_scope_options(args)          # before anything moves
    with scope_for(args, cfg, "frf") as ring:     # the page before the drive is enabled; held after the run
        result, st, ctrl = measure_axis(args, cfg, pm_min, gm_min_db, ring)
    keep_stable_gains(result, lambda key, value: load(args.config, dict(overrides, **{key: value})))
    out = Path(args.out)
    report = result.as_dict()
    try:
        out.mkdir(parents=True, exist_ok=True)
        import matplotlib.pyplot as plt

        from hil.plots.frf import bode_measured_vs_model, coherence_figure
        title = f"{cfg.get('meta.name') or cfg.source}: measured ({st.signal}, {st.input}) vs model"
        plant_names = [n for n in ("TF1p", "TF2", "TF3", "tip") if n in result.responses]
        loop_names = [n for n in ("Lv", "Tv", "Lp", "Tp") if n in result.responses]
        paths = {}
        for key, names in (("bode_plant", plant_names), ("bode_loops", loop_names)):
            fig = bode_measured_vs_model(result, names, title)
            paths[key] = str(out / f"{key}.png")
            save_figure(fig, paths[key], dpi=110)
            plt.close(fig)
        fig = coherence_figure(result, title)
        paths["coherence"] = str(out / "coherence.png")
        save_figure(fig, paths["coherence"], dpi=110)
        plt.close(fig)
        write_atomic(out / "frf.json", dumps(report, indent=None))
        write_atomic(out / "config_diff.txt", _diff_text(result) + "\n")
        from hil.plots.report import write_frf_report
        write_frf_report(out / "report.html", report, list(paths.values()), config=cfg.source, title=title,
                         config_diff=_diff_text(result))
        report["plots"] = paths
        report["report"] = str(out / "report.html")
    except OSError as exc:
        raise UserError(f"--out {args.out}: cannot write ({exc.strerror or exc})") from None
    if args.json:
        print(dumps(report, indent=None))
    else:
        print(_text(result, report))
    return 0


def _diff_text(result) -> str:
    lines = ["# hil frf: suggested changes (not applied)"]
    for d in result.discrepancies:
        lines.append("# " + d["sentence"])
        for k, (old, new) in d["changes"].items():
            lines.append(f"{k} = {new:.4g}   # was {old:.4g}")
    if result.tuning.get("config_diff"):
        lines.append(result.tuning["config_diff"])
    return "\n".join(lines)


def _fmt(x, spec, unit=""):
    return "-" if x is None else f"{x:{spec}}{unit}"


def _text(result, report) -> str:
    ex = report["excitation"]
    lines = [f"frf on {ex['backend']}: {ex['signal']} {ex['input']} excitation, {ex['lines']} lines, "
             f"{ex['periods']} periods of {ex['period_s']:g} s averaged"]
    lines.append("modes (fit of the measured peaks | same fit on the model | model eigenvalues):")
    for m in result.modes:
        me, mo, mi = m["measured"], m["model"], m["model_eigen"]
        lines.append(f"  mode {m['mode']} in {m['response']:5s}: {me['frequency_hz']:8.3f} Hz zeta {me['damping_ratio']:.4f}"
                     f" | {mo['frequency_hz']:8.3f} Hz {mo['damping_ratio']:.4f}"
                     f" | {mi['frequency_hz']:8.3f} Hz {mi['damping_ratio']:.4f}")
    if result.discrepancies:
        lines.append("discrepancies:")
        lines += ["  " + d["sentence"] for d in result.discrepancies]
    else:
        lines.append("no discrepancy beyond 2 % in frequency and 20 % in damping")
    t = result.tuning
    v, p = t.get("velocity_loop", {}), t.get("position_loop", {})
    lines.append(f"velocity loop: crossover {_fmt(v.get('crossover_hz'), '.1f', ' Hz')}, PM "
                 f"{_fmt(v.get('phase_margin_deg'), '.1f', ' deg')}, GM {_fmt(v.get('gain_margin_db'), '.1f', ' dB')}, "
                 f"bandwidth {_fmt(v.get('bandwidth_hz'), '.1f', ' Hz')}")
    lines.append(f"position loop: crossover {_fmt(p.get('crossover_hz'), '.1f', ' Hz')}, PM "
                 f"{_fmt(p.get('phase_margin_deg'), '.1f', ' deg')}, GM {_fmt(p.get('gain_margin_db'), '.1f', ' dB')}, "
                 f"bandwidth {_fmt(p.get('bandwidth_hz'), '.1f', ' Hz')}")
    a = t.get("acceleration_feed_forward")
    if a:
        lines.append(f"following error per acceleration: {a['error_per_acc_now'] * 1e6:.3g} um/(m/s^2) now, "
                     f"{a['error_per_acc_with_ff'] * 1e6:.3g} with acc_ff = 1")
    lines += ["warning: " + w for w in result.warnings]
    lines.append("suggested config diff (not applied):")
    lines += ["  " + ln for ln in _diff_text(result).splitlines()[1:]] or ["  (none)"]
    if "plots" in report:
        lines.append("plots: " + ", ".join(report["plots"].values()))
    if "report" in report:
        lines.append(f"report: {report['report']}")
    return "\n".join(lines)

