"""pendsim validate: compare a recording with the MuJoCo model and the planar reference."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from pendsim_mj.rig.params import PARAMETER_LIMITS

from .. import heap, options


def damping_choice(text: str) -> str | tuple[float, float]:
    """'identified', 'recorded' or B1,B2 (finite, >= 0, N m s/rad)."""
    if text in ("identified", "recorded"):
        return text
    try:
        b1, b2 = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--damping must be 'identified', 'recorded' or B1,B2 in N m s/rad, got {text!r}"
        ) from None
    _, high = PARAMETER_LIMITS["b1_n_m_s"]
    if not (math.isfinite(b1) and math.isfinite(b2) and 0 <= b1 <= high and 0 <= b2 <= high):
        raise argparse.ArgumentTypeError(f"--damping values must be finite, >= 0 and at most {high:g}, got {text!r}")
    return (b1, b2)


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "validate",
        help="compare a recording with the MuJoCo model and the planar reference (the paper's metrics and figures)",
        description="Align a recording (each node's clock, hinge axis and mounting; the release, or the state at "
        "the first samples of a recording that starts in motion), identify or take the "
        "damping, simulate with MuJoCo and the planar reference from the estimated and the nominal 30 deg release, "
        "and compare phi1, omega1, omega2 and M1's tangential and normal accelerations over 5 s and the whole run: "
        "frequency (zero crossings and spectral peak) and its relative error delta, max |Delta|, IAE, ISE. "
        "Writes report.json and the paper's Figures 9-15. Exit 1 when a --max-* gate is exceeded.",
    )
    p.add_argument("path", type=options.mcap_file, help="the .mcap recording")
    options.add_alignment_options(p)
    p.add_argument("-o", "--out-dir", type=Path, help="where report.json and the figures go (default NAME_validation/)")
    p.add_argument(
        "--damping",
        type=damping_choice,
        default="identified",
        help="'identified' (least-squares fit on this recording; default), 'recorded' (its metadata) or B1,B2",
    )
    options.add_parameter_options(p, what="the model being validated")
    p.add_argument(
        "--model",
        type=options.choice(("planar", "spatial"), "unknown --model {value!r}; allowed: {allowed}"),
        choices=("planar", "spatial"),
        default="planar",
        help="planar (default) or spatial: also compare with the spatial MuJoCo model (planes offset, tilt "
        "freedoms) and report which model fits better, per quantity and overall",
    )
    p.add_argument("--no-plots", action="store_true", help="write report.json only")
    options.add_force_option(p, "report.json and the figures in the output folder")
    # Gates beyond these pass every run: a relative error of 100, 1e4 rad s over 5 s, a full turn.
    p.add_argument(
        "--max-delta",
        type=options.float_in(0.0, 100.0),
        metavar="X",
        help="fail if any quantity's relative frequency error (MuJoCo, estimated release, whole run) exceeds X",
    )
    p.add_argument(
        "--max-iae",
        type=options.float_in(0.0, 1e4, "rad s"),
        metavar="X",
        help="fail if the IAE of phi1 over the first 5 s (MuJoCo, estimated release) exceeds X rad s",
    )
    p.add_argument(
        "--max-error-phi1",
        type=options.float_in(0.0, 2 * math.pi, "rad"),
        metavar="RAD",
        help="fail if max |Delta phi1| over the whole run (MuJoCo, estimated release) exceeds RAD",
    )
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..report.validation_report import table, write_outputs  # start-up: loaded when the command runs
    from ..run.validate import Gates, gate_failures, validate

    heap.map_large_blocks()  # a long run's whole-run temporaries go back to the system when freed

    out_dir = args.out_dir or args.path.with_name(f"{args.path.stem}_validation")
    options.check_output_dir(out_dir, ("report.json",), force=args.force)
    report = validate(
        args.path,
        damping=args.damping,
        overrides=options.overrides_from(args),
        release_s=args.release_s,
        max_gap_s=args.max_gap_s,
        model=args.model,
    )
    print(table(report))
    options.print_warnings(report.warnings)
    # (--model spatial compares the spatial model: its planar damping fit missing is what it shows)
    misfit = args.model == "planar" and report.identification is not None and report.identification.fit.misfit
    written = write_outputs(report, out_dir, plots=not args.no_plots, replace=args.force)
    print(f"wrote {', '.join(str(p) for p in written)}")
    if misfit:  # the model does not fit: its metrics are the rig's error, not the damping law's (exit 1)
        assert report.identification is not None
        print(f"pendsim: validate: {report.identification.fit.misfit_note()}", file=sys.stderr)
    failures = gate_failures(report, Gates(args.max_delta, args.max_iae, args.max_error_phi1))
    for f in failures:
        print(f"pendsim: validation failed: {f}", file=sys.stderr)
    if report.model_warnings:  # its step does not resolve the rig: no verdict to trust (exit 1)
        print("pendsim: validate: the model's run is not resolved by its step (warning above)", file=sys.stderr)
    return 1 if failures or misfit or report.model_warnings else 0
