"""pendsim replay: re-emit a recording's messages in log-time order."""

from __future__ import annotations

import argparse
import contextlib
import math
from pathlib import Path
from typing import TYPE_CHECKING

from .. import options

if TYPE_CHECKING:
    from ..run.replay import ReplayMessage, ReplayStats

SPEED_RANGE = (1e-3, 1e6)
"""Replay speeds, x real time: from 1000 times slower to a million times faster (or max)."""


def speed(text: str) -> float:
    """A replay speed in ``SPEED_RANGE``, or 'max' (as fast as possible: inf)."""
    if text == "max":
        return math.inf
    low, high = SPEED_RANGE
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and low <= value <= high):
        raise argparse.ArgumentTypeError(f"--speed must be a number in [{low:g}, {high:g}] or max, got {text!r}")
    return value


speed.low, speed.high, speed.low_open = SPEED_RANGE[0], SPEED_RANGE[1], False  # type: ignore[attr-defined]


def topic_list(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "replay",
        help="re-emit a recording's messages in log-time order, paced, cut and filtered, to terminal, MCAP or Rerun",
        description="Replay the messages of a recording in log-time order at --speed (1 = real time, 10, or max), "
        "within --start/--end (s of log time), for --topics, optionally --loop. Prints one line per message, or "
        "writes them to a new MCAP (-o, cut and filtered; --shift moves the window to t = 0) or to Rerun (--rerun). "
        "From Python: pendsim_bridge.run.replay.replay() yields decoded messages.",
    )
    p.add_argument("path", type=options.mcap_file, help="the .mcap recording")
    p.add_argument("--speed", type=speed, default=math.inf, help="1 = real time, any factor > 0, or max (default)")
    log_time = options.float_in(0.0, options.MAX_LOG_TIME_S, "s")
    p.add_argument("--start", type=log_time, metavar="S", help="first time to replay, s since the recording's start")
    p.add_argument("--end", type=log_time, metavar="S", help="last time to replay, s since the recording's start")
    p.add_argument("--topics", type=topic_list, help="comma-separated topics (default all)")
    p.add_argument("--loop", action="store_true", help="start again after the end (Ctrl-C stops)")
    p.add_argument("-o", "--output", type=Path, help="write the replayed messages to a new .mcap")
    p.add_argument("--shift", action="store_true", help="with -o: move log times so that the window starts at 0")
    p.add_argument(
        "--keep-unverified",
        action="store_true",
        help="with -o: also carry content no CRC covers, listed in the new file's pendsim/unverified metadata",
    )
    p.add_argument("--rerun", type=Path, metavar="FILE.rrd", help="log the replayed Imu and JointState values to Rerun")
    p.add_argument("--quiet", action="store_true", help="print only the summary")
    options.add_force_option(p, "the -o or --rerun file")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from ..run.replay import ReplayStats, replay, replay_to_mcap  # start-up: loaded when the command runs

    if args.output is not None:
        if args.loop:
            raise options.UsageError("--loop cannot write to a file (it never ends); drop --loop or -o")
        options.check_not_input(args.output, args.path)
        options.check_output(args.output, (".mcap",), force=args.force)
        with options.replacing(args.output, force=args.force) as target:
            count = replay_to_mcap(
                args.path,
                target,
                topics=args.topics,
                start_s=args.start,
                end_s=args.end,
                shift_to_zero=args.shift,
                keep_unverified=args.keep_unverified,
            )
        print(f"wrote {args.output}: {count} messages")
        return 0
    options.check_output(args.rerun, (".rrd",), force=args.force)
    stats = ReplayStats()
    with _rerun_sink(args.rerun, replace=args.force):
        try:
            for message in replay(
                args.path, speed=args.speed, topics=args.topics, start_s=args.start, end_s=args.end, loop=args.loop,
                stats=stats,
            ):  # fmt: skip
                _emit(message, args)
        except KeyboardInterrupt:
            if not args.loop:
                raise  # an interrupted replay: exit 130, no --rerun file
            # Ctrl-C is how a --loop replay ends: the summary and the --rerun file follow
    print(_summary_line(stats, args.speed))
    if args.rerun is not None:
        print(f"wrote {args.rerun}")
    return 0


def _emit(message: ReplayMessage, args: argparse.Namespace) -> None:
    from ..run.replay import log_to_rerun  # start-up: loaded when the command runs

    if args.rerun is not None and message.schema_name in ("sensor_msgs/msg/Imu", "sensor_msgs/msg/JointState"):
        log_to_rerun(message)
    if not args.quiet:
        print(f"{message.t_s:12.4f}  {message.topic}  {len(message.data)} B")


def _summary_line(stats: ReplayStats, speed: float) -> str:
    summary = stats.summary()
    line = f"replayed {summary.messages} messages"
    if math.isfinite(speed):
        late = f"p50 {summary.p50_ms:.2f} ms, p99 {summary.p99_ms:.2f} ms, max {summary.max_ms:.2f} ms"
        line += f" at {speed:g}x; lateness {late}"
    return line


def _rerun_sink(path: Path | None, *, replace: bool) -> contextlib.AbstractContextManager[object]:
    """Log to an .rrd file while replaying, published when the replay ends (nothing when ``path``
    is None)."""
    if path is None:
        return contextlib.nullcontext()
    from ..report.rerun_view import rrd_output  # start-up: Rerun, only with --rerun

    return rrd_output(path, replace=replace, series=None, application_id="pendsim_replay")
