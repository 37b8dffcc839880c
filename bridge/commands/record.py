"""pendsim record: simulate the rig and record both IMUs, joint states and poses to MCAP."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pendsim_mj.rig.model import build_model
from pendsim_mj.sensors.bno055 import Bno055, ImuNoise

from .. import options
from ..io.mcap.writer import COMPRESSIONS
from ..run.record import MODELS, Model, RecordInterrupted, RecordSpec, record, simulate_for
from .node_options import add_imperfection_options, imperfections_from

RELEASED_MODELS = tuple(m for m in MODELS if m != "static")


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "record",
        help="simulate the rig and record both IMUs, joint states and poses to an MCAP file",
        description="Simulate a run and write one MCAP file (ROS 2 messages: /imu/m1, /imu/m2, /joint_states, "
        "/tf, ...; metadata and the exact MJCF attached). Defaults: 30 deg release, 120 s, BNO055 noise on, seed 0.",
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="the .mcap file to write")
    options.add_force_option(p, "the output files (-o, --rerun)")
    options.add_run_options(p)
    options.add_drive_options(p, what="the recorded run (recorded as the /drive topic)")
    p.add_argument("--no-noise", action="store_true", help="ideal IMU signals: no noise, clipping or quantisation")
    p.add_argument(
        "--hold-s",
        type=options.float_in(0.0, 3600.0, "s"),
        default=0.0,
        help="start recording this long before the release, the pendulums held still (as real recordings do)",
    )
    p.add_argument("--seed", type=options.int_in(0, 2**63 - 1), default=0, help="seed of the noise generator")
    p.add_argument(
        "--ideal-timing",
        action="store_true",
        help="sample at exactly k/80 s instead of reading the latest 100 Hz fused value (the real node's timing)",
    )
    p.add_argument(
        "--compression",
        type=options.choice(COMPRESSIONS, "unknown compression {value!r}; allowed: {allowed}"),
        choices=COMPRESSIONS,
        default="zstd",
        help="chunk compression (default zstd)",
    )
    options.add_rerun_option(p, "recording.rrd", "also log the simulated run to Rerun, as simulate --rerun does")
    p.add_argument(
        "--model",
        type=options.choice(RELEASED_MODELS, "unknown model {value!r}; allowed: {allowed}"),
        choices=RELEASED_MODELS,
        default="planar",
        help="planar (default) or spatial: the pendulums' planes --offset-m apart, with tilt freedoms",
    )
    p.add_argument(
        "--offset-m",
        type=options.float_in(0.0, 0.5, "m"),
        default=0.050,
        help="with --model spatial: distance between the planes, m (paper: 0.050 or 0.023)",
    )
    p.add_argument(
        "--static",
        action="store_true",
        help="a static noise test: both nodes at rest, IMU topics only (e.g. --duration-s 21600 for 6 h)",
    )
    add_imperfection_options(p)
    noise_size = options.float_in(0.0, 10.0)
    for sensor, unit, what in (("accel", "m-s2", "m/s^2"), ("gyro", "rad-s", "rad/s")):
        p.add_argument(
            f"--{sensor}-bias-instability-{unit}",
            type=noise_size,
            default=0.0,
            metavar="B",
            help=f"{sensor} bias instability B, {what}, every axis (flicker noise; Allan floor 0.664 B); default 0",
        )
        p.add_argument(
            f"--{sensor}-random-walk-{unit}-sqrt-s",
            type=noise_size,
            default=0.0,
            metavar="K",
            help=f"{sensor} bias random walk K, {what}/sqrt(s), every axis (Allan K sqrt(tau/3)); default 0",
        )
    p.set_defaults(handler=run)


def spec_from(args: argparse.Namespace) -> RecordSpec:
    """The RecordSpec the options describe."""
    if args.model == "spatial" and (args.static or args.engine != "mujoco"):
        raise options.UsageError("--model spatial needs the mujoco engine and a released run (not --static)")
    noise = ImuNoise(
        accel_bias_instability_m_s2=(args.accel_bias_instability_m_s2,) * 3,
        gyro_bias_instability_rad_s=(args.gyro_bias_instability_rad_s,) * 3,
        accel_bias_walk_m_s2_per_sqrt_s=(args.accel_random_walk_m_s2_sqrt_s,) * 3,
        gyro_bias_walk_rad_s_per_sqrt_s=(args.gyro_random_walk_rad_s_sqrt_s,) * 3,
    )
    imperfect, mounts = imperfections_from(args)
    imu = Bno055(
        noise=not args.no_noise,
        seed=args.seed,
        fusion_timing=not args.ideal_timing,
        noise_model=noise,
        mount_quat_wxyz=mounts,
        imperfections=imperfect,
    )
    params = options.params_from(args)
    if args.model == "spatial":
        params = params.with_overrides(plane_offset_m=args.offset_m)
    phi0, omega0 = options.initial_state_from(args)
    model: Model = "static" if args.static else args.model
    return RecordSpec(
        params, phi0, omega0, args.duration_s, args.dt_s, args.engine, model, args.hold_s, imu, args.compression,
        drive=options.drive_from(args),
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm  # start-up: loaded when the command runs

    options.check_output(args.output, (".mcap",), force=args.force)
    options.check_output(args.rerun, (".rrd",), force=args.force)
    spec = spec_from(args)
    try:
        with tqdm(total=spec.duration_s + spec.hold_s, unit="s", desc="recording", disable=None, leave=False) as bar:
            result = record(spec, args.output, replace=args.force, progress=bar.update)
    except RecordInterrupted as interrupted:
        print(f"pendsim: {interrupted}", file=sys.stderr)
        return EXIT_INTERRUPTED
    if args.rerun is not None and spec.model != "static":
        from ..report.rerun_view import view_trajectory  # start-up: Rerun, only with --rerun

        targets = spec.drive.targets if spec.drive else ()
        view_trajectory(
            simulate_for(spec), build_model(spec.params, drive_targets=targets), args.rerun, replace=args.force
        )
        print(f"wrote {args.rerun}")
    size_mb = result.size_bytes / 1e6
    print(f"wrote {args.output}: {result.recorded_s:g} s, {result.samples_text()}, {size_mb:.2f} MB")  # hold included
    options.print_warnings(result.warnings)  # after the file is written: it says so in its metadata too
    return 0


EXIT_INTERRUPTED = 130
