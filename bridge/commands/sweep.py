"""pendsim sweep: many runs over parameters and release states, to Parquet, maps and rankings."""

from __future__ import annotations

import argparse
from pathlib import Path

from pendsim_mj.errors import ParameterError
from pendsim_mj.sweep.features import FEATURE_GROUPS
from pendsim_mj.sweep.plan import ENGINES, SweepPlan, axis_mapping, parse_vary

from .. import options

# Options that define the sweep (not allowed together with a definition file).
PLAN_OPTIONS = (
    "vary",
    "overrides",
    "random",
    "lhs",
    "cases",
    "sensitivity",
    "relative_step",
    "parameters",
    "engine",
    "duration_s",
    "dt_s",
    "save_every",
    "features",
    "seed",
    "trajectories",
)


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "sweep",
        help="run many cases (grid, random, Latin hypercube, CSV, sensitivity) to Parquet and maps",
        description="Run the rig over many parameter sets and release states and write one Parquet row per case "
        "(inputs and features), maps per feature and, for --sensitivity, a ranking of every parameter. "
        "Define the sweep in a TOML/JSON file or with options; run it again into the same folder to resume. "
        "Defaults: fast planar engine, 30 s at 10 ms, features frequency, amplitude, energy.",
    )
    p.add_argument("definition", nargs="?", type=options.input_file, help="sweep definition (.toml or .json)")
    p.add_argument(
        "-o", "--output", type=Path, default=Path("sweep-results"), help="results folder (default sweep-results)"
    )
    p.add_argument(
        "--vary",
        action="append",
        default=[],
        metavar="NAME=SPEC",
        help="vary an input: NAME=FROM:TO:NUM (grid), NAME=V1,V2,... (grid) or NAME=FROM:TO (--random, --lhs); "
        "append :log for geometric spacing; repeatable",
    )
    p.add_argument(
        "--params-file",
        type=options.input_file,
        help="JSON object of the rig's parameters (SI names as in 'pendsim info'; e.g. the params.json of 'pendsim "
        "calibrate' or 'pendsim identify --write'): every case's rig, under --set or the definition's base; "
        "the inputs the sweep varies keep their values",
    )
    p.add_argument(
        "--set",
        dest="overrides",
        type=options.assignment,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a fixed input of every case, e.g. --set phi1_deg=45 or --set c2_n_m=6; repeatable",
    )
    how = p.add_mutually_exclusive_group()
    how.add_argument(
        "--random", type=options.int_in(1, 10**8), metavar="N", help="N cases drawn uniformly in the ranges"
    )
    how.add_argument(
        "--lhs", type=options.int_in(1, 10**8), metavar="N", help="N cases of a Latin hypercube over the ranges"
    )
    how.add_argument(
        "--cases", type=options.input_file, metavar="FILE.csv", help="one case per row; the header names the inputs"
    )
    how.add_argument(
        "--sensitivity",
        action="store_true",
        help="every rig parameter alone at (1 -/+ step) x its value, and a ranked bar chart per feature",
    )
    p.add_argument(
        "--relative-step",
        type=options.float_in(0.0, 0.5, low_open=True),
        metavar="STEP",
        help="sensitivity step (default 0.01)",
    )
    p.add_argument(
        "--parameters", metavar="NAMES", help="sensitivity: comma-separated parameters (default: every RigParams field)"
    )
    p.add_argument(
        "--engine",
        type=options.choice(ENGINES, "unknown engine {value!r}; allowed: {allowed}"),
        choices=ENGINES,
        help="fast (compiled planar, default), mujoco (planar) or spatial (MuJoCo)",
    )
    p.add_argument(
        "--duration-s",
        metavar="S",
        type=options.ranged("duration_s", "--duration-s"),
        help="simulated time per case, s (default 30)",
    )
    p.add_argument(
        "--dt-s",
        type=options.ranged("dt_s", "--dt-s"),
        metavar="S",
        help="step, s (default 0.01)",
    )
    p.add_argument(
        "--save-every",
        type=options.int_in(1, 10**6),
        metavar="K",
        help="keep every k-th step for the features and trajectories (default 1)",
    )
    p.add_argument(
        "--features",
        help=f"comma-separated feature groups: {', '.join(FEATURE_GROUPS)} (default frequency,amplitude,energy)",
    )
    p.add_argument("--seed", type=options.int_in(0, 2**32 - 1), help="seed of --random and --lhs (default 0)")
    p.add_argument(
        "--trajectories", action="store_true", help="also store every case's phi and omega in trajectories.zarr"
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=options.int_in(1, 1024),
        metavar="N",
        help="run on a local Dask cluster of N worker processes (loopback only); where this process's threads "
        "already use the cores (the fast engine; the MuJoCo engines with N >= cores) the sweep runs here and says so",
    )
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run on the Dask scheduler at this address")
    p.add_argument(
        "--cases-per-task", type=options.int_in(1, 10**8), metavar="N", help="cases per task (default: automatic)"
    )
    p.add_argument("--no-plots", action="store_true", help="write no maps")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..run.sweep import describe, run_sweep  # start-up: numba, scipy and pyarrow, when the command runs

    rig = options.read_params_file(args.params_file) if args.params_file is not None else None
    plan = _plan(args, rig)
    if args.output.exists() and not args.output.is_dir():
        raise options.UsageError(f"output {str(args.output)!r} is a file; give a folder for the sweep's results")
    summary = run_sweep(
        plan,
        args.output,
        workers=args.workers,
        scheduler=args.scheduler,
        cases_per_task=args.cases_per_task,
        plots=not args.no_plots,
    )
    print(describe(summary, plan))
    if rig is not None:
        print(_rig_line(args.params_file, rig, plan))
    return 0


