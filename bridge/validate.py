"""Validate the model against a recording: what the IMUs measured against what the MuJoCo model
and the planar reference compute, with the paper's metrics (spec RIG.md sections 5-7).

Only the IMU topics are used as the measurement (never /joint_states, which a simulated recording
holds as ground truth): phi_n from each node's orientation, omega_n from its gyro z, and M1's
tangential and normal accelerations from its accelerometer x and y (what the sensor reads, gravity
included; the computed ones are the model's accelerometer at the same mount, which is the paper's
computed normal acceleration with the projection of g added).

Alignment: the release is the first sample where the gyros leave their rest noise (walked back
to where the motion starts), refined by least-squares cross-correlation of the measured omega1
against the model's over the first seconds (1 ms grid, parabolic refinement). The release angles
are estimated from the accelerometers while the pendulums are held (gravity direction), or from
the orientation at the first sample if the recording starts in motion. Both comparisons the paper
discusses are made: from the estimated release and from the nominal 30 deg.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from bridge.recording import Recording, read_recording
from pendsim_mj import rotations
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.identification import DampingFit, LogDecrement, fit_damping, log_decrement
from pendsim_mj.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors import Bno055
from pendsim_mj.trajectory import Trajectory
from pendsim_mj.validation import Comparison, compare, resample

QUANTITIES = {
    "phi1": ("phi1", "rad", "angle of M1"),
    "omega1": ("omega1", "rad/s", "angular velocity of M1"),
    "omega2": ("omega2", "rad/s", "angular velocity of M2"),
    "tangential_m1": ("a_t M1", "m/s^2", "tangential acceleration of M1 (accelerometer x, with gravity)"),
    "normal_m1": ("a_n M1", "m/s^2", "normal acceleration of M1 (accelerometer y, with gravity)"),
}
NOMINAL_RELEASE_RAD = (math.pi / 6, 0.0)  # paper: the simulation releases M1 from 30 deg


@dataclasses.dataclass(frozen=True)
class MeasuredRun:
    """The measured series after the release; t_s = 0 at the release."""

    t_s: np.ndarray  # (m,)
    series: dict[str, np.ndarray]  # each of QUANTITIES, and phi2 -> (m,)
    release_time_s: float  # on the recording's clock
    release_angle_rad: tuple[float, float]
    fusion_rate_hz: float | None  # the node's fusion timing, if it has one
    rate_hz: float
    gyro_sigma_rad_s: tuple[float, float]


def _phi_from_quat(quat_wxyz: np.ndarray) -> np.ndarray:
    y_axis = rotations.to_matrix(quat_wxyz)[..., :, 1]  # the IMU's y (toward the pivot) in the world
    return np.arctan2(-y_axis[..., 0], y_axis[..., 2])


def measured_series(rec: Recording) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """Recording clock (m,), the quantities (m,), and the raw accelerometers (m, 2, 3)."""
    if "m1" not in rec.imu or "m2" not in rec.imu:
        raise RecordingError(f"{rec.path}: validation needs both /imu/m1 and /imu/m2")
    m1, m2 = rec.imu["m1"], rec.imu["m2"]
    n = min(len(m1.t_ns), len(m2.t_ns))
    if n < 100:
        raise RecordingError(f"{rec.path}: {n} IMU samples; too few to validate")
    if not np.array_equal(m1.t_ns[:n], m2.t_ns[:n]):
        raise RecordingError(f"{rec.path}: /imu/m1 and /imu/m2 are not sampled at the same instants")
    t = (m1.t_ns[:n] - m1.t_ns[0]) * 1e-9
    series = {
        "phi1": np.unwrap(_phi_from_quat(m1.quat_wxyz[:n])),
        "omega1": m1.gyro_rad_s[:n, 2],
        "omega2": m2.gyro_rad_s[:n, 2],
        "tangential_m1": m1.accel_m_s2[:n, 0],
        "normal_m1": m1.accel_m_s2[:n, 1],
        "phi2": np.unwrap(_phi_from_quat(m2.quat_wxyz[:n])),
    }
    accel = np.stack([m1.accel_m_s2[:n], m2.accel_m_s2[:n]], axis=1)
    return t, series, accel


def detect_release(t_s: np.ndarray, omega: np.ndarray) -> int:
    """Index of the first sample of the motion: where |omega1| + |omega2| leaves the rest noise
    (8 sigma of the first 0.25 s, at least 0.03 rad/s), walked back to 3 sigma."""
    speed = np.abs(omega[:, 0]) + np.abs(omega[:, 1])
    head = speed[t_s <= t_s[0] + 0.25]
    sigma = float(np.std(head)) if len(head) > 4 else 0.0
    threshold = max(8 * sigma + float(np.mean(head)), 0.03)
    above = np.flatnonzero(speed > threshold)
    if len(above) == 0:
        raise ParameterError("no release found: the gyros never leave their rest noise")
    i = int(above[0])
    quiet = 3 * sigma + float(np.mean(head)) if sigma > 0 else threshold / 2
    while i > 0 and speed[i - 1] > quiet:
        i -= 1
    return i


def _model_at(traj: Trajectory, t_s: np.ndarray, fusion_rate_hz: float | None) -> dict[str, np.ndarray]:
    """The computed quantities at measured instants (the latest fused value if the node fuses)."""
    at = np.floor(t_s * fusion_rate_hz + 1e-9) / fusion_rate_hz if fusion_rate_hz else t_s
    values = {
        "phi1": traj.phi_rad[:, 0],
        "omega1": traj.omega_rad_s[:, 0],
        "omega2": traj.omega_rad_s[:, 1],
        "tangential_m1": traj.imu_accel_m_s2[:, 0, 0],
        "normal_m1": traj.imu_accel_m_s2[:, 0, 1],
    }
    return {name: resample(traj.t_s, v, np.clip(at, 0.0, traj.t_s[-1])) for name, v in values.items()}


def _runs(
    engine: str, params: RigParams, releases: list[tuple[float, float]], duration_s: float, dt_s: float = 0.01
) -> list[Trajectory]:
    """One trajectory per release, from rest, computed as one batch."""
    steps = math.floor(duration_s / dt_s + 1e-9)
    if engine == "mujoco":
        from pendsim_mj.simulation import simulate_batch as run
    else:
        from pendsim_mj.reference import solve_batch as run
    batch = run(params, np.array(releases, dtype=float), (0.0, 0.0), steps * dt_s, dt_s)
    return [batch.member(i) for i in range(len(releases))]


def align(rec: Recording, params: RigParams, *, refine_s: float = 5.0) -> MeasuredRun:
    """Find the release, estimate the release angles, refine the time offset against the model."""
    t, series, accel = measured_series(rec)
    omega = np.stack([series["omega1"], series["omega2"]], axis=1)
    i = detect_release(t, omega)
    if i >= 8:  # held before the release: the accelerometers see gravity alone
        held = accel[max(0, i - 80) : i - 2]
        angles = np.arctan2(held[..., 0], held[..., 1]).mean(axis=0)
        release_angle = (float(angles[0]), float(angles[1]))
    else:
        release_angle = (float(series["phi1"][0]), float(series["phi2"][0]))
    imu_meta = rec.metadata.get("pendsim/imu", {})
    fusion = None
    if imu_meta.get("fusion_timing", "true") == "true":
        fusion = float(imu_meta.get("fusion_rate_hz", "100"))
    rate = float(imu_meta.get("sample_rate_hz", 0) or 1 / np.median(np.diff(t)))
    coarse = float(t[i])
    # Refine: least squares of measured omega1 against the model's over the first seconds.
    window = (t >= coarse - 0.1) & (t <= coarse + refine_s)
    model = _runs("mujoco", params, [release_angle], refine_s + 0.3)[0]
    lags = np.arange(-0.05, 0.0501, 0.001)
    costs = []
    for lag in lags:
        since = t[window] - coarse - lag
        valid = since >= 0
        at = since[valid]
        at = np.floor(at * fusion + 1e-9) / fusion if fusion else at
        prediction = resample(model.t_s, model.omega_rad_s[:, 0], np.clip(at, 0.0, model.t_s[-1]))
        measured = series["omega1"][window][valid]
        before = series["omega1"][window][~valid]  # before the release the model is at rest
        costs.append((np.sum((prediction - measured) ** 2) + np.sum(before**2)) / max(1, window.sum()))
    k = int(np.argmin(costs))
    shift = lags[k]
    if 0 < k < len(lags) - 1:
        a, b, c = costs[k - 1], costs[k], costs[k + 1]
        denom = a - 2 * b + c
        if denom > 0:
            shift += 0.5 * (a - c) / denom * (lags[1] - lags[0])
    release = coarse + float(shift)
    after = t >= release - 1e-9
    noise = Bno055().noise_model.gyro_sigma_rad_s[2]
    cov = rec.imu["m1"].gyro_covariance
    sigma1 = math.sqrt(cov[0, 2, 2]) if cov[0, 2, 2] > 0 else noise
    cov2 = rec.imu["m2"].gyro_covariance
    sigma2 = math.sqrt(cov2[0, 2, 2]) if cov2[0, 2, 2] > 0 else noise
    return MeasuredRun(
        t_s=t[after] - release,
        series={name: v[after] for name, v in series.items()},  # the QUANTITIES and phi2
        release_time_s=release,
        release_angle_rad=release_angle,
        fusion_rate_hz=fusion,
        rate_hz=rate,
        gyro_sigma_rad_s=(sigma1, sigma2),
    )


@dataclasses.dataclass(frozen=True)
class Identification:
    log_decrement: list[LogDecrement]
    fit: DampingFit
    release_angle_rad: tuple[float, float]
    release_time_s: float


def identify(path: str | Path, *, window_s: float = 120.0, params: RigParams | None = None) -> Identification:
    """Both damping estimates from a recording's free decay."""
    rec = read_recording(path)
    params = params or recorded_params(rec)
    return _identify(align(rec, params), params, window_s)


