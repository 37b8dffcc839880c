"""pendsim nodes: emulate the rig's two sensor nodes, sending the simulated rig over UDP."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from pendsim_mj.errors import ParameterError
from pendsim_mj.sensors.bno055 import Bno055

from .. import options
from .node_options import add_imperfection_options, add_stream_options, imperfections_from, nodes_from, stream_from

if TYPE_CHECKING:
    from ..acquire.emulator import EmulatorSpec
    from ..acquire.rig_faults import RigFault


def per_node(flag: str, low: float, high: float, unit: str) -> Callable[[str], tuple[str | None, float]]:
    """An argument type: ``m1=20`` (one node) or ``20`` (every node) to (name or None, value), the
    value in [low, high] ``unit`` (messages name ``flag``)."""
    number = options.float_in(low, high, unit, name=flag)

    def parse(text: str) -> tuple[str | None, float]:
        name, sep, value = text.rpartition("=")
        if sep and name.strip() not in ("m1", "m2"):
            raise ParameterError(f"{flag}: unknown node {name.strip()!r}; allowed: m1, m2")
        try:
            return (name.strip() if sep else None), number(value)
        except argparse.ArgumentTypeError as exc:
            raise ParameterError(str(exc)) from None

    return parse


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "nodes",
        help="emulate the rig's two sensor nodes: send the simulated rig over UDP in real time",
        description="Simulate a release (the options of 'pendsim record'), sample both BNO055 nodes and send their "
        "packets in real time to the given ports, as the rig's ESP32 nodes do, each on its own clock; with seeded "
        "packet loss, duplicates, reordering, jitter, clock drift and malformed packets; --log writes exactly what "
        "was sent. For 'pendsim acquire'.",
    )
    add_stream_options(p, what="sends to")
    p.add_argument("--host", default="127.0.0.1", help="where to send (default 127.0.0.1)")
    options.add_run_options(p)
    duration = p._option_string_actions["--duration-s"]  # the nodes stream for this long, the hold included
    duration.help = "how long the nodes send, s: the hold, then the release (default 30)"
    duration.default = 30.0
    p.add_argument(
        "--hold-s",
        type=options.float_in(0.0, 3600.0, "s"),
        default=2.0,
        help="send this long with the pendulums held still before the release, s (default 2)",
    )
    p.add_argument("--no-noise", action="store_true", help="ideal BNO055 signals: no noise, clipping or quantisation")
    p.add_argument("--seed", type=options.int_in(0, 2**63 - 1), default=0, help="seed of noise, faults and clocks")
    rate = options.float_in(0.0, 1.0)
    p.add_argument("--loss", type=rate, default=0.0, help="share of packets lost, 0-1 (default 0)")
    p.add_argument("--duplicate", type=rate, default=0.0, help="share of packets sent twice, 0-1 (default 0)")
    p.add_argument("--reorder", type=rate, default=0.0, help="share of packets held back, 0-1 (default 0)")
    p.add_argument(
        "--reorder-depth",
        type=options.int_in(1, 1000),
        default=2,
        help="a held-back packet is sent after this many later ones (default 2)",
    )
    p.add_argument(
        "--jitter-ms",
        type=options.float_in(0.0, 10_000.0, "ms"),
        default=0.0,
        help="mean extra network delay per packet, exponential, first in first out, ms (default 0)",
    )
    p.add_argument("--malformed", type=rate, default=0.0, help="rate of extra malformed datagrams, 0-1 (default 0)")
    p.add_argument(
        "--clock-drift-ppm",
        type=options.argument(per_node("--clock-drift-ppm", -1000.0, 1000.0, "ppm"), "[NAME=]PPM"),
        action="append",
        default=[],
        metavar="[NAME=]PPM",
        help="a node's clock rate error, ppm, + runs fast (m1=20, or 20 for every node; repeatable; default 0)",
    )
    p.add_argument(
        "--clock-offset-s",
        type=options.argument(per_node("--clock-offset-s", 0.0, 1e8, "s"), "[NAME=]S"),
        action="append",
        default=[],
        metavar="[NAME=]S",
        help="a node's clock reading at the start, s (default: drawn from --seed, 10-600 s)",
    )
    add_imperfection_options(p, transport=False)  # loss, drift and latency are this command's own
    p.add_argument(
        "--fault",
        type=options.argument(_parse_fault, "fault"),
        action="append",
        default=[],
        metavar="KIND:TARGETCHANGE@WHEN",
        help="a scripted rig fault, T in s after the release (repeatable): stiffness:[c1|c2]CHANGE, "
        "damping:m1|m2CHANGE, friction:m1|m2CHANGE with CHANGE *FACTOR, =VALUE or +-PERCENT%%; mount:m1|m2=ANGLEdeg "
        "(the node turns about the hinge axis); clock:m1|m2=JUMP (s); @T a step, @T..T2 a ramp (physics only), "
        "@T~T2 a step at a time drawn from --seed; e.g. stiffness:-5%%@20, damping:m1*2@20, clock:m2=+0.5@20 "
        "(docs/acquisition.md, Scripted faults)",
    )
    p.add_argument(
        "--log",
        type=Path,
        metavar="FILE.jsonl|FILE.csv",
        help="write what was sent to this file, JSON lines (.jsonl) or CSV (.csv): the name must end in one of them",
    )
    p.add_argument("--force", action="store_true", help="replace the log file if it exists")
    add_motor_options(p)
    p.set_defaults(handler=run)


def _parse_fault(text: str) -> RigFault:
    from ..acquire.rig_faults import parse_fault

    return parse_fault(text)


def spec_from(args: argparse.Namespace) -> EmulatorSpec:
    """The emulator spec the options describe."""
    from ..acquire.emulator import EmulatorSpec, Faults, NodeClock  # start-up: MuJoCo, when the command runs
    from ..run.record import RecordSpec

    phi0, omega0 = options.initial_state_from(args)
    imperfect, mounts = imperfections_from(args)
    imu = Bno055(noise=not args.no_noise, seed=args.seed, mount_quat_wxyz=mounts, imperfections=imperfect)
    after_release_s = args.duration_s - args.hold_s
    if after_release_s <= 0:
        raise options.UsageError(f"--duration-s {args.duration_s:g} must be longer than --hold-s {args.hold_s:g}")
    run = RecordSpec(
        options.params_from(args), phi0, omega0, after_release_s, args.dt_s, args.engine, "planar", args.hold_s, imu
    )
    nodes = nodes_from(args)
    names = [n.name for n in nodes]
    drift: dict[str, float] = {}
    offset: dict[str, float] = {}
    for store, given, what in (
        (drift, args.clock_drift_ppm, "--clock-drift-ppm"),
        (offset, args.clock_offset_s, "--clock-offset-s"),
    ):
        for name, value in given:
            for target in [name] if name is not None else names:
                if target not in names:
                    raise options.UsageError(f"{what} {name}=...: node {name} is not sent to (--node)")
                store[target] = value
    clocks = tuple(
        (n, NodeClock(drift.get(n, 0.0), offset.get(n))) for n in names if n in drift or n in offset
    )  # fmt: skip
    faults = Faults(args.loss, args.duplicate, args.reorder, args.reorder_depth, args.jitter_ms, args.malformed)
    return EmulatorSpec(
        run, nodes, args.host, stream_from(args), args.rate_hz, faults, clocks, args.seed, tuple(args.fault)
    )


def run(args: argparse.Namespace) -> int:
    from ..acquire.emulator import LOG_SUFFIXES, plan, summary  # start-up: MuJoCo, when the command runs
    from ..acquire.emulator import run as send

    if args.motor:
        return run_motor(args)
    given = [flag for flag, dest in MOTOR_OPTIONS if getattr(args, dest) not in (None, [])]
    if given:
        raise options.UsageError(f"{given[0]} is for the rig with motors: add --motor")
    if args.log is not None:
        options.check_output(args.log, LOG_SUFFIXES, force=args.force)
    spec = spec_from(args)
    if not math.isfinite(spec.total_s):
        raise options.UsageError("the run must have a finite duration")
    result = send(spec, log=args.log, replace_log=args.force, prepared=plan(spec))
    print(summary(result))
    return 0


MOTOR_OPTIONS = (
    ("--actuator-port", "actuator_port"),
    ("--actuator-bind", "actuator_bind"),
    ("--command-latency-ms", "command_latency_ms"),
    ("--command-jitter-ms", "command_jitter_ms"),
    ("--torque-limit-n-m", "torque_limit_n_m"),
    ("--command-period-ms", "command_period_ms"),
    ("--watchdog-margin-ms", "watchdog_margin_ms"),
    ("--silent-after-s", "silent_after_s"),
)
"""The options of the rig with motors (``--motor``), as (flag, dest)."""


def add_motor_options(p: argparse.ArgumentParser) -> None:
    """--motor and the actuator's options (docs/control.md, "The loop over UDP")."""
    g = p.add_argument_group("the rig with motors (--motor: a controller closes the loop over UDP)")
    g.add_argument(
        "--motor",
        action="store_true",
        help="play the rig with a motor at each hinge, live: the rig moves with the torques the actuator node "
        "applies, the nodes send what they measure, the actuator takes commands on --actuator-port",
    )
    g.add_argument(
        "--actuator-port",
        type=options.int_in(1, 65535),
        help="the actuator's UDP port for commands (default 5603)",
    )
    g.add_argument(
        "--actuator-bind",
        type=options.bind_address,
        help="the address the actuator listens on (default 127.0.0.1: this machine only)",
    )
    g.add_argument(
        "--command-latency-ms",
        type=options.float_in(0.0, 1000.0, "ms"),
        help="from a command's arrival to its torque, ms (default 2)",
    )
    g.add_argument(
        "--command-jitter-ms",
        type=options.float_in(0.0, 1000.0, "ms"),
        help="mean of the exponential delay added to the latency, first in first out, ms (default 0.5)",
    )
    g.add_argument(
        "--torque-limit-n-m",
        type=options.float_in(0.0, 10.0, "N m", low_open=True, name="--torque-limit-n-m"),
        help="each motor's limit: a command above it gives zero torque, N m (default 0.05)",
    )
    g.add_argument(
        "--command-period-ms",
        type=options.float_in(1.0, 100.0, "ms"),
        help="the controller's period the watchdog expects, ms (default 10)",
    )
    g.add_argument(
        "--watchdog-margin-ms",
        type=options.float_in(0.0, 1000.0, "ms"),
        help="no valid command for the period plus this: zero torque, ms (default 10)",
    )
    g.add_argument(
        "--silent-after-s",
        type=options.argument(per_node("--silent-after-s", 0.0, 1e6, "s"), "[NAME=]S"),
        action="append",
        default=[],
        metavar="[NAME=]S",
        help="a node stops sending this long after the start, s (m2=5: a node going silent; repeatable)",
    )


