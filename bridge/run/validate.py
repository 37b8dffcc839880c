"""Validate the model against a recording: what the IMUs measured against what the MuJoCo model
and the planar reference compute, with the paper's metrics (spec RIG.md sections 5-7).

This module reads and wires; the physics layer does the work on arrays:
``pendsim_mj.estimation.alignment`` (clocks, start, swing frames, fusion timing, coverage),
``pendsim_mj.estimation.validation`` (metrics on covered samples), ``pendsim_mj.estimation.identification`` (damping)
and ``pendsim_mj.estimation.quantities`` (what is compared).

Only the IMU topics are used as the measurement (never /joint_states, which a simulated recording
holds as ground truth): phi_n from each node's orientation about its hinge axis, omega_n from its
gyro about that axis, and M1's tangential and normal accelerations from its accelerometer along
its swing frame (what the sensor reads, gravity included; the computed ones are the model's
accelerometer at the same mount, the paper's computed normal acceleration with g projected).
Both comparisons the paper discusses are made: from the estimated start and, when the run starts
from rest, from the nominal 30 deg.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import DTypeLike

from pendsim_mj.engines import dispatch as engines
from pendsim_mj.engines.dispatch import whole_steps_s
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.estimation.alignment import MeasuredRun, NodeSamples, align
from pendsim_mj.estimation.quantities import VALIDATED, Quantity
from pendsim_mj.estimation.timing import DEFAULT_MAX_GAP_S
from pendsim_mj.estimation.validation import Comparison, compare, resample
from pendsim_mj.rig.checks import check_step
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams

from .. import heap
from ..acquire.clock import recorded_stamp_clock
from ..io.outputs import atomic_directory
from ..io.recording import DRIVE_TOPIC, NODES, Recording, imu_topic, read_recording
from ..report.figure_lines import DrawnLines, drawn_lines

if TYPE_CHECKING:  # the identification (and scipy) is imported where it runs: the view needs none of it
    from pendsim_mj.estimation.identification import DampingFit, LogDecrement, ModalDecrement

NOMINAL_RELEASE_RAD = (math.pi / 6, 0.0)  # paper: the simulation releases M1 from 30 deg
AT_REST_RAD_S = 0.1
MODEL_BLOCK_STEPS = 6000  # model steps simulated at once (60 s at 0.01 s)
FIGURES = (
    ("fig09_tangential_acceleration_m1", "tangential_m1", "short"),
    ("fig10_normal_acceleration_m1", "normal_m1", "short"),
    ("fig11_phi1", "phi1", "short"),
    ("fig12_phi1", "phi1", "whole"),
    ("fig13_omega1", "omega1", "short"),
    ("fig15_omega2", "omega2", "whole"),
)
"""The paper's Figures 9-13 and 15 (``plots.validation_figures``): (file stem, quantity, window).
The whole-run comparisons keep their metrics only; of the quantities a whole-run figure draws,
the lines it draws are kept, reduced to their envelopes when compared (``figure_lines``, in
``ValidationReport.lines``; not of the planar reference from the nominal start, which no figure
draws), so a long run's memory holds none of its whole-run series."""


def node_samples(rec: Recording) -> tuple[NodeSamples, NodeSamples]:
    """Both nodes' /imu/mN samples as arrays (log times and header stamps in s)."""
    missing = [imu_topic(n) for n in NODES if n not in rec.imu]
    if missing:
        raise RecordingError(
            f"{rec.path}: needs both /imu/m1 and /imu/m2 (M1's and M2's IMU); {', '.join(missing)} missing; "
            "a one-node recording is for 'pendsim inspect' and 'pendsim allan' (docs/acquisition.md)"
        )
    out = []
    for n in NODES:
        topic = rec.imu[n]
        stamps = topic.stamp_ns
        clock = recorded_stamp_clock(rec.metadata, n, rec.start_time_ns)  # acquire's fit over the arrivals
        out.append(
            NodeSamples(
                log_t_s=topic.t_ns * 1e-9 if clock is None else clock.to_recorder_in_place(stamps * 1e-9),
                quat_wxyz=topic.quat_wxyz,
                gyro_rad_s=topic.gyro_rad_s,
                accel_m_s2=topic.accel_m_s2,
                stamp_s=stamps * 1e-9 if np.any(stamps != stamps[0]) else None,  # constant stamps: none
                gyro_covariance=topic.gyro_covariance[0] if len(topic.gyro_covariance) else None,
            )
        )
    return out[0], out[1]


