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
    sim.add_argument("--phi1-deg", type=_finite_float, default=30.0, help="initial angle of M1, deg (default 30)")
    sim.add_argument("--phi2-deg", type=_finite_float, default=0.0, help="initial angle of M2, deg (default 0)")
    sim.add_argument("--omega1-deg-s", type=_finite_float, default=0.0, help="initial rate of M1, deg/s (default 0)")
    sim.add_argument("--omega2-deg-s", type=_finite_float, default=0.0, help="initial rate of M2, deg/s (default 0)")
    sim.add_argument("--duration-s", type=_finite_float, default=120.0, help="simulated time, s (default 120)")
    sim.add_argument("--dt-s", type=_finite_float, default=0.01, help="integration step, s (default 0.01)")
    sim.add_argument(
        "--engine", default="mujoco", help="mujoco (the MJCF model) or reference (planar Newtonian RK4); default mujoco"
    )
    sim.add_argument(
        "--b1", type=_finite_float, help=f"hinge damping of M1, N m s/rad (default {DEFAULT_PARAMS.b1_n_m_s:.4g})"
    )
    sim.add_argument(
        "--b2", type=_finite_float, help=f"hinge damping of M2, N m s/rad (default {DEFAULT_PARAMS.b2_n_m_s:.4g})"
    )
    sim.add_argument(
        "--set",
        dest="overrides",
        type=_assignment,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override any parameter in SI units, e.g. --set c1_n_m=6.0 (see 'pendsim info'); repeatable",
    )
    sim.add_argument("-o", "--output", type=Path, help="write the trajectory to FILE.npz (all arrays) or FILE.csv")

    sub.add_parser(
        "info",
        help="print every rig parameter with its unit and source",
        description="Print every rig parameter with value, unit and source.",
    )
    return parser


def _params_from(args: argparse.Namespace) -> RigParams:
    overrides = dict(args.overrides)
    if args.b1 is not None:
        overrides["b1_n_m_s"] = args.b1
    if args.b2 is not None:
        overrides["b2_n_m_s"] = args.b2
    return DEFAULT_PARAMS.with_mapping(overrides)


def _check_output(path: Path | None) -> None:
    if path is None:
        return
    if path.suffix.lower() not in OUTPUT_SUFFIXES:
        raise UsageError(f"output {str(path)!r} must end in .npz or .csv")
    parent = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise UsageError(f"output {str(path)!r} is a directory; give a file name ending in .npz or .csv")
    if not parent.is_dir():
        raise UsageError(f"output directory {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise UsageError(f"output directory {str(parent)!r} is not writable")


def _cmd_simulate(args: argparse.Namespace) -> int:
    if args.engine not in ENGINES:
        raise UsageError(f"unknown engine {args.engine!r}; allowed: {', '.join(ENGINES)}")
    _check_output(args.output)
    params = _params_from(args)
    phi0 = (math.radians(args.phi1_deg), math.radians(args.phi2_deg))
    omega0 = (math.radians(args.omega1_deg_s), math.radians(args.omega2_deg_s))
    if args.engine == "mujoco":
        from pendsim_mj.simulation import simulate as run
    else:
        from pendsim_mj.reference import solve as run
    traj = run(params, phi0, omega0, args.duration_s, args.dt_s)
    print(_summary(traj, args.engine))
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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``pendsim`` console script; returns the exit code."""
    parser = _build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return EXIT_USAGE
        handler = {"simulate": _cmd_simulate, "info": _cmd_info}[args.command]
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