def run_motor(args: argparse.Namespace) -> int:
    """``pendsim nodes --motor``: the emulated rig with motors until its duration ends."""
    from ..acquire.udp_loop.actuator import ActuatorSpec  # start-up: MuJoCo, when the command runs
    from ..acquire.udp_loop.motor_rig import LOG_SUFFIX, MotorRigSpec, run_motor_rig, summary

    if args.fault:
        raise options.UsageError("--fault is for the precomputed run; the rig with motors (--motor) has no faults yet")
    if args.log is not None:
        options.check_output(args.log, (LOG_SUFFIX,), force=args.force)
    emulated = spec_from(args)
    names = [n.name for n in emulated.nodes]
    silent: dict[str, float] = {}
    for name, value in args.silent_after_s:
        for target in [name] if name is not None else names:
            if target not in names:
                raise options.UsageError(f"--silent-after-s {name}=...: node {name} is not sent to (--node)")
            silent[target] = value

    def given(value: float | None, default: float) -> float:
        return default if value is None else value

    actuator = ActuatorSpec(
        torque_limit_n_m=given(args.torque_limit_n_m, 0.05),
        command_latency_s=given(args.command_latency_ms, 2.0) * 1e-3,
        command_jitter_s=given(args.command_jitter_ms, 0.5) * 1e-3,
        command_period_s=given(args.command_period_ms, 10.0) * 1e-3,
        watchdog_margin_s=given(args.watchdog_margin_ms, 10.0) * 1e-3,
        seed=args.seed,
    )
    spec = MotorRigSpec(
        nodes=emulated,
        actuator=actuator,
        actuator_bind=args.actuator_bind or "127.0.0.1",
        actuator_port=args.actuator_port or 5603,
        silent_after_s=tuple(silent.items()),
    )
    result = run_motor_rig(spec, log=args.log, replace_log=args.force)
    print(summary(result))
    return 0
