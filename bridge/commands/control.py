"""pendsim control: run a controller on the simulated rig in closed loop, compare it with the
open loop, and record it."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from pendsim_mj.control.names import CONTROLLER_NAMES, LOOP_ENGINES, MOTOR_NAMES, OBSERVERS
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import Bno055

from .. import options
from .node_options import add_imperfection_options, imperfections_from, nodes_from, parse_node

if TYPE_CHECKING:
    from ..acquire.udp_loop.rig_loop import RigLoopResult
    from ..run.control import ControlResult, ControlSpec

MAX_GAIN = 1e4  # N m per rad (or per rad/s): far beyond anything a 0.05 N m motor can use
NODE_OPTIONS = ("--packet-loss", "--loss-burst-samples", "--latency-s", "--fusion-error-deg")
"""What changes what the controller reads of the nodes (their values and timing; the mounts and
clocks are taken as calibrated, as acquire's alignment does)."""
MOTOR_SETS = ("m1,m2", "m2,m1", "m1", "m2")


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "control",
        help="run a controller on the simulated rig in closed loop and compare it with the open loop",
        description="Close the loop on the simulated rig: every 10 ms the controller reads the state (exactly, or as "
        "the BNO055 nodes deliver it with --observe nodes) and sets the motor torques, held over the step. Prints "
        "each mode's decay time (to 1/e) against the open loop, the energy used and the peak torque; with -o, writes "
        "a recording (/drive: the torques; /control: what the controller saw and did) that validate, view and "
        "replay open. Controllers: lqr (active damping of both modes), scheduled-lqr (gains scheduled on the "
        "amplitude), energy (each mode's energy to a target: damp, or hold --target-amplitude-deg), beating (no "
        "energy exchange between the pendulums: M2 held still while M1 swings), none (the open loop).",
    )
    p.add_argument(
        "controller",
        type=options.choice(CONTROLLER_NAMES, "unknown controller {value!r}; allowed: {allowed}"),
        choices=CONTROLLER_NAMES,
        help="the controller",
    )
    p.add_argument("-o", "--output", type=Path, help="record the closed loop to this .mcap file")
    options.add_force_option(p, "the output file")
    options.add_run_options(p)
    p.set_defaults(duration_s=30.0)
    p._option_string_actions["--duration-s"].help = "length of the closed loop, s (default 30)"
    p._option_string_actions[
        "--dt-s"
    ].help = "the control period, which is also the engine's step, s (default 0.01; at most 0.02)"
    engine = p._option_string_actions["--engine"]
    engine.type = options.choice(LOOP_ENGINES, "unknown engine {value!r} for a closed loop; allowed: {allowed}")
    engine.choices = LOOP_ENGINES
    engine.help = "mujoco (the MJCF model; default) or fast (the planar equations stepped in numpy)"
    p.add_argument(
        "--design-params-file",
        type=options.input_file,
        help="JSON parameter overrides of the rig the controller is designed for (e.g. 'pendsim calibrate' "
        "params.json; default: the simulated rig itself)",
    )
    p.add_argument(
        "--motors",
        type=options.choice(MOTOR_SETS, "unknown motors {value!r}; allowed: m1,m2 (both), m1, m2"),
        default="m1,m2",
        help="the motors: m1,m2 (both; default), m1 or m2",
    )
    p.add_argument(
        "--torque-limit-n-m",
        type=options.float_in(1e-4, 2.0, "N m", name="--torque-limit-n-m"),
        default=0.05,
        help="each motor's torque limit, N m (default 0.05)",
    )
    p.add_argument(
        "--input-weight",
        type=options.float_in(1e-6, 1e6, name="--input-weight"),
        help="lqr, scheduled-lqr: the weight R of the torque in the cost (J per (N m)^2; larger is gentler; "
        "default 10)",
    )
    p.add_argument(
        "--gain-file",
        type=options.input_file,
        help="lqr: a JSON matrix of gains (one row per motor; columns phi1, phi2 in N m/rad, omega1, omega2 in "
        "N m s/rad), checked to stabilise the linearised rig, instead of the design",
    )
    p.add_argument(
        "--target-amplitude-deg",
        type=options.float_in(0.0, 80.0, "deg", name="--target-amplitude-deg"),
        default=0.0,
        help="energy: hold mode 1 at this amplitude (deg of M1) and damp mode 2 (default 0: damp both)",
    )
    p.add_argument(
        "--observe",
        type=options.choice(OBSERVERS, "unknown observation {value!r}; allowed: {allowed}"),
        choices=OBSERVERS,
        default="state",
        help="what the controller reads: state (exact; default) or nodes (80 Hz, the BNO055 noise, and the "
        "--packet-loss, --latency-s and --fusion-error-deg below)",
    )
    p.add_argument("--seed", type=options.int_in(0, 2**63 - 1), default=0, help="seed of the node noise")
    p.add_argument("--no-open-loop", action="store_true", help="skip the open-loop run (no decay comparison; faster)")
    add_imperfection_options(p, only=NODE_OPTIONS)
    g = p.add_argument_group("on the rig over UDP (--rig; 'pendsim nodes --motor' emulates it)")
    g.add_argument(
        "--rig",
        action="store_true",
        help="close the loop on the rig instead of the simulation: read its two nodes as acquire does and send "
        "commands to its actuator node (docs/control.md, 'The loop over UDP'); --duration-s, then a stop",
    )
    g.add_argument(
        "--node",
        dest="nodes",
        type=options.argument(parse_node, "NAME=PORT"),
        action="append",
        metavar="NAME=PORT",
        help="with --rig: a node and the UDP port it sends to (repeatable; default m1=5601 m2=5602)",
    )
    g.add_argument("--bind", help="with --rig: address the node ports listen on (default 127.0.0.1: this machine only)")
    g.add_argument("--actuator-host", help="with --rig: the actuator node's address (default 127.0.0.1)")
    g.add_argument(
        "--actuator-port",
        type=options.int_in(1, 65535),
        help="with --rig: the actuator node's UDP port for commands (default 5603)",
    )
    p.set_defaults(handler=run)


