"""pendsim acquire: record the rig's two sensor nodes over UDP into a pendsim recording."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

from pendsim_mj.errors import ParameterError

from .. import options
from ..acquire.packets import (
    DEFAULT_CSV_COLUMNS,
    DEFAULT_JSON_FIELDS,
    FORMATS,
    StreamFormat,
    Units,
    parse_columns,
    parse_fields,
    parse_units,
)
from ..acquire.ports import DEFAULT_NODES, NodeSpec, check_nodes, parse_node
from ..io.mcap.writer import COMPRESSIONS

if TYPE_CHECKING:
    from ..acquire.live import LiveView
    from ..acquire.receiver import AcquireSpec

T = TypeVar("T")


def argument(parse: Callable[[str], T], name: str) -> Callable[[str], T]:
    """An argparse type from a parser that raises ParameterError."""

    def convert(text: str) -> T:
        try:
            return parse(text)
        except ParameterError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    convert.__name__ = name
    return convert


def add_stream_options(p: argparse.ArgumentParser, *, what: str) -> None:
    """--node, --format, --columns, --units, --fields, --rate-hz (shared by acquire and nodes)."""
    p.add_argument(
        "--node",
        dest="nodes",
        type=argument(parse_node, "NAME=PORT"),
        action="append",
        metavar="NAME=PORT",
        help=f"a node and the UDP port it {what} (repeatable; default m1=5601 m2=5602; names m1, m2)",
    )
    p.add_argument(
        "--format",
        type=options.choice(FORMATS, "unknown format {value!r}; allowed: {allowed}"),
        choices=FORMATS,
        default="pendsim-v1",
        help="packet format: pendsim-v1 (binary, docs/acquisition.md), csv (one line per packet), json "
        "(one object per packet); default pendsim-v1",
    )
    p.add_argument(
        "--columns",
        type=argument(parse_columns, "column map"),
        metavar="NAMES",
        help=f"csv: the column map, comma-separated (default {','.join(DEFAULT_CSV_COLUMNS)}; names: t_s|t_ms|t_us, "
        "seq, node, qw..qz, gx..gz, ax..az (with gravity), lax..laz (linear), gvx..gvz (gravity), calib (CALIB_STAT) "
        "or cal_sys,cal_gyro,cal_accel,cal_mag, _ to skip)",
    )
    p.add_argument(
        "--units",
        type=argument(parse_units, "units"),
        metavar="MAP",
        help="csv/json: units, e.g. accel=m/s2,gyro=dps (accel: m/s2, g, mg; gyro: dps, rad/s; "
        "default accel=m/s2,gyro=dps)",
    )
    p.add_argument(
        "--fields",
        type=argument(parse_fields, "field map"),
        metavar="MAP",
        help="json: NAME=PATH pairs, comma-separated, e.g. t_us=time,gx=imu/gyro/x (default: node, seq, t_us, quat/w, "
        "..., gyro/x, ..., accel/x, ..., linear_accel/x, ..., gravity/x, ..., calib/sys, ...)",
    )
    p.add_argument(
        "--rate-hz",
        type=options.float_in(0.0, 100_000.0, "Hz", low_open=True, name="rate_hz"),
        default=80.0,
        help="the nodes' sample rate, Hz (default 80, the paper's)",
    )


def stream_from(args: argparse.Namespace) -> StreamFormat:
    """The packet format the options describe."""
    if args.columns is not None and args.format != "csv":
        raise options.UsageError("--columns is for --format csv")
    if args.fields is not None and args.format != "json":
        raise options.UsageError("--fields is for --format json")
    if args.units is not None and args.format == "pendsim-v1":
        raise options.UsageError("--units is for csv and json (pendsim-v1 carries the chip's own unit register)")
    return StreamFormat(
        args.format,
        args.columns or DEFAULT_CSV_COLUMNS,
        args.fields or DEFAULT_JSON_FIELDS,
        args.units or Units(),
    )


def nodes_from(args: argparse.Namespace) -> tuple[NodeSpec, ...]:
    return check_nodes(tuple(args.nodes)) if args.nodes else DEFAULT_NODES


def add_mjcf_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--mjcf",
        type=options.input_file,
        metavar="FILE.xml",
        help="the rig's MJCF model to attach (default: pendsim's, with the --set/--params-file parameters)",
    )


def mjcf_from(args: argparse.Namespace) -> tuple[str | None, str]:
    """(the MJCF text or None, where it came from), checked by compiling it with MuJoCo."""
    if args.mjcf is None:
        return None, "built by pendsim from the rig parameters"
    import mujoco

    try:
        text = args.mjcf.read_text()
        mujoco.MjModel.from_xml_string(text)
    except (OSError, UnicodeDecodeError) as exc:
        raise options.UsageError(f"{args.mjcf}: cannot read: {exc}") from None
    except ValueError as exc:
        raise options.UsageError(f"{args.mjcf}: not a valid MJCF model: {' '.join(str(exc).split())}") from None
    return text, str(args.mjcf.resolve())


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "acquire",
        help="record the rig's two sensor nodes (UDP) into a pendsim recording",
        description="Listen for each node's UDP packets on its own port (127.0.0.1 unless --bind), account for lost, "
        "duplicated, reordered, late and malformed packets, map each node's device time to one host time base, and "
        "write the recording (the layout of 'pendsim record', plus /diagnostics at 1 Hz). Stops after --duration-s, "
        "on Ctrl-C or SIGTERM. 'pendsim nodes' emulates the nodes.",
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="the .mcap file to write")
    p.add_argument("--force", action="store_true", help="replace the output file if it exists")
    add_stream_options(p, what="sends to")
    p.add_argument(
        "--bind", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only; 0.0.0.0: all)"
    )
    p.add_argument(
        "--duration-s",
        type=options.float_in(0.0, 7 * 86400.0, "s", low_open=True, name="duration_s"),
        help="stop after this long, s (default: on Ctrl-C or SIGTERM)",
    )
    p.add_argument(
        "--reorder-window-ms",
        type=options.float_in(0.0, 10_000.0, "ms"),
        default=200.0,
        help="how long a packet waits for earlier missing ones before they count as lost, ms (default 200)",
    )
    options.add_parameter_options(p, what="the rig recorded with the data")
    add_mjcf_option(p)
    p.add_argument(
        "--compression",
        type=options.choice(COMPRESSIONS, "unknown compression {value!r}; allowed: {allowed}"),
        choices=COMPRESSIONS,
        default="zstd",
        help="chunk compression (default zstd)",
    )
    options.add_rerun_option(p, "acquire.rrd", "also show the data live in Rerun, saved to an .rrd file")
    p.add_argument("--spawn", action="store_true", help="show the data live in the Rerun desktop viewer")
    p.add_argument("--serve", action="store_true", help="show the data live in Rerun's web viewer (--bind, --port)")
    p.add_argument(
        "--port", type=options.int_in(1024, 65534), default=9090, help="web viewer port for --serve (default 9090)"
    )
    p.set_defaults(handler=run)


def live_view(args: argparse.Namespace, spec: AcquireSpec) -> LiveView | None:
    """The live view the options ask for (None: none)."""
    if args.rerun is None and not args.spawn and not args.serve:
        return None
    from pendsim_mj.rig.model import exact_mjcf

    from ..acquire.live import LiveView

    live = LiveView(
        tuple(n.name for n in spec.nodes),
        spec.mjcf_xml or exact_mjcf(spec.params),
        rrd=args.rerun,
        spawn=args.spawn,
        serve=(args.bind, args.port) if args.serve else None,
    )
    if live.url is not None:
        print(f"live view: {live.url}", flush=True)
    return live


def run(args: argparse.Namespace) -> int:
    from ..acquire.receiver import AcquireSpec, acquire, summary

    options.check_output(args.output, (".mcap",), force=args.force)
    options.check_output(args.rerun, (".rrd",), force=True)
    mjcf, mjcf_source = mjcf_from(args)
    spec = AcquireSpec(
        nodes=nodes_from(args),
        bind=args.bind,
        stream=stream_from(args),
        rate_hz=args.rate_hz,
        duration_s=args.duration_s,
        reorder_window_s=args.reorder_window_ms * 1e-3,
        params=options.params_from(args),
        mjcf_xml=mjcf,
        mjcf_source=mjcf_source,
        compression=args.compression,
    )
    live = live_view(args, spec)
    try:
        result = acquire(spec, args.output, replace=args.force, live=live)
    except BaseException:
        if live is not None:
            live.close(publish_rrd=False)  # no recording: no live file either
        raise
    if live is not None:
        live.close()
    print(summary(result))
    if args.rerun is not None:
        print(f"wrote {args.rerun} ({result.live_batches} live batches)")
    return 0
