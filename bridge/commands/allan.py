"""pendsim allan: Allan deviation of a static recording."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .. import options

USUAL_PLOTS = tuple(f"allan_{node}_{sensor}.png" for node in ("m1", "m2") for sensor in ("accel", "gyro"))
"""The plots of a two-node recording, checked before the analysis (others at publication)."""


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "allan",
        help="Allan deviation of a static recording: the paper's noise table, noise terms and plots",
        description="Analyse every accelerometer and gyroscope axis of a static recording (e.g. from "
        "'pendsim record --static'): overlapping Allan deviation with confidence intervals, the paper's table "
        "(sigma at tau = 1/fs, mean, CV), the noise terms N, B, K, and a log-log plot per node and sensor.",
    )
    p.add_argument("path", type=options.mcap_file, help="the .mcap recording")
    p.add_argument("--json", action="store_true", help="print the full result (curves included) as JSON instead")
    p.add_argument("--plot-dir", type=Path, help="where to write the PNG plots (default: NAME_allan/ beside the file)")
    p.add_argument("--no-plots", action="store_true", help="write no plots")
    options.add_force_option(p, "plots of the same names in the plot folder")
    p.add_argument(
        "--longest-segment",
        action="store_true",
        help="if the timestamps have gaps or irregular intervals, or a node moves (a swing before or after a "
        "static stretch), analyse the longest static, uniformly sampled stretch",
    )
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm  # start-up: loaded when the command runs

    from ..report.allan_report import analyse, as_json, plots, table

    plot_dir = args.plot_dir or args.path.with_name(f"{args.path.stem}_allan")
    if not args.no_plots:
        try:
            options.check_output_dir(plot_dir, USUAL_PLOTS, force=args.force)
        except options.UsageError as exc:  # a second run: the table alone needs no plots
            raise options.UsageError(f"{exc}, or --no-plots for the table alone") from None
    with tqdm(
        total=args.path.stat().st_size, unit="B", unit_scale=True, desc="reading", disable=None, leave=False
    ) as bar:
        report = analyse(
            args.path,
            longest_segment=args.longest_segment,
            progress=bar.update,
            while_computing=None if args.no_plots else _import_plotting,
        )
    written = [] if args.no_plots else plots(report, plot_dir, replace=args.force)
    if args.json:
        print(json.dumps({**as_json(report), "plots": [str(p) for p in written]}))
        return 0
    print(table(report))
    if written:
        print(f"plots: {', '.join(str(p) for p in written)}")
    return 0


def _import_plotting() -> None:
    """matplotlib, imported while the deviations are computed (``analyse``'s while_computing)."""
    from ..report import plots  # noqa: F401  (start-up: matplotlib loads meanwhile)