def _rig_line(path: Path, given: dict[str, float], plan: SweepPlan) -> str:
    """What the sweep took from its --params-file's values ``given`` (the plan on that rig:
    ``SweepPlan.on_rig``)."""
    from ..run.sweep import shorten

    base = dict(plan.base)
    taken = [name for name, value in given.items() if base.get(name) == float(value)]
    others = [name for name in given if name not in taken]

    line = f"rig: from {path}: {shorten(taken, keep=6) if taken else 'nothing'}"
    return line + (f"; not taken: {', '.join(others)} (the sweep varies or sets it itself)" if others else "")


def _plan(args: argparse.Namespace, rig: dict[str, float] | None) -> SweepPlan:
    """The sweep from the definition file, or from the options (never both), on the rig of
    --params-file (its values ``rig``) if given."""
    plan = _plan_of(args)
    return plan.on_rig(rig) if rig is not None else plan


def _plan_of(args: argparse.Namespace) -> SweepPlan:
    """The sweep from the definition file, or from the options (never both)."""
    given = [name for name in PLAN_OPTIONS if getattr(args, name) not in (None, False, [])]
    if args.definition is not None:
        if given:
            flags = ", ".join("--" + n.replace("_", "-").replace("overrides", "set") for n in given)
            raise options.UsageError(f"give the sweep in {args.definition} or by options, not both (found {flags})")
        return SweepPlan.load(args.definition)
    if not (args.vary or args.random or args.lhs or args.cases or args.sensitivity):
        raise options.UsageError(
            "nothing to sweep: give a definition file, --vary NAME=SPEC, --cases FILE.csv or --sensitivity"
        )
    data: dict[str, object] = {"base": dict(args.overrides)}
    try:
        axes = [parse_vary(v) for v in args.vary]
        twice = sorted({a.name for a in axes if [b.name for b in axes].count(a.name) > 1})
        if twice:
            raise ParameterError(f"{', '.join(twice)} given more than once; vary each input once")
        data["vary"] = {a.name: axis_mapping(a) for a in axes}
    except ParameterError as exc:  # the plan's "vary NAME: ..." said once as the option's
        raise options.UsageError(f"argument --vary: {str(exc).removeprefix('vary').lstrip(': ')}") from None
    method = "random" if args.random else "lhs" if args.lhs else "csv" if args.cases else None
    method = "sensitivity" if args.sensitivity else method
    if method:
        data["method"] = method
    if args.random or args.lhs:
        data["samples"] = args.random or args.lhs
    if args.cases:
        data["cases"] = str(args.cases)
    for name in ("relative_step", "parameters", "engine", "duration_s", "dt_s", "save_every", "features", "seed"):
        if getattr(args, name) is not None:
            data[name] = getattr(args, name)
    if args.trajectories:
        data["trajectories"] = True
    return SweepPlan.from_mapping(data)
