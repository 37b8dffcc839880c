"""pendsim identify: the hinge damping from a recorded free decay."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pendsim_mj.errors import ParameterError

from .. import options
from ..io.outputs import atomic_output

LAW_CHOICES = (
    "auto",
    "viscous",
    "coulomb",
    "both",
)  # pendsim_mj.estimation.planar_fit.LAW_CHOICES (not imported: fast start)


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "identify",
        help="identify the hinge damping (viscous b1, b2 and/or dry friction) from a recorded free decay",
        description="Print b1, b2 by the paper's logarithmic decrement (per pendulum, amplitudes over --window-s) "
        "and by a least-squares fit of the whole measured gyro record on the planar model, the start state "
        "fitted too, with 95 %% confidence intervals; the damping law (viscous, Coulomb or both) chosen by BIC, "
        "with the residuals' whiteness. --write saves the fitted values for 'simulate --params-file' and "
        "'record --params-file'.",
    )
    p.add_argument("path", type=options.mcap_file, help="the .mcap recording")
    options.add_alignment_options(p)
    p.add_argument(
        "--window-s",
        type=options.float_in(0.0, 86400.0, "s", low_open=True),
        default=120.0,
        help="log-decrement window, s (default 120)",
    )
    p.add_argument(
        "--law",
        type=options.choice(LAW_CHOICES, "unknown law {value!r}; allowed: {allowed}"),
        choices=LAW_CHOICES,
        default="auto",
        help="damping law of the fit: auto (the smallest BIC of the three; default), viscous, coulomb or both",
    )
    p.add_argument(
        "--model",
        type=options.choice(("planar", "spatial"), "unknown --model {value!r}; allowed: {allowed}"),
        choices=("planar", "spatial"),
        default="planar",
        help="planar (default) or spatial: also the support's tilt stiffness and damping, fitted with "
        "the spatial model to all three gyro axes of both nodes (viscous hinge damping)",
    )
    options.add_parameter_options(p, what="the recording's rig (e.g. calibrate's params.json)")
    p.add_argument(
        "--write", type=Path, metavar="FILE.json", help="write the fitted values (b1_n_m_s, b2_n_m_s, ...) as JSON"
    )
    options.add_force_option(p, "the --write file")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..report.tables import identification_table  # start-up: MuJoCo and scipy, when the command runs
    from ..run.validate import identify

    options.check_output(args.write, (".json",), force=args.force)
    if args.model == "spatial":
        from ..run.spatial_validate import identify_and_write  # start-up: MuJoCo and scipy

        if options.overrides_from(args):
            raise ParameterError(
                "--params-file and --set apply to the planar fit; --model spatial fits the recorded rig"
            )
        if args.law not in ("auto", "viscous"):
            raise ParameterError(f"--law {args.law} applies to the planar fit; --model spatial fits viscous damping")
        print(identify_and_write(args.path, release_s=args.release_s, max_gap_s=args.max_gap_s, write=args.write,
                                 replace=args.force))  # fmt: skip
        return 0
    result = identify(
        args.path,
        window_s=args.window_s,
        release_s=args.release_s,
        max_gap_s=args.max_gap_s,
        law=args.law,
        overrides=options.overrides_from(args),
    )
    print(identification_table(args.path, result))
    options.print_warnings(result.warnings)
    if result.fit.misfit:
        print(f"pendsim: identify: {result.fit.misfit_note()}", file=sys.stderr)
        return 1
    if args.write is not None:
        values = result.fit.overrides()
        with atomic_output(args.write, replace=args.force) as tmp:
            tmp.write_text(json.dumps(values, indent=1) + "\n")
        print(f"wrote {args.write} (use: pendsim simulate --params-file {args.write})")
    return 0
