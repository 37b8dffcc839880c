"""pendsim import: a lab file (CSV, LabVIEW .lvm, TDMS) into a pendsim recording."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .. import options
from ..acquire.importers import IMPORT_FORMATS, ImportSpec, import_file, parse_utc
from ..acquire.packets import Units, parse_units
from ..io.mcap.writer import COMPRESSIONS


def column_list(text: str) -> tuple[str, ...]:
    return tuple(c.strip() for c in text.split(","))


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "import",
        help="import a lab file (CSV, LabVIEW .lvm, TDMS) of the rig's IMUs into a pendsim recording",
        description="Read a CSV, LabVIEW measurement (.lvm) or TDMS file and write a recording with the layout of "
        "'pendsim record', so that inspect, view, validate, identify and allan work on it. --columns names each "
        "column of the file in order (t_s|t_ms|t_us, m1.gx, m1.gy, ..., m2.qw, ...; _ skips a column; TDMS columns "
        "are its channels, group by group); the source file is recorded in the metadata.",
    )
    p.add_argument("source", type=options.input_file, help="the file to import")
    p.add_argument("-o", "--output", type=Path, required=True, help="the .mcap file to write")
    p.add_argument("--force", action="store_true", help="replace the output file if it exists")
    p.add_argument(
        "--format",
        type=options.choice(IMPORT_FORMATS, "unknown import format {value!r}; allowed: {allowed}"),
        choices=IMPORT_FORMATS,
        help="csv, lvm or tdms (default: from the file's extension)",
    )
    p.add_argument(
        "--columns",
        type=column_list,
        metavar="NAMES",
        help="one name per column of the file, comma-separated, e.g. t_s,m1.gx,m1.gy,m1.gz,_,... "
        "(default: the file's own column names)",
    )
    p.add_argument(
        "--units",
        type=options.argument(parse_units, "units"),
        metavar="MAP",
        help="units of the values, e.g. accel=m/s2,gyro=dps (accel: m/s2, g, mg, raw-m/s2; gyro: dps, rad/s, "
        "raw-dps, raw-rad/s; raw-: the BNO055's register counts; default accel=m/s2,gyro=dps). The data's own "
        "physics check them (the gyro against the quaternions' rotation, gravity's magnitude): a mix-up is an error "
        "that names the right units",
    )
    p.add_argument(
        "--trust-units",
        action="store_true",
        help="import with the --units given even where the data contradict them: the mix-up becomes a warning, "
        "recorded in the metadata",
    )
    p.add_argument(
        "--node",
        choices=("m1", "m2"),
        type=options.choice(("m1", "m2"), "unknown node {value!r}; allowed: {allowed}"),
        help="the file holds this one node: its column names have no m1./m2. prefix",
    )
    p.add_argument(
        "--rate-hz",
        type=options.float_in(0.0, 100_000.0, "Hz", low_open=True, name="--rate-hz"),
        help="sample rate, for a file with no time column and no timing of its own, Hz",
    )
    p.add_argument(
        "--start-utc",
        type=options.argument(parse_utc, "time"),
        metavar="TIME",
        help="when the first sample was taken, ISO 8601 with its zone, e.g. 2026-11-25T10:00:00Z: for files whose "
        "times count from the node's boot (millis()) or from zero (default: the file's times, taken as UTC if they "
        "are Unix times, else kept relative and said so)",
    )
    options.add_parameter_options(p, what="the rig recorded with the data")
    options.add_mjcf_option(p)
    p.add_argument(
        "--compression",
        type=options.choice(COMPRESSIONS, "unknown compression {value!r}; allowed: {allowed}"),
        choices=COMPRESSIONS,
        default="zstd",
        help="chunk compression (default zstd)",
    )
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    options.check_output(args.output, (".mcap",), force=args.force)
    mjcf, mjcf_source = options.mjcf_from(args)
    spec = ImportSpec(
        format=args.format,
        columns=args.columns,
        units=args.units or Units(),
        node=args.node,
        rate_hz=args.rate_hz,
        start_utc_ns=args.start_utc,
        trust_units=args.trust_units,
        params=options.params_from(args),
        mjcf_xml=mjcf,
        mjcf_source=mjcf_source,
        compression=args.compression,
    )
    result = import_file(args.source, args.output, spec, replace=args.force)
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    counts = ", ".join(f"{n}: {k} samples" for n, k in result.samples.items())
    print(
        f"wrote {result.path}: {result.format} file {result.source.name}, {result.duration_s:.3f} s, {counts}, "
        f"{result.size_bytes / 1e6:.2f} MB"
    )
    return 0
