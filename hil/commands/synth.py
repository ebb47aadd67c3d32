"""``hil synth``: write a measurement file of a richer plant with a hidden effect."""
from __future__ import annotations

from hil.errors import UserError
from hil.io.jsonout import JsonKey, dumps
from hil.units import DIMENSIONS, SI_UNIT

HELP = "synthetic measurement with a hidden effect (0.5 um quantization, noise, 4 ms sampling)"
DESCRIPTION = """\
  hil synth --config config/paper_bench.toml --effect coulomb_friction --out data.csv
  hil synth --config config/paper_bench.toml --effect parameter:plant.c2 --param value=40 --out c2.csv
  hil synth --config config/paper_bench.toml --out clean.csv          (no hidden effect)
  hil synth --config config/paper_bench.toml --effect coulomb_friction --param level=2Nm --duration 5s --out f.csv
  hil synth --config config/paper_bench.toml --pulses 0.5N*m --out pulses.csv   (u_add after the controller)
  hil synth --config config/paper_bench.toml --external-force 300N --force-on tip --out cut.csv
  hil synth --config config/paper_bench.toml --open-loop --pulses 1.5N*m --pulse-period 4s --pulse-width 2s --out ol.csv
  hil synth --config config/paper_bench.toml --fleet fleet.toml --out fleet/      (axes x dates, drifting effects)

Quantities take their unit (--duration 5s, --sample-period 4ms, --param level=2Nm); a bare number is refused.

Pulses (--pulses, --external-force) are 0/amplitude pulses of --pulse-width every --pulse-period
from 0.5 s. --pulses: a command added after the controller, written as the u_add channel (a
torque on a rotary axis, a command in V or a force in N on a linear one); with --open-loop the
pulses are the actuator's whole command (torque steps), no position loop.

--fleet SPEC.toml: a fleet with a known answer (hil.fleet.synth: axes, dates, effects, drifts),
written to the folder --out with its manifest.csv and truth.json (for hil fleet); --fleet example:
the tutorial's (docs/tutorials/fleet.md).
"""


# the keys of --json (docs/reference/json.md is generated from them; tests/test_json_reference.py
# checks them against what run() prints)
JSON_KEYS = {
    "out": JsonKey("", "path of the record written"),
    "effect": JsonKey("", "the hidden effect (null: none)"),
    "params": JsonKey("SI", "its parameters by name (units in units.params)"),
    "samples": JsonKey("", "number of samples"),
    "duration": JsonKey("s", "length of the record"),
    "sample_period": JsonKey("s", "sampling period"),
    "inputs": JsonKey("", "the added inputs: u_add (--pulses), f_ext_table or f_ext_tip (--external-force)"),
    "open_loop": JsonKey("", "no position loop (--open-loop)"),
    "units": JsonKey("", "the SI unit of each parameter (params), of duration and of sample_period"),
    "fleet": JsonKey("", "with --fleet: axes, dates, records (number written), manifest (path), drift (the spec's "
                         "drifts: axis, effect, param, from, step, rate per day; SI)", when="with --fleet"),
}