def _identify(run: MeasuredRun, params: RigParams, window_s: float) -> Identification:
    """Log decrement of the measured angles and the least-squares fit of the gyros."""
    phi = np.stack([run.series["phi1"], run.series["phi2"]], axis=1)
    decrement = log_decrement(run.t_s, phi, params, min(window_s, float(run.t_s[-1])))
    omega = np.stack([run.series["omega1"], run.series["omega2"]], axis=1)
    fit = fit_damping(
        params,
        run.release_angle_rad,
        run.t_s,
        omega,
        gyro_sigma_rad_s=run.gyro_sigma_rad_s,
        fusion_rate_hz=run.fusion_rate_hz,
    )
    return Identification(decrement, fit, run.release_angle_rad, run.release_time_s)


def recorded_params(rec: Recording) -> RigParams:
    try:
        return rec.params()
    except RecordingError:
        return DEFAULT_PARAMS  # a recording from elsewhere: the paper's rig


@dataclasses.dataclass(frozen=True)
class CaseResult:
    engine: str
    release: str  # "estimated" or "nominal"
    window: str  # "5 s" or "whole"
    comparisons: dict[str, Comparison]


@dataclasses.dataclass(frozen=True)
class ValidationReport:
    path: Path
    params: RigParams
    damping_source: str
    identification: Identification | None
    run: MeasuredRun
    cases: list[CaseResult]

    def case(self, engine: str = "mujoco", release: str = "estimated", window: str = "whole") -> CaseResult:
        for c in self.cases:
            if (c.engine, c.release, c.window) == (engine, release, window):
                return c
        raise KeyError((engine, release, window))


