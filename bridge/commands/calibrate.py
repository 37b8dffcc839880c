"""pendsim calibrate: the rig's physical parameters fitted to its recordings."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pendsim_mj.errors import ParameterError

from .. import options

LAWS = ("viscous", "coulomb", "both")  # pendsim_mj.calibration.parameters.DAMPING_BY_LAW (not imported: fast start)
# pendsim_mj.calibration.parameters.PLANAR_PARAMETERS (not imported: fast start; a test checks they agree)
PLANAR_PARAMETERS = (
    "c1_n_m", "c2_n_m", "j1_kg_m2", "j2_kg_m2", "oc1_m", "oc2_m", "m1_kg", "m2_kg", "l01_m", "l04_m", "l24_m",
    "l34_m", "l05_m", "l08_m", "l68_m", "l78_m", "g_m_s2", "b1_n_m_s", "b2_n_m_s", "friction1_n_m", "friction2_n_m",
)  # fmt: skip
SPATIAL_PARAMETERS = ("tilt_stiffness_n_m_rad", "tilt_damping_n_m_s_rad", "plane_offset_m")  # ditto
OUTPUTS = ("params.json", "calibration.json", "calibration.md", "calibration.png")


def added_mass(text: str) -> tuple[int, int, float, float]:
    """N:M1:KG@M -> (recording index from 0, pendulum, kg, m)."""
    import re

    found = re.fullmatch(r"\s*(\d+)\s*:\s*[Mm]([12])\s*:\s*([^@]+)@(.+)", text)
    if not found:
        raise argparse.ArgumentTypeError(f"expected N:M1:KG@M (e.g. 2:M1:0.050@0.417), got {text!r}")
    index, pendulum = int(found.group(1)), int(found.group(2))
    mass, radius = options.finite_float(found.group(3)), options.finite_float(found.group(4))
    if index < 1 or not (0 < mass <= 5) or not (0 < radius <= 1):
        raise argparse.ArgumentTypeError(
            f"--added-mass {text!r}: the recording is counted from 1, the mass must be 0-5 kg and the radius 0-1 m"
        )
    return index - 1, pendulum, mass, radius


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "calibrate",
        help="fit the rig's springs, inertias and centres of mass to one or several recordings",
        description="Fit the rig's physical parameters (c1, c2, J1, J2, OC1, OC2, the anchors' asymmetries and the "
        "hinge damping) to one or several recordings at once on the planar model (--model spatial: on the "
        "spatial model, with the support's tilt stiffness and damping), each recording with its own start state. "
        "Only what the recordings determine is fitted (from the Fisher information: its directions "
        "and intervals); the rest is held at the stated values and named. Writes DIR/params.json (for "
        "--params-file of simulate, record, validate, identify, view, analyze, acquire, twin and sweep), "
        "DIR/calibration.json, "
        "DIR/calibration.md and DIR/calibration.png: what was determined, to what interval, what was not and "
        "which recording would determine it, and the validation of each recording before and after (and left "
        "out). Exit 1 when the residual stays far above the noise (model error, named).",
    )
    p.add_argument("paths", nargs="+", type=options.mcap_file, metavar="REC", help="the .mcap recordings")
    p.add_argument("-o", "--out-dir", type=Path, help="output folder (default: REC_calibration beside the first)")
    p.add_argument(
        "--model",
        type=options.choice(("planar", "spatial"), "unknown --model {value!r}; allowed: {allowed}"),
        choices=("planar", "spatial"),
        default="planar",
        help="planar (default), or spatial: the support's tilt stiffness and damping fitted with the rig, on both "
        "nodes' gyros, all three axes (free decays only; the planes' offset from the stated rig, else 50 mm)",
    )
    p.add_argument(
        "--law",
        type=options.choice(LAWS, "unknown law {value!r}; allowed: {allowed}"),
        choices=LAWS,
        default="viscous",
        help="the hinges' damping law fitted with the rig (default viscous)",
    )
    p.add_argument(
        "--fix",
        dest="fixed",
        type=options.assignment,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="hold a parameter at a known value in SI units (e.g. a weighed mass or a measured inertia: "
        "--fix j1_kg_m2=0.0262); repeatable",
    )
    p.add_argument(
        "--free",
        type=options.choice(
            PLANAR_PARAMETERS + SPATIAL_PARAMETERS,
            "--free {value!r} is not a parameter of the planar or spatial model; allowed: {allowed}",
        ),
        action="append",
        default=[],
        metavar="NAME",
        help="also fit this parameter (default: c1_n_m, c2_n_m, j1_kg_m2, j2_kg_m2, oc1_m, oc2_m, l24_m, l68_m "
        "and the damping; with --model spatial also the tilt's stiffness and damping, and plane_offset_m when "
        "named); repeatable",
    )
    p.add_argument(
        "--added-mass",
        dest="added",
        type=added_mass,
        action="append",
        default=[],
        metavar="N:M1:KG@M",
        help="the N-th recording (1 = the first given) was made with a known mass of KG kg clamped on M1 or M2 at "
        "M metres from the axis, e.g. 2:M1:0.050@0.417: a known moment that fixes the scale of all moments; "
        "repeatable",
    )
    options.add_parameter_options(p, what="the stated rig (the calibration's start and what it holds)")
    options.add_alignment_options(p)
    p.add_argument(
        "--no-checks",
        action="store_true",
        help="skip the validations before and after and the cross-validation (the calibration alone)",
    )
    options.add_force_option(p, "the outputs")
    p.set_defaults(handler=run)


def _checked(args: argparse.Namespace) -> dict[str, float]:
    """The options' combinations checked (each alone is checked by its parser); the fixed values."""
    spatial_only = [name for name in args.free if name in SPATIAL_PARAMETERS]
    if args.model != "spatial" and spatial_only:
        raise ParameterError(f"--free {spatial_only[0]}: a parameter of the spatial model only; add --model spatial")
    if args.model == "spatial" and args.added:
        raise ParameterError(
            "--added-mass with --model spatial: not available (the spatial model's inertia tensor of a loaded "
            "pendulum is not modelled); calibrate the recordings with a known mass on the planar model"
        )
    if args.release_s is not None and len(args.paths) > 1:
        raise ParameterError("--release-s applies to one recording; with several, each one's release is found")
    if any(index >= len(args.paths) for index, *_ in args.added):
        raise ParameterError(f"--added-mass names a recording beyond the {len(args.paths)} given")
    names = [name for name, _ in args.fixed]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise ParameterError(f"--fix {repeated[0]} given twice; fix each parameter once")
    both = sorted(set(names) & set(args.free))
    if both:
        raise ParameterError(f"{both[0]} is both fixed (--fix) and freed (--free); give one of them")
    return dict(args.fixed)