def add_arguments(parser) -> None:
    parser.add_argument("--config", required=True, metavar="FILE", help="axis configuration (TOML)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a config parameter, e.g. --set plant.c2=33 (repeatable)")
    parser.add_argument("--effect", default=None, metavar="EFFECT",
                        help="hidden effect (catalogue name or parameter:<key>)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="a parameter of the effect, with its unit (level=2Nm; repeatable)")
    parser.add_argument("--duration", default="12s", metavar="TIME", help="length of the record (default 12s)")
    parser.add_argument("--sample-period", metavar="TIME",
                        help="sampling period (default 4ms, or the shortest whole multiple of the config's "
                             "control.position_period above it, as the record must be)")
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="random seed of the moves and the noise")
    parser.add_argument("--pulses", default=None, metavar="AMPLITUDE",
                        help="u_add pulses after the controller (N*m on a rotary axis; V or N on a linear one)")
    parser.add_argument("--external-force", default=None, metavar="FORCE", help="external force pulses (N)")
    parser.add_argument("--force-on", choices=("table", "tip"), default="table", help="the mass the force acts on")
    parser.add_argument("--pulse-period", default="1 s", metavar="TIME", help="pulse period (default 1 s)")
    parser.add_argument("--pulse-width", default="0.2 s", metavar="TIME", help="pulse width (default 0.2 s)")
    parser.add_argument("--open-loop", action="store_true", help="no position loop: the pulses are the whole command")
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="the measurement file to write: .csv (the measurement format) or .mat (MATLAB, SI)")
    parser.add_argument("--fleet", default=None, metavar="SPEC",
                        help="a fleet (TOML spec: axes, dates, effects, drifts) written to the folder --out")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _fleet(args) -> int:
    """--fleet SPEC: the records of axes x dates, their manifest and the truth, in the folder --out."""
    from pathlib import Path

    from hil.config import load, parse_assignment
    from hil.fleet.synth import read_spec, synthesize_fleet
    if args.effect or args.param or args.pulses or args.external_force or args.open_loop:
        raise UserError("--fleet: the spec gives the effects; drop --effect, --param, --pulses, --external-force, "
                        "--open-loop")
    if Path(args.out).suffix.lower() in (".csv", ".mat"):
        raise UserError(f"--out {args.out}: with --fleet, expected a folder")
    cfg = load(args.config, dict(parse_assignment(s) for s in args.set))
    spec = read_spec(args.fleet, cfg)
    _check_times(spec["duration"], spec["sample_period"])
    synthesize_fleet(cfg, spec, args.out, args.config, inputs=(args.config,) + (() if args.fleet == "example" else
                                                                               (args.fleet,)))
    n = len(spec["axes"]) * len(spec["dates"])
    manifest = str(Path(args.out) / "manifest.csv")
    if args.json:
        print(dumps({"out": args.out, "fleet": {"axes": spec["axes"], "dates": spec["dates"], "records": n,
                                                "manifest": manifest, "drift": spec["drift"]}}))
    else:
        print(f"wrote {n} records ({len(spec['axes'])} axes x {len(spec['dates'])} dates, "
              f"{spec['dates'][0]} to {spec['dates'][-1]}) and {manifest}")
        for d in spec["drift"]:
            print(f"  {d['axis']}: {d['effect']}.{d['param']} moves from {d['from']}")
    return 0


def default_sample_period(position_period: float, least: float = 4e-3) -> float:
    """4 ms, or the shortest whole multiple of the position period at or above it (a record is
    sampled on the position loop's ticks: a 10 ms loop cannot be read every 4 ms)."""
    import math
    return position_period * max(1, math.ceil(least / position_period - 1e-9))


def _check_times(duration: float, sample_period: float) -> None:
    """A record of at least 10 samples, at most an hour, sampled at most every second."""
    import math
    if not (math.isfinite(duration) and 0 < duration <= 3600):
        raise UserError(f"--duration: expected 0 < time <= 3600 s, got {duration:g} s")
    if not (math.isfinite(sample_period) and 0 < sample_period <= 1.0):
        raise UserError(f"--sample-period: expected 0 < time <= 1 s, got {sample_period:g} s")
    if duration / sample_period < 10:
        raise UserError(f"--sample-period {sample_period:g} s: fewer than 10 samples in --duration {duration:g} s")


def _shown(value, kind, choices) -> str:
    """A parameter's value as the text output writes it: a setting's name, a quantity in its unit."""
    from hil.units import fmt
    if choices:
        return choices[int(round(value))]
    return fmt(value, kind) if kind in DIMENSIONS else f"{value:g}"


def _choices(effect: str | None, cfg) -> dict:
    """The names of the effect's settings named by a word (encoder_error's encoder: motor, table)."""
    from hil.plant_config import candidate
    if not effect:
        return {}
    return {p.name: p.choices for p in candidate(effect, cfg).params if p.choices}


