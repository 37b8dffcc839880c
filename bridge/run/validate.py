"""Validate the model against a recording: what the IMUs measured against what the MuJoCo model
and the planar reference compute, with the paper's metrics (spec RIG.md sections 5-7).

This module reads and wires; the physics layer does the work on arrays:
``pendsim_mj.estimation.alignment`` (clocks, start, swing frames, fusion timing, coverage),
``pendsim_mj.estimation.validation`` (metrics on covered samples), ``pendsim_mj.estimation.identification`` (damping)
and ``pendsim_mj.estimation.quantities`` (what is compared). The recording is read into arrays and
aligned by ``pendsim_bridge.io.measured``; the ``ValidationReport`` returned, its files and its
table are ``pendsim_bridge.report.validation_report``'s.

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
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import DTypeLike

from pendsim_mj.engines import dispatch as engines
from pendsim_mj.engines.dispatch import whole_steps_s
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.estimation.alignment import MeasuredRun
from pendsim_mj.estimation.analysis import BlockBalance
from pendsim_mj.estimation.identification import (
    LogDecrement,
    ModalDecrement,
    fit_warnings,
    log_decrement,
    modal_decrement,
    planar_damping,
    timing_at_edge,
)
from pendsim_mj.estimation.quantities import VALIDATED
from pendsim_mj.estimation.timing import DEFAULT_MAX_GAP_S
from pendsim_mj.estimation.validation import Comparison, compare, resample
from pendsim_mj.rig.checks import check_step
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.params import RigParams

from .. import heap
from ..io.measured import align_recording, node_samples, recorded_params, recording_drive
from ..io.recording import read_recording
from ..io.recording_layout import DRIVE_TOPIC, NODES, imu_topic
from ..report.figure_lines import FIGURES, DrawnLines, drawn_lines
from ..report.validation_report import AT_REST_RAD_S, NOMINAL_RELEASE_RAD, CaseResult
from ..report.validation_report import Identification as Identification  # what identify returns, beside it
from ..report.validation_report import ValidationReport as ValidationReport  # what validate returns, beside it
from . import spatial_validate

MODEL_BLOCK_STEPS = 6000  # model steps simulated at once (60 s at 0.01 s)
MODEL_DT_S = 0.01  # the model runs' step, s (``model_series``'s default)
UNRESOLVED_REMEDY = (
    "validate runs its model at 0.01 s and cannot judge this rig there (its comparison and damping fit would "
    "blame the model for its step): see the rig's motion resolved with 'pendsim simulate --dt-s' and a step "
    "small enough"
)


def model_series(
    engine: str,
    params: RigParams,
    start: tuple[tuple[float, float], tuple[float, float]],
    duration_s: float,
    dt_s: float = MODEL_DT_S,
    *,
    block_steps: int = MODEL_BLOCK_STEPS,
    drive: Drive | None = None,
    dtype: DTypeLike = np.float64,
    balance: BlockBalance | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One model run from a start state (angles, rates), simulated block by block and reduced to
    what is compared: its instants (n,) s and each ``VALIDATED`` quantity there (n,). Memory is
    these arrays and one block, never the whole run's Trajectory (a driven run: see
    ``engines.run_blocks``); the rows equal one run's. The planar reference runs on its compiled
    kernel (``engines.FAST_PATH``). ``drive``: the run's inputs, time 0 at the start; ``dtype``:
    of the quantities (float32: half the memory of a long run; the instants stay float64);
    ``balance``: gathers the run's energy balance (is the run resolved by its step?)."""
    engine = engines.FAST_PATH.get(engine, engine)
    total_s = whole_steps_s(duration_s, dt_s)
    n = check_step(total_s, dt_s) + 1
    t = np.empty(n)
    values = {q.name: np.empty(n, dtype=dtype) for q in VALIDATED}
    blocks = engines.run_blocks(engine, params, start[0], start[1], total_s, dt_s, block_steps=block_steps, drive=drive)
    for first, block in blocks:
        if balance is not None:
            balance.add(block, first)
        rows = slice(first, first + len(block.t_s))
        t[rows] = block.t_s
        for q in VALIDATED:
            values[q.name][rows] = q.computed(block)
    return t, values


