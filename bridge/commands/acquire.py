"""pendsim acquire: record the rig's two sensor nodes over UDP into a pendsim recording."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from .. import options
from ..io.mcap.writer import COMPRESSIONS
from .node_options import add_stream_options, nodes_from, stream_from

if TYPE_CHECKING:
    from ..acquire.live import LiveView
    from ..acquire.receiver import AcquireSpec


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "acquire",
        help="record the rig's two sensor nodes (UDP) into a pendsim recording",
        description="Listen for each node's UDP packets on its own port (127.0.0.1 unless --bind), account for lost, "
        "duplicated, reordered, late, malformed and implausible (off the node's timeline) packets, map each node's "
        "device time to one host time base, and "
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
        type=options.float_in(0.0, 7 * 86400.0, "s", low_open=True, name="--duration-s"),
        help="stop after this long, s (default: on Ctrl-C or SIGTERM)",
    )
    p.add_argument(
        "--reorder-window-ms",
        type=options.float_in(0.0, 10_000.0, "ms"),
        default=200.0,
        help="how long a packet waits for earlier missing ones before they count as lost, ms (default 200)",
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
    from pendsim_mj.rig.model import exact_mjcf  # start-up: MuJoCo and Rerun, only for a live view

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
    from ..acquire.receiver import AcquireSpec, acquire, summary  # start-up: loaded when the command runs

    options.check_output(args.output, (".mcap",), force=args.force)
    options.check_output(args.rerun, (".rrd",), force=True)
    mjcf, mjcf_source = options.mjcf_from(args)
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
