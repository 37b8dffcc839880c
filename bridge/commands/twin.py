"""pendsim twin: the rig's digital twin running beside it, on live packets or a replayed recording."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from .. import options
from .node_options import add_stream_options, nodes_from, stream_from

if TYPE_CHECKING:
    from pendsim_mj.rig.params import RigParams

    from ..acquire.twin.pipeline import TwinSpec
    from ..report.twin_views import TwinView

TRACK_ALL = "all"
NODES = ("m1", "m2")


def track_list(text: str) -> tuple[str, ...]:
    """``all``, ``none`` or a comma-separated list of the rig's parameters the twin can track."""
    from pendsim_mj.twin.session import RIG_PARAMETERS as TRACKABLE  # start-up: numpy only

    text = text.strip()
    if text == TRACK_ALL:
        return tuple(TRACKABLE)
    if text == "none":
        return ()
    names = tuple(n.strip() for n in text.split(","))
    unknown = [n for n in names if n and n not in TRACKABLE]
    if unknown or not all(names) or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(
            f"--track {text!r}: {'unknown ' + ', '.join(unknown) if unknown else 'an empty or repeated name'}; "
            f"allowed: all, none, or a comma-separated list of {', '.join(TRACKABLE)}"
        )
    return names


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "twin",
        help="run the rig's digital twin beside it: state, forecast and health from the live nodes (or a recording)",
        description="Listen to both nodes' UDP packets (as 'pendsim acquire' does; 'pendsim nodes' emulates them) or "
        "replay a recording (--replay), and run the twin on them: an unscented Kalman filter on the planar model "
        "estimates the state at every sample, tracks the parameters that can drift (damping, dry friction, the "
        "coupling springs, each node's mount) with their intervals, forecasts the next seconds (scored afterwards "
        "against what was measured), and raises an alarm when a parameter leaves its reference (which one, since "
        "when, by how much). Writes a recording: the measured data, /twin/estimate, /twin/parameters, "
        "/twin/forecast and /diagnostics (docs/twin.md). Stops after --duration-s, at the recording's end, on "
        "Ctrl-C or SIGTERM.",
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="the .mcap file to write")
    p.add_argument("--force", action="store_true", help="replace the output file if it exists")
    p.add_argument(
        "--replay",
        type=options.mcap_file,
        metavar="REC.mcap",
        help="run on this recording instead of live packets, on the rig it states (--params-file, --set on top: "
        "e.g. the rig 'pendsim calibrate' found from it)",
    )
    p.add_argument(
        "--speed",
        type=options.float_in(0.0, 1000.0, "x"),
        help="--replay: this many times the recording's pace; 0: as fast as it can (default 1)",
    )
    add_stream_options(p, what="sends to")
    p.add_argument(
        "--bind",
        type=options.bind_address,
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1: this machine only; 0.0.0.0: all)",
    )
    p.add_argument(
        "--duration-s",
        type=options.float_in(0.0, 7 * 86400.0, "s", low_open=True, name="--duration-s"),
        help="stop after this long, s (default: on Ctrl-C or SIGTERM)",
    )
    options.add_parameter_options(p, what="the twin's rig")
    p.add_argument(
        "--track",
        type=options.argument(track_list, "LIST"),
        default=None,
        metavar="LIST",
        help="the rig's parameters tracked and monitored: all (default), none, or a comma-separated list of "
        "b1_n_m_s, b2_n_m_s, friction1_n_m, friction2_n_m, coupling_sin_n_m (the nodes' states are tracked always: "
        "their mount offsets, monitored, and their offsets' rates, M2's delay and the accelerometers' turns, not)",
    )
    p.add_argument(
        "--forecast-s",
        type=options.float_in(0.0, 60.0, "s"),
        default=2.0,
        help="each forecast's horizon, s; 0: none (default 2; one forecast a second)",
    )
    p.add_argument(
        "--threshold-sigma",
        type=options.float_in(2.0, 100.0, "sigma", low_open=True),
        default=5.0,
        help="a parameter this many standard deviations from its reference counts as changed (default 5)",
    )
    p.add_argument(
        "--persist-s",
        type=options.float_in(0.0, 3600.0, "s"),
        default=3.0,
        help="how long a change must last before the alarm, s (default 3)",
    )
    p.add_argument(
        "--baseline-s",
        type=options.float_in(0.0, 86400.0, "s"),
        default=0.0,
        help="the references are the estimates this long after the start, s; 0: the rig given (default 0)",
    )
    p.add_argument(
        "--hold-ms",
        type=options.float_in(0.0, 1000.0, "ms"),
        default=20.0,
        help="the longest a node's sample waits for the other node's, to take both in time order, ms (default 20)",
    )
    options.add_rerun_option(p, "twin.rrd", "also show the twin live in Rerun, saved to an .rrd file")
    p.add_argument("--spawn", action="store_true", help="show the twin live in the Rerun desktop viewer")
    p.add_argument("--serve", action="store_true", help="show the twin live in Rerun's web viewer (--bind, --port)")
    p.add_argument(
        "--port", type=options.int_in(1024, 65534), default=9090, help="web viewer port for --serve (default 9090)"
    )
    p.add_argument(
        "--foxglove",
        type=options.int_in(1024, 65535),
        nargs="?",
        const=8765,
        metavar="PORT",
        help="serve the twin live to Foxglove (WebSocket, on --bind) on this port (default 8765)",
    )
    p.set_defaults(handler=run)


