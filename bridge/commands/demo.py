"""pendsim demo: the whole chain on built-in defaults."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import options


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "demo",
        help="the whole chain on built-in defaults: simulate, record, validate, report, plots, Rerun file",
        description="Simulate the rig from 30 deg, record a synthetic IMU MCAP (BNO055 noise, 2 s held before the "
        "release), identify the damping and validate the recording against the MuJoCo model and the planar "
        "reference, and write the report, the paper's figures and a Rerun .rrd; prints where everything is.",
    )
    p.add_argument(
        "-o", "--out-dir", type=Path, default=Path("pendsim_demo"), help="output folder (default pendsim_demo)"
    )
    p.add_argument(
        "--duration-s",
        type=options.float_in(10.0, 3600.0, "s"),
        default=120.0,
        help="simulated time after the release, s (default 120)",
    )
    options.add_force_option(p, "files of the same names in the output folder")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..run.demo import DEMO_FILES, run_demo  # start-up: MuJoCo, scipy and Rerun, when the command runs

    options.check_output_dir(args.out_dir, DEMO_FILES, force=args.force)
    result = run_demo(args.out_dir, duration_s=args.duration_s, replace=args.force)
    print("\ndone:")
    print(f"  recording     {result.recording}   (pendsim inspect {result.recording})")
    print(f"  report        {result.report_json}")
    print(f"  figures       {', '.join(p.name for p in result.figures)} in {args.out_dir}")
    print(f"  Rerun         {result.rrd}   (open it with: rerun {result.rrd})")
    return 0
