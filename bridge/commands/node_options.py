"""Options that describe the rig's sensor nodes, shared by the commands that simulate or receive
them: the packet stream (``pendsim acquire`` and ``pendsim nodes``: ``add_stream_options``,
``stream_from``, ``nodes_from``) and the imperfections of real nodes (``pendsim record`` and
``pendsim nodes``: ``add_imperfection_options``, ``imperfections_from``). Not a command itself.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Collection
from typing import Any

import numpy as np

from pendsim_mj.errors import ParameterError
from pendsim_mj.sensors.bno055 import SAMPLE_RATE_HZ
from pendsim_mj.sensors.imperfections import Imperfections, axis_remap_matrix, random_mount

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


def add_stream_options(p: argparse.ArgumentParser, *, what: str) -> None:
    """--node, --format, --columns, --units, --fields, --rate-hz (shared by acquire and nodes)."""
    p.add_argument(
        "--node",
        dest="nodes",
        type=options.argument(parse_node, "NAME=PORT"),
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
        type=options.argument(parse_columns, "column map"),
        metavar="NAMES",
        help=f"csv: the column map, comma-separated (default {','.join(DEFAULT_CSV_COLUMNS)}; names: t_s|t_ms|t_us, "
        "seq, node, qw..qz, gx..gz, ax..az (with gravity), lax..laz (linear), gvx..gvz (gravity), calib (CALIB_STAT) "
        "or cal_sys,cal_gyro,cal_accel,cal_mag, _ to skip)",
    )
    p.add_argument(
        "--units",
        type=options.argument(parse_units, "units"),
        metavar="MAP",
        help="csv/json: units, e.g. accel=m/s2,gyro=dps (accel: m/s2, g, mg, raw-m/s2; gyro: dps, rad/s, raw-dps, "
        "raw-rad/s; raw-: the BNO055's register counts; default accel=m/s2,gyro=dps)",
    )
    p.add_argument(
        "--fields",
        type=options.argument(parse_fields, "field map"),
        metavar="MAP",
        help="json: NAME=PATH pairs, comma-separated, e.g. t_us=time,gx=imu/gyro/x (default: node, seq, t_us, quat/w, "
        "..., gyro/x, ..., accel/x, ..., linear_accel/x, ..., gravity/x, ..., calib/sys, ...)",
    )
    p.add_argument(
        "--rate-hz",
        type=options.float_in(0.0, 100_000.0, "Hz", low_open=True, name="--rate-hz"),
        default=SAMPLE_RATE_HZ,
        help=f"the nodes' sample rate, Hz (default {SAMPLE_RATE_HZ:g}, the paper's)",
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


def axis_remap(text: str) -> tuple[int, int]:
    """CONFIG,SIGN: the BNO055's AXIS_MAP_CONFIG and AXIS_MAP_SIGN registers (hex 0x.. or decimal)."""
    try:
        config, sign = (int(v, 0) for v in text.split(","))
        axis_remap_matrix(config, sign)
    except ValueError as exc:
        detail = str(exc) if isinstance(exc, ParameterError) else "expected CONFIG,SIGN such as 0x21,0x04"
        raise argparse.ArgumentTypeError(f"--axis-remap {text!r}: {detail}") from None
    return config, sign