def _window(inside: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """The arrays where ``inside``; the arrays themselves (no copy) when all of them are."""
    return arrays if inside.all() else tuple(a[inside] for a in arrays)


def identify(
    path: str | Path,
    *,
    window_s: float = 120.0,
    params: RigParams | None = None,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    law: str = "auto",
    overrides: Mapping[str, float] | None = None,
) -> Identification:
    """Both damping estimates from a recording's free decay (``law``: the planar fit's damping
    law, "auto" chooses by BIC; ``overrides``: parameter changes on the rig, e.g. a calibration's)."""
    rec = read_recording(path, topics=[*(imu_topic(n) for n in NODES), DRIVE_TOPIC])
    params = (params or recorded_params(rec)).with_mapping(overrides or {})
    run = align_recording(rec, params, release_s=release_s, max_gap_s=max_gap_s)
    drive = recording_drive(rec, run)
    del rec  # the decoded recording is not needed by the fit (a 1 h record: about 120 MB)
    return _identify(run, params, window_s, law, drive, source=path)


def _identify(
    run: MeasuredRun,
    params: RigParams,
    window_s: float,
    law: str = "auto",
    drive: Drive | None = None,
    *,
    source: str | Path = "the recording",
) -> Identification:
    """Log decrement of the measured angles and the planar least-squares fit of the gyros (hinge
    losses and start state together; the one call into ``pendsim_mj.estimation.identification``). A driven
    run (``drive``, time 0 at the start): the fit with the drive, no decrements (they assume a
    free decay)."""
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
    edge = timing_at_edge(fit, run.relative_timing_range_s)
    if edge is not None and run.timing_open_s > 0:  # a lab file's times, off by more than they may be
        raise RecordingError(f"{source}: the damping cannot be identified: {edge}")
    warnings = run.warnings + fit_warnings(fit, run.relative_timing_range_s)
    return Identification(
        decrement, fit, start.phi_rad, start.time_s, start.omega_rad_s, start.kind, modal, drive is not None, warnings
    )


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
        tilt_start = spatial_validate.tilt_start_of(rec)
    del rec  # the decoded topics: the aligned run holds what is compared
    heap.trim()
    identification = None
    if damping == "identified":
        identification = _identify(run, base, 120.0, drive=drive, source=path)
        fit = identification.fit
        model_params = base.with_mapping(fit.overrides())
        source = (
            "identified (least squares; NO law chosen: the model does not fit, see the line below)"
            if fit.misfit
            else f"identified (least squares, {fit.law} law)"
        )
    elif damping == "recorded":
        model_params, source = base, "recorded"
    elif isinstance(damping, tuple) and len(damping) == 2:
        model_params = base.with_overrides(b1_n_m_s=damping[0], b2_n_m_s=damping[1])
        source = "given"
    else:
        raise ParameterError(f"damping must be 'identified', 'recorded' or (b1, b2), got {damping!r}")
    duration = run.duration_s
    cases = []
    model_warnings: tuple[str, ...] = ()
    start = run.start
    starts = {"estimated": (start.phi_rad, start.omega_rad_s)}
    if max(abs(w) for w in start.omega_rad_s) < AT_REST_RAD_S:
        starts["nominal"] = (NOMINAL_RELEASE_RAD, (0.0, 0.0))
    plotted = {q for _, q, window in FIGURES if window == "whole"}
    lines: dict[tuple[str, str, str], DrawnLines] = {}
    windows = ((f"{short_window_s:g} s", short_window_s), ("whole", math.inf))
    # MuJoCo and the planar reference from the estimated start; from the nominal start, the paper's
    # simulation: its planar equations, the reference alone (MuJoCo from there too was a second
    # whole-record MuJoCo run, 4-5 s of a 1 h validate's CPU)
    for engine, release_name in [("mujoco", "estimated"), ("reference", "estimated"), ("reference", "nominal")]:
        if release_name not in starts:
            continue
        state = starts[release_name]
        # the model's quantities in float32 (its errors against the IMUs are 1e4 times larger)
        balance = BlockBalance() if (engine, release_name) == ("mujoco", "estimated") else None
        t_model, values = model_series(
            engine, model_params, state, duration + 0.02, drive=drive, dtype=np.float32, balance=balance
        )
        unresolved = balance.warning(model_params, MODEL_DT_S, remedy=UNRESOLVED_REMEDY) if balance else None
        model_warnings += (f"the model: {unresolved}",) if unresolved is not None else ()
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
                if window_name == "whole" and q.name in plotted:
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
        Path(path), model_params, source, identification, run, cases, mjcf_xml, choice, drive, lines, model_warnings
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
