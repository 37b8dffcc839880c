"""pendsim inspect: what an MCAP file holds."""

from __future__ import annotations

import argparse

from .. import options
from ..io.mcap.reader import read_mcap


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "inspect",
        help="print the topics, message counts, rates, duration and metadata of an MCAP file",
        description="Print what an MCAP file holds. A truncated or damaged file is an error (exit 2) that says "
        "how much is readable; 'pendsim recover' rewrites that part.",
    )
    p.add_argument("path", type=options.mcap_file, help="the .mcap file")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..report.tables import contents_table  # start-up: MuJoCo and scipy (the tables' result types)

    print(contents_table(read_mcap(args.path, strict=True, payloads=False)))
    return 0