def _imperfection_options() -> list[tuple[str, bool, dict[str, Any]]]:
    """(flag, a transport option, argparse keywords) of every imperfection option."""
    return [
        ("--heading-deg", False, dict(
            type=options.float_in(-360.0, 360.0, "deg"), default=0.0,
            help="NDOF heading: the orientation's world frame turned by this angle about the vertical (magnetic north)",
        )),
        ("--mount-misalignment-deg", False, dict(
            type=options.float_in(0.0, 45.0, "deg"), default=0.0, metavar="A",
            help="each node glued on turned by A deg about a random axis (drawn from --seed)",
        )),
        ("--axis-remap", False, dict(
            type=axis_remap, default=(0x24, 0x00), metavar="CONFIG,SIGN",
            help="both nodes' AXIS_MAP_CONFIG,AXIS_MAP_SIGN registers, e.g. 0x21,0x04 (default 0x24,0x00: none)",
        )),
        ("--fusion-error-deg", False, dict(
            type=options.float_in(0.0, 10.0, "deg"), default=0.0, metavar="E",
            help="rms per axis of a slowly varying error of the fused orientation (periods around 30 s), deg",
        )),
        ("--packet-loss", True, dict(
            type=options.float_in(0.0, 0.9), default=0.0, metavar="P",
            help="share of each node's samples lost in transport, in bursts (e.g. 0.05)",
        )),
        ("--loss-burst-samples", True, dict(
            type=options.float_in(1.0, 1000.0), default=3.0, metavar="L",
            help="mean length of a burst of lost samples (default 3; 1: independent losses)",
        )),
        ("--clock-drift-ppm", True, dict(
            type=options.float_in(-1000.0, 1000.0, "ppm"), default=0.0, metavar="PPM",
            help="M2's node clock runs this much faster than M1's (its stamps are on its own clock)",
        )),
        ("--latency-s", True, dict(
            type=options.float_in(0.0, 1.0, "s"), default=0.0,
            help="mean transport latency (exponential) between sampling and logging, s",
        )),
        ("--hold-wobble-deg", False, dict(
            type=options.float_in(0.0, 5.0, "deg"), default=0.0,
            help="with --hold-s: rms angle the hand moves the held pendulums by (slow drift plus 8-12 Hz tremor), deg",
        )),
    ]  # fmt: skip


def add_imperfection_options(
    p: argparse.ArgumentParser, *, transport: bool = True, only: Collection[str] | None = None
) -> None:
    """What real nodes add (pendsim_mj.sensors.imperfections); all off by default. Without ``transport``,
    only what changes the values (heading, mount, axis remap, fusion error, hold wobble): loss,
    clock drift and latency are then the caller's (``pendsim nodes`` sends real packets). ``only``:
    just these flags (a command whose runs the others would not change); ``imperfections_from``
    takes the missing ones as off."""
    g = p.add_argument_group("imperfections of real nodes (all off by default; the paper is silent on them)")
    for flag, is_transport, keywords in _imperfection_options():
        if (transport or not is_transport) and (only is None or flag in only):
            g.add_argument(flag, **keywords)


def imperfections_from(args: argparse.Namespace) -> tuple[Imperfections, tuple[tuple[float, float, float, float], ...]]:
    """The Imperfections and the two mount rotations the options describe."""
    config, sign = getattr(args, "axis_remap", (0x24, 0x00))
    loss = getattr(args, "packet_loss", 0.0)
    imperfect = Imperfections(
        heading_rad=math.radians(getattr(args, "heading_deg", 0.0)),
        axis_map_config=(config, config),
        axis_map_sign=(sign, sign),
        fusion_error_rad=math.radians(getattr(args, "fusion_error_deg", 0.0)),
        packet_loss=loss,
        loss_burst_samples=args.loss_burst_samples if loss > 0 else 1.0,
        # a transport option only where the transport options were given (``pendsim nodes`` has
        # a per-node --clock-drift-ppm of its own and no --latency-s)
        clock_drift_ppm=(0.0, args.clock_drift_ppm)
        if hasattr(args, "latency_s") and hasattr(args, "clock_drift_ppm")
        else (0.0, 0.0),
        latency_s=getattr(args, "latency_s", 0.0),
        hold_wobble_rad=math.radians(getattr(args, "hold_wobble_deg", 0.0)),
    )
    rng = np.random.default_rng([args.seed, 5])
    angle = math.radians(getattr(args, "mount_misalignment_deg", 0.0))
    mounts = tuple(random_mount(angle, rng) if angle else (1.0, 0.0, 0.0, 0.0) for _ in range(2))
    return imperfect, mounts
