"""pendsim recover: rewrite the readable part of a damaged MCAP file."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import options


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "recover",
        help="rewrite the readable part of a truncated or damaged MCAP file into a valid one",
        description="Read every intact chunk and record of BROKEN (for instance a recording whose process was "
        "killed; after a damaged record it resynchronises on the next chunk whose CRC checks) and write them to "
        "FIXED as a complete, indexed MCAP file. Content no CRC covers is left out unless --keep-unverified.",
    )
    p.add_argument("broken", type=options.mcap_file, help="the damaged .mcap file (read only)")
    p.add_argument("fixed", type=Path, help="the new .mcap file to write")
    options.add_force_option(p, "FIXED (never BROKEN itself)")
    p.add_argument(
        "--keep-unverified",
        action="store_true",
        help="also carry content no CRC covers (e.g. metadata of a file cut off before its end), "
        "listed in the new file's pendsim/unverified metadata",
    )
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..io.mcap.tools import recover  # start-up: loaded when the command runs

    options.check_not_input(args.fixed, args.broken)
    options.check_output(args.fixed, (".mcap",), force=args.force)
    with options.replacing(args.fixed, force=args.force) as target:
        contents = recover(args.broken, target, keep_unverified=args.keep_unverified)
    state = "was complete" if contents.complete else "; ".join(contents.problems)
    print(f"{args.broken}: {state}")
    if contents.unverified:
        what = ", ".join(str(u) for u in contents.unverified)
        action = (
            "kept (listed in pendsim/unverified)" if args.keep_unverified else "left out (--keep-unverified keeps it)"
        )
        print(f"unverified, {action}: {what}")
    print(f"wrote {args.fixed}: {contents.summary_line()}")
    return 0