def fusion_rate_of(rec: Recording) -> float | None:
    """The nodes' fusion rate from the recording's metadata (a recording from elsewhere: a BNO055
    in NDOF mode, 100 Hz)."""
    imu_meta = rec.metadata.get("pendsim/imu", {})
    if imu_meta.get("fusion_timing", "true") != "true":
        return None
    return float(imu_meta.get("fusion_rate_hz", "100"))


def align_recording(
    rec: Recording,
    params: RigParams,
    *,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    samples: tuple[NodeSamples, NodeSamples] | None = None,
    off_hinge: bool = True,
    float32_values: bool = False,
) -> MeasuredRun:
    """The measured run of a recording (``pendsim_mj.estimation.alignment.align`` on its IMU topics, and on
    its /drive topic for a driven run); ``samples``: its ``node_samples`` if the caller has them;
    ``off_hinge``: keep the gyros off the hinge axes (for a spatial fit); ``float32_values``: the
    run's values as float32 (``align``)."""
    if samples is None:
        samples = node_samples(rec)  # its errors name the file already
    try:
        return align(
            samples,
            params,
            fusion_rate_hz=fusion_rate_of(rec),
            release_s=release_s,
            max_gap_s=max_gap_s,
            drive_input=rec.drive_input_s,
            off_hinge=off_hinge,
            float32_values=float32_values,
        )
    except RecordingError as exc:
        raise RecordingError(f"{rec.path}: {exc}") from None


def recording_drive(rec: Recording, run: MeasuredRun) -> Drive | None:
    """The recording's drive from the aligned run's start on (drive time 0 there), covering the
    whole run; None for a free run."""
    return rec.drive_from(run.start.time_s, until_s=run.duration_s + 0.1)


def _runs(
    engine: str,
    params: RigParams,
    starts: list[tuple[tuple[float, float], tuple[float, float]]],
    duration_s: float,
    dt_s: float = 0.01,
    drive: Drive | None = None,
) -> list[Trajectory]:
    """One trajectory per start state (angles, rates), computed as one batch (the planar
    reference on its compiled kernel, ``engines.FAST_PATH``), driven by ``drive`` (time 0 at
    the start) or free."""
    engine = engines.FAST_PATH.get(engine, engine)
    phi0 = np.array([s[0] for s in starts], dtype=float)
    omega0 = np.array([s[1] for s in starts], dtype=float)
    batch = engines.run_batch(engine, params, phi0, omega0, whole_steps_s(duration_s, dt_s), dt_s, drive=drive)
    return [batch.member(i) for i in range(len(starts))]  # fmt: skip


def model_series(
    engine: str,
    params: RigParams,
    start: tuple[tuple[float, float], tuple[float, float]],
    duration_s: float,
    dt_s: float = 0.01,
    *,
    block_steps: int = MODEL_BLOCK_STEPS,
    drive: Drive | None = None,
    dtype: DTypeLike = np.float64,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One model run from a start state (angles, rates), simulated block by block and reduced to
    what is compared: its instants (n,) s and each ``VALIDATED`` quantity there (n,). Memory is
    these arrays and one block, never the whole run's Trajectory (a driven run: see
    ``engines.run_blocks``); the rows equal one run's. The planar reference runs on its compiled
    kernel (``engines.FAST_PATH``). ``drive``: the run's inputs, time 0 at the start; ``dtype``:
    of the quantities (float32: half the memory of a long run; the instants stay float64)."""
    engine = engines.FAST_PATH.get(engine, engine)
    total_s = whole_steps_s(duration_s, dt_s)
    n = check_step(total_s, dt_s) + 1
    t = np.empty(n)
    values = {q.name: np.empty(n, dtype=dtype) for q in VALIDATED}
    blocks = engines.run_blocks(engine, params, start[0], start[1], total_s, dt_s, block_steps=block_steps, drive=drive)
    for first, block in blocks:
        rows = slice(first, first + len(block.t_s))
        t[rows] = block.t_s
        for q in VALIDATED:
            values[q.name][rows] = q.computed(block)
    return t, values


def _window(inside: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """The arrays where ``inside``; the arrays themselves (no copy) when all of them are."""
    return arrays if inside.all() else tuple(a[inside] for a in arrays)


def model_at(traj: Trajectory, run: MeasuredRun, quantity: Quantity) -> np.ndarray:
    """A quantity of a model run at the instants its node's measured values belong to."""
    at = run.nodes[quantity.node].value_t_s
    return resample(traj.t_s, quantity.computed(traj), np.clip(at, 0.0, traj.t_s[-1]))