def _views_for(args: argparse.Namespace, params: RigParams) -> Callable[[int], tuple[TwinView, ...]] | None:
    """What opens the live views the options ask for, once the twin's start is known (None: none)."""
    if args.rerun is None and not args.spawn and not args.serve and args.foxglove is None:
        return None

    def open_views(start_utc_ns: int) -> tuple[TwinView, ...]:
        from pendsim_mj.rig.model import exact_mjcf  # start-up: MuJoCo and the viewers, only for a live view

        mjcf = exact_mjcf(params)
        views: list[TwinView] = []
        try:
            if args.rerun is not None or args.spawn or args.serve:
                from ..report.twin_rerun import TwinRerunView

                serve = (args.bind, args.port) if args.serve else None
                rerun = TwinRerunView(start_utc_ns, NODES, mjcf, rrd=args.rerun, spawn=args.spawn, serve=serve)
                views.append(rerun)
                if rerun.url is not None:
                    print(f"live view: {rerun.url}", flush=True)
            if args.foxglove is not None:
                from ..report.twin_foxglove import TwinFoxgloveView

                fox = TwinFoxgloveView(start_utc_ns, NODES, mjcf_xml=mjcf, bind=args.bind, port=args.foxglove)
                views.append(fox)
                print(f"foxglove: {fox.url} (Foxglove: Open connection, Foxglove WebSocket)", flush=True)
        except BaseException:
            for v in views:
                v.close()
            raise
        return tuple(views)

    return open_views


def _rig_of(args: argparse.Namespace) -> RigParams:
    """The twin's rig: live, the paper's with --params-file/--set on top; a replay, the recording's
    own with them on top (as ``validate`` takes it): a rig calibrated from its recordings
    (``pendsim calibrate``) differs from what they state, and is given to replay them."""
    if args.replay is None:
        return options.params_from(args)
    from ..io.measured import recorded_params
    from ..io.recording import read_recording

    return recorded_params(read_recording(args.replay, topics=())).with_mapping(options.overrides_from(args))


def spec_from(args: argparse.Namespace) -> TwinSpec:
    """The twin the options describe (bad combinations refused first)."""
    from pendsim_mj.twin.session import RIG_PARAMETERS

    from ..acquire.twin.pipeline import TwinSpec

    options.check_output(args.output, (".mcap",), force=args.force)
    options.check_output(args.rerun, (".rrd",), force=args.force)
    if args.replay is not None:
        options.check_not_input(args.output, args.replay)
        if args.duration_s is not None:
            raise options.UsageError("--duration-s is for live packets; a replay runs to the recording's end")
    elif args.speed is not None:
        raise options.UsageError("--speed is for --replay")
    return TwinSpec(
        params=_rig_of(args),
        track=args.track if args.track is not None else RIG_PARAMETERS,
        forecast_horizon_s=args.forecast_s,
        threshold=args.threshold_sigma,
        persist_s=args.persist_s,
        baseline_s=args.baseline_s,
        hold_s=args.hold_ms * 1e-3,
    )


def run(args: argparse.Namespace) -> int:
    import time

    from ..acquire.receiver import StatusLine
    from ..acquire.twin.summary import summary_text

    spec = spec_from(args)
    views_for = _views_for(args, spec.params)
    # live and replayed alike: events and alarms as they come, and the status line, on stderr (in place
    # on a terminal, every 10 s otherwise); the summary on stdout
    line, started = StatusLine(None), time.monotonic()
    try:
        if args.replay is not None:
            from ..acquire.twin.replay import replay

            speed = 1.0 if args.speed is None else args.speed
            result = replay(
                spec, args.replay, output=args.output, replace=args.force, speed=speed, views_for=views_for,
                say=line.say, status=lambda text: line.show(text, time.monotonic() - started),
            )  # fmt: skip
        else:
            from ..acquire.twin.live import run_twin_live

            result = run_twin_live(
                spec, output=args.output, replace=args.force, nodes=nodes_from(args), bind=args.bind,
                stream=stream_from(args), rate_hz=args.rate_hz, duration_s=args.duration_s, views_for=views_for,
                say=line.say, status=lambda text: line.show(text, time.monotonic() - started),
            )  # fmt: skip
    finally:
        line.end()
    print(summary_text(result))
    return 0