def _gain(path: Path, rows: int) -> tuple[tuple[float, ...], ...]:
    try:
        value = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ParameterError(f"--gain-file {path}: not a JSON matrix ({exc})") from None
    ok = (
        isinstance(value, list)
        and len(value) == rows
        and all(isinstance(r, list) and len(r) == 4 for r in value)
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for r in value for v in r)
    )
    if not ok:
        raise ParameterError(
            f"--gain-file {path}: need {rows} row{'s' if rows > 1 else ''} (one per motor) of 4 numbers"
        )
    if not all(math.isfinite(v) and abs(v) <= MAX_GAIN for r in value for v in r):
        raise ParameterError(f"--gain-file {path}: every gain must be finite and within +-{MAX_GAIN:g}")
    return tuple(tuple(float(v) for v in r) for r in value)


def _design(path: Path | None) -> RigParams | None:
    """The rig the controller is designed for: --design-params-file's overrides of the paper's."""
    if path is None:
        return None
    try:
        return DEFAULT_PARAMS.with_mapping(options.read_params_file(path))
    except ParameterError as exc:
        raise ParameterError(f"--design-params-file {path}: {exc}") from None


def spec_from(args: argparse.Namespace) -> ControlSpec:
    """The ControlSpec the options describe."""
    from ..run.control import ControlSpec  # start-up: the control room loads scipy when the command runs

    motors = tuple(m for m in MOTOR_NAMES if m in args.motors.split(","))
    if args.observe != "nodes":
        given = [flag for flag in NODE_OPTIONS if getattr(args, flag[2:].replace("-", "_")) != 0.0]
        given = [flag for flag in given if flag != "--loss-burst-samples" or args.packet_loss > 0]
        if given:
            raise options.UsageError(f"{given[0]} describes the nodes the controller reads: add --observe nodes")
    if args.target_amplitude_deg and args.controller != "energy":
        raise options.UsageError("--target-amplitude-deg is for the energy controller")
    params = options.params_from(args)
    design = _design(args.design_params_file)
    imperfect, mounts = imperfections_from(args)
    imu = Bno055(seed=args.seed, mount_quat_wxyz=mounts, imperfections=imperfect)
    phi0, omega0 = options.initial_state_from(args)
    return ControlSpec(
        controller=args.controller, params=params, design_params=design, phi0_rad=phi0, omega0_rad_s=omega0,
        duration_s=args.duration_s, dt_s=args.dt_s, engine=args.engine, motors=motors,
        torque_limit_n_m=args.torque_limit_n_m, input_weight=args.input_weight,
        gain=_gain(args.gain_file, len(motors)) if args.gain_file is not None else None,
        target_amplitudes_rad=(math.radians(args.target_amplitude_deg), 0.0), observe=args.observe, imu=imu,
        open_loop=not args.no_open_loop,
    )  # fmt: skip


