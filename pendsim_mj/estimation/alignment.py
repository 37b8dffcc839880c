"""Turn two IMU nodes' raw samples into the measured run a model is compared with.

Works on arrays (time stamps, quaternions, gyro and accelerometer per node), from any recorder:

1. **Clocks**: each node's stamps are mapped to the recorder's clock by the lower envelope of
   (stamp, log time) (``timing.fit_clock``): drifting node clocks line up, latency drops out.
2. **Start**: the large swing is found from the gyro magnitudes (no axis assumed) and traced
   back to its foot. If the pendulums rest (hand wobble allowed) for at least 0.1 s before it,
   the run starts at a *release* from rest; otherwise it starts *in motion* at its first samples
   (a recording started at the release, a replay cut, a start mid-swing). A driven run (its
   recorded inputs given) starts where its drive starts: a release there if the pendulums rest
   before it, else in motion at its first samples. ``release_s`` gives the start instead. A
   found start the model from it cannot explain is refused.
3. **Swing frames** (``swing_frame``): each node's hinge axis, mounting and angle from its own
   data, whatever the heading, mount and axis remap. Signs: M1's first large excursion counts as
   positive (the paper releases M1 to +34 deg; the rig is mirror symmetric, so this convention
   cannot change a comparison); M2's sense against M1's is the one the model fits (step 5).
4. **Start state**: least squares of the model's first ``start_fit_s`` seconds against both
   nodes' angles and rates: the release instant and angles (from rest) for a release, else the
   full state (angles and rates) at the first samples. A driven run's model is driven by the
   recorded inputs (drive time 0 at the start); as the drive breaks the rig's mirror symmetry,
   the sign of the swing frames is the one whose start fit is better.
5. **Sense and timing**: a BNO055 sample carries the latest 100 Hz fused value, so it is 0-10 ms
   old in a pattern set by where the chip's fusion ticks fall; that phase is found per node from
   its own data within a stretch (``timing.fusion_phase``). M2's sense against M1's and the
   nodes' relative timing (within both stretches, and for a lab file's times within a sample
   period more: ``file_times``) are chosen together by the start fit over 3 s, both senses tried
   (``start_fit.sense_and_timing``); what is left open of the timing
   (``MeasuredRun.relative_timing_range_s``) the damping fit refines. A lab file's clock steps
   are removed first (``timing.clock_steps``); what the data leave unclear is a warning
   (``MeasuredRun.warnings``).
6. **Gaps**: nothing is filled in; each node keeps its own instants, and its coverage (share of
   the run inside segments whose spacing stays below ``max_gap_s``) is reported.

Where each step lives: this module holds ``align`` (the steps in order, the refusal of a found
start, each node's run from the start on) and re-exports what it takes and gives
(``measured_run``); the node-by-node steps (clocks, start detection, swing-frame window and
signs) are in ``node_alignment``, the start fit and the relative fusion timing in ``start_fit``,
its Gauss-Newton in ``least_squares``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.estimation.measured_run import (
    UNEXPLAINED_POOR,
    Floats,
    MeasuredRun,
    NodeRun,
    NodeSamples,
    StartKind,
    StartState,
)
from pendsim_mj.estimation.node_alignment import (
    FIRST_SWING_S,
    FRAME_FIT_S,
    LARGE_SWING,
    MIN_REST_S,
    AlignedNode,
    detect_driven_start,
    detect_start,
    drive_onset_s,
    frame_window,
    gyro_sigma,
    orient,
    prepare_node,
    shows_fusion_hold,
)
from pendsim_mj.estimation.start_fit import (
    ANGLE_SIGMA_RAD,
    TIMING_FIT_S,
    TIMING_MIN_RANGE_S,
    StartModel,
    fit_start,
    mirrored_differs,
    sense_and_timing,
)
from pendsim_mj.estimation.swing_frame import fit_swing_frame
from pendsim_mj.estimation.timing import DEFAULT_MAX_GAP_S, check_max_gap, coverage, fusion_phase
from pendsim_mj.rig.params import RigParams
from pendsim_mj.sensors.bno055 import FUSION_RATE_HZ

__all__ = [
    "ANGLE_SIGMA_RAD",
    "FILE_TIMING_OPEN_S",
    "FIRST_SWING_S",
    "FRAME_FIT_S",
    "LARGE_SWING",
    "MIN_REST_S",
    "TIMING_FIT_S",
    "TIMING_MIN_RANGE_S",
    "UNEXPLAINED_POOR",
    "UNEXPLAINED_REFUSED",
    "MeasuredRun",
    "NodeRun",
    "NodeSamples",
    "StartKind",
    "StartState",
    "align",
]

UNEXPLAINED_REFUSED = 0.5  # a found start whose model leaves this share of the motion unexplained is refused
FILE_TIMING_OPEN_S = 0.006
"""How far a lab file's two nodes' times may be off against each other at least, s (a logger's
per-node offsets of a few ms); at least one sample period: one time column shared by two nodes
sampled at other instants puts one node's values up to a period off."""


