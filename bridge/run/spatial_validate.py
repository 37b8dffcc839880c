"""A recording against the spatial model: which model fits better (``validate --model spatial``)
and the support's tilt stiffness and damping (``identify --model spatial``).

Reads and wires; the work is in ``pendsim_mj`` (``alignment``, ``validation.compare``,
``spatial_identification``). Both use the run as ``pendsim_bridge.io.measured`` aligns it.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from pendsim_mj.engines.dispatch import whole_steps_s
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.estimation.alignment import MeasuredRun
from pendsim_mj.estimation.quantities import VALIDATED, Quantity
from pendsim_mj.estimation.spatial_identification import NAMES, TILT_STARTS, TiltFit, fit_tilt, static_tilt_rad
from pendsim_mj.estimation.timing import DEFAULT_MAX_GAP_S
from pendsim_mj.estimation.validation import compare, resample
from pendsim_mj.rig.model import SPATIAL
from pendsim_mj.rig.params import DEFAULT_PARAMS, PLANE_OFFSET_PRESETS_M, RigParams
from pendsim_mj.sensors.bno055 import ImuNoise

from ..io.measured import align_recording, node_samples, recorded_params
from ..io.outputs import atomic_output
from ..io.recording import Recording, read_recording
from ..report.validation_report import CaseResult

MODELS = ("planar", "spatial")
RELEASE_AT_START_RAD_S = 0.2  # a start "in motion" slower than this is a release at the recording's start
PAPER_OFFSET_M = max(PLANE_OFFSET_PRESETS_M)  # 0.050: the spatial model of a rig whose offset is unknown


def spatial_params(params: RigParams) -> RigParams:
    """The rig for the spatial model: its plane offset, or the paper's 50 mm if it has none."""
    return params if params.plane_offset_m > 0 else params.with_overrides(plane_offset_m=PAPER_OFFSET_M)


def model_at(traj: Trajectory, run: MeasuredRun, quantity: Quantity) -> np.ndarray:
    """A quantity of a model run at the instants its node's measured values belong to."""
    at = run.nodes[quantity.node].value_t_s
    return resample(traj.t_s, quantity.computed(traj), np.clip(at, 0.0, traj.t_s[-1]))


def spatial_case(
    run: MeasuredRun,
    params: RigParams,
    max_gap_s: float,
    *,
    damping_fit: bool = False,
    covariance: list[np.ndarray | None] | None = None,
    tilt_start: str = "zero",
) -> tuple[CaseResult, RigParams]:
    """The spatial MuJoCo model from the estimated start (tilts per ``tilt_start``: "zero" or
    "static", see ``spatial_identification``), compared over the whole run on every validated
    quantity, as a ``CaseResult`` with engine "mujoco-spatial", and the rig it ran. With
    ``damping_fit`` its b1, b2 are fitted to the gyros first, with the start state (tilt values
    as given; ``covariance``: each node's gyro covariance)."""
    start = run.start
    params = spatial_params(params)
    if damping_fit:  # the spatial model's own b1, b2 (each model with its best damping)
        t, gyro, sigma = gyro_in_swing_frames(run, covariance or [None, None])
        fit = fit_tilt(
            params, start.phi_rad, t, gyro, sigma, omega0_rad_s=start.omega_rad_s, names=NAMES[2:],
            tilt_start=tilt_start, timing_range_s=run.relative_timing_range_s,
        )  # fmt: skip
        params = params.with_mapping(fit.as_mapping())
    traj = simulate(
        spatial_params(params),
        start.phi_rad,
        start.omega_rad_s,
        whole_steps_s(run.duration_s + 0.02, 0.01),
        0.01,
        variant=SPATIAL,
        tilt0_rad=static_tilt_rad(params, start.phi_rad) if tilt_start == "static" else (0.0, 0.0),
    )
    comparisons = {}
    for q in VALIDATED:
        t, measured, _ = run.series(q)
        comparisons[q.name] = compare(t, measured, model_at(traj, run, q), max_gap_s=max_gap_s)
    return CaseResult("mujoco-spatial", "estimated", "whole", comparisons), params


