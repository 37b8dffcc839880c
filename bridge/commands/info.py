"""pendsim info: every rig parameter with value, unit and source; with a file, the rig it states."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pendsim_mj.errors import RecordingError
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams

from .. import options

PAPER = "Ganev et al., Machines 2025, 13(8), 660"


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "info",
        help="print every rig parameter with its unit and source (with a file: the rig it states)",
        description="Print every rig parameter with value, unit and source. With a recording (.mcap) or a "
        "parameter file (.json), the rig it states: each value it gives that is not the paper's is marked "
        "with the paper's beside it. --json prints the rig as a parameter file (for --params-file).",
    )
    p.add_argument(
        "path",
        nargs="?",
        type=Path,
        help="a recording (the rig its metadata state: what validate takes as its rig) or a parameter file",
    )
    p.add_argument("--json", action="store_true", help="print every parameter as one JSON object (a --params-file)")
    p.set_defaults(handler=run)


def stated_by(path: Path) -> RigParams:
    """The rig a recording's metadata or a parameter file states, on top of the paper's."""
    if path.suffix.lower() != ".mcap":
        return RigParams().with_mapping(options.read_params_file(path))
    from ..io.recording import rig_stated_in  # start-up: with a recording only

    if not path.is_file():
        raise options.UsageError(f"{path}: no such file")
    rig, damaged = rig_stated_in(path)
    if rig is None and damaged:  # cut before its metadata, or its metadata damaged
        raise RecordingError(damaged)
    if damaged:  # its rig is read; the rest is not whole, which the commands that read it will refuse
        print(f"warning: {damaged}", file=sys.stderr)
    if rig is None:
        raise RecordingError(
            f"{path} states no rig (no pendsim/rig_parameters metadata: another tool's recording, or an import); "
            f"its contents: pendsim inspect {path}"
        )
    return rig


def run(args: argparse.Namespace) -> int:
    params = DEFAULT_PARAMS if args.path is None else stated_by(args.path)
    if args.json:
        print(json.dumps(params.as_dict(), indent=2))
        return 0
    paper = DEFAULT_PARAMS.as_dict()
    rows = []
    for name, unit, source in RigParams.describe():
        value = getattr(params, name)
        if value != paper[name]:
            source = f"{args.path} (the paper's: {paper[name]:.6g})"
        rows.append((name, f"{value:.6g}", unit, source))
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    if args.path is None:
        print(f"Rig parameters ({PAPER}; doi:10.3390/machines13080660)")
    else:
        differ = sum(1 for name in paper if getattr(params, name) != paper[name])
        print(f"Rig parameters stated by {args.path}: {differ} not the paper's ({PAPER})")
    for name, value, unit, source in rows:
        print(f"  {name:{widths[0]}}  {value:>{widths[1]}}  {unit:{widths[2]}}  {source}")
    return 0