def _decay(value: float) -> str:
    return f"{value:.2f} s" if math.isfinite(value) else ("not excited" if math.isnan(value) else "not within the run")


def summary(result: ControlResult) -> list[str]:
    """The lines the command prints."""
    m, loop = result.metrics, result.loop
    lines = [
        f"{loop.controller} on the {loop.engine} engine, motors {'+'.join(loop.motors)} (limit "
        f"{loop.torque_limit_n_m:g} N m), reading the {loop.observer} every {1000 * loop.dt_s:g} ms, "
        f"{loop.t_s[-1]:g} s",
        "  mode   start amplitude   decay to 1/e   open loop      shorter by",
    ]
    speed = result.speedup()
    for i in range(2):
        open_ = _decay(float(result.open_loop.decay_s[i])) if result.open_loop is not None else "-"
        ratio = f"{speed[i]:.1f}x" if math.isfinite(speed[i]) else "-"
        lines.append(
            f"  {i + 1}      {math.degrees(m.start_amplitudes_rad[i]):8.2f} deg    {_decay(float(m.decay_s[i])):>14}"
            f"   {open_:>14}   {ratio}"
        )
    if result.held_amplitude_rad is not None:
        held, target = math.degrees(result.held_amplitude_rad), math.degrees(result.target_amplitude_rad)
        lines.append(f"  mode 1 held at {held:.2f} deg over the last 5 s (target {target:g} deg)")
    swing1, swing2 = (math.degrees(a) for a in m.final_swing_rad)
    lines.append(
        f"  last second's swing M1 {swing1:.3f} deg, M2 {swing2:.3f} deg; energy used {m.energy_used_j:.4f} J; "
        f"peak torque {m.peak_torque_n_m[0]:.4f} / {m.peak_torque_n_m[1]:.4f} N m; at the limit "
        f"{100 * m.saturated_share:.1f} % of steps"
    )
    if (
        loop.states[0, 0] != 0
        and abs(loop.states[0, 0]) >= abs(loop.states[0, 1])
        and math.isfinite(m.largest_ratio_m2_m1)
    ):
        lines.append(f"  M2's swing at most {m.largest_ratio_m2_m1:.3f} of M1's while M1 swings")
    return lines


RIG_ONLY = ("--node", "--bind", "--actuator-host", "--actuator-port")


