"""pendsim calibrate's work: recordings aligned, the rig calibrated on all of them, checked
(before and after, each recording left out in turn, the residual's cause tested), and written.

The calibration itself is ``pendsim_mj.calibration``; this module reads the recordings, runs the
validations that show what it changed, and writes the parameter file and the report.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Collection, Mapping, Sequence
from pathlib import Path

import numpy as np

from pendsim_mj.calibration import Calibration, CalibrationRun, calibrate
from pendsim_mj.calibration.design import suggest
from pendsim_mj.calibration.fit import LOSSES
from pendsim_mj.calibration.information import describe_held
from pendsim_mj.calibration.parameters import SPATIAL_PARAMETERS, ParameterSpace, added_mass_constants
from pendsim_mj.calibration.spatial import SpatialRun, calibrate_spatial
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.alignment import DEFAULT_MAX_GAP_S
from pendsim_mj.estimation.measured_run import MeasuredRun
from pendsim_mj.rig.params import RigParams

from ..io.measured import align_recording, node_samples, recording_drive
from ..io.recording import DRIVE_TOPIC, NODES, imu_topic, read_recording, rig_stated_in
from ..report.calibration_report import CalibrationReport, Metrics
from .spatial_validate import RELEASE_AT_START_RAD_S, gyro_in_swing_frames, spatial_params, tilt_start_of
from .validate import validate

MODEL_ERROR_SIGMAS = 1.5  # a residual rms above this many noise sigmas after calibration is model error
STRUCTURED_SIGMAS = 1.05  # above this and not white (WHITE_P): structure the model leaves, model error too
WHITE_P = 1e-3
SPATIAL_SIGMAS = 3.0  # rotation across the hinge above this many gyro noise sigmas rms (planar: 1.4): the support tilts
INCONSISTENT_RATIO = 1.3  # a recording whose joint-fit residual is this much above its own fit's: another rig


MODELS = ("planar", "spatial")
MID_SWING_RAD_S = 0.5  # a spatial recording starting faster than this: the support's tilt there is unknown
REALIGN_ROUNDS = 3  # the spatial calibration's rounds of alignment with the rig it found
REALIGNED_S = 1e-4  # ... until no node's value instants move by more than this, s
RETRY_SIGMAS = 1.5  # a spatial fit from the planar calibration's rig left above this: also tried from the stated rig


def _metrics(path: Path, params: RigParams, rig: str, damping: str, model: str = "planar") -> Metrics:
    report = validate(path, params=params, damping=damping, model=model)
    engine = "mujoco-spatial" if model == "spatial" else "mujoco"
    case = report.case(engine, "estimated", "whole").comparisons
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


def load_spatial_runs(
    paths: Sequence[Path], params: RigParams, *, release_s: float | None = None, max_gap_s: float = DEFAULT_MAX_GAP_S
) -> list[SpatialRun]:
    """Each recording aligned with ``params`` (the spatial model's rig) as a ``SpatialRun``: both
    nodes' gyros in their swing frames, all three axes. Free decays only, released from rest
    (or at the recording's start)."""
    out = []
    for path in paths:
        rec = read_recording(path, topics=[*(imu_topic(n) for n in NODES), DRIVE_TOPIC])
        if rec.drive_input_s is not None:
            raise ParameterError(
                f"{path} is a driven recording (a /drive topic); --model spatial calibrates free decays only: "
                "calibrate it with the planar model (drop --model spatial)"
            )
        covariance = [n.gyro_covariance for n in node_samples(rec)]
        run = align_recording(rec, params, release_s=release_s, max_gap_s=max_gap_s)
        fastest = max(abs(w) for w in run.start.omega_rad_s)
        if run.start.kind != "release" and fastest > MID_SWING_RAD_S:
            raise ParameterError(
                f"{path}: starts mid-swing ({fastest:.2f} rad/s at its start); --model spatial needs the release "
                "(the support's tilt there is unknown): record from before the release"
            )
        t, gyro, sigma = gyro_in_swing_frames(run, covariance)
        # a recording that starts at the release begins "in motion" but all but at rest: a release
        # at its start, its instant fitted (as identify --model spatial takes it)
        moving = run.start.kind != "release" and fastest >= RELEASE_AT_START_RAD_S
        out.append(
            SpatialRun(
                str(path), t, gyro, sigma, run.start.phi_rad, run.start.omega_rad_s if moving else (0.0, 0.0),
                moving, run.relative_timing_range_s, tilt_start_of(rec),
            )
        )  # fmt: skip
        del rec
    return out


def _instants_moved_s(a: Sequence[SpatialRun], b: Sequence[SpatialRun]) -> float:
    out = 0.0
    for x, y in zip(a, b, strict=True):
        if x.value_t_s.shape != y.value_t_s.shape:
            return math.inf
        out = max(out, float(np.nanmax(np.abs(x.value_t_s - y.value_t_s))))
    return out


def calibrate_spatial_recordings(
    paths: Sequence[Path],
    params: RigParams,
    *,
    law: str = "viscous",
    free: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    progress: Callable[[str], None] | None = None,
) -> tuple[Calibration, list[SpatialRun]]:
    """The spatial calibration (``pendsim_mj.calibration.spatial``) of the recordings.

    Started from the planar calibration of the same recordings (its rig, the recordings aligned
    with it); where that ends above ``RETRY_SIGMAS`` also from the stated rig, and the better fit
    kept. Then the recordings are aligned again with the calibrated rig (the alignment's timing of
    each node's values depends on the model a little) and the fit refined from there, until no
    value instant moves by more than ``REALIGNED_S`` (at most ``REALIGN_ROUNDS`` rounds).
    Returns the calibration and the recordings as it last aligned them."""
    say = progress or (lambda line: None)
    stated = spatial_params(params)
    rig = stated.with_mapping(fixed or {})
    planar_free = None if free is None else [n for n in free if n not in SPATIAL_PARAMETERS]
    stated_runs = load_spatial_runs(paths, rig, release_s=release_s, max_gap_s=max_gap_s)  # refuses what it cannot fit
    planar = calibrate(
        load_runs(paths, rig, release_s=release_s, max_gap_s=max_gap_s), rig, law=law, free=planar_free, fixed=fixed
    )
    say(
        f"calibrate (spatial): from the planar calibration's rig ({planar.residual_rms_sigma:.2f} sigmas on the hinges)"
    )
    start = {n: v for n, v in planar.overrides().items() if n not in SPATIAL_PARAMETERS}
    runs = load_spatial_runs(paths, stated.with_mapping(start), release_s=release_s, max_gap_s=max_gap_s)
    cal = calibrate_spatial(runs, stated, law=law, free=free, fixed=fixed, start=start, progress=say)
    seconds, iterations = cal.seconds, cal.iterations
    if cal.residual_rms_sigma > RETRY_SIGMAS:
        say(f"calibrate (spatial): {cal.residual_rms_sigma:.2f} sigmas from the planar rig; from the stated rig too")
        other_runs = stated_runs
        other = calibrate_spatial(other_runs, stated, law=law, free=free, fixed=fixed, progress=say)
        seconds, iterations = seconds + other.seconds, iterations + other.iterations
        if other.residual_rms_sigma < cal.residual_rms_sigma:
            cal, runs = other, other_runs
    for _ in range(REALIGN_ROUNDS):
        again = load_spatial_runs(paths, cal.params, release_s=release_s, max_gap_s=max_gap_s)
        moved = _instants_moved_s(runs, again)
        if moved <= REALIGNED_S:
            return dataclasses.replace(cal, seconds=seconds, iterations=iterations), runs
        say(f"calibrate (spatial): aligned again with the calibrated rig (value instants moved {1000 * moved:.2f} ms)")
        runs = again
        cal = calibrate_spatial(
            runs, stated, law=law, free=free, fixed=fixed, start=cal.overrides(), refine=True, progress=say
        )
        seconds, iterations = seconds + cal.seconds, iterations + cal.iterations
    raise ParameterError(
        f"the spatial calibration did not settle: after {REALIGN_ROUNDS} rounds the alignment with the calibrated rig "
        f"still moves the nodes' value instants by {1000 * moved:.2f} ms; check the recordings with "
        "'pendsim validate --model spatial'"
    )


def _spatial_report(
    paths: Sequence[Path],
    params: RigParams,
    *,
    law: str,
    free: Sequence[str] | None,
    fixed: Mapping[str, float] | None,
    release_s: float | None,
    max_gap_s: float,
    checks: bool,
    progress: Callable[[str], None] | None,
) -> CalibrationReport:
    """``calibrate_recordings`` on the spatial model: the same checks, each with the spatial model
    (validation ``--model spatial``, the left-out fits, the damping law tested)."""
    say = progress or (lambda line: None)
    stated = spatial_params(params)
    cal, runs = calibrate_spatial_recordings(
        paths, params, law=law, free=free, fixed=fixed, release_s=release_s, max_gap_s=max_gap_s, progress=say
    )

    def fit(subset: Sequence[SpatialRun], law: str = law) -> Calibration:
        # from the joint fit's rig (a subset of the same rig's recordings, or a law tested on them)
        return calibrate_spatial(subset, stated, law=law, free=free, fixed=fixed, start=cal.overrides())

    return _report(cal, runs, paths, fit, checks=checks, say=say, off_hinge={}, fixed=fixed)


def _report(
    cal: Calibration,
    runs: Sequence[CalibrationRun] | Sequence[SpatialRun],
    paths: Sequence[Path],
    fit: Callable[..., Calibration],
    *,
    checks: bool,
    say: Callable[[str], None],
    off_hinge: Mapping[str, float],
    fixed: Mapping[str, float] | None,
) -> CalibrationReport:
    """The calibration checked, on its own model (``cal.model``): recordings of different rigs
    refused, the held directions in words, each recording validated with the stated and the
    calibrated rig and left out (``checks``), the model error tested, the next experiment."""
    _consistency(runs, cal, fit)
    space = ParameterSpace(cal.stated, cal.free)
    words = describe_held(cal.undetermined, cal.free, space.scale_direction(cal.x))
    before: list[Metrics] = []
    after: list[Metrics] = []
    left_out: list[Metrics] = []
    if checks:
        shown = " (spatial model)" if cal.model == "spatial" else ""
        for path in paths:
            say(f"calibrate: validating {path} with the stated and the calibrated rig{shown}")
            losses = {n: v for n, v in cal.overrides().items() if n in LOSSES}
            before.append(_metrics(path, cal.stated.with_mapping(losses), "stated", "recorded", model=cal.model))
            after.append(_metrics(path, cal.params, "calibrated", "recorded", model=cal.model))
        if len(runs) > 1:
            for k, path in enumerate(paths):
                say(f"calibrate: cross-validation, {path} left out")
                other = fit([r for i, r in enumerate(runs) if i != k])
                left_out.append(_metrics(path, other.params, "left out", "recorded", model=cal.model))
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


def _consistency(
    runs: Sequence[CalibrationRun] | Sequence[SpatialRun], joint: Calibration, fit: Callable[..., Calibration]
) -> None:
    """Recordings of different rigs: one explained to the noise alone but not with the others."""
    if len(runs) < 2:
        return
    for run, result in zip(runs, joint.runs, strict=True):
        alone = fit([run]).residual_rms_sigma
        if result.residual_rms_sigma > INCONSISTENT_RATIO * alone and alone < MODEL_ERROR_SIGMAS:
            raise ParameterError(
                f"{result.name} is not of the same rig as the other recordings: alone it is explained to "
                f"{alone:.2f} noise sigmas, with them to {result.residual_rms_sigma:.2f}; calibrate each rig on its own"
            )


def _model_error(
    cal: Calibration,
    runs: Sequence[CalibrationRun] | Sequence[SpatialRun],
    fit: Callable[..., Calibration],
    off_hinge: Mapping[str, float],
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
        f"{white:.2g}): what the {cal.model} model with these parameters cannot explain; its intervals do not hold"
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


def stated_elsewhere(paths: Sequence[Path], start: RigParams, given: Collection[str]) -> list[str]:
    """Lines saying which recordings state a rig other than the calibration's ``start`` (their
    ``pendsim/rig_parameters``: what ``validate`` takes as the rig) in parameters not ``given``
    on the command line: calibrate starts from and holds the paper's rig unless told, so that a
    rig the recording states (the values a user gave ``acquire``, a simulated recording's own) is
    never taken silently, nor left silently (``docs/calibration.md``)."""
    lines = []
    ours = start.as_dict()
    for path in paths:
        rig, _ = rig_stated_in(path)  # (a damaged file was refused by the read before)
        if rig is None:
            continue  # another tool's recording: it states no rig
        theirs = rig.as_dict()
        differ = [name for name, value in theirs.items() if name not in given and value != ours[name]]
        if differ:
            shown = ", ".join(f"{name} {theirs[name]:.6g} (here {ours[name]:.6g})" for name in differ[:4])
            more = f" and {len(differ) - 4} more" if len(differ) > 4 else ""
            lines.append(
                f"calibrate: {path} states another rig: {shown}{more}; calibrating from the paper's rig with "
                "--params-file/--set on top (to start from the recording's and hold it: "
                f"pendsim info {path} --json > rig.json, then --params-file rig.json)"
            )
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
    model: str = "planar",
) -> CalibrationReport:
    """Calibrate the rig on the recordings and check the result (module docstring); ``checks``
    False: no validations, no left-out fits (the calibration alone). ``added``: recording index ->
    (pendulum, kg, m) of a known mass clamped on it while it was recorded. ``model``: "planar"
    or "spatial" (``calibrate_spatial_recordings``)."""
    if model not in MODELS:
        raise ParameterError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    if model == "spatial":
        if added:
            raise ParameterError(
                "--added-mass with --model spatial: not available (the spatial model's inertia tensor of a loaded "
                "pendulum is not modelled); calibrate the recordings with a known mass on the planar model"
            )
        return _spatial_report(
            paths, params, law=law, free=free, fixed=fixed, release_s=release_s, max_gap_s=max_gap_s, checks=checks,
            progress=progress,
        )  # fmt: skip
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
    return _report(cal, runs, paths, fit, checks=checks, say=say, off_hinge=off_hinge, fixed=fixed)