def _param_values(args, cfg) -> tuple[dict | None, dict]:
    """--param NAME=VALUE of the effect, each read in its parameter's unit (SI); and the kind of
    quantity of every parameter of the effect (for the output)."""
    import difflib

    from hil.plant_config import candidate
    from hil.units import parse_option
    kinds = {}
    if args.effect:
        from hil.commands.record_inputs import check_candidates
        check_candidates([args.effect], cfg, "--effect")      # one line: unknown, or not for this axis
        eff = candidate(args.effect, cfg)
        kinds = {p.name: p.kind_for(cfg.rotary) for p in eff.params}
    if not args.param:
        return None, kinds
    if not args.effect:
        raise UserError("--param: no --effect to give it to")
    vals = {}
    for text in args.param:
        name, eq, value = text.partition("=")
        name = name.strip()
        if not eq or not value.strip():
            raise UserError(f"--param {text!r}: expected NAME=VALUE, e.g. level=2Nm")
        if name not in kinds:
            close = difflib.get_close_matches(name, list(kinds), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise UserError(f"--param {name}: not a parameter of {args.effect} ({hint}its parameters: "
                            f"{', '.join(kinds)})")
        choices = eff.param(name).choices
        if choices:                 # a setting named by a word (encoder_error's encoder: motor or table)
            if value.strip() not in choices:
                raise UserError(f"--param {name}: expected one of {', '.join(choices)}, got {value.strip()!r}")
            vals[name] = eff.param(name).number(value.strip())
            continue
        vals[name] = parse_option(value.strip(), kinds[name] if kinds[name] in DIMENSIONS else "dimensionless",
                           f"--param {name}")
    return vals, kinds


def _inputs(args, cfg):
    """The pulse trains asked for (functions of the record's sample times) and the written kind of u_add."""
    from functools import partial

    from hil.ident.synth import pulse_train
    from hil.units import UnitError, parse_option
    inputs, kinds = {}, {}
    try:
        period = parse_option(args.pulse_period, "time", "--pulse-period")
        width = parse_option(args.pulse_width, "time", "--pulse-width")
        if not 0 < width < period:
            raise UserError(f"--pulse-width {args.pulse_width}: expected between 0 and --pulse-period")
        if args.pulses is not None:
            kind = "torque" if cfg.rotary else "voltage"
            try:
                amp = parse_option(args.pulses, kind, "--pulses")
            except UnitError:
                if cfg.rotary:
                    raise
                amp = parse_option(args.pulses, "force", "--pulses") / cfg["actuator.gain"]
            inputs["u_add"] = partial(pulse_train, amplitude=amp, period=period, width=width)
            kinds["u_add"] = kind
        elif args.open_loop:
            raise UserError("--open-loop: give the actuator's command as --pulses AMPLITUDE")
        if args.external_force is not None:
            f = parse_option(args.external_force, "force", "--external-force")
            inputs[f"f_ext_{args.force_on}"] = partial(pulse_train, amplitude=f, period=period, width=width)
    except UnitError as exc:
        raise UserError(str(exc)) from None
    if args.open_loop:
        kinds = {}                     # the pulses are written as the torque (command) channel
    return inputs, kinds


def run(args) -> int:
    from pathlib import Path

    from hil.config import load, parse_assignment
    from hil.ident.synth import synthesize
    from hil.io.measurement import write
    from hil.io.safe_write import refuse_inputs
    from hil.units import fmt, parse_option
    refuse_inputs(args.out, (args.config,))
    if args.fleet:
        return _fleet(args)
    if Path(args.out).suffix.lower() not in (".csv", ".mat"):
        # the suffix says the format: a CSV text under another name misleads every reader
        raise UserError(f"--out {args.out}: expected a .csv (the measurement format) or .mat (MATLAB) file name")
    cfg = load(args.config, dict(parse_assignment(s) for s in args.set))
    duration = parse_option(args.duration, "time", "--duration")
    sample_period = (default_sample_period(cfg["control.position_period"]) if args.sample_period is None
                     else parse_option(args.sample_period, "time", "--sample-period"))
    _check_times(duration, sample_period)
    vals, kinds = _param_values(args, cfg)
    inputs, input_kinds = _inputs(args, cfg)
    try:
        ch, truth = synthesize(cfg, args.effect, vals, duration=duration, sample_period=sample_period,
                               seed=args.seed, inputs=inputs, open_loop=args.open_loop)
    except KeyError as exc:
        raise UserError(str(exc).strip("'\"")) from None
    except ValueError as exc:
        raise UserError(str(exc)) from None
    meta = {"sample_period": f"{sample_period:g} s", "config": args.config, "hidden_effect": truth["effect"],
            "seed": args.seed}
    if args.open_loop:
        meta["open_loop"] = "true (replay with --open-loop)"
    write(args.out, ch, meta, inputs=(args.config,), kinds=input_kinds)
    info = {"out": args.out, "effect": truth["effect"], "params": truth["params"], "samples": int(ch["t"].size),
            "duration": float(ch["t"][-1] - ch["t"][0]) + sample_period, "sample_period": sample_period,
            "inputs": sorted(inputs), "open_loop": bool(args.open_loop),
            "units": {"params": {k: SI_UNIT.get(kinds.get(k, ""), "") for k in truth["params"]},
                      "duration": "s", "sample_period": "s"}}
    if args.json:
        print(dumps(info))
    else:
        choices = _choices(args.effect, cfg)
        params = ", ".join(f"{k} = {_shown(v, kinds.get(k), choices.get(k))}" for k, v in truth["params"].items())
        print(f"wrote {args.out}: {info['samples']} samples every {fmt(sample_period, 'time')} "
              f"({fmt(info['duration'], 'time')}), hidden effect {truth['effect']}" + (f": {params}" if params else ""))
    return 0