def model_choice(planar: CaseResult, spatial: CaseResult) -> dict[str, Any]:
    """Which model fits better, per quantity and overall.

    Per quantity: the rms of the residual (computed - measured) over the whole run and the
    relative frequency error |delta f|; the better model has the smaller rms. Overall: the mean
    over the quantities of rms / rms of the measured signal about its mean (so that angles,
    rates and accelerations weigh alike); the smaller wins.
    """
    quantities: dict[str, dict[str, Any]] = {}
    scores: dict[str, list[float]] = {m: [] for m in MODELS}
    for q in VALIDATED:
        pair = {"planar": planar.comparisons[q.name], "spatial": spatial.comparisons[q.name]}
        scale = pair["planar"].measured_std or 1.0
        for m in MODELS:
            scores[m].append(pair[m].rms / scale)
        quantities[q.name] = {
            "unit": q.unit,
            "rms": {m: pair[m].rms for m in MODELS},
            "delta_f": {m: _finite(pair[m].delta_f) for m in MODELS},
            "better": min(MODELS, key=lambda m: float(pair[m].rms)),
        }
    overall = {m: float(np.mean(scores[m])) for m in MODELS}
    return {
        "metric": "rms of (computed - measured) over the whole run from the estimated start, MuJoCo; "
        "overall: mean over the quantities of rms / std of the measured quantity",
        "quantities": quantities,
        "overall": overall,
        "better": min(MODELS, key=lambda m: overall[m]),
    }


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None


@dataclasses.dataclass(frozen=True)
class SpatialIdentification:
    """``identify --model spatial``: the fit and the start it began from."""

    fit: TiltFit
    params: RigParams  # the rig fitted (its plane offset)
    release_angle_rad: tuple[float, float]  # the alignment's (the fit's own: fit.value("phi1_0"), ...)
    release_time_s: float
    start_kind: str


def gyro_in_swing_frames(run: MeasuredRun, covariance: list[np.ndarray | None]) -> tuple[np.ndarray, ...]:
    """Both nodes' value instants (m, 2), gyros along (tangential, toward pivot, hinge) (m, 2, 3)
    and their noise sigmas (2, 3) from each node's gyro covariance (None: the BNO055's)."""
    m = max(len(n.t_s) for n in run.nodes)
    t = np.full((m, 2), np.nan)
    gyro = np.full((m, 2, 3), np.nan)
    sigma = np.zeros((2, 3))
    for k, node in enumerate(run.nodes):
        n = len(node.t_s)
        assert node.off_hinge_gyro_rad_s is not None
        t[:n, k] = node.value_t_s
        gyro[:n, k, :2] = node.off_hinge_gyro_rad_s
        gyro[:n, k, 2] = node.omega_rad_s
        cov = covariance[k]
        if cov is None or not np.any(cov):
            cov = np.diag(np.square(ImuNoise().gyro_sigma_rad_s))
        f = node.frame
        for j, axis in enumerate((f.tangential, f.toward_pivot, f.hinge_axis)):
            sigma[k, j] = math.sqrt(max(float(axis @ cov @ axis), 1e-12))
    return np.clip(t, 0.0, None), gyro, sigma


def tilt_start_of(rec: Recording) -> str:
    """The support's tilt at the start of a recording, as it was made: "zero" for a run pendsim
    simulated (``record --model spatial`` starts the support untilted, its hold included; a planar
    run has no tilt), "static" for a recording from elsewhere (a real support rests at its static
    tilt while the pendulums are held)."""
    try:
        rec.run_info()
    except RecordingError:
        return "static"
    return "zero"