@dataclasses.dataclass(frozen=True)
class Identification:
    log_decrement: list[LogDecrement]
    fit: DampingFit
    release_angle_rad: tuple[float, float]
    release_time_s: float
    release_rate_rad_s: tuple[float, float] = (0.0, 0.0)
    start_kind: str = "release"
    modal_decrement: ModalDecrement | None = None  # None: a mode without three amplitude peaks
    driven: bool = False  # the fit used the recorded drive; the decrements (free decay only) are skipped


def identify(
    path: str | Path,
    *,
    window_s: float = 120.0,
    params: RigParams | None = None,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    law: str = "auto",
) -> Identification:
    """Both damping estimates from a recording's free decay (``law``: the planar fit's damping
    law, "auto" chooses by BIC)."""
    rec = read_recording(path, topics=[*(imu_topic(n) for n in NODES), DRIVE_TOPIC])
    params = params or recorded_params(rec)
    run = align_recording(rec, params, release_s=release_s, max_gap_s=max_gap_s)
    drive = recording_drive(rec, run)
    del rec  # the decoded recording is not needed by the fit (a 1 h record: about 120 MB)
    return _identify(run, params, window_s, law, drive)


def _identify(
    run: MeasuredRun, params: RigParams, window_s: float, law: str = "auto", drive: Drive | None = None
) -> Identification:
    """Log decrement of the measured angles and the planar least-squares fit of the gyros (hinge
    losses and start state together; the one call into ``pendsim_mj.estimation.identification``). A driven
    run (``drive``, time 0 at the start): the fit with the drive, no decrements (they assume a
    free decay)."""
    from pendsim_mj.estimation.identification import log_decrement, modal_decrement, planar_damping

    decrement: list[LogDecrement] = []
    modal: ModalDecrement | None = None
    if drive is None:
        t_phi, phi = run.both_nodes("t_s"), run.both_nodes("phi_rad")
        decrement = log_decrement(t_phi, phi, params, min(window_s, run.duration_s))
        try:
            modal = modal_decrement(t_phi, phi, params, min(window_s, run.duration_s))
        except ParameterError:
            modal = None
    start = run.start
    fit = planar_damping(
        params,
        # each node's own arrays, not both_nodes' (m, 2) copies: where each value belongs (the
        # sample instants moved by the fusion age) and its rate
        tuple(node.value_t_s for node in run.nodes),
        tuple(node.omega_rad_s for node in run.nodes),
        gyro_sigma_rad_s=run.gyro_sigma_rad_s,
        phi0_rad=start.phi_rad,
        omega0_rad_s=start.omega_rad_s,
        moving=start.kind != "release",
        law=law,
        drive=drive,
        timing_range_s=run.relative_timing_range_s,
    )
    return Identification(
        decrement, fit, start.phi_rad, start.time_s, start.omega_rad_s, start.kind, modal, drive is not None
    )


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
    mjcf_xml: str | None  # the recording's MJCF attachment, if any
    model_choice: dict[str, Any] | None = None  # --model spatial: planar vs spatial (spatial_validate)
    drive: Drive | None = None  # a driven recording's drive from the start on (every model run has it)
    lines: dict[tuple[str, str, str], DrawnLines] = dataclasses.field(default_factory=dict)
    """What the whole-run figures draw: (engine, release, quantity) -> its lines (``FIGURES``)."""

    @functools.cached_property
    def model_run(self) -> Trajectory:
        """MuJoCo from the estimated start with the validated parameters, the whole Trajectory
        (simulated when first asked for: the validation itself keeps only what it compares)."""
        start = self.run.start
        state = [(start.phi_rad, start.omega_rad_s)]
        return _runs("mujoco", self.params, state, self.run.duration_s + 0.02, drive=self.drive)[0]

    def case(self, engine: str = "mujoco", release: str = "estimated", window: str = "whole") -> CaseResult:
        for c in self.cases:
            if (c.engine, c.release, c.window) == (engine, release, window):
                return c
        raise KeyError((engine, release, window))

    @property
    def has_nominal(self) -> bool:
        """The nominal 30 deg release is compared too (the run starts from rest)."""
        return any(c.release == "nominal" for c in self.cases)