def rig_summary(result: RigLoopResult) -> list[str]:
    """The lines ``--rig`` prints: what the controller read and did, and the loop's timing."""
    import numpy as np

    from pendsim_mj.control.linear import decay_time_s, linearise

    seen = np.all(np.isfinite(result.states), axis=1)
    applied = np.array([s.torques_n_m for s in result.statuses]).reshape(-1, 2)
    lines = [
        f"{result.controller} on the rig over UDP, motors {'+'.join(result.motors)} (limit "
        f"{result.torque_limit_n_m:g} N m), every {1000 * result.dt_s:g} ms; {len(result.t_s)} ticks, ended: "
        f"{result.stop}"
    ]
    if np.count_nonzero(seen) > 1:
        # from the swing's largest total amplitude on (a hold before the release is no decay)
        t, x = result.t_s[seen], result.states[seen]
        amplitudes = linearise(DEFAULT_PARAMS).mode_amplitudes_rad(x)
        first = int(np.argmax(np.hypot(amplitudes[:, 0], amplitudes[:, 1])))
        for i in range(2):
            decay = decay_time_s(t[first:] - t[first], amplitudes[first:, i])
            lines.append(
                f"  mode {i + 1}: {math.degrees(amplitudes[first, i]):.2f} deg at {t[first]:.2f} s (the swing's "
                f"largest), decay to 1/e {_decay(decay)} (from the nodes' readings)"
            )
    timing = result.timing()
    peak1, peak2 = (float(np.max(np.abs(applied[:, k]), initial=0.0)) for k in range(2))
    lines.append(
        f"  peak torque applied (the actuator's statuses) {peak1:.4f} / {peak2:.4f} N m; "
        f"command -> status {timing.round_trip_ms[0]:.2f} ms median "
        f"({timing.round_trip_ms[1]:.2f} p99); oldest sample -> command {timing.sample_to_command_ms[0]:.1f} ms; "
        f"tick lateness {timing.tick_lateness_ms[0]:.2f} ms ({timing.tick_lateness_ms[1]:.2f} p99); "
        f"{result.skipped_ticks} ticks skipped"
    )
    return lines


def _run_rig(args: argparse.Namespace, spec: ControlSpec) -> int:
    import numpy as np

    from ..acquire.udp_loop.rig_loop import run_rig_loop  # start-up: the loop loads when it runs
    from ..run.control import make_controller

    if args.output is not None:
        raise options.UsageError("-o with --rig: the loop writes no recording (the emulated rig's --log does)")
    if args.observe != "state" or args.engine != "mujoco":
        raise options.UsageError("--observe and --engine are for the simulated loop; --rig reads the real nodes")
    actuator = (args.actuator_host or "127.0.0.1", args.actuator_port or 5603)
    result = run_rig_loop(
        make_controller(spec), nodes=nodes_from(args), bind=args.bind or "127.0.0.1", actuator=actuator,
        duration_s=spec.duration_s, dt_s=spec.dt_s,
    )  # fmt: skip
    for line in rig_summary(result):
        print(line)
    failure = ""
    if not np.any(np.all(np.isfinite(result.states), axis=1)):
        failure = "no sample came from both nodes: nothing was controlled (are they sending to --node's ports?)"
    elif not result.statuses:
        failure = "the actuator never answered: nothing was applied (is it listening on --actuator-port?)"
    elif result.stop == "actuator_limit":
        failure = "the actuator's torque limit is below the controller's: give --torque-limit-n-m its limit"
    if failure:
        print(f"pendsim: {failure}", file=sys.stderr)
        return 1
    return 0


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm  # start-up: loaded when the command runs

    from ..run.control import run_control  # start-up: the control room loads scipy when the command runs

    spec = spec_from(args)
    if args.rig:
        return _run_rig(args, spec)
    given = [flag for flag, dest in zip(RIG_ONLY, ("nodes", "bind", "actuator_host", "actuator_port"), strict=True)
             if getattr(args, dest) is not None]  # fmt: skip
    if given:
        raise options.UsageError(f"{given[0]} is for the loop on the rig: add --rig")
    options.check_output(args.output, (".mcap",), force=args.force)
    with tqdm(total=spec.duration_s, unit="s", desc="closed loop", disable=None, leave=False) as bar:
        last = [0.0]

        def progress(done_s: float) -> None:
            bar.update(done_s - last[0])
            last[0] = done_s

        result = run_control(spec, args.output, replace=args.force, progress=progress)
    for line in summary(result):
        print(line)
    if result.recording is not None:
        print(f"wrote {result.recording.path}: {result.recording.size_bytes / 1e6:.2f} MB")
    return 0
