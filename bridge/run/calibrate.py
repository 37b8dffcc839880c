"""pendsim calibrate's work: recordings aligned, the rig calibrated on all of them, checked
(before and after, each recording left out in turn, the residual's cause tested), and written.

The calibration itself is ``pendsim_mj.calibration``; this module reads the recordings, runs the
validations that show what it changed, and writes the parameter file and the report.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from pendsim_mj.calibration import Calibration, CalibrationRun, calibrate
from pendsim_mj.calibration.design import suggest
from pendsim_mj.calibration.fit import LOSSES
from pendsim_mj.calibration.information import describe_held
from pendsim_mj.calibration.parameters import ParameterSpace, added_mass_constants
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.alignment import DEFAULT_MAX_GAP_S
from pendsim_mj.estimation.measured_run import MeasuredRun
from pendsim_mj.rig.params import RigParams

from ..io.measured import align_recording, recording_drive
from ..io.recording import DRIVE_TOPIC, NODES, imu_topic, read_recording
from ..report.calibration_report import CalibrationReport, Metrics
from .validate import validate

MODEL_ERROR_SIGMAS = 1.5  # a residual rms above this many noise sigmas after calibration is model error
STRUCTURED_SIGMAS = 1.05  # above this and not white (WHITE_P): structure the model leaves, model error too
WHITE_P = 1e-3
SPATIAL_SIGMAS = 3.0  # rotation across the hinge above this many gyro noise sigmas rms (planar: 1.4): the support tilts
INCONSISTENT_RATIO = 1.3  # a recording whose joint-fit residual is this much above its own fit's: another rig


def _metrics(path: Path, params: RigParams, rig: str, damping: str) -> Metrics:
    report = validate(path, params=params, damping=damping)
    case = report.case("mujoco", "estimated", "whole").comparisons
    phi1, omega2 = case["phi1"], case["omega2"]
    return Metrics(str(path), rig, phi1.max_abs, omega2.max_abs, phi1.iae, phi1.delta_f)


def load_runs(
    paths: Sequence[Path],
    params: RigParams,
    *,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    off_hinge: dict[str, float] | None = None,
) -> list[CalibrationRun]:
    """Each recording aligned (as identify and validate align it) as a ``CalibrationRun``;
    ``off_hinge``: filled with each recording's ``off_hinge_sigmas``."""
    runs = []
    for path in paths:
        rec = read_recording(path, topics=[*(imu_topic(n) for n in NODES), DRIVE_TOPIC])
        run = align_recording(rec, params, release_s=release_s, max_gap_s=max_gap_s)
        runs.append(CalibrationRun.from_measured(str(path), run, recording_drive(rec, run)))
        if off_hinge is not None:
            off_hinge[str(path)] = off_hinge_sigmas(run)
        del rec
    return runs


def off_hinge_sigmas(run: MeasuredRun) -> float:
    """How much the gyros turn about axes across the hinge, in their noise sigmas rms (the larger
    node's): about 1 for a planar swing (noise alone), far above it when the support tilts (the
    spatial motion a planar model leaves out). A test from the data, not from any model."""
    out = 0.0
    for node in run.nodes:
        off = node.off_hinge_gyro_rad_s
        if off is None or not len(off):
            continue
        ok = np.all(np.isfinite(off), axis=1)
        out = max(out, float(np.sqrt(np.mean(off[ok] ** 2))) / node.gyro_sigma_rad_s)
    return out


def _refuse_repeats(runs: Sequence[CalibrationRun]) -> None:
    """The same data given twice (a file twice, or a copy) would count twice: intervals sqrt(2)
    too narrow."""
    for i, a in enumerate(runs):
        for b in runs[i + 1 :]:
            if all(np.array_equal(x, y) for x, y in zip(a.gyro_z_rad_s, b.gyro_z_rad_s, strict=True)):
                raise ParameterError(f"{a.name} and {b.name} hold the same data; give each recording once")


def _consistency(runs: Sequence[CalibrationRun], joint: Calibration, fit: Callable[..., Calibration]) -> None:
    """Recordings of different rigs: one explained to the noise alone but not with the others."""
    if len(runs) < 2:
        return
    for run, result in zip(runs, joint.runs, strict=True):
        alone = fit([run]).residual_rms_sigma
        if result.residual_rms_sigma > INCONSISTENT_RATIO * alone and alone < MODEL_ERROR_SIGMAS:
            raise ParameterError(
                f"{run.name} is not of the same rig as the other recordings: alone it is explained to "
                f"{alone:.2f} noise sigmas, with them to {result.residual_rms_sigma:.2f}; calibrate each rig on its own"
            )


