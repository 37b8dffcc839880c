"""pendsim simulate: run the rig and print frequencies, amplitudes and the energy balance."""

from __future__ import annotations

import argparse
from pathlib import Path

from pendsim_mj.engines import dispatch as engines
from pendsim_mj.estimation.analysis import summarize
from pendsim_mj.rig.model import build_model

from .. import options

OUTPUT_SUFFIXES = (".npz", ".csv")


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate the rig and print a summary (frequencies, amplitudes, energy)",
        description="Simulate the rig from a release and print the dominant frequencies, the start and end "
        "amplitudes and the energy lost. Defaults: M1 released from 30 deg, M2 at rest, 120 s, 10 ms RK4 steps.",
    )
    options.add_run_options(p)
    options.add_drive_options(p)
    p.add_argument("-o", "--output", type=Path, help="write the trajectory to FILE.npz (all arrays) or FILE.csv")
    options.add_force_option(p, "the output files (-o, --rerun)")
    options.add_rerun_option(p, "simulation.rrd", "also log the run to Rerun: the rig in 3D and its time series")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..report.tables import run_summary  # start-up: MuJoCo and scipy, when the command runs

    options.check_output(args.output, OUTPUT_SUFFIXES, force=args.force)
    options.check_output(args.rerun, (".rrd",), force=args.force)
    params = options.params_from(args)
    phi0, omega0 = options.initial_state_from(args)
    drive = options.drive_from(args)
    traj = engines.run(args.engine, params, phi0, omega0, args.duration_s, args.dt_s, drive=drive)
    summary = summarize(traj)
    dry = params.friction1_n_m > 0 or params.friction2_n_m > 0
    print(run_summary(summary, args.engine, dry_friction=dry))
    options.print_warnings([w for w in (summary.unresolved_warning(),) if w is not None])
    if args.rerun is not None:
        from ..report.rerun_view import view_trajectory  # start-up: Rerun, only with --rerun

        model = build_model(params, drive_targets=drive.targets if drive else ())
        view_trajectory(traj, model, args.rerun, replace=args.force)
        print(f"wrote {args.rerun} (open it with: rerun {args.rerun})")
    if args.output is not None:
        from ..io.trajectory_file import save_trajectory  # start-up: only with -o

        save_trajectory(traj, args.output, replace=args.force)
        print(f"wrote {args.output}")
    return 0