def identify_spatial(
    path: str | Path,
    *,
    params: RigParams | None = None,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    tilt_start: str | None = None,
) -> SpatialIdentification:
    """Tilt stiffness, tilt damping, b1 and b2 from a recording's free decay (spatial model), with
    the start state; ``tilt_start`` ("zero", "static"; default ``tilt_start_of`` the recording)."""
    rec = read_recording(path)
    if rec.drive_input_s is not None:
        raise ParameterError(
            f"{path} is a driven recording (a /drive topic); the spatial fit takes free decays only: "
            "identify it with the planar model (drop --model spatial)"
        )
    if tilt_start is not None and tilt_start not in TILT_STARTS:
        raise ParameterError(f"tilt_start must be one of {TILT_STARTS}, got {tilt_start!r}")
    # the geometry is the recording's; the fitted values start from the assumed defaults
    start_values = {n: getattr(DEFAULT_PARAMS, n) for n in NAMES}
    base = spatial_params(params or recorded_params(rec)).with_mapping(start_values)
    run = align_recording(rec, base, release_s=release_s, max_gap_s=max_gap_s)
    if run.start.kind == "in motion" and max(abs(w) for w in run.start.omega_rad_s) > 0.5:
        raise ParameterError(
            f"{path}: starts mid-swing; the tilt fit needs the release (the support's tilt there is unknown)"
        )
    t, gyro, sigma = gyro_in_swing_frames(run, [n.gyro_covariance for n in node_samples(rec)])
    # a recording that starts at the release begins "in motion" but all but at rest: a release at
    # its start (the tilt state there known: the support's rest), its instant fitted
    moving = run.start.kind != "release" and max(abs(w) for w in run.start.omega_rad_s) >= RELEASE_AT_START_RAD_S
    fit = fit_tilt(
        base, run.start.phi_rad, t, gyro, sigma, omega0_rad_s=run.start.omega_rad_s, moving=moving,
        tilt_start=tilt_start or tilt_start_of(rec), timing_range_s=run.relative_timing_range_s,
    )  # fmt: skip
    return SpatialIdentification(fit, base, run.start.phi_rad, run.start.time_s, run.start.kind)


def identification_lines(path: str | Path, result: SpatialIdentification) -> list[str]:
    """The printed tilt fit: each estimate with its 95 % interval, and the residual."""
    fit = result.fit
    phi1, phi2 = (math.degrees(a) for a in result.release_angle_rad)
    tilt = "untilted" if fit.tilt_start == "zero" else "at its static tilt"
    lines = [
        f"{path}: {result.start_kind} at {result.release_time_s:.3f} s from {phi1:.2f} deg, {phi2:.2f} deg; "
        f"spatial model, {1000 * result.params.plane_offset_m:g} mm between the planes, the support {tilt} "
        "at the start",
        "least squares of both gyros, all three axes, with the start state (mujoco.sysid on the spatial model), "
        "95 % intervals:",
    ]
    units = {
        "tilt_stiffness_n_m_rad": "N m/rad", "phi1_0": "rad", "phi2_0": "rad", "omega1_0": "rad/s",
        "omega2_0": "rad/s", "release_offset_s": "s", "timing2_s": "s",
    }  # fmt: skip
    for name, value, half in zip(fit.names, fit.values, fit.ci95, strict=True):
        lines.append(f"  {name:24} {value:.6g} +- {half:.2g} {units.get(name, 'N m s/rad')}")
    lines.append(f"  residual {fit.residual_rms_sigma:.2f} sigma rms, {fit.iterations} iterations, {fit.seconds:.1f} s")
    return lines


def identify_and_write(
    path: str | Path,
    *,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    write: Path | None = None,
    replace: bool = False,
) -> str:
    """``identify --model spatial``: the fit's printed lines; with ``write``, the four values as
    JSON (parameter names, for ``--params-file`` of simulate and record; the plane offset is
    record's --offset-m) written atomically."""
    result = identify_spatial(path, release_s=release_s, max_gap_s=max_gap_s)
    lines = identification_lines(path, result)
    if write is not None:
        values = result.fit.as_mapping()
        with atomic_output(write, replace=replace) as tmp:
            tmp.write_text(json.dumps(values, indent=1) + "\n")
        lines.append(f"wrote {write} (use: pendsim record --model spatial --params-file {write})")
    return "\n".join(lines)
