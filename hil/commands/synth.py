"""``hil synth``: write a measurement file of a richer plant with a hidden effect."""
from __future__ import annotations

from hil.errors import UserError
from hil.io.jsonout import dumps

HELP = "synthetic measurement with a hidden effect (0.5 um quantization, noise, 4 ms sampling)"
DESCRIPTION = """\
  hil synth --config config/paper_bench.toml --effect coulomb_friction --out data.csv
  hil synth --config config/paper_bench.toml --effect parameter:plant.c2 --param value=40 --out c2.csv
  hil synth --config config/paper_bench.toml --out clean.csv          (no hidden effect)
"""


def add_arguments(parser) -> None:
    parser.add_argument("--config", required=True, metavar="FILE")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--effect", default=None, help="hidden effect (catalogue name or parameter:<key>)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="its values (SI)")
    parser.add_argument("--duration", type=float, default=12.0, help="seconds (default 12)")
    parser.add_argument("--sample-period", type=float, default=4e-3, help="seconds (default 0.004)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", required=True, metavar="FILE")
    parser.add_argument("--json", action="store_true")


def _check_times(duration: float, sample_period: float) -> None:
    """A record of at least 10 samples, at most an hour, sampled at most every second."""
    import math
    if not (math.isfinite(duration) and 0 < duration <= 3600):
        raise UserError(f"--duration: expected 0 < seconds <= 3600, got {duration:g}")
    if not (math.isfinite(sample_period) and 0 < sample_period <= 1.0):
        raise UserError(f"--sample-period: expected 0 < seconds <= 1, got {sample_period:g}")
    if duration / sample_period < 10:
        raise UserError(f"--sample-period {sample_period:g} s: fewer than 10 samples in --duration {duration:g} s")


def run(args) -> int:
    from hil.config import load, parse_assignment
    from hil.ident.synth import synthesize
    from hil.io.measurement import write
    cfg = load(args.config, dict(parse_assignment(s) for s in args.set))
    _check_times(args.duration, args.sample_period)
    vals = None
    if args.param:
        try:
            vals = {k.strip(): float(v) for k, _, v in (p.partition("=") for p in args.param)}
        except ValueError:
            raise UserError(f"--param: expected NAME=NUMBER (SI), got {args.param}") from None
    try:
        ch, truth = synthesize(cfg, args.effect, vals, duration=args.duration, sample_period=args.sample_period,
                               seed=args.seed)
    except KeyError as exc:
        raise UserError(str(exc).strip("'\"")) from None
    except ValueError as exc:
        raise UserError(str(exc)) from None
    write(args.out, ch, {"sample_period": f"{args.sample_period} s", "config": args.config,
                         "hidden_effect": truth["effect"], "seed": args.seed}, inputs=(args.config,))
    info = {"out": args.out, "effect": truth["effect"], "params": truth["params"], "samples": int(ch["t"].size)}
    print(dumps(info) if args.json else f"wrote {args.out}: hidden {truth['effect']} {truth['params']}")
    return 0