def validate(
    path: str | Path,
    *,
    damping: str | tuple[float, float] = "identified",
    params: RigParams | None = None,
    overrides: Mapping[str, float] | None = None,
    short_window_s: float = 5.0,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    model: str = "planar",
) -> ValidationReport:
    """Compare a recording with the MuJoCo model and the planar reference.

    Args:
      path: the recording.
      damping: "identified" (least-squares fit on this recording), "recorded" (the parameters in
        its metadata) or (b1, b2) in N m s/rad.
      params: the rig to validate (default: the recording's parameters, else the paper's).
      overrides: parameter changes applied on top of that rig (e.g. a deliberately wrong model).
      short_window_s: the paper's short window (5 s).
      release_s: the start (release) on the recording's clock, s, instead of detecting it.
      max_gap_s: spacing of samples above which nothing is interpolated or integrated, s.
      model: "planar" (default), or "spatial": also the spatial MuJoCo model (case engine
        "mujoco-spatial") and which of the two fits better (``spatial_validate.model_choice``).
    """
    if model not in ("planar", "spatial"):
        raise ParameterError(f"model must be 'planar' or 'spatial', got {model!r}")
    # the sensor values as float32: half the memory of a long recording (stamps stay exact)
    rec = read_recording(path, topics=[*(imu_topic(n) for n in NODES), DRIVE_TOPIC], sensor_float32=True)
    if model == "spatial" and rec.drive_input_s is not None:
        raise ParameterError(
            f"{path} is a driven recording (a /drive topic); --model spatial validates free runs only: "
            "validate it with the planar model (drop --model spatial)"
        )
    base = (params or recorded_params(rec)).with_mapping(overrides or {})
    samples = node_samples(rec)  # the measured series, decoded once
    rec = rec.without_imu()  # the samples hold what alignment needs of the IMU topics
    run = align_recording(
        rec,
        base,
        release_s=release_s,
        max_gap_s=max_gap_s,
        samples=samples,
        off_hinge=model == "spatial",
        float32_values=True,
    )
    drive = recording_drive(rec, run)
    mjcf_xml = rec.mjcf_xml
    covariance = [n.gyro_covariance for n in samples] if model == "spatial" else None
    del samples
    tilt_start = "zero"
    if model == "spatial":
        from .spatial_validate import tilt_start_of

        tilt_start = tilt_start_of(rec)
    del rec  # the decoded topics: the aligned run holds what is compared
    heap.trim()
    identification = None
    if damping == "identified":
        identification = _identify(run, base, 120.0, drive=drive)
        fit = identification.fit
        model_params = base.with_mapping(fit.overrides())
        source = f"identified (least squares, {fit.law} law)"
    elif damping == "recorded":
        model_params, source = base, "recorded"
    elif isinstance(damping, tuple) and len(damping) == 2:
        model_params = base.with_overrides(b1_n_m_s=damping[0], b2_n_m_s=damping[1])
        source = "given"
    else:
        raise ParameterError(f"damping must be 'identified', 'recorded' or (b1, b2), got {damping!r}")
    duration = run.duration_s
    cases = []
    start = run.start
    starts = {"estimated": (start.phi_rad, start.omega_rad_s)}
    if max(abs(w) for w in start.omega_rad_s) < AT_REST_RAD_S:
        starts["nominal"] = (NOMINAL_RELEASE_RAD, (0.0, 0.0))
    plotted = {q for _, q, window in FIGURES if window == "whole"}
    lines: dict[tuple[str, str, str], DrawnLines] = {}
    windows = ((f"{short_window_s:g} s", short_window_s), ("whole", math.inf))
    for engine in ("mujoco", "reference"):
        for release_name, state in starts.items():
            # the model's quantities in float32 (its errors against the IMUs are 1e4 times larger)
            t_model, values = model_series(engine, model_params, state, duration + 0.02, drive=drive, dtype=np.float32)
            by_window: dict[str, dict[str, Comparison]] = {name: {} for name, _ in windows}
            # phi1 last: its swing stays resolved longest (the angle's noise is the smallest), so
            # its comparison's whole-run transients meet no model series but its own
            for q in reversed(VALIDATED):
                t, measured, at = run.series(q)
                computed = resample(t_model, values.pop(q.name), at, clip_s=(0.0, t_model[-1]))
                if not values:  # the last quantity: the model's grid goes before its comparison
                    t_model = np.empty(0)
                for window_name, limit in windows:
                    # a long run's series: none stay, and its errors go window by window
                    inside = _window(t <= limit + 1e-9, t, measured, computed)
                    cmp = compare(*inside, max_gap_s=max_gap_s, series=None if window_name != "whole" else ())
                    by_window[window_name][q.name] = cmp
                    drawn = q.name in plotted and (engine, release_name) != ("reference", "nominal")
                    if window_name == "whole" and drawn:
                        # the lines a whole-run figure draws: their envelopes (the computed line float32)
                        main = (engine, release_name) == ("mujoco", "estimated")
                        lines[(engine, release_name, q.name)] = drawn_lines(
                            t,
                            measured,
                            computed.astype(np.float32),
                            run.max_gap_s,
                            with_measured=main,
                            with_difference=release_name == "estimated",
                        )
                del computed, inside  # (the whole window's are the arrays themselves)
                heap.trim()  # the comparison's transients go back to the system (not kept as heap)
            del t_model, values
            cases += [
                CaseResult(engine, release_name, name, {q.name: by_window[name][q.name] for q in VALIDATED})
                for name, _ in windows
            ]
    choice = None
    if model == "spatial":
        from . import spatial_validate

        case, spatial = spatial_validate.spatial_case(
            run,
            model_params,
            max_gap_s,
            damping_fit=damping == "identified",
            covariance=covariance,
            tilt_start=tilt_start,
        )
        cases.append(case)
        planar = next(c for c in cases if (c.engine, c.release, c.window) == ("mujoco", "estimated", "whole"))
        choice = spatial_validate.model_choice(planar, case)
        choice["plane_offset_m"] = spatial.plane_offset_m
        choice["spatial_params"] = {n: getattr(spatial, n) for n in spatial_validate.NAMES}
    return ValidationReport(
        Path(path), model_params, source, identification, run, cases, mjcf_xml, choice, drive, lines
    )


