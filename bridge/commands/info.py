"""pendsim info: every rig parameter with value, unit and source."""

from __future__ import annotations

import argparse

from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams

from .. import options


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "info",
        help="print every rig parameter with its unit and source",
        description="Print every rig parameter with value, unit and source.",
    )
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    rows = [(name, f"{getattr(DEFAULT_PARAMS, name):.6g}", unit, source) for name, unit, source in RigParams.describe()]
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    print("Rig parameters (Ganev et al., Machines 2025, 13(8), 660; doi:10.3390/machines13080660)")
    for name, value, unit, source in rows:
        print(f"  {name:{widths[0]}}  {value:>{widths[1]}}  {unit:{widths[2]}}  {source}")
    return 0