def run(args: argparse.Namespace) -> int:
    from pendsim_mj.calibration.parameters import DEFAULT_FREE  # start-up: with the command
    from pendsim_mj.rig.params import RigParams

    from ..report.calibration_report import report_text, write_outputs  # start-up: numba, when it runs
    from ..run.calibrate import calibrate_recordings, stated_elsewhere

    fixed = _checked(args)
    out_dir = args.out_dir or args.paths[0].with_name(f"{args.paths[0].stem}_calibration")
    options.check_output_dir(out_dir, OUTPUTS, force=args.force)
    overrides = options.overrides_from(args)
    params = RigParams().with_mapping(overrides)
    report = calibrate_recordings(
        args.paths,
        params,
        law=args.law,
        free=[*DEFAULT_FREE, *args.free],
        fixed=fixed,
        release_s=args.release_s,
        max_gap_s=args.max_gap_s,
        checks=not args.no_checks,
        added={index: (pendulum, mass, radius) for index, pendulum, mass, radius in args.added},
        progress=lambda line: print(line, file=sys.stderr),
        model=args.model,
    )
    print(report_text(report), end="")
    for line in stated_elsewhere(args.paths, params, given=set(overrides)):  # after the input's checks
        print(line, file=sys.stderr)
    written = write_outputs(report, out_dir, replace=args.force)
    spatial = " --model spatial" if args.model == "spatial" else ""
    use = f"pendsim validate {args.paths[0]} --params-file {out_dir / 'params.json'}{spatial}"
    if not spatial:  # the twin models the planar rig
        use += f"; the live twin: pendsim twin -o twin.mcap --params-file {out_dir / 'params.json'}"
    if report.model_error:  # no rig fits: its params.json is no calibration to hand on
        use = "none as a calibration: the model does not fit these recordings (below)"
    print(f"wrote {', '.join(str(p) for p in written)} (use: {use})")
    for line in report.model_error[:1]:
        print(f"pendsim: calibration: {line}", file=sys.stderr)
    return 1 if report.model_error else 0