@dataclasses.dataclass(frozen=True)
class Gates:
    """Pass/fail thresholds for CI (None: not checked).

    Attributes:
      max_delta: relative frequency error of any quantity (MuJoCo, estimated release, whole run).
      max_iae: IAE of phi1 over the short window (MuJoCo, estimated release), rad s.
      max_error_phi1: max |Delta phi1| over the whole run (MuJoCo, estimated release), rad.
    """

    max_delta: float | None = None
    max_iae: float | None = None
    max_error_phi1: float | None = None


def gate_failures(report: ValidationReport, gates: Gates) -> list[str]:
    """One line per exceeded threshold (empty when the model passes)."""
    failures = []
    main_case = report.case("mujoco", "estimated", "whole")
    short = next(c for c in report.cases if c.engine == "mujoco" and c.release == "estimated" and c.window != "whole")
    if gates.max_delta is not None:
        worst_q, worst = max(((q, c.delta_f) for q, c in main_case.comparisons.items()), key=lambda kv: kv[1])
        if not worst <= gates.max_delta:
            failures.append(f"relative frequency error of {worst_q} {worst:.3g} > --max-delta {gates.max_delta:g}")
    if gates.max_iae is not None:
        iae = short.comparisons["phi1"].iae
        if not iae <= gates.max_iae:
            failures.append(f"IAE of phi1 over {short.window} {iae:.4g} rad s > --max-iae {gates.max_iae:g}")
    if gates.max_error_phi1 is not None:
        err = main_case.comparisons["phi1"].max_abs
        if not err <= gates.max_error_phi1:
            failures.append(f"max |Delta phi1| {err:.4g} rad > --max-error-phi1 {gates.max_error_phi1:g}")
    return failures