def file_timing_open_s(rate_hz: float) -> float:
    """How far a lab file's nodes' times may be off against each other (nodes sampled at
    ``rate_hz``, Hz), s: FILE_TIMING_OPEN_S or one sample period, the larger."""
    return max(FILE_TIMING_OPEN_S, 1.0 / rate_hz)


def _owned(a: Floats, samples: NodeSamples) -> bool:
    """``a`` is an array alignment made itself (no view of the caller's sample times)."""
    theirs = [samples.log_t_s] + ([] if samples.stamp_s is None else [samples.stamp_s])
    return not any(np.may_share_memory(a, b) for b in theirs)


def _node_run(
    node: AlignedNode,
    at: Floats,
    phase: float | None,
    samples: NodeSamples,
    kind: StartKind,
    start_time: float,
    max_gap_s: float,
    off_hinge: bool,
    float32_values: bool,
) -> NodeRun:
    """One node's series from the start on: from the release on (values just before it are the
    model's rest); from the first values after a start in motion. ``at``: its values' instants,
    s on the recorder's clock. The instants increase, so what is kept is a suffix: the kept
    angles and rates are views (float64) or float32 copies; the times are shifted to the start
    in place where alignment made the arrays (``node`` and ``at`` are not used after this)."""
    first = int(np.searchsorted(node.t if kind == "release" else at, start_time - 1e-9, side="left"))
    keep = slice(first, None)
    frame = node.frame
    assert frame is not None
    same = np.may_share_memory(at, node.t)  # values at their sample instants: one array for both
    t = node.t[keep]
    if _owned(node.t, samples):
        t -= start_time
    else:
        t = t - start_time
    value_t = t
    if not same:
        value_t = at[keep]
        if _owned(at, samples):
            value_t -= start_time
        else:
            value_t = value_t - start_time
    covered = coverage(t, max_gap_s, node.rate_hz)  # before the values: its steps meet none of them
    dtype = np.float32 if float32_values else np.float64
    off_axes = np.stack([frame.tangential, frame.toward_pivot], axis=1)
    accel = node.accel[keep]
    return NodeRun(
        t_s=t,
        value_t_s=value_t,
        phi_rad=node.phi[keep].astype(dtype, copy=False),
        omega_rad_s=node.omega[keep].astype(dtype, copy=False),
        tangential_m_s2=frame.tangential_of(accel, dtype=dtype),
        normal_m_s2=frame.normal_of(accel, dtype=dtype),
        frame=frame,
        clock=node.clock,
        fusion_phase_s=phase,
        coverage=covered,
        gyro_sigma_rad_s=node.sigma,
        off_hinge_gyro_rad_s=(node.gyro[keep] @ off_axes).astype(dtype, copy=False) if off_hinge else None,
        before_start=first,
    )