def validate(
    path: str | Path,
    *,
    damping: str | tuple[float, float] = "identified",
    params: RigParams | None = None,
    overrides: Mapping[str, float] | None = None,
    short_window_s: float = 5.0,
) -> ValidationReport:
    """Compare a recording with the MuJoCo model and the planar reference.

    Args:
      path: the recording.
      damping: "identified" (least-squares fit on this recording), "recorded" (the parameters in
        its metadata) or (b1, b2) in N m s/rad.
      params: the rig to validate (default: the recording's parameters, else the paper's).
      overrides: parameter changes applied on top of that rig (e.g. a deliberately wrong model).
      short_window_s: the paper's short window (5 s).
    """
    rec = read_recording(path)
    base = (params or recorded_params(rec)).with_mapping(overrides or {})
    run = align(rec, base)
    identification = None
    if damping == "identified":
        identification = _identify(run, base, 120.0)
        fit = identification.fit
        model_params = base.with_overrides(b1_n_m_s=float(fit.b_n_m_s[0]), b2_n_m_s=float(fit.b_n_m_s[1]))
        source = "identified (least squares)"
    elif damping == "recorded":
        model_params, source = base, "recorded"
    elif isinstance(damping, tuple) and len(damping) == 2:
        model_params = base.with_overrides(b1_n_m_s=damping[0], b2_n_m_s=damping[1])
        source = "given"
    else:
        raise ParameterError(f"damping must be 'identified', 'recorded' or (b1, b2), got {damping!r}")
    duration = float(run.t_s[-1])
    cases = []
    releases = {"estimated": run.release_angle_rad, "nominal": NOMINAL_RELEASE_RAD}
    for engine in ("mujoco", "reference"):
        trajectories = _runs(engine, model_params, list(releases.values()), duration + 0.02)
        for release_name, traj in zip(releases, trajectories, strict=True):
            computed = _model_at(traj, run.t_s, run.fusion_rate_hz)
            for window_name, limit in ((f"{short_window_s:g} s", short_window_s), ("whole", math.inf)):
                inside = run.t_s <= limit + 1e-9
                comparisons = {
                    q: compare(run.t_s[inside], run.series[q][inside], computed[q][inside]) for q in QUANTITIES
                }
                cases.append(CaseResult(engine, release_name, window_name, comparisons))
    return ValidationReport(Path(path), model_params, source, identification, run, cases)