def _model_error(
    cal: Calibration, runs: Sequence[CalibrationRun], fit: Callable[..., Calibration], off_hinge: Mapping[str, float]
) -> list[str]:
    """Name the cause of a residual far above the noise, by testing the alternatives the planar
    model can test (the damping law); what it cannot is said as such."""
    worst = max(r.residual_rms_sigma for r in cal.runs)
    white = min(min(r.ljung_box_p) for r in cal.runs)
    structured = worst > STRUCTURED_SIGMAS and white < WHITE_P
    if worst <= MODEL_ERROR_SIGMAS and not structured:
        return []
    lines = [
        f"model error: after calibration the residual is {worst:.2f} noise sigmas rms and not white (Ljung-Box p "
        f"{white:.2g}): what the planar model with these parameters cannot explain; its intervals do not hold"
    ]
    if cal.law != "both":
        other = fit(runs, law="both")
        if other.residual_rms_sigma < min(0.8 * cal.residual_rms_sigma, cal.residual_rms_sigma - 0.05):
            lines.append(
                f"tested: dry friction at the hinges lowers it to {other.residual_rms_sigma:.1f} sigmas "
                "(calibrate --law both)"
            )
        else:
            lines.append(f"tested: dry friction does not explain it ({other.residual_rms_sigma:.1f} sigmas with it)")
    for name, sigmas in off_hinge.items():
        if sigmas > SPATIAL_SIGMAS:
            lines.append(
                f"tested: {Path(name).name}'s gyros turn about axes across the hinge at {sigmas:.1f} noise sigmas rms "
                "(a planar swing: about 1): the support tilts, spatial motion the planar model leaves out (compare "
                "'pendsim validate --model spatial')"
            )
        else:
            lines.append(f"tested: no spatial motion in {Path(name).name} (across the hinge: {sigmas:.1f} sigmas)")
    lines.append("not tested: spring nonlinearity (the model's springs are linear, zero free length)")
    return lines


def calibrate_recordings(
    paths: Sequence[Path],
    params: RigParams,
    *,
    law: str = "viscous",
    free: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    checks: bool = True,
    added: Mapping[int, tuple[int, float, float]] | None = None,
    progress: Callable[[str], None] | None = None,
) -> CalibrationReport:
    """Calibrate the rig on the recordings and check the result (module docstring); ``checks``
    False: no validations, no left-out fits (the calibration alone). ``added``: recording index ->
    (pendulum, kg, m) of a known mass clamped on it while it was recorded."""
    say = progress or (lambda line: None)
    off_hinge: dict[str, float] = {}
    runs = load_runs(paths, params, release_s=release_s, max_gap_s=max_gap_s, off_hinge=off_hinge)
    _refuse_repeats(runs)

    def with_masses(runs: list[CalibrationRun]) -> list[CalibrationRun]:
        for index, (pendulum, mass_kg, radius_m) in (added or {}).items():
            extra = added_mass_constants(params, pendulum, mass_kg, radius_m)
            runs[index] = dataclasses.replace(runs[index], added_coef=extra)
        return runs

    runs = with_masses(runs)

    def fit(subset: Sequence[CalibrationRun], law: str = law) -> Calibration:
        return calibrate(subset, params, law=law, free=free, fixed=fixed)

    start = None
    if any(run.drive for run in runs):
        # a driven run is timed against the model that aligns it (its fusion timing, its start):
        # aligned with the stated rig, that can be tens of ms off. Calibrate on the free runs
        # first (on all, if none is free), align the driven ones again with that rig, then fit all.
        first = [run for run in runs if not run.drive] or runs
        say("calibrate: the free runs first, then the driven ones aligned with their rig")
        rig = calibrate(first, params, law=law, free=free, fixed=fixed).params
        start = rig.as_dict()
        again = load_runs([p for p, run in zip(paths, runs, strict=True) if run.drive], rig, release_s=release_s,
                          max_gap_s=max_gap_s)  # fmt: skip
        runs = with_masses([again.pop(0) if run.drive else run for run in runs])
    cal = calibrate(runs, params, law=law, free=free, fixed=fixed, start=start, progress=say)
    _consistency(runs, cal, fit)
    space = ParameterSpace(cal.stated, cal.free)
    words = describe_held(cal.undetermined, cal.free, space.scale_direction(cal.x))
    before: list[Metrics] = []
    after: list[Metrics] = []
    left_out: list[Metrics] = []
    if checks:
        for path in paths:
            say(f"calibrate: validating {path} with the stated and the calibrated rig")
            losses = {n: v for n, v in cal.overrides().items() if n in LOSSES}
            before.append(_metrics(path, cal.stated.with_mapping(losses), "stated", "recorded"))
            after.append(_metrics(path, cal.params, "calibrated", "recorded"))
        if len(runs) > 1:
            for k, path in enumerate(paths):
                say(f"calibrate: cross-validation, {path} left out")
                other = fit([r for i, r in enumerate(runs) if i != k])
                left_out.append(_metrics(path, other.params, "left out", "recorded"))
    sigma = float(np.mean([np.mean(r.gyro_sigma_rad_s) for r in runs]))
    duration = float(np.median([r.duration_s for r in runs]))
    suggestions = suggest(cal, sigma_rad_s=sigma, duration_s=min(duration, 120.0)) if cal.undetermined else []
    return CalibrationReport(
        calibration=cal,
        paths=tuple(str(p) for p in paths),
        held_words=tuple(words),
        before=tuple(before),
        after=tuple(after),
        left_out=tuple(left_out),
        model_error=tuple(_model_error(cal, runs, fit, off_hinge)),
        suggestions=tuple(suggestions),
        fixed=tuple(sorted((fixed or {}).items())),
    )