def align(
    nodes: Sequence[NodeSamples],
    params: RigParams,
    *,
    fusion_rate_hz: float | None = FUSION_RATE_HZ,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    start_fit_s: float = 1.0,
    engine: str = "mujoco",
    drive_input: tuple[Floats, Floats] | None = None,
    off_hinge: bool = True,
    float32_values: bool = False,
    file_times: bool = False,
) -> MeasuredRun:
    """The measured run of two nodes (M1's, M2's) against which ``params`` will be compared.

    Args:
      nodes: the two nodes' samples.
      params: the rig (its model fits the start state).
      fusion_rate_hz: the chips' fusion rate (each sample carries the latest fused value), or
        None for values taken at their sample instants.
      release_s: the start on the recorder's clock, s, instead of detecting it.
      max_gap_s: spacing above which samples are not interpolated across, s.
      start_fit_s: length of the start fit, s.
      engine: the model that fits the start ("mujoco" or "reference").
      drive_input: a driven run's recorded inputs: (n,) the start of each step on the recorder's
        clock, s, and (n, 4) the inputs held over it (``pendsim_mj.rig.drives`` channels); None for
        a free run. The model is driven by them from the start on (``drives.recorded_drive``).
      off_hinge: keep each node's gyro off its hinge axis (``NodeRun.off_hinge_gyro_rad_s``,
        what a spatial fit needs; False: None, 16 bytes a sample less).
      float32_values: the run's values (angles, rates, accelerations, off-hinge gyros) as
        float32, its instants float64: 32 instead of 48 bytes a sample (a long run; float32
        rounds an angle of 0.5 rad by 3e-8 rad, far below the sensors' resolution).
      file_times: the nodes' times are a lab file's columns (``pendsim import``), not a
        recorder's clock: steps in them are found and removed (``timing.clock_steps``), and each
        node's times may be off against the other's (a constant offset, one column shared by
        nodes sampled at other instants) by up to ``file_timing_open_s`` of the slower node's
        rate, which the start fit and the damping fit then estimate.

    Raises:
      RecordingError: too few samples, no motion, no swing to find a frame in.
      ParameterError: bad options (release_s outside the samples, shapes).
    """
    if len(nodes) != 2:
        raise ParameterError(f"align needs the two nodes (M1, M2), got {len(nodes)}")
    check_max_gap(max_gap_s)
    prepared = [prepare_node(n, k, find_steps=file_times) for k, n in enumerate(nodes)]
    for k in range(2):  # a step one node's values could not read: the other's, of the same clock, may
        clear = [(s.at_s, s.step_s) for s in prepared[1 - k].steps if s.other_s is None]
        if clear and any(s.other_s is not None for s in prepared[k].steps):
            prepared[k] = prepare_node(nodes[k], k, find_steps=True, known_steps=clear)
    notes = [step.describe(f"M{k + 1}") for k, node in enumerate(prepared) for step in node.steps]
    open_s = file_timing_open_s(min(n.rate_hz for n in prepared)) if file_times else 0.0
    onset_s = None
    if drive_input is not None:
        drive_input = (np.asarray(drive_input[0], dtype=float), np.asarray(drive_input[1], dtype=float))
        onset_s = drive_onset_s(drive_input)
        if onset_s is None:  # a drive topic that never drives: a free run
            drive_input = None
    phases: list[float | None] = [None, None]
    timing_range: tuple[float, float] | None = None
    if fusion_rate_hz:  # where each chip's fusion ticks fall: the phase that makes its gyro smoothest
        estimated = [fusion_phase(n.stamp, n.gyro, fusion_rate_hz) for n in prepared]
        if any(shows_fusion_hold(n, fusion_rate_hz, p) for n, p in zip(prepared, estimated, strict=True)):
            phases = list(estimated)
        else:  # values taken at their stamps, not a chip's held fused values
            fusion_rate_hz = None
    instants = [n.value_instants(fusion_rate_hz, p) for n, p in zip(prepared, phases, strict=True)]
    first = max(float(n.t[0]) for n in prepared)
    last = min(float(n.t[-1]) for n in prepared)
    kind: StartKind
    if release_s is not None:
        if not (math.isfinite(release_s) and first <= release_s <= last - 1.0):
            raise ParameterError(
                f"release_s = {release_s!r} s is outside the samples of both nodes "
                f"({first:.3f} to {last - 1.0:.3f} s on the recording's clock, leaving 1 s to compare)"
            )
        kind, t0 = "given", float(release_s)
    elif onset_s is not None:
        kind, t0 = detect_driven_start(prepared, onset_s)
    else:
        kind, t0 = detect_start(prepared)
    frames = []
    for k, node in enumerate(prepared):
        near = frame_window(instants[k], t0)
        try:
            frame = fit_swing_frame(
                instants[k][near],
                node.quat[near],
                node.gyro[near],
                node.accel[near],
                g_m_s2=params.g_m_s2,
                max_step_s=2.5 / node.rate_hz,
            )
        except RecordingError as exc:
            raise RecordingError(f"node M{k + 1}: {exc}") from None
        frames.append(node.with_frame(frame))
    prepared = orient(frames, t0, kind)
    prepared = [dataclasses.replace(n, sigma=gyro_sigma(n, nodes[k].gyro_covariance)) for k, n in enumerate(prepared)]

    # Start state: least squares of the model's first seconds against both nodes.
    model = StartModel(kind, t0, params, engine, start_fit_s + 0.6, drive_input)
    x, rms, unexplained = fit_start(model, prepared, instants, start_fit_s)
    if drive_input is not None and mirrored_differs(model.drive()):
        # the drive has a sense (a torque, a sideways support): the frames' sign must match it
        flipped = [n.with_frame(n.frame.flipped()) for n in prepared if n.frame is not None]
        x_f, rms_f, unexplained_f = fit_start(model, flipped, instants, start_fit_s)
        if rms_f < rms:
            prepared, x, rms, unexplained = flipped, x_f, rms_f, unexplained_f
    # M2's sense against M1's and the nodes' relative timing, which their own data leave open
    chosen = sense_and_timing(model, prepared, phases, fusion_rate_hz, start_fit_s, (x, rms, unexplained), open_s)
    prepared, phases, instants, timing_range = chosen.nodes, chosen.phases, chosen.instants, chosen.timing_range_s
    x, rms, unexplained = chosen.fitted
    notes += chosen.notes
    phi0, omega0, start_time = model.states(x)
    shift = model.shift_s(x)
    if drive_input is not None and kind == "release":
        # the drive's clock is the reference: the release is at its onset, the fitted offset
        # from it an error of the values' instants (the fusion phase: a free decay absorbs it)
        shift, start_time = t0 - start_time, t0
    if shift:  # the values' instants as the driven start fit found them
        instants = [at + shift for at in instants]
    start = StartState(
        kind=kind,
        time_s=start_time,
        phi_rad=(float(phi0[0]), float(phi0[1])),
        omega_rad_s=(float(omega0[0]), float(omega0[1])),
        fit_rms=rms,
        unexplained=unexplained,
        fit_window_s=start_fit_s,
    )
    if kind != "given":
        _check_found_start(start, t0, prepared, instants, start_fit_s, driven=drive_input is not None)

    frames.clear()  # the nodes before their signs were set (and the series they computed)
    runs = []
    for k, phase in enumerate(phases):  # node by node, each node's whole-run arrays let go once used
        node, at = prepared.pop(0), instants.pop(0)
        runs.append(_node_run(node, at, phase, nodes[k], kind, start_time, max_gap_s, off_hinge, float32_values))
        del node, at
    return MeasuredRun(
        nodes=(runs[0], runs[1]),
        start=start,
        fusion_rate_hz=fusion_rate_hz,
        max_gap_s=max_gap_s,
        relative_timing_range_s=timing_range,
        relative_timing_s=chosen.relative_s,
        timing_open_s=open_s,
        warnings=tuple(notes),
    )