def report_json(report: ValidationReport) -> dict:
    """Everything a machine needs: alignment, damping, and every metric of every case."""

    def clean(v):
        return None if isinstance(v, float) and not math.isfinite(v) else v

    ident = None
    if report.identification is not None:
        i = report.identification
        ident = {
            "log_decrement": [
                {"b_n_m_s": d.b_n_m_s, "a0_rad": d.a0_rad, "at_rad": d.at_rad, "window_s": d.window_s}
                for d in i.log_decrement
            ],
            "least_squares": {
                "b_n_m_s": i.fit.b_n_m_s.tolist(),
                "ci95_n_m_s": i.fit.ci95_n_m_s.tolist(),
                "residual_rms_sigma": i.fit.residual_rms_sigma,
                "iterations": i.fit.iterations,
                "seconds": i.fit.seconds,
            },
        }
    return {
        "file": str(report.path),
        "release": {
            "time_s": report.run.release_time_s,
            "estimated_angle_rad": list(report.run.release_angle_rad),
            "nominal_angle_rad": list(NOMINAL_RELEASE_RAD),
        },
        "damping": {
            "source": report.damping_source,
            "b1_n_m_s": report.params.b1_n_m_s,
            "b2_n_m_s": report.params.b2_n_m_s,
        },
        "identification": ident,
        "cases": [
            {
                "engine": c.engine,
                "release": c.release,
                "window": c.window,
                "metrics": {q: {k: clean(v) for k, v in cmp.summary().items()} for q, cmp in c.comparisons.items()},
            }
            for c in report.cases
        ],
    }


def table(report: ValidationReport) -> str:
    """Per quantity: measured and computed frequency and delta, max |Delta|, IAE, ISE."""
    r = report.run
    lines = [
        f"{report.path}: release at {r.release_time_s:.3f} s on the recording's clock, estimated release angles "
        f"{math.degrees(r.release_angle_rad[0]):.2f} deg, {math.degrees(r.release_angle_rad[1]):.2f} deg",
        f"damping {report.damping_source}: b1 = {report.params.b1_n_m_s:.5g}, "
        f"b2 = {report.params.b2_n_m_s:.5g} N m s/rad",
    ]
    for case in report.cases:
        if case.release != "estimated":
            continue
        lines.append("")
        lines.append(f"{case.engine} model, from the estimated release, {case.window}:")
        head = f"  {'quantity':14} {'f meas (Hz)':>11} {'f comp (Hz)':>11} {'delta':>9}"
        lines.append(f"{head} {'max|Delta|':>11} {'IAE':>10} {'ISE':>10}  unit")
        for q, cmp in case.comparisons.items():
            label, unit, _ = QUANTITIES[q]
            lines.append(
                f"  {label:14} {cmp.f_measured_hz:11.5f} {cmp.f_computed_hz:11.5f} {cmp.delta_f:9.2e} "
                f"{cmp.max_abs:11.4g} {cmp.iae:10.4g} {cmp.ise:10.4g}  {unit}"
            )
    nominal = report.case("mujoco", "nominal", "whole").comparisons["phi1"]
    lines.append("")
    lines.append(
        f"from the nominal 30 deg instead (the paper's simulation): phi1 max|Delta| {nominal.max_abs:.4g} rad, "
        f"IAE {nominal.iae:.4g} rad s over the whole run"
    )
    return "\n".join(lines)