def write_outputs(
    report: ValidationReport, out_dir: str | Path, *, plots: bool = True, replace: bool = False
) -> list[Path]:
    """report.json and (with ``plots``) the paper's Figures 9-15 into ``out_dir``, published
    together when all are written (``atomic_directory``: never over files of the same names
    unless ``replace``). Returns the paths written."""
    from ..report.plots import validation_figures

    out = Path(out_dir)
    with atomic_directory(out, replace=replace) as tmp:
        (tmp / "report.json").write_text(json.dumps(report_json(report), indent=1))
        names = ["report.json"] + ([p.name for p in validation_figures(report, tmp)] if plots else [])
    return [out / name for name in names]


def report_json(report: ValidationReport) -> dict[str, Any]:
    """Everything a machine needs: alignment, coverage, damping, and every metric of every case."""

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
            "modal_decrement": None
            if i.modal_decrement is None
            else {
                "b_n_m_s": i.modal_decrement.b_n_m_s.tolist(),
                "decay_rate_1_s": i.modal_decrement.decay_rate_1_s.tolist(),
                "frequency_hz": i.modal_decrement.frequency_hz.tolist(),
                "window_s": i.modal_decrement.window_s,
            },
            "least_squares": {
                "b_n_m_s": i.fit.b_n_m_s.tolist(),
                "ci95_n_m_s": i.fit.ci95_n_m_s.tolist(),
                "residual_rms_sigma": i.fit.residual_rms_sigma,
                "iterations": i.fit.iterations,
                "seconds": i.fit.seconds,
                "law": i.fit.law,
                "friction_n_m": i.fit.friction_n_m.tolist(),
                "friction_ci95_n_m": i.fit.friction_ci95_n_m.tolist(),
                "timing2_s": i.fit.timing2_s,
                "timing2_ci95_s": i.fit.timing2_ci95_s,
                "laws": [
                    {
                        "law": f.law,
                        "bic": f.bic,
                        "ljung_box_p": list(f.ljung_box_p),
                        "residual_rms_sigma": f.residual_rms_sigma,
                    }
                    for f in i.fit.laws
                ],
            },
        }
    run = report.run
    nodes = {}
    for name, node in zip(NODES, run.nodes, strict=True):
        frame = node.frame
        nodes[name] = {
            "hinge_axis": frame.hinge_axis.tolist(),
            "toward_pivot": frame.toward_pivot.tolist(),
            "tangential": frame.tangential.tolist(),
            "radius_m": frame.radius_m,
            "mirrored_axes": frame.mirrored,
            "frame_fit_rms_m_s2": frame.fit_rms_m_s2,
            "clock_drift_ppm": node.clock.drift_ppm if node.clock is not None else None,
            "fusion_phase_s": node.fusion_phase_s,
            "coverage": node.coverage.summary(),
        }
    return {
        "file": str(report.path),
        "release": {
            "kind": run.start.kind,
            "time_s": run.start.time_s,
            "estimated_angle_rad": list(run.start.phi_rad),
            "estimated_rate_rad_s": list(run.start.omega_rad_s),
            "start_fit_rms_sigma": run.start.fit_rms,
            "start_fit_unexplained": run.start.unexplained,
            "nominal_angle_rad": list(NOMINAL_RELEASE_RAD) if report.has_nominal else None,
        },
        "nodes": nodes,
        "relative_timing_range_s": None if run.relative_timing_range_s is None else list(run.relative_timing_range_s),
        "max_gap_s": run.max_gap_s,
        "damping": {
            "source": report.damping_source,
            "b1_n_m_s": report.params.b1_n_m_s,
            "b2_n_m_s": report.params.b2_n_m_s,
        },
        "identification": ident,
        **({"model_choice": report.model_choice} if report.model_choice is not None else {}),
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


def start_line(path: str | Path, run: MeasuredRun) -> str:
    """Where the run starts, how, and from what state; one line."""
    s = run.start
    phi1, phi2 = (math.degrees(a) for a in s.phi_rad)
    how = {
        "release": "release from rest found",
        "in motion": (
            "no hold before the release (the recording starts in motion or at its release); "
            "the model starts from the state at its first samples"
        ),
        "given": "start given",
    }[s.kind]
    rates = ""
    if s.kind != "release":
        rates = f", {math.degrees(s.omega_rad_s[0]):.2f} deg/s, {math.degrees(s.omega_rad_s[1]):.2f} deg/s"
    note = f"; {s.fit_note()}" if s.poor_fit else ""
    return (
        f"{path}: {how} at {s.time_s:.3f} s on the recording's clock; from {phi1:.2f} deg, {phi2:.2f} deg{rates}{note}"
    )


def _before(count: int) -> str:
    return f" from the start, {count} before it" if count else ""


def coverage_line(run: MeasuredRun) -> str:
    """How much of the run each node's samples cover; one line."""
    parts = []
    for name, node in zip(NODES, run.nodes, strict=True):
        c = node.coverage
        part = (
            f"{name} {100 * c.covered_fraction:.1f} % ({c.samples} samples{_before(node.before_start)}, "
            f"{100 * c.lost_fraction:.1f} % lost, "
            f"{c.gaps} gaps over {run.max_gap_s:g} s, longest {c.longest_gap_s:.3f} s"
        )
        if node.clock is not None and abs(node.clock.drift_ppm) >= 1:
            part += f", clock {node.clock.drift_ppm:+.0f} ppm"
        parts.append(part + ")")
    return f"covered: {'; '.join(parts)}"


def table(report: ValidationReport) -> str:
    """Per quantity: measured and computed frequency and delta, max |Delta|, IAE, ISE."""
    lines = [
        start_line(report.path, report.run),
        coverage_line(report.run),
        f"damping {report.damping_source}: b1 = {report.params.b1_n_m_s:.5g}, "
        f"b2 = {report.params.b2_n_m_s:.5g} N m s/rad",
    ]
    for case in report.cases:
        if case.release != "estimated":
            continue
        lines.append("")
        lines.append(f"{case.engine} model, from the estimated start, {case.window}:")
        head = f"  {'quantity':14} {'f meas (Hz)':>11} {'f comp (Hz)':>11} {'delta':>9}"
        lines.append(f"{head} {'max|Delta|':>11} {'IAE':>10} {'ISE':>10}  unit")
        for q in VALIDATED:
            cmp = case.comparisons[q.name]
            lines.append(
                f"  {q.label:14} {cmp.f_measured_hz:11.5f} {cmp.f_computed_hz:11.5f} {cmp.delta_f:9.2e} "
                f"{cmp.max_abs:11.4g} {cmp.iae:10.4g} {cmp.ise:10.4g}  {q.unit}"
            )
    if report.model_choice is not None:
        from .spatial_validate import choice_lines

        lines += choice_lines(report.model_choice, report.model_choice["plane_offset_m"])
    if report.has_nominal:
        nominal = report.case("mujoco", "nominal", "whole").comparisons["phi1"]
        lines.append("")
        lines.append(
            "from the nominal 30 deg at rest instead (the paper's simulation; compared because the estimated start "
            f"is at rest within {AT_REST_RAD_S:g} rad/s): phi1 max|Delta| {nominal.max_abs:.4g} rad, "
            f"IAE {nominal.iae:.4g} rad s over the whole run"
        )
    return "\n".join(lines)