def _check_found_start(
    start: StartState,
    detected_s: float,
    nodes: Sequence[AlignedNode],
    instants: Sequence[Floats],
    window_s: float,
    driven: bool = False,
) -> None:
    """Refuse a found start (detected at ``detected_s``, s) that is not the start of the swing
    that follows it.

    Raises:
      RecordingError: a release from rest (of a free run) not at the largest excursion of the
        swing after it, or a model (from the start) that leaves UNEXPLAINED_REFUSED of the
        motion unexplained.
    """
    what = "release from rest" if start.kind == "release" else "start in motion"
    advice = "give the release instant with --release-s (seconds on the recording's clock)"
    where = f"the {what} found at {detected_s:.3f} s"
    if start.kind == "release" and not driven:  # a drive may swing the pendulums beyond the release
        span = (start.time_s, start.time_s + FIRST_SWING_S)
        after = [n.phi[(at >= span[0]) & (at <= span[1])] for n, at in zip(nodes, instants, strict=True)]
        swing = max(float(np.max(np.abs(a))) if len(a) else 0.0 for a in after)
        held = max(abs(a) for a in start.phi_rad)
        if held < 0.5 * swing:
            raise RecordingError(
                f"{where} is not where the swing starts: it is from {math.degrees(held):.2f} deg while the swing "
                f"after it reaches {math.degrees(swing):.2f} deg (a release is at the largest excursion); {advice}"
            )
    if not start.unexplained <= UNEXPLAINED_REFUSED:
        raise RecordingError(
            f"{where} does not start the motion that follows it: the model from there leaves "
            f"{100 * start.unexplained:.0f} % of the next {window_s:g} s unexplained; {advice}, "
            "or check the rig parameters"
        )
