"""pendsim analyze: nonlinear-dynamics analyses of the driven rig (backbone, response, bifurcation,
lyapunov, tongues, sync), each writing a JSON and a CSV of its numbers and a PNG into one folder."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from pendsim_mj.rig.drives import Drive, Sine

from .. import options

VERBS = ("backbone", "response", "bifurcation", "lyapunov", "tongues", "sync")
# What a sweep drives when no drive option is given (the same as the documented examples).
DEFAULT_SWEEP_DRIVE = Drive(torque_m1=Sine(0.003, 0.85))
DEFAULT_CHAOS_DRIVE = Drive(torque_m1=Sine(0.5, 0.6))
DEFAULT_SYNC_DRIVE = Drive(torque_m1=Sine(0.002, 1.2))


def register(sub: argparse._SubParsersAction[options.Parser]) -> None:
    p = sub.add_parser(
        "analyze",
        help="nonlinear analyses: backbone, response, bifurcation, lyapunov, tongues, sync (JSON, CSV, PNG)",
        description="Nonlinear-dynamics analyses on the MuJoCo model of the planar rig. Each verb writes "
        "VERB.json (every number), VERB.csv (the main table) and VERB.png into --out-dir, with a progress bar. "
        "Drives are given with the same options as 'pendsim simulate' (a sweep replaces the sine's frequency).",
    )
    verbs = p.add_subparsers(dest="verb", metavar="VERB", parser_class=options.Parser)
    for name, helptext, adder, handler in _VERBS:
        v = verbs.add_parser(name, help=helptext, description=helptext)
        adder(v)
        options.add_parameter_options(v)
        v.add_argument("-o", "--out-dir", type=Path, default=Path(f"analyze_{name}"), help=f"default analyze_{name}/")
        options.add_force_option(v, f"{name}.json, .csv and .png in the output folder")
        v.set_defaults(handler=handler)
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """``pendsim analyze`` without a verb."""
    raise options.UsageError(f"analyze needs a verb: {', '.join(VERBS)} (pendsim analyze VERB --help)")


def _frequency_range(p: argparse.ArgumentParser, low: float, high: float, count: int, what: str) -> None:
    hz = options.float_in(0.01, 50.0, "Hz")
    p.add_argument("--f-min-hz", type=hz, default=low, help=f"lowest drive frequency, Hz (default {low:g})")
    p.add_argument("--f-max-hz", type=hz, default=high, help=f"highest drive frequency, Hz (default {high:g})")
    p.add_argument("--frequencies", type=options.int_in(2, 2000), default=count, help=f"{what} (default {count})")


def _steps(p: argparse.ArgumentParser, default: int) -> None:
    p.add_argument(
        "--steps-per-period",
        type=options.int_in(16, 4096),
        default=default,
        help=f"RK4 steps per drive (or orbit) period, even (default {default})",
    )


def _add_backbone(p: argparse.ArgumentParser) -> None:
    modes = ("1", "2", "both")
    p.add_argument("--mode", type=options.choice(modes, "--mode must be 1, 2 or both, got {value!r}"),
                   choices=modes, default="both", help="which nonlinear normal mode (default both)")  # fmt: skip
    p.add_argument("--max-amplitude-deg", type=options.float_in(1.0, 170.0, "deg"), default=90.0,
                   help="continue until a swing exceeds this, deg (default 90)")  # fmt: skip
    _steps(p, 128)


def _add_response(p: argparse.ArgumentParser) -> None:
    options.add_drive_options(p, what="the rig (sines at one frequency; default torque1 sine:0.003,0.85)")
    _frequency_range(p, 0.8, 0.92, 25, "stepped-sine frequencies")
    p.add_argument("--method", type=options.choice(("both", "stepped", "continuation"), "unknown method {value!r}"),
                   choices=("both", "stepped", "continuation"), default="both", help="default both")  # fmt: skip
    p.add_argument("--max-periods", type=options.int_in(20, 100000), default=600,
                   help="longest dwell of a stepped-sine step, drive periods (default 600)")  # fmt: skip
    _steps(p, 64)


def _add_bifurcation(p: argparse.ArgumentParser) -> None:
    options.add_drive_options(p, what="the rig (sines at one frequency; default torque1 sine:0.5,0.6)")
    p.add_argument("--parameter", type=options.choice(("frequency", "level"), "unknown parameter {value!r}"),
                   choices=("frequency", "level"), default="level",
                   help="sweep the drive frequency (Hz) or level (the first sine's amplitude)")  # fmt: skip
    # the widest range of either parameter here; the parameter's own range is checked in _bifurcation
    widest = max(options.MAX_DRIVE_FREQUENCY_HZ, *(limit for limit, _ in options.DRIVE_LIMITS.values()))
    bound = options.float_in(-widest, widest)
    p.add_argument("--from", dest="low", type=bound, help="first value (default: the drive's / 3)")
    p.add_argument("--to", dest="high", type=bound, help="last value (default: the drive's)")
    p.add_argument("--values", type=options.int_in(2, 2000), default=31, help="values swept (default 31)")
    p.add_argument("--transient-periods", type=options.int_in(0, 100000), default=300, help="default 300")
    p.add_argument("--sample-periods", type=options.int_in(1, 10000), default=40, help="default 40")
    _steps(p, 64)


def _add_lyapunov(p: argparse.ArgumentParser) -> None:
    options.add_drive_options(p, what="the rig (any signal; default torque1 sine:0.5,0.6; none: the free rig)")
    angle = options.float_in(-180.0, 180.0, "deg")
    p.add_argument("--phi1-deg", type=angle, default=0.0, help="initial angle of M1, deg (default 0)")
    p.add_argument("--phi2-deg", type=angle, default=0.0, help="initial angle of M2, deg (default 0)")
    p.add_argument("--free", action="store_true", help="no drive: the free (released) rig")
    p.add_argument("--duration-s", type=options.float_in(1.0, 1e6, "s"), default=600.0, help="default 600")
    p.add_argument("--transient-s", type=options.float_in(0.0, 1e6, "s"), default=200.0, help="default 200")
    p.add_argument("--interval-s", type=options.float_in(0.001, 100.0, "s"),
                   help="renormalisation interval (default: the drive period, or 1 s)")  # fmt: skip
    p.add_argument("--dt-s", type=options.float_in(1e-4, 0.1, "s"), default=0.01, help="step, s (default 0.01)")
    p.add_argument("--members", type=options.int_in(2, 256), default=8,
                   help="runs in the ensemble, started within 1e-5 rad of the release (default 8)")  # fmt: skip
    p.add_argument("--tolerance-per-s", type=options.float_in(1e-6, 100.0, "1/s"), default=0.01,
                   help="absolute tolerance of the exponent, 1/s (default 0.01)")  # fmt: skip
    p.add_argument("--rel-tol", type=options.float_in(0.0, 10.0, ""), default=0.1,
                   help="relative tolerance of the exponent (default 0.1); the larger of the two applies")  # fmt: skip


def _add_tongues(p: argparse.ArgumentParser) -> None:
    _frequency_range(p, 1.4, 3.3, 121, "frequencies of the map")
    p.add_argument("--level-max-m-s2", type=options.float_in(0.01, 100.0, "m/s^2"), default=3.0,
                   help="highest pivot acceleration amplitude, m/s^2 (default 3)")  # fmt: skip
    p.add_argument("--levels", type=options.int_in(2, 1000), default=24, help="levels of the map (default 24)")
    _steps(p, 64)


def _add_sync(p: argparse.ArgumentParser) -> None:
    options.add_drive_options(p, what="one pendulum (sines at one frequency; default torque1 sine:0.002,1.2)")
    _frequency_range(p, 0.7, 1.7, 26, "drive frequencies")
    p.add_argument("--measure-periods", type=options.int_in(10, 10000), default=40, help="window, periods")
    _steps(p, 64)


def _bar(total: float | None, desc: str) -> Any:
    from tqdm import tqdm  # start-up: loaded when the command runs

    return tqdm(total=total, desc=desc, unit="", disable=None, leave=False)


def _files(args: argparse.Namespace) -> tuple[str, ...]:
    """Files a verb writes (checked before the work; all of them again when publishing)."""
    return (f"{args.verb}.json", f"{args.verb}.png")


def _written(paths: list[Path]) -> None:
    print(f"wrote {', '.join(str(p) for p in paths)}")


def _backbone(args: argparse.Namespace) -> int:
    from pendsim_mj.nonlinear import backbone  # start-up: MuJoCo, scipy

    from ..report.analysis_report import write_backbone  # start-up: matplotlib

    options.check_output_dir(args.out_dir, _files(args), force=args.force)
    params = options.params_from(args)
    modes = (1, 2) if args.mode == "both" else (int(args.mode),)
    top = math.radians(args.max_amplitude_deg)
    results = []
    for mode in modes:
        with _bar(args.max_amplitude_deg, f"backbone mode {mode} (deg)") as bar:
            done = [0.0]

            def step(a: float, bar: Any = bar, done: list[float] = done) -> None:
                bar.update(max(0.0, min(math.degrees(a), args.max_amplitude_deg) - done[0]))
                done[0] = max(done[0], math.degrees(a))

            b = backbone(params, mode, max_amplitude_rad=top, steps_per_period=args.steps_per_period, progress=step)
        results.append(b)
        worst = float(np.nanmax(b.free_relative_difference))
        print(f"mode {mode}: {len(b.frequency_hz)} orbits, {b.frequency_hz[0]:.5f} Hz (linear "
              f"{b.linear_frequency_hz:.5f}) to {b.frequency_hz[-1]:.5f} Hz at "
              f"{math.degrees(np.max(b.amplitude_rad[-1])):.1f} deg; free-simulation frequency within {worst:.1e}; "
              f"periodicity residual <= {np.max(b.periodicity_residual):.1e}")  # fmt: skip
    settings = {"modes": modes, "max_amplitude_deg": args.max_amplitude_deg, "steps_per_period": args.steps_per_period}
    _written(write_backbone(results, args.out_dir, settings=settings, replace=args.force))
    return 0


def _sweep_drive(args: argparse.Namespace, default: Drive) -> Drive:
    from pendsim_mj.nonlinear.periodic import drive_frequency_hz  # start-up: MuJoCo, scipy

    drive = options.drive_from(args) or default
    try:
        drive_frequency_hz(drive)
    except Exception as exc:  # ParameterError: name the option
        raise options.UsageError(f"this analysis sweeps a sine drive: {exc}") from None
    return drive


def _range(args: argparse.Namespace) -> np.ndarray:
    if not args.f_max_hz > args.f_min_hz:
        raise options.UsageError(f"--f-max-hz ({args.f_max_hz:g}) must exceed --f-min-hz ({args.f_min_hz:g})")
    return np.linspace(args.f_min_hz, args.f_max_hz, args.frequencies)


def _response(args: argparse.Namespace) -> int:
    from pendsim_mj.nonlinear import compare_with_branch, continue_response, stepped_sine  # start-up: MuJoCo, scipy

    from ..report.analysis_report import write_response  # start-up: matplotlib

    options.check_output_dir(args.out_dir, _files(args), force=args.force)
    params, drive, freqs = options.params_from(args), _sweep_drive(args, DEFAULT_SWEEP_DRIVE), _range(args)
    sweeps: tuple[Any, ...] = ()
    branch = None
    if args.method in ("both", "stepped"):
        with _bar(len(freqs), "stepped sine (frequencies)") as bar:
            sweeps = stepped_sine(params, drive, freqs, steps_per_period=args.steps_per_period,
                                  max_periods=args.max_periods, progress=bar.update)  # fmt: skip
    if args.method in ("both", "continuation"):
        with _bar(None, "continuation (orbits)") as bar:
            branch = continue_response(params, drive, freqs[0], freqs[-1], steps_per_period=args.steps_per_period,
                                       progress=lambda p: bar.update(1))  # fmt: skip
    agreements = [compare_with_branch(params, drive, s, branch) for s in sweeps] if branch is not None else []
    _print_response(sweeps, branch, agreements)
    settings = {"frequencies_hz": freqs, "method": args.method, "steps_per_period": args.steps_per_period}
    _written(write_response(drive, branch, sweeps, agreements, args.out_dir, settings=settings, replace=args.force))
    return 0


def _print_response(sweeps: Any, branch: Any, agreements: Any) -> None:
    for s in sweeps:
        k = int(np.argmax(s.amplitude_rad[:, 0]))
        print(f"stepped sine {s.direction}: peak {math.degrees(s.amplitude_rad[k, 0]):.2f} deg at "
              f"{s.frequency_hz[k]:.4f} Hz; {int(np.sum(~s.settled))} steps not settled")  # fmt: skip
    if branch is not None:
        k = int(np.argmax(branch.amplitude_rad[:, 0]))
        peak = math.degrees(branch.amplitude_rad[k, 0])
        print(f"continuation: {len(branch.frequency_hz)} orbits, peak {peak:.2f} deg at {branch.frequency_hz[k]:.4f} "
              f"Hz, {int(np.sum(~branch.stable))} unstable ({branch.end_reason})")  # fmt: skip
        for b in branch.bifurcations:
            amp, amp_tol = math.degrees(b.amplitude_rad[0]), math.degrees(b.amplitude_tol_rad[0])
            how = (
                f"the turning point, bracketed to {b.frequency_tol_hz:.0e} Hz and {amp_tol:.0e} deg"
                if b.refined
                else f"interpolated between branch points {b.frequency_tol_hz:.1g} Hz and {amp_tol:.2g} deg apart"
            )
            print(f"  {b.kind} at {b.frequency_hz:.6f} Hz, phi1 amplitude {amp:.3f} deg ({how})")
    for s, a in zip(sweeps, agreements, strict=False):
        print(f"stepped {s.direction} vs continuation (stable branches): max relative difference "
              f"{a.max_relative_difference:.2e}")  # fmt: skip


def _bifurcation(args: argparse.Namespace) -> int:
    from pendsim_mj.nonlinear import poincare_sweep  # start-up: MuJoCo, scipy
    from pendsim_mj.nonlinear.periodic import drive_frequency_hz

    from ..report.analysis_report import write_bifurcation  # start-up: matplotlib

    options.check_output_dir(args.out_dir, _files(args), force=args.force)
    params, drive = options.params_from(args), _sweep_drive(args, DEFAULT_CHAOS_DRIVE)
    first = drive.signal(drive.targets[0])
    base = drive_frequency_hz(drive) if args.parameter == "frequency" else abs(getattr(first, "amplitude", 1.0))
    low = args.low if args.low is not None else base / 3
    high = args.high if args.high is not None else base
    if not high > low or (args.parameter == "frequency" and low <= 0):
        raise options.UsageError(f"--to ({high:g}) must exceed --from ({low:g}), frequencies > 0")
    if args.parameter == "frequency":
        top, unit = options.MAX_DRIVE_FREQUENCY_HZ, "Hz"
    else:
        top, unit = options.DRIVE_LIMITS[drive.targets[0].value]
    for flag, value in (("--from", low), ("--to", high)):
        if abs(value) > top:
            raise options.UsageError(
                f"{flag} must be within +-{top:g} {unit} for the drive {args.parameter}, got {value:g}"
            )
    values = np.linspace(low, high, args.values)
    with _bar(len(values), f"sweep of the drive {args.parameter}") as bar:
        diagram = poincare_sweep(
            params, drive, values, parameter=args.parameter, steps_per_period=args.steps_per_period,
            transient_periods=args.transient_periods, sample_periods=args.sample_periods, progress=bar.update,
        )  # fmt: skip
    for s in diagram.sweeps:
        counts = {p: int(np.sum(s.period == p)) for p in sorted(set(s.period.tolist()))}
        print(f"sweep {s.direction}: response period per value {counts} (0: not periodic up to 8 periods)")
    settings = {"parameter": args.parameter, "values": values, "steps_per_period": args.steps_per_period}
    _written(write_bifurcation(diagram, drive, args.out_dir, settings=settings, replace=args.force))
    return 0


def _lyapunov(args: argparse.Namespace) -> int:
    from pendsim_mj.nonlinear import largest_lyapunov  # start-up: MuJoCo, scipy

    from ..report.analysis_report import write_lyapunov  # start-up: matplotlib

    options.check_output_dir(args.out_dir, _files(args), force=args.force)
    drive = None if args.free else (options.drive_from(args) or DEFAULT_CHAOS_DRIVE)
    interval = args.interval_s or _period_or(drive, 1.0)
    dt = interval / max(1, round(interval / args.dt_s))  # a whole number of steps per interval
    x0 = (math.radians(args.phi1_deg), math.radians(args.phi2_deg), 0.0, 0.0)
    with _bar(2 * (args.duration_s + args.transient_s), "Lyapunov (simulated s, both steps)") as bar:
        result = largest_lyapunov(
            options.params_from(args), drive, x0=x0, duration_s=args.duration_s, transient_s=args.transient_s,
            interval_s=interval, dt_s=dt, members=args.members, abs_tol_per_s=args.tolerance_per_s,
            rel_tol=args.rel_tol, progress=bar.update,
        )  # fmt: skip
    r = result
    print(
        f"largest Lyapunov exponent {r.exponent_per_s:.4g} +- {r.uncertainty_per_s:.2g} 1/s ({args.members} runs of "
        f"{len(r.t_s)} intervals of {r.interval_s:g} s, from {np.min(r.member_exponents_per_s):.3g} to "
        f"{np.max(r.member_exponents_per_s):.3g}; at dt/2 {r.step_difference_per_s:+.2g}, over the first half "
        f"{r.time_difference_per_s:+.2g}; {'converged' if r.converged else 'NOT converged'} to "
        f"{r.tolerance_per_s:.2g} 1/s)"
    )  # fmt: skip
    settings = {"interval_s": result.interval_s, "dt_s": dt, "x0": x0, "free": args.free, "members": args.members}
    _written(write_lyapunov(result, drive, args.out_dir, settings=settings, replace=args.force))
    if not r.converged:
        change = {
            "spread": f"the runs disagree: run longer (about --duration-s {_round_up(r.needed_duration_s)})",
            "step": f"the runs at dt/2 disagree: halve the step (--dt-s {dt / 2:.3g})",
            "time": f"the first half disagrees: run longer (--duration-s {_round_up(2 * args.duration_s)})",
        }[r.failed_check]
        print(f"pendsim: unconverged: the Lyapunov exponent is {r.exponent_per_s:.3g} +- {r.uncertainty_per_s:.2g} "
              f"1/s, wider than the tolerance {r.tolerance_per_s:.2g} 1/s; {change}, or widen --tolerance-per-s / "
              "--rel-tol", file=sys.stderr)  # fmt: skip
        return 1
    return 0


def _round_up(seconds: float) -> str:
    """A duration rounded up to two significant digits, for advice."""
    magnitude = 10 ** max(0, math.floor(math.log10(max(seconds, 1.0))) - 1)
    return f"{math.ceil(seconds / magnitude) * magnitude:g}"


def _period_or(drive: Drive | None, default: float) -> float:
    if drive is None:
        return default
    freqs = {getattr(drive.signal(t), "frequency_hz", None) for t in drive.targets}
    only = freqs.pop() if len(freqs) == 1 else None
    return 1.0 / only if isinstance(only, float) else default


def _tongues(args: argparse.Namespace) -> int:
    from pendsim_mj.nonlinear import tongues  # start-up: MuJoCo, scipy
    from pendsim_mj.nonlinear.tongues import TIP_LEVEL_REL_TOL

    from ..report.analysis_report import write_tongues  # start-up: matplotlib

    options.check_output_dir(args.out_dir, _files(args), force=args.force)
    freqs = _range(args)
    with _bar(None, "tongues (rounds)") as bar:
        result = tongues(options.params_from(args), freqs, args.level_max_m_s2, levels=args.levels,
                         steps_per_period=args.steps_per_period, progress=bar.update)  # fmt: skip
    f1, f2 = result.linear_frequency_hz
    print(f"principal tongues grow from 2 f1 = {2 * f1:.4f} Hz and 2 f2 = {2 * f2:.4f} Hz")
    for tip in result.tips:
        where = f" near {tip.near}" if tip.near else ""
        edge = " (at the edge of the frequency range: the tongue's tip may lie outside it)" if tip.at_edge else ""
        print(f"tongue tip{where}: {tip.level_m_s2:.5g} m/s^2 +- {tip.level_tol_m_s2:.1g} at {tip.frequency_hz:.5f} Hz "
              f"+- {tip.frequency_tol_hz:.0e} ({2 * args.steps_per_period} steps per period; "
              f"{args.steps_per_period} give {tip.level_n_m_s2:.5g}){edge}")  # fmt: skip
    lowest = result.lowest_tip
    print(
        f"lowest unstable level {lowest.level_m_s2:.4g} m/s^2 at {lowest.frequency_hz:.4f} Hz"
        if lowest is not None
        else f"rest is stable everywhere up to {args.level_max_m_s2:g} m/s^2"
    )
    settings = {"level_max_m_s2": args.level_max_m_s2, "steps_per_period": args.steps_per_period}
    _written(write_tongues(result, args.out_dir, settings=settings, replace=args.force))
    loose = [t for t in result.tips if not t.converged]
    for t in loose:
        print(f"pendsim: unconverged: the tongue tip at {t.frequency_hz:.4f} Hz is not located to "
              f"{TIP_LEVEL_REL_TOL:g} of its level ({t.level_tol_m_s2:.1g} m/s^2 between {args.steps_per_period} and "
              f"{2 * args.steps_per_period} steps per period); raise --steps-per-period", file=sys.stderr)  # fmt: skip
    return 1 if loose else 0


def _sync(args: argparse.Namespace) -> int:
    from pendsim_mj.nonlinear import stepped_sine  # start-up: MuJoCo, scipy

    from ..report.analysis_report import write_sync  # start-up: matplotlib

    options.check_output_dir(args.out_dir, _files(args), force=args.force)
    params, drive, freqs = options.params_from(args), _sweep_drive(args, DEFAULT_SYNC_DRIVE), _range(args)
    with _bar(len(freqs), "synchronisation sweep (frequencies)") as bar:
        sweeps = stepped_sine(params, drive, freqs, steps_per_period=args.steps_per_period, directions=("up",),
                              min_periods=args.measure_periods, measure_periods=args.measure_periods,
                              progress=bar.update)  # fmt: skip
    s = sweeps[0]
    locked = s.locking_index > 0.9
    print(f"1:1 locked (index > 0.9) at {int(locked.sum())} of {len(freqs)} drive frequencies; "
          f"frequency ratio f1/f2 from {np.min(s.frequency_ratio):.3f} to {np.max(s.frequency_ratio):.3f}")  # fmt: skip
    settings = {"frequencies_hz": freqs, "measure_periods": args.measure_periods}
    _written(write_sync(drive, sweeps, args.out_dir, settings=settings, replace=args.force))
    return 0


_VERBS: tuple[tuple[str, str, Callable[[argparse.ArgumentParser], None], Callable[[argparse.Namespace], int]], ...] = (
    ("backbone", "backbone curves (frequency against amplitude) of both nonlinear normal modes of the undamped rig",
     _add_backbone, _backbone),
    ("response", "frequency-response curves: stepped sine up and down, and continuation with Floquet stability "
     "and bifurcations", _add_response, _response),
    ("bifurcation", "bifurcation diagram: stroboscopic (Poincare) samples against drive frequency or level",
     _add_bifurcation, _bifurcation),
    ("lyapunov", "largest Lyapunov exponent of a driven (or free) run, with its convergence", _add_lyapunov,
     _lyapunov),
    ("tongues", "instability tongues of parametric excitation (vertical pivot motion) with the Mathieu-type limit",
     _add_tongues, _tongues),
    ("sync", "synchronisation of the two pendulums under a drive on one: phase-locking index and frequency ratio",
     _add_sync, _sync),
)  # fmt: skip
