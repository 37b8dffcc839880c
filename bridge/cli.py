"""The ``pendsim`` command line. Errors a user can fix print one line and exit with code 2."""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from pendsim_mj import __version__
from pendsim_mj.errors import PendsimError
from pendsim_mj.params import DEFAULT_PARAMS, RigParams

EXIT_USAGE = 2
ENGINES = ("mujoco", "reference")
OUTPUT_SUFFIXES = (".npz", ".csv")


class UsageError(Exception):
    """Bad command-line input; reported in one line with exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2, no usage dump
        raise UsageError(message)


def _finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def _non_negative_float(text: str) -> float:
    value = _finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def _assignment(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    return name.strip(), _finite_float(value)


def _build_parser() -> _Parser:
    parser = _Parser(
        prog="pendsim",
        description="Digital twin of the spring-coupled two-pendulum rig of Ganev et al., Machines 2025, 13(8), 660.",
        epilog="Units: angles in degrees at the command line, SI elsewhere. 'pendsim COMMAND --help' for details.",
    )
    parser.add_argument("--version", action="version", version=f"pendsim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    sim = sub.add_parser(
        "simulate",
        help="simulate the rig and print a summary (frequencies, amplitudes, energy)",
        description="Simulate the rig from a release and print the dominant frequencies, the start and end "
        "amplitudes and the energy lost. Defaults: M1 released from 30 deg, M2 at rest, 120 s, 10 ms RK4 steps.",
    )
    _add_run_options(sim)
    sim.add_argument("-o", "--output", type=Path, help="write the trajectory to FILE.npz (all arrays) or FILE.csv")
    _add_rerun_option(sim, "simulation.rrd", "also log the run to Rerun: the rig in 3D and its time series")

    rec = sub.add_parser(
        "record",
        help="simulate the rig and record both IMUs, joint states and poses to an MCAP file",
        description="Simulate a run and write one MCAP file (ROS 2 messages: /imu/m1, /imu/m2, /joint_states, "
        "/tf, ...; metadata and the exact MJCF attached). Defaults: 30 deg release, 120 s, BNO055 noise on, seed 0.",
    )
    rec.add_argument("-o", "--output", type=Path, required=True, help="the .mcap file to write")
    rec.add_argument("--force", action="store_true", help="replace the output file if it exists")
    _add_run_options(rec)
    rec.add_argument("--no-noise", action="store_true", help="ideal IMU signals: no noise, clipping or quantisation")
    rec.add_argument(
        "--hold-s",
        type=_non_negative_float,
        default=0.0,
        help="start recording this long before the release, the pendulums held still (as real recordings do)",
    )
    rec.add_argument("--seed", type=int, default=0, help="seed of the noise generator (default 0)")
    rec.add_argument(
        "--ideal-timing",
        action="store_true",
        help="sample at exactly k/80 s instead of reading the latest 100 Hz fused value (the real node's timing)",
    )
    rec.add_argument("--compression", default="zstd", help="chunk compression: zstd (default), lz4 or none")
    _add_rerun_option(rec, "recording.rrd", "also log the simulated run to Rerun, as simulate --rerun does")
    rec.add_argument(
        "--model",
        default="planar",
        help="planar (default) or spatial: the pendulums' planes --offset-m apart, with tilt freedoms",
    )
    rec.add_argument(
        "--offset-m",
        type=_non_negative_float,
        default=0.050,
        help="with --model spatial: distance between the planes, m (paper: 0.050 or 0.023)",
    )
    rec.add_argument(
        "--static",
        action="store_true",
        help="a static noise test: both nodes at rest, IMU topics only (e.g. --duration-s 21600 for 6 h)",
    )
    for sensor, unit, what in (("accel", "m-s2", "m/s^2"), ("gyro", "rad-s", "rad/s")):
        rec.add_argument(
            f"--{sensor}-bias-instability-{unit}",
            type=_non_negative_float,
            default=0.0,
            metavar="B",
            help=f"{sensor} bias instability B, {what}, every axis (flicker noise; Allan floor 0.664 B); default 0",
        )
        rec.add_argument(
            f"--{sensor}-random-walk-{unit}-sqrt-s",
            type=_non_negative_float,
            default=0.0,
            metavar="K",
            help=f"{sensor} bias random walk K, {what}/sqrt(s), every axis (Allan K sqrt(tau/3)); default 0",
        )

    ins = sub.add_parser(
        "inspect",
        help="print the topics, message counts, rates, duration and metadata of an MCAP file",
        description="Print what an MCAP file holds. A truncated or damaged file is an error (exit 2) that says "
        "how much is readable; 'pendsim recover' rewrites that part.",
    )
    ins.add_argument("path", type=Path, help="the .mcap file")

    aln = sub.add_parser(
        "allan",
        help="Allan deviation of a static recording: the paper's noise table, noise terms and plots",
        description="Analyse every accelerometer and gyroscope axis of a static recording (e.g. from "
        "'pendsim record --static'): overlapping Allan deviation with confidence intervals, the paper's table "
        "(sigma at tau = 1/fs, mean, CV), the noise terms N, B, K, and a log-log plot per node and sensor.",
    )
    aln.add_argument("path", type=Path, help="the .mcap recording")
    aln.add_argument("--json", action="store_true", help="print the full result (curves included) as JSON instead")
    aln.add_argument(
        "--plot-dir", type=Path, help="where to write the PNG plots (default: NAME_allan/ beside the recording)"
    )
    aln.add_argument("--no-plots", action="store_true", help="write no plots")
    aln.add_argument(
        "--longest-segment",
        action="store_true",
        help="if the timestamps have gaps or irregular intervals, analyse the longest uniform stretch",
    )

    val = sub.add_parser(
        "validate",
        help="compare a recording with the MuJoCo model and the planar reference (the paper's metrics and figures)",
        description="Align a recording (detect the release, estimate the release angles), identify or take the "
        "damping, simulate with MuJoCo and the planar reference from the estimated and the nominal 30 deg release, "
        "and compare phi1, omega1, omega2 and M1's tangential and normal accelerations over 5 s and the whole run: "
        "frequency (zero crossings and spectral peak) and its relative error delta, max |Delta|, IAE, ISE. "
        "Writes report.json and the paper's Figures 9-15. Exit 1 when a --max-* gate is exceeded.",
    )
    val.add_argument("path", type=Path, help="the .mcap recording")
    val.add_argument(
        "-o", "--out-dir", type=Path, help="where report.json and the figures go (default NAME_validation/)"
    )
    val.add_argument(
        "--damping",
        default="identified",
        help="'identified' (least-squares fit on this recording; default), 'recorded' (its metadata) or B1,B2",
    )
    val.add_argument("--params-file", type=Path, help="JSON overrides of the rig parameters to validate")
    val.add_argument(
        "--set",
        dest="overrides",
        type=_assignment,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a rig parameter of the model being validated; repeatable",
    )
    val.add_argument("--no-plots", action="store_true", help="write report.json only")
    val.add_argument(
        "--max-delta",
        type=_non_negative_float,
        metavar="X",
        help="fail if any quantity's relative frequency error (MuJoCo, estimated release, whole run) exceeds X",
    )
    val.add_argument(
        "--max-iae",
        type=_non_negative_float,
        metavar="X",
        help="fail if the IAE of phi1 over the first 5 s (MuJoCo, estimated release) exceeds X rad s",
    )
    val.add_argument(
        "--max-error-phi1",
        type=_non_negative_float,
        metavar="RAD",
        help="fail if max |Delta phi1| over the whole run (MuJoCo, estimated release) exceeds RAD",
    )

    idn = sub.add_parser(
        "identify",
        help="identify the hinge damping b1, b2 from a recorded free decay (log decrement and least squares)",
        description="Print b1, b2 by the paper's logarithmic decrement (per pendulum, amplitudes over --window-s) "
        "and by a least-squares fit of the whole measured gyro record (mujoco.sysid), with 95 %% confidence "
        "intervals. --write saves the fitted values for 'simulate --params-file' and 'record --params-file'.",
    )
    idn.add_argument("path", type=Path, help="the .mcap recording")
    idn.add_argument("--window-s", type=_finite_float, default=120.0, help="log-decrement window, s (default 120)")
    idn.add_argument("--write", type=Path, metavar="FILE.json", help="write the fitted b1_n_m_s, b2_n_m_s as JSON")

    cmp = sub.add_parser(
        "compare",
        help="planar against spatial model from the same release: in-plane difference, tilt, beats, spectra",
        description="Run the planar model and the spatial variant (plane offset, tilt freedoms) from the same "
        "release and report per pendulum the in-plane angle difference, the out-of-plane amplitude, the beat "
        "period and depth of the swing envelope and the spectrum near the main frequency; writes summary.json and "
        "PNG plots; --rerun shows both rigs side by side.",
    )
    _add_run_options(cmp)
    cmp.add_argument(
        "--offset-m",
        type=_non_negative_float,
        default=0.050,
        help="distance between the pendulum planes, m (paper: 0.050 or 0.023; default 0.050)",
    )
    cmp.add_argument("--fixed-points-plane", default="m2", help="plane of points 6 and 7: m2 (default) or m1")
    cmp.add_argument("-o", "--out-dir", type=Path, default=Path("compare"), help="output folder (default compare/)")
    _add_rerun_option(cmp, "compare.rrd", "also show both rigs side by side and their angles in Rerun")

    dm = sub.add_parser(
        "demo",
        help="the whole chain on built-in defaults: simulate, record, validate, report, plots, Rerun file",
        description="Simulate the rig from 30 deg, record a synthetic IMU MCAP (BNO055 noise, 2 s held before the "
        "release), identify the damping and validate the recording against the MuJoCo model and the planar "
        "reference, and write the report, the paper's figures and a Rerun .rrd; prints where everything is.",
    )
    dm.add_argument(
        "-o", "--out-dir", type=Path, default=Path("pendsim_demo"), help="output folder (default pendsim_demo)"
    )
    dm.add_argument(
        "--duration-s", type=_finite_float, default=120.0, help="simulated time after the release, s (default 120)"
    )

    rp = sub.add_parser(
        "replay",
        help="re-emit a recording's messages in log-time order, paced, cut and filtered, to terminal, MCAP or Rerun",
        description="Replay the messages of a recording in log-time order at --speed (1 = real time, 10, or max), "
        "within --start/--end (s of log time), for --topics, optionally --loop. Prints one line per message, or "
        "writes them to a new MCAP (-o, cut and filtered; --shift moves the window to t = 0) or to Rerun (--rerun). "
        "From Python: bridge.replay.replay() yields decoded messages.",
    )
    rp.add_argument("path", type=Path, help="the .mcap recording")
    rp.add_argument("--speed", default="max", help="1 = real time, any factor > 0, or max (default)")
    rp.add_argument("--start", type=_finite_float, metavar="S", help="first log time to replay, s")
    rp.add_argument("--end", type=_finite_float, metavar="S", help="last log time to replay, s")
    rp.add_argument("--topics", help="comma-separated topics (default all)")
    rp.add_argument("--loop", action="store_true", help="start again after the end (Ctrl-C stops)")
    rp.add_argument("-o", "--output", type=Path, help="write the replayed messages to a new .mcap")
    rp.add_argument("--shift", action="store_true", help="with -o: move log times so that the window starts at 0")
    rp.add_argument(
        "--rerun", type=Path, metavar="FILE.rrd", help="log the replayed Imu and JointState values to Rerun"
    )
    rp.add_argument("--quiet", action="store_true", help="print only the summary")

    vw = sub.add_parser(
        "view",
        help="show a recording in Rerun: the rig in 3D, measured against model time series, phase portraits",
        description="Log a recording and the model's prediction (re-simulated from its metadata and MJCF) to "
        "Rerun: the rig in 3D with springs coloured by tension, measured and computed phi, omega and accelerations, "
        "the phi1 error with cumulative IAE and ISE, phase portraits, on a ready-made layout. Writes an .rrd file "
        "(default NAME.rrd beside the recording); --spawn opens the desktop viewer, --serve the web viewer.",
    )
    vw.add_argument("path", type=Path, help="the .mcap recording")
    vw.add_argument("--save", type=Path, metavar="FILE.rrd", help="the .rrd file to write (default NAME.rrd)")
    vw.add_argument("--spawn", action="store_true", help="open the Rerun desktop viewer on the result")
    vw.add_argument("--serve", action="store_true", help="serve the result to a web browser (Ctrl-C stops)")
    vw.add_argument(
        "--bind", default="127.0.0.1", help="address --serve listens on (default 127.0.0.1, this machine only)"
    )
    vw.add_argument("--port", type=int, default=9090, help="web viewer port for --serve (default 9090)")

    rcv = sub.add_parser(
        "recover",
        help="rewrite the readable part of a truncated or damaged MCAP file into a valid one",
        description="Read every complete chunk and record of BROKEN (for instance a recording whose process was "
        "killed) and write them to FIXED as a complete, indexed MCAP file.",
    )
    rcv.add_argument("broken", type=Path, help="the damaged .mcap file (read only)")
    rcv.add_argument("fixed", type=Path, help="the new .mcap file to write (must not exist)")

    sub.add_parser(
        "info",
        help="print every rig parameter with its unit and source",
        description="Print every rig parameter with value, unit and source.",
    )
    return parser


def _add_rerun_option(p: argparse.ArgumentParser, default: str, what: str) -> None:
    help_text = f"{what} (default file {default})"
    p.add_argument("--rerun", type=Path, nargs="?", const=Path(default), metavar="FILE.rrd", help=help_text)


def _add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--phi1-deg", type=_finite_float, default=30.0, help="initial angle of M1, deg (default 30)")
    p.add_argument("--phi2-deg", type=_finite_float, default=0.0, help="initial angle of M2, deg (default 0)")
    p.add_argument("--omega1-deg-s", type=_finite_float, default=0.0, help="initial rate of M1, deg/s (default 0)")
    p.add_argument("--omega2-deg-s", type=_finite_float, default=0.0, help="initial rate of M2, deg/s (default 0)")
    p.add_argument("--duration-s", type=_finite_float, default=120.0, help="simulated time, s (default 120)")
    p.add_argument("--dt-s", type=_finite_float, default=0.01, help="integration step, s (default 0.01)")
    p.add_argument(
        "--engine", default="mujoco", help="mujoco (the MJCF model) or reference (planar Newtonian RK4); default mujoco"
    )
    for n in (1, 2):
        default_b = getattr(DEFAULT_PARAMS, f"b{n}_n_m_s")
        p.add_argument(
            f"--b{n}", type=_finite_float, help=f"hinge damping of M{n}, N m s/rad (default {default_b:.4g})"
        )
    p.add_argument(
        "--params-file",
        type=Path,
        help="JSON object of parameter overrides (SI names as in 'pendsim info'), e.g. from 'pendsim identify --write'",
    )
    p.add_argument(
        "--set",
        dest="overrides",
        type=_assignment,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override any parameter in SI units, e.g. --set c1_n_m=6.0 (see 'pendsim info'); repeatable",
    )


def _overrides_from(args: argparse.Namespace) -> dict[str, float]:
    """Parameter overrides from --params-file, then --set, then --b1/--b2 (later ones win)."""
    overrides: dict[str, float] = {}
    if getattr(args, "params_file", None) is not None:
        import json

        try:
            loaded = json.loads(args.params_file.read_text())
        except OSError as exc:
            raise UsageError(f"cannot read {args.params_file}: {exc.strerror}") from None
        except json.JSONDecodeError as exc:
            raise UsageError(f"{args.params_file} is not JSON: {exc.msg} at line {exc.lineno}") from None
        if not isinstance(loaded, dict) or not all(isinstance(v, (int, float)) for v in loaded.values()):
            raise UsageError(f'{args.params_file} must hold a JSON object of numbers, e.g. {{"b1_n_m_s": 0.0007}}')
        overrides.update(loaded)
    overrides.update(dict(getattr(args, "overrides", [])))
    for n in (1, 2):
        if getattr(args, f"b{n}", None) is not None:
            overrides[f"b{n}_n_m_s"] = getattr(args, f"b{n}")
    return overrides


def _params_from(args: argparse.Namespace) -> RigParams:
    return DEFAULT_PARAMS.with_mapping(_overrides_from(args))


def _check_output(path: Path | None, suffixes: tuple[str, ...], *, force: bool = True) -> None:
    if path is None:
        return
    if path.suffix.lower() not in suffixes:
        raise UsageError(f"output {str(path)!r} must end in {' or '.join(suffixes)}")
    if path.exists() and not force and not path.is_dir():
        raise UsageError(f"output {str(path)!r} exists; choose another name or pass --force to replace it")
    parent = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise UsageError(f"output {str(path)!r} is a directory; give a file name ending in {' or '.join(suffixes)}")
    if not parent.is_dir():
        raise UsageError(f"output directory {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise UsageError(f"output directory {str(parent)!r} is not writable")


def _simulate_from_args(args: argparse.Namespace, *, spatial: bool = False):
    """Simulate the run the common options describe; returns (params, phi0, omega0, trajectory)."""
    if args.engine not in ENGINES:
        raise UsageError(f"unknown engine {args.engine!r}; allowed: {', '.join(ENGINES)}")
    params = _params_from(args)
    if spatial:
        from pendsim_mj.model import SPATIAL
        from pendsim_mj.simulation import simulate

        params = params.with_overrides(plane_offset_m=args.offset_m)
        phi0 = (math.radians(args.phi1_deg), math.radians(args.phi2_deg))
        omega0 = (math.radians(args.omega1_deg_s), math.radians(args.omega2_deg_s))
        return params, phi0, omega0, simulate(params, phi0, omega0, args.duration_s, args.dt_s, variant=SPATIAL)
    phi0 = (math.radians(args.phi1_deg), math.radians(args.phi2_deg))
    omega0 = (math.radians(args.omega1_deg_s), math.radians(args.omega2_deg_s))
    if args.engine == "mujoco":
        from pendsim_mj.simulation import simulate as run
    else:
        from pendsim_mj.reference import solve as run
    return params, phi0, omega0, run(params, phi0, omega0, args.duration_s, args.dt_s)


def _cmd_simulate(args: argparse.Namespace) -> int:
    _check_output(args.output, OUTPUT_SUFFIXES)
    if args.rerun is not None:
        _check_output(args.rerun, (".rrd",))
    params, _, _, traj = _simulate_from_args(args)
    print(_summary(traj, args.engine))
    if args.rerun is not None:
        from bridge.rerun_view import view_trajectory
        from pendsim_mj.model import build_model

        view_trajectory(traj, build_model(params), args.rerun)
        print(f"wrote {args.rerun} (open it with: rerun {args.rerun})")
    if args.output is not None:
        traj.save(args.output)
        print(f"wrote {args.output}")
    return 0


def _summary(traj, engine: str) -> str:
    from pendsim_mj.analysis import peak_amplitudes, spectral_peak_hz

    lines = [
        f"engine {engine}, {traj.t_s[-1]:g} s at dt = {traj.dt_s:g} s ({len(traj.t_s)} samples)",
        f"{'':6} {'dominant f (Hz)':>16} {'start amp (deg)':>16} {'end amp (deg)':>14}",
    ]
    for k, name in enumerate(("phi1", "phi2")):
        x = traj.phi_rad[:, k]
        freq = spectral_peak_hz(traj.t_s, x)
        _, amps = peak_amplitudes(traj.t_s, x)
        start = math.degrees(amps[0]) if len(amps) else math.degrees(abs(x[0]))
        end = math.degrees(amps[-1]) if len(amps) else math.degrees(abs(x[-1]))
        lines.append(f"{name:6} {freq:16.4f} {start:16.3f} {end:14.3f}")
    e0, e1 = traj.total_energy_j[0], traj.total_energy_j[-1]
    lost = e0 - e1
    share = f" ({100 * lost / e0:.1f} % of the initial {e0:.4g} J)" if e0 > 0 else ""
    dissipated = traj.dissipated_j[-1]
    lines.append(f"energy lost {lost:.6g} J{share}; dissipated by hinge damping {dissipated:.6g} J")
    residual = lost - dissipated
    lines.append(f"energy balance residual {residual:.3g} J (integration error; large means reduce --dt-s)")
    return "\n".join(lines)


def _cmd_info(args: argparse.Namespace) -> int:
    p = DEFAULT_PARAMS
    rows = [(name, f"{getattr(p, name):.6g}", unit, source) for name, unit, source in RigParams.describe()]
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    print("Rig parameters (Ganev et al., Machines 2025, 13(8), 660; doi:10.3390/machines13080660)")
    for name, value, unit, source in rows:
        print(f"  {name:{widths[0]}}  {value:>{widths[1]}}  {unit:{widths[2]}}  {source}")
    return 0


def _cmd_record(args: argparse.Namespace) -> int:
    from bridge.mcap_writer import COMPRESSIONS
    from bridge.recording import RunInfo, write_recording
    from pendsim_mj.model import PLANAR, SPATIAL, exact_mjcf
    from pendsim_mj.sensors import Bno055, ImuNoise, sample_imu, static_imu

    _check_output(args.output, (".mcap",), force=args.force)
    if args.rerun is not None:
        _check_output(args.rerun, (".rrd",))
    if args.compression not in COMPRESSIONS:
        raise UsageError(f"unknown compression {args.compression!r}; allowed: {', '.join(COMPRESSIONS)}")
    if args.model not in ("planar", "spatial"):
        raise UsageError(f"unknown model {args.model!r}; allowed: planar, spatial")
    spatial = args.model == "spatial"
    if spatial and (args.engine != "mujoco" or args.static):
        raise UsageError("--model spatial needs the mujoco engine and a released run (not --static)")
    noise = ImuNoise(
        accel_bias_instability_m_s2=(args.accel_bias_instability_m_s2,) * 3,
        gyro_bias_instability_rad_s=(args.gyro_bias_instability_rad_s,) * 3,
        accel_bias_walk_m_s2_per_sqrt_s=(args.accel_random_walk_m_s2_sqrt_s,) * 3,
        gyro_bias_walk_rad_s_per_sqrt_s=(args.gyro_random_walk_rad_s_sqrt_s,) * 3,
    )
    config = Bno055(noise=not args.no_noise, seed=args.seed, fusion_timing=not args.ideal_timing, noise_model=noise)
    if args.static:
        params = _params_from(args)
        traj = None
        imu = static_imu(params, args.duration_s, config)
        run = RunInfo("static", (0.0, 0.0), (0.0, 0.0), args.duration_s, 1 / config.sample_rate_hz, model="static")
    else:
        params, phi0, omega0, traj = _simulate_from_args(args, spatial=spatial)
        imu = sample_imu(traj, config, hold_s=args.hold_s)
        release = round(args.hold_s * config.sample_rate_hz) / config.sample_rate_hz
        run = RunInfo(args.engine, phi0, omega0, args.duration_s, args.dt_s, model=args.model, release_time_s=release)
    partial = args.output.with_name(f".{args.output.name}.partial")
    from tqdm import tqdm

    try:
        with tqdm(total=float(imu.t_s[-1]), unit="s", desc="recording", disable=None, leave=False) as bar:
            write_recording(
                partial,
                imu,
                run,
                exact_mjcf(params, timestep_s=args.dt_s, variant=SPATIAL if spatial else PLANAR),
                params,
                traj=traj,
                compression=args.compression,
                progress=bar.update,
            )
    except OSError as exc:
        partial.unlink(missing_ok=True)
        raise UsageError(f"cannot write {args.output}: {exc.strerror}") from None
    partial.replace(args.output)
    if args.rerun is not None and traj is not None:
        from bridge.rerun_view import view_trajectory
        from pendsim_mj.model import build_model

        view_trajectory(traj, build_model(params), args.rerun)
        print(f"wrote {args.rerun}")
    size = args.output.stat().st_size
    print(f"wrote {args.output}: {args.duration_s:g} s, {len(imu.t_s)} IMU samples per node, {size / 1e6:.2f} MB")
    return 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from bridge.mcap_reader import read_mcap

    contents = read_mcap(args.path, strict=True)
    print(_describe(contents))
    return 0


def _describe(contents) -> str:
    lines = [f"{contents.path}: {contents.file_size / 1e6:.2f} MB, {contents.chunks} chunks, complete"]
    starts = [int(m.log_time_ns[0]) for m in contents.messages.values() if len(m)]
    ends = [int(m.log_time_ns[-1]) for m in contents.messages.values() if len(m)]
    if starts:
        t0, t1 = min(starts) / 1e9, max(ends) / 1e9
        lines.append(f"duration {t1 - t0:.3f} s (log time {t0:.3f} to {t1:.3f} s)")
    lines.append(f"{'topic':32} {'schema':30} {'messages':>9} {'rate (Hz)':>10}")
    for cid, ch in sorted(contents.channels.items(), key=lambda kv: kv[1].topic):
        data = contents.messages.get(cid)
        count = len(data) if data is not None else 0
        span = (data.log_time_ns[-1] - data.log_time_ns[0]) / 1e9 if count > 1 else 0.0
        rate = f"{(count - 1) / span:10.2f}" if span > 0 else f"{'-':>10}"
        schema = contents.schemas[ch.schema_id].name if ch.schema_id in contents.schemas else "?"
        lines.append(f"{ch.topic:32} {schema:30} {count:9d} {rate}")
    for name, values in sorted(contents.metadata.items()):
        lines.append(f"metadata {name}:")
        lines += [f"  {k} = {v}" for k, v in values.items()]
    for name, a in sorted(contents.attachments.items()):
        lines.append(f"attachment {name} ({a.media_type}, {len(a.data)} bytes)")
    return "\n".join(lines)


def _cmd_allan(args: argparse.Namespace) -> int:
    import json

    from tqdm import tqdm

    from bridge.allan_report import analyse, as_json, plots, table

    if not args.path.is_file():
        raise UsageError(f"{args.path}: no such file")
    plot_dir = args.plot_dir or args.path.with_name(f"{args.path.stem}_allan")
    if not args.no_plots and plot_dir.exists() and not plot_dir.is_dir():
        raise UsageError(f"plot directory {str(plot_dir)!r} is a file")
    size = args.path.stat().st_size
    with tqdm(total=size, unit="B", unit_scale=True, desc="reading", disable=None, leave=False) as bar:
        report = analyse(args.path, longest_segment=args.longest_segment, progress=bar.update)
    written = [] if args.no_plots else plots(report, plot_dir)
    if args.json:
        result = as_json(report)
        result["plots"] = [str(p) for p in written]
        print(json.dumps(result))
    else:
        print(table(report))
        if written:
            print(f"plots: {', '.join(str(p) for p in written)}")
    return 0


def _cmd_validate(args: argparse.Namespace) -> int:
    import json

    from bridge.validate import report_json, table, validate

    if not args.path.is_file():
        raise UsageError(f"{args.path}: no such file")
    if args.damping in ("identified", "recorded"):
        damping = args.damping
    else:
        try:
            b1, b2 = (float(v) for v in args.damping.split(","))
        except ValueError:
            raise UsageError(
                f"--damping must be 'identified', 'recorded' or B1,B2 in N m s/rad, got {args.damping!r}"
            ) from None
        if not (math.isfinite(b1) and math.isfinite(b2) and b1 >= 0 and b2 >= 0):
            raise UsageError(f"--damping values must be finite and >= 0, got {args.damping!r}")
        damping = (b1, b2)
    out_dir = args.out_dir or args.path.with_name(f"{args.path.stem}_validation")
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"output directory {str(out_dir)!r} is a file")
    report = validate(args.path, damping=damping, overrides=_overrides_from(args))
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "report.json").write_text(json.dumps(report_json(report), indent=1))
    print(table(report))
    written = [out_dir / "report.json"]
    if not args.no_plots:
        from bridge.plots import validation_figures

        written += validation_figures(report, out_dir)
    print(f"wrote {', '.join(str(p) for p in written)}")
    failures = []
    main_case = report.case("mujoco", "estimated", "whole")
    short = next(c for c in report.cases if c.engine == "mujoco" and c.release == "estimated" and c.window != "whole")
    if args.max_delta is not None:
        worst_q, worst = max(((q, c.delta_f) for q, c in main_case.comparisons.items()), key=lambda kv: kv[1])
        if not worst <= args.max_delta:
            failures.append(f"relative frequency error of {worst_q} {worst:.3g} > --max-delta {args.max_delta:g}")
    if args.max_iae is not None:
        iae = short.comparisons["phi1"].iae
        if not iae <= args.max_iae:
            failures.append(f"IAE of phi1 over {short.window} {iae:.4g} rad s > --max-iae {args.max_iae:g}")
    if args.max_error_phi1 is not None:
        err = main_case.comparisons["phi1"].max_abs
        if not err <= args.max_error_phi1:
            failures.append(f"max |Delta phi1| {err:.4g} rad > --max-error-phi1 {args.max_error_phi1:g}")
    for f in failures:
        print(f"pendsim: validation failed: {f}", file=sys.stderr)
    return 1 if failures else 0


def _cmd_identify(args: argparse.Namespace) -> int:
    import json

    from bridge.validate import identify

    if not args.path.is_file():
        raise UsageError(f"{args.path}: no such file")
    if args.write is not None and not args.write.parent.is_dir():
        raise UsageError(f"output directory {str(args.write.parent)!r} does not exist")
    result = identify(args.path, window_s=args.window_s)
    print(
        f"{args.path}: release at {result.release_time_s:.3f} s, from "
        f"{math.degrees(result.release_angle_rad[0]):.2f} deg, {math.degrees(result.release_angle_rad[1]):.2f} deg"
    )
    print("log decrement b = 2 J ln(A0/AT)/t1 (the paper's; exact only if b1/J1 = b2/J2):")
    for n, d in enumerate(result.log_decrement, start=1):
        print(
            f"  b{n} = {d.b_n_m_s:.5g} N m s/rad  (A0 {math.degrees(d.a0_rad):.3f} deg, "
            f"AT {math.degrees(d.at_rad):.3f} deg, t1 {d.window_s:.2f} s)"
        )
    fit = result.fit
    print(f"least squares on both gyros (mujoco.sysid, {fit.iterations} iterations, {fit.seconds:.1f} s):")
    for n in range(2):
        print(f"  b{n + 1} = {fit.b_n_m_s[n]:.5g} +- {fit.ci95_n_m_s[n]:.2g} N m s/rad (95 %)")
    print(f"  residual rms {fit.residual_rms_sigma:.3f} gyro noise sigmas (1 = explained to the noise level)")
    if args.write is not None:
        values = {"b1_n_m_s": float(fit.b_n_m_s[0]), "b2_n_m_s": float(fit.b_n_m_s[1])}
        args.write.write_text(json.dumps(values, indent=1) + "\n")
        print(f"wrote {args.write} (use: pendsim simulate --params-file {args.write})")
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    import json

    from bridge.plots import comparison_figures
    from pendsim_mj.comparison import compare_planar_spatial
    from pendsim_mj.model import Variant

    if args.fixed_points_plane not in ("m1", "m2"):
        raise UsageError(f"--fixed-points-plane must be m1 or m2, got {args.fixed_points_plane!r}")
    if args.engine != "mujoco":
        raise UsageError("the spatial model runs in MuJoCo only; drop --engine")
    out = args.out_dir
    if out.exists() and not out.is_dir():
        raise UsageError(f"output {str(out)!r} is a file; give a folder")
    if args.rerun is not None:
        _check_output(args.rerun, (".rrd",))
    params = _params_from(args).with_overrides(plane_offset_m=args.offset_m)
    phi0 = (math.radians(args.phi1_deg), math.radians(args.phi2_deg))
    result = compare_planar_spatial(
        params, phi0, args.duration_s, args.dt_s, variant=Variant(tilt=True, fixed_points_plane=args.fixed_points_plane)
    )  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps(result.summary, indent=1))
    figures = comparison_figures(result, out)
    main_hz = result.summary["main_frequency_hz"]
    print(
        f"planar vs spatial ({1000 * args.offset_m:g} mm between the planes, tilt freedoms), {args.duration_s:g} s "
        f"from {args.phi1_deg:g} deg, {args.phi2_deg:g} deg; main frequency {main_hz:.4f} Hz"
    )
    head = f"{'':4} {'max|dphi| (deg)':>16} {'>1 deg after (s)':>17} {'tilt amp (deg)':>15}"
    print(f"{head} {'beat planar':>12} {'beat spatial':>13}")
    for name, p in result.summary["pendulums"].items():
        first = p["first_time_difference_exceeds_1_deg_s"]

        def beat_text(variant: str, p=p) -> str:
            period = p["beat_period_s"][variant]
            return f"{period:.1f} s/{100 * p['beat_depth'][variant]:.0f}%" if period else "none"

        first_text = f"{first:.2f}" if first is not None else "-"
        row = f"{name:4} {math.degrees(p['in_plane_difference_max_rad']):16.2f} {first_text:>17}"
        tilt = math.degrees(p["out_of_plane_amplitude_rad"])
        print(f"{row} {tilt:15.2f} {beat_text('planar'):>12} {beat_text('spatial'):>13}")
    print(f"wrote {out / 'summary.json'}, {', '.join(str(f) for f in figures)}")
    if args.rerun is not None:
        from bridge.rerun_view import view_comparison

        view_comparison(result, params, Variant(tilt=True, fixed_points_plane=args.fixed_points_plane), args.rerun)
        print(f"wrote {args.rerun}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    import json

    from bridge.plots import validation_figures
    from bridge.rerun_view import view_recording
    from bridge.validate import report_json, table, validate

    out = args.out_dir
    if out.exists() and not out.is_dir():
        raise UsageError(f"output {str(out)!r} is a file; give a folder")
    if not (math.isfinite(args.duration_s) and 10 <= args.duration_s <= 3600):
        raise UsageError(f"--duration-s must be between 10 and 3600 s, got {args.duration_s:g}")
    out.mkdir(parents=True, exist_ok=True)
    recording = out / "run.mcap"
    print(f"1/4 simulating the rig from 30 deg for {args.duration_s:g} s and recording both IMUs to {recording}")
    code = main(["record", "-o", str(recording), "--force", "--duration-s", f"{args.duration_s:g}", "--hold-s", "2"])
    if code:
        return code
    print("2/4 identifying the damping and validating against the MuJoCo model and the planar reference")
    report = validate(recording)
    (out / "report.json").write_text(json.dumps(report_json(report), indent=1))
    print(table(report))
    print("3/4 drawing the paper's Figures 9-15")
    figures = validation_figures(report, out)
    print("4/4 writing the Rerun view")
    rrd = view_recording(recording, out / "run.rrd")
    print("\ndone:")
    print(f"  recording     {recording}   (pendsim inspect {recording})")
    print(f"  report        {out / 'report.json'}")
    print(f"  figures       {', '.join(p.name for p in figures)} in {out}")
    print(f"  Rerun         {rrd}   (open it with: rerun {rrd})")
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    from bridge.replay import ReplayStats, log_to_rerun, replay, replay_to_mcap

    if not args.path.is_file():
        raise UsageError(f"{args.path}: no such file")
    if args.speed == "max":
        speed = math.inf
    else:
        try:
            speed = float(args.speed)
        except ValueError:
            raise UsageError(f"--speed must be a number > 0 or max, got {args.speed!r}") from None
        if not (math.isfinite(speed) and speed > 0):
            raise UsageError(f"--speed must be a number > 0 or max, got {args.speed!r}")
    topics = [t.strip() for t in args.topics.split(",") if t.strip()] if args.topics else None
    if args.output is not None:
        if args.loop:
            raise UsageError("--loop cannot write to a file (it never ends); drop --loop or -o")
        _check_output(args.output, (".mcap",), force=False)
        count = replay_to_mcap(
            args.path, args.output, topics=topics, start_s=args.start, end_s=args.end, shift_to_zero=args.shift
        )
        print(f"wrote {args.output}: {count} messages")
        return 0
    if args.rerun is not None:
        _check_output(args.rerun, (".rrd",))
        import rerun as rr

        rr.init("pendsim_replay")
        rr.save(str(args.rerun))
    stats = ReplayStats()
    for message in replay(
        args.path, speed=speed, topics=topics, start_s=args.start, end_s=args.end, loop=args.loop, stats=stats
    ):
        if args.rerun is not None and message.schema_name in ("sensor_msgs/msg/Imu", "sensor_msgs/msg/JointState"):
            log_to_rerun(message)
        if not args.quiet:
            print(f"{message.t_s:12.4f}  {message.topic}  {len(message.data)} B")
    summary = stats.summary()
    line = f"replayed {summary['messages']} messages"
    if math.isfinite(speed):
        late = f"p50 {summary['p50_ms']:.2f} ms, p99 {summary['p99_ms']:.2f} ms, max {summary['max_ms']:.2f} ms"
        line += f" at {speed:g}x; lateness {late}"
    print(line)
    if args.rerun is not None:
        import rerun as rr

        rr.disconnect()
        print(f"wrote {args.rerun}")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    import contextlib
    import subprocess

    from bridge.rerun_view import view_recording

    if not args.path.is_file():
        raise UsageError(f"{args.path}: no such file")
    rrd = args.save or args.path.with_suffix(".rrd")
    _check_output(rrd, (".rrd",))
    view_recording(args.path, rrd)
    print(f"wrote {rrd} (open it with: rerun {rrd})")
    rerun_cli = str(Path(sys.executable).with_name("rerun"))
    if args.spawn:
        subprocess.Popen([rerun_cli, str(rrd)])
    if args.serve:
        grpc_port = args.port + 1
        command = [
            rerun_cli,
            "--serve-web",
            "--bind",
            args.bind,
            "--web-viewer-port",
            str(args.port),
            "--port",
            str(grpc_port),
            str(rrd),
        ]
        print(f"serving on http://{args.bind}:{args.port} (Ctrl-C stops)", flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            subprocess.run(command, check=False)
    return 0


def _cmd_recover(args: argparse.Namespace) -> int:
    from bridge.mcap_tools import recover

    if args.fixed.exists():
        raise UsageError(f"output {str(args.fixed)!r} exists; recover never overwrites a file")
    if args.fixed.suffix.lower() != ".mcap":
        raise UsageError(f"output {str(args.fixed)!r} must end in .mcap")
    if not args.fixed.parent.is_dir():
        raise UsageError(f"output directory {str(args.fixed.parent)!r} does not exist")
    contents = recover(args.broken, args.fixed)
    state = "was complete" if contents.complete else "; ".join(contents.problems)
    print(f"{args.broken}: {state}")
    print(f"wrote {args.fixed}: {contents.summary_line()}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``pendsim`` console script; returns the exit code."""
    parser = _build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return EXIT_USAGE
        handler = {
            "simulate": _cmd_simulate,
            "info": _cmd_info,
            "record": _cmd_record,
            "inspect": _cmd_inspect,
            "recover": _cmd_recover,
            "allan": _cmd_allan,
            "validate": _cmd_validate,
            "identify": _cmd_identify,
            "view": _cmd_view,
            "demo": _cmd_demo,
            "compare": _cmd_compare,
            "replay": _cmd_replay,
        }[args.command]
        return handler(args)
    except (UsageError, PendsimError) as exc:
        print(f"pendsim: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("pendsim: interrupted", file=sys.stderr)
        return 130


def _run() -> None:  # pragma: no cover - console script wrapper
    sys.exit(main())


if __name__ == "__main__":  # pragma: no cover
    _run()
