"""pendsim view: a recording and the model in Rerun."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import options


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "view",
        help="show a recording in Rerun: the rig in 3D, measured against model time series, phase portraits",
        description="Log a recording and the model's prediction (re-simulated from its metadata and MJCF) to "
        "Rerun: the rig in 3D with springs coloured by tension, measured and computed phi, omega and accelerations, "
        "the phi1 error with cumulative IAE and ISE, phase portraits, on a ready-made layout. Writes an .rrd file "
        "(default NAME.rrd beside the recording); --spawn opens the desktop viewer, --serve the web viewer.",
    )
    p.add_argument("path", type=options.mcap_file, help="the .mcap recording")
    options.add_alignment_options(p)
    options.add_drive_options(p, what="the model's re-simulation (default: the recording's own /drive topic)")
    p.add_argument(
        "-o",
        "--output",
        "--save",  # its name before -o, as every other command has it; kept so that scripts still work
        dest="save",
        type=Path,
        metavar="FILE.rrd",
        help="the .rrd file to write (default NAME.rrd; --save is the same option)",
    )
    options.add_force_option(p, "the .rrd file")
    p.add_argument("--spawn", action="store_true", help="open the Rerun desktop viewer on the result")
    p.add_argument(
        "--serve",
        action="store_true",
        help="serve the result to a web browser until Ctrl-C; prints the URL that opens it",
    )
    p.add_argument(
        "--bind",
        type=options.bind_address,
        default="127.0.0.1",
        help="IP address --serve listens on (default 127.0.0.1, this machine only; 0.0.0.0 every network)",
    )
    p.add_argument(
        "--port",
        type=options.int_in(1024, 65534),
        default=9090,
        help="web viewer port for --serve; the data port is PORT + 1 (default 9090)",
    )
    options.add_parameter_options(p, what="the recording's rig (the model drawn beside it)")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..report.rerun_view import view_recording  # start-up: Rerun and MuJoCo, when the command runs
    from ..report.serve import check_port_free, serve_web, spawn_viewer

    rrd = args.save or args.path.with_suffix(".rrd")
    options.check_output(rrd, (".rrd",), force=args.force)
    if args.serve:  # before the work: a port in use or a foreign address fails at once
        for port in (args.port, args.port + 1):
            check_port_free(args.bind, port)
    view_recording(
        args.path,
        rrd,
        replace=args.force,
        release_s=args.release_s,
        max_gap_s=args.max_gap_s,
        drive=options.drive_from(args),
        overrides=options.overrides_from(args),
    )
    print(f"wrote {rrd} (open it with: rerun {rrd})", flush=True)
    if args.spawn:
        spawn_viewer(rrd)
    if args.serve:
        serve_web(rrd, bind=args.bind, port=args.port)
    return 0
