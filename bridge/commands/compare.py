"""pendsim compare: the planar against the spatial model from the same release."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import options

PLANES = ("m2", "m1")


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "compare",
        help="planar against spatial model from the same release: in-plane difference, tilt, beats, spectra",
        description="Run the planar model and the spatial variant (plane offset, tilt freedoms) from the same "
        "release and report per pendulum the in-plane angle difference, the out-of-plane amplitude, the beat "
        "period and depth of the swing envelope and the spectrum near the main frequency; writes summary.json and "
        "PNG plots; --rerun shows both rigs side by side.",
    )
    options.add_run_options(p)
    options.add_drive_options(p, what="both models")
    p.add_argument(
        "--offset-m",
        type=options.float_in(0.0, 0.5, "m"),
        default=0.050,
        help="distance between the pendulum planes, m (paper: 0.050 or 0.023; default 0.050)",
    )
    p.add_argument(
        "--fixed-points-plane",
        type=options.choice(PLANES, "--fixed-points-plane must be m1 or m2, got {value!r}"),
        choices=PLANES,
        default="m2",
        help="plane of points 6 and 7 (default m2)",
    )
    p.add_argument("-o", "--out-dir", type=Path, default=Path("compare"), help="output folder (default compare/)")
    options.add_rerun_option(p, "compare.rrd", "also show both rigs side by side and their angles in Rerun")
    options.add_force_option(p, "the files in the output folder and the --rerun file")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from pendsim_mj.estimation.comparison import compare_planar_spatial  # start-up: MuJoCo, scipy, matplotlib
    from pendsim_mj.rig.model import Variant

    from ..report.plots import COMPARISON_FILES, write_comparison
    from ..report.tables import comparison_table

    if args.engine != "mujoco":
        raise options.UsageError("the spatial model runs in MuJoCo only; drop --engine")
    options.check_output_dir(args.out_dir, COMPARISON_FILES, force=args.force)
    options.check_output(args.rerun, (".rrd",), force=args.force)
    params = options.params_from(args).with_overrides(plane_offset_m=args.offset_m)
    phi0, _ = options.initial_state_from(args)
    variant = Variant(tilt=True, fixed_points_plane=args.fixed_points_plane)
    drive = options.drive_from(args)
    result = compare_planar_spatial(params, phi0, args.duration_s, args.dt_s, variant=variant, drive=drive)
    written = write_comparison(result, args.out_dir, replace=args.force)
    print(comparison_table(result))
    print(f"wrote {', '.join(str(f) for f in written)}")
    if args.rerun is not None:
        from ..report.rerun_view import view_comparison  # start-up: Rerun, only with --rerun

        view_comparison(result, params, variant, args.rerun, replace=args.force)
        print(f"wrote {args.rerun}")
    return 0
