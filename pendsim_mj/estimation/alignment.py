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
   cannot change a comparison); M2 follows M1 through the coupling springs, which pull M2 toward
   M1 (d alpha2 / d phi1 > 0, about 5 s^-2 on the paper's rig).
4. **Start state**: least squares of the model's first ``start_fit_s`` seconds against both
   nodes' angles and rates: the release instant and angles (from rest) for a release, else the
   full state (angles and rates) at the first samples. A driven run's model is driven by the
   recorded inputs (drive time 0 at the start); as the drive breaks the rig's mirror symmetry,
   the sign of the swing frames is the one whose start fit is better.
5. **Fusion timing**: a BNO055 sample carries the latest 100 Hz fused value, so it is 0-10 ms
   old in a pattern set by where the chip's fusion ticks fall; that phase is found per node from
   its own data within a stretch (``timing.fusion_phase``), and the nodes' relative timing within
   both stretches by the start fit (``_relative_fusion_timing``); what is left open of it
   (``MeasuredRun.relative_timing_range_s``) the damping fit refines.
6. **Gaps**: nothing is filled in; each node keeps its own instants, and its coverage (share of
   the run inside segments whose spacing stays below ``max_gap_s``) is reported.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.engines import dispatch as engines
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.estimation.quantities import BY_NAME, Quantity
from pendsim_mj.estimation.swing_frame import SwingFrame, fit_swing_frame
from pendsim_mj.estimation.timing import (
    DEFAULT_MAX_GAP_S,
    ClockRelation,
    Coverage,
    check_max_gap,
    coverage,
    fit_clock,
    fused_value_instants,
    fusion_phase,
    fusion_phase_stretch,
    nominal_rate_hz,
    roughness,
)
from pendsim_mj.rig.drives import Drive, Target, recorded_drive
from pendsim_mj.rig.params import RigParams
from pendsim_mj.sensors.bno055 import MIN_MOTION_RAD_S, ImuNoise

Floats = NDArray[np.float64]
StartKind = Literal["release", "in motion", "given"]

MIN_REST_S = 0.1  # rest this long before the motion makes it a release
ANGLE_SIGMA_RAD = 0.002  # weight of the fused angle in the start fit (the gyro's own sigma weights rates)
PHASE_STEP_S = 0.00025  # grid of the fusion-phase search
FIRST_SWING_S = 1.5  # M1's sign: its largest excursion this long after the start is positive
LARGE_SWING = 0.5  # the large swing: gyro magnitude above this share of its 99th percentile
UNEXPLAINED_REFUSED = 0.5  # a found start whose model leaves this share of the motion unexplained is refused
UNEXPLAINED_POOR = 0.03  # above this share the start fit is reported as poor (a 5 % frequency error gives 0.02)
FRAME_FIT_S = 600.0
"""The swing frames are fitted on the samples within this long of the start (before and after it),
s. The motion is what carries the mounting; a long run's later hours at rest add only noise to the
fit's kinematic columns, enough to flip its choice of handedness (a 6 h free decay: M2 found
mirrored, 80 mm from its hinge), and memory that grows with the run."""
TIMING_PROBE = 0.25  # the nodes' relative fusion timing is probed this share of its open range either side
TIMING_FIT_S = 3.0  # the start fit's window when it chooses that timing (at least start_fit_s), s
TIMING_MIN_RANGE_S = 1e-4  # a relative timing open by less than this is left as the nodes' own data give it, s


@dataclasses.dataclass(frozen=True)
class NodeSamples:
    """One node's samples as recorded: n of them, any spacing, gaps allowed.

    Attributes:
      log_t_s: (n,) when the recorder logged each sample, s on its clock.
      quat_wxyz: (n, 4) fused orientation (this and the two below float64, or float32 to save
        memory: ``bridge.recording.read_recording(sensor_float32=True)``).
      gyro_rad_s: (n, 3) angular velocity, sensor axes.
      accel_m_s2: (n, 3) acceleration with gravity (specific force), sensor axes.
      stamp_s: (n,) the node's own time stamps, s (None: use log_t_s).
      gyro_covariance: (3, 3) of the gyro noise, (rad/s)^2 (None or zeros: the BNO055's).
    """

    log_t_s: Floats
    quat_wxyz: Floats
    gyro_rad_s: Floats
    accel_m_s2: Floats
    stamp_s: Floats | None = None
    gyro_covariance: Floats | None = None


@dataclasses.dataclass(frozen=True)
class NodeRun:
    """One node's measured series from the start on (m samples, the node's own instants).

    Attributes:
      t_s: (m,) sample instants since the start, s (the recorder's clock).
      value_t_s: (m,) instants the values belong to (fused values are older than their
        samples), s since the start: where the model is evaluated.
      phi_rad, omega_rad_s: (m,) the pendulum's angle and rate in its swing frame.
      tangential_m_s2, normal_m_s2: (m,) accelerometer along the swing frame's tangential and
        toward-pivot directions (gravity included).
      frame: the node's swing frame (hinge axis, mounting).
      clock: its stamps' relation to the recorder's clock (None: its stamps were unusable and
        log times were used).
      fusion_phase_s: where its chip's fusion ticks fall on its clock (mod one fusion period), s;
        None without fusion timing.
      coverage: how much of the run its samples cover.
      gyro_sigma_rad_s: noise sigma of its rate, rad/s.
      off_hinge_gyro_rad_s: (m, 2) gyro along the swing frame's tangential and toward-pivot
        directions, rad/s: zero for a planar swing; the tilt rate of a spatial one (what
        ``pendsim_mj.estimation.spatial_identification`` fits).
      before_start: the node's samples left out as before the start: a hold before a release,
        or, for a start in motion or a given one, samples whose (fused) values are older than
        the start (the first sample of a recording that starts in motion: its value is up to one
        fusion period old).
    """

    t_s: Floats
    value_t_s: Floats
    phi_rad: Floats
    omega_rad_s: Floats
    tangential_m_s2: Floats
    normal_m_s2: Floats
    frame: SwingFrame
    clock: ClockRelation | None
    fusion_phase_s: float | None
    coverage: Coverage
    gyro_sigma_rad_s: float
    off_hinge_gyro_rad_s: Floats | None = None
    before_start: int = 0


@dataclasses.dataclass(frozen=True)
class StartState:
    """Where the run starts and the model with it.

    Attributes:
      kind: "release" (from rest, found in the data), "in motion" (the recording starts
        moving; the state at its first samples) or "given" (the caller's start instant).
      time_s: the start on the recorder's clock, s.
      phi_rad, omega_rad_s: (phi1, phi2) and (omega1, omega2) there (rates 0 for a release).
      fit_rms: rms of the start fit's residuals in units of their sigmas.
      unexplained: how much of the motion over the start fit's window after the start the model
        leaves unexplained: rms of the angle residuals over the rms of the angles' change since
        the start (both nodes); 0 is a perfect fit, 1 is no better than "nothing moves".
      fit_window_s: the start fit's window after the start, s.
    """

    kind: StartKind
    time_s: float
    phi_rad: tuple[float, float]
    omega_rad_s: tuple[float, float]
    fit_rms: float
    unexplained: float = 0.0
    fit_window_s: float = 1.0

    @property
    def poor_fit(self) -> bool:
        """The model does not explain the first seconds after the start (UNEXPLAINED_POOR)."""
        return not self.unexplained <= UNEXPLAINED_POOR

    def fit_note(self) -> str:
        """A warning when the fit is poor, else "" (one sentence)."""
        if not self.poor_fit:
            return ""
        return (
            f"poor start fit: the model leaves {100 * self.unexplained:.0f} % of the motion over the first "
            f"{self.fit_window_s:g} s unexplained; check the start (give --release-s) or the rig parameters"
        )


@dataclasses.dataclass(frozen=True)
class MeasuredRun:
    """Both nodes' measured series from the start (t = 0) on, and how they were aligned.

    ``relative_timing_range_s``: (lo_s < 0, hi_s > 0), the shifts of M2's value instants against
    M1's that the nodes' fusion timing still allows (their fusion phases are known only within a
    stretch each): a fit through the whole run (``planar_fit``) refines the timing within it;
    None where the timing is pinned or the nodes have no fusion timing."""

    nodes: tuple[NodeRun, NodeRun]
    start: StartState
    fusion_rate_hz: float | None
    max_gap_s: float
    relative_timing_range_s: tuple[float, float] | None = None

    def series(self, quantity: Quantity | str) -> tuple[Floats, Floats, Floats]:
        """(t_s, values, value_t_s) of a quantity (see ``pendsim_mj.estimation.quantities``), each (m,)."""
        q = BY_NAME[quantity] if isinstance(quantity, str) else quantity
        node = self.nodes[q.node]
        return node.t_s, getattr(node, q.attribute), node.value_t_s

    def both_nodes(self, field: str) -> Floats:
        """One per-node field (a ``NodeRun`` attribute of shape (m_k,), e.g. ``value_t_s``,
        ``omega_rad_s``) of both nodes as (m, 2) float64, NaN where a node has fewer samples."""
        m = max(len(n.t_s) for n in self.nodes)
        out = np.full((m, 2), np.nan)
        for k, node in enumerate(self.nodes):
            values = getattr(node, field)
            out[: len(values), k] = values
        return out

    @property
    def duration_s(self) -> float:
        """From the start to the later node's last sample, s."""
        return max(float(n.t_s[-1]) for n in self.nodes)

    @property
    def release_time_s(self) -> float:
        return self.start.time_s

    @property
    def release_angle_rad(self) -> tuple[float, float]:
        return self.start.phi_rad

    @property
    def gyro_sigma_rad_s(self) -> tuple[float, float]:
        return (self.nodes[0].gyro_sigma_rad_s, self.nodes[1].gyro_sigma_rad_s)


@dataclasses.dataclass(frozen=True)
class _Node:
    """A node's samples sorted, on the recorder's clock, with its swing-frame series."""

    t: Floats  # recorder clock
    stamp: Floats  # node clock (= t when the stamps are unusable)
    clock: ClockRelation | None
    quat: Floats
    gyro: Floats
    accel: Floats
    sigma: float
    rate_hz: float
    frame: SwingFrame | None = None
    series: dict[str, Floats] = dataclasses.field(default_factory=dict, repr=False, compare=False)
    """phi and omega in ``frame`` once computed: shared by the copies ``dataclasses.replace``
    makes with the same frame (a long run's whole-run series computed and held once)."""

    def with_frame(self, frame: SwingFrame) -> _Node:
        return dataclasses.replace(self, frame=frame, series={})

    def flipped(self) -> _Node:
        """This node in its frame's other sense (``SwingFrame.flipped``). The series it computed
        move to the copy, negated in place (phi and omega change sign with the frame; the
        whole run is not computed and held twice); this node computes them again if asked."""
        assert self.frame is not None
        series = {name: np.negative(values, out=values) for name, values in self.series.items()}
        self.series.clear()
        return dataclasses.replace(self, frame=self.frame.flipped(), series=series)

    @property
    def phi(self) -> Floats:
        """The angle (n,) in the swing frame, rad."""
        if "phi" not in self.series:
            assert self.frame is not None
            self.series["phi"] = self.frame.angle(self.quat)
        return self.series["phi"]

    @property
    def omega(self) -> Floats:
        """The rate (n,) about the hinge axis, rad/s."""
        if "omega" not in self.series:
            assert self.frame is not None
            self.series["omega"] = self.frame.rate(self.gyro)
        return self.series["omega"]

    def value_instants(self, fusion_rate_hz: float | None, phase_s: float | None) -> Floats:
        """Recorder-clock instants of the values (fused, with the given phase on the node clock)."""
        if not fusion_rate_hz or phase_s is None:
            return self.t
        fused = fused_value_instants(self.stamp, fusion_rate_hz, phase_s)  # a new array: mapped in place
        return self.clock.to_recorder_in_place(fused) if self.clock is not None else fused


def _floating(values: Floats) -> Floats:
    """values as a float array: float32 ones as they are (a long recording's sensor values; what
    is computed from them is float64), anything else as float64."""
    a = np.asarray(values)
    return a if a.dtype in (np.float32, np.float64) else a.astype(float)


HOLD_TEST_S = 30.0  # how much of the fastest swing tells held fused values from stamped ones, s


def _shows_fusion_hold(node: _Node, fusion_rate_hz: float, phase_s: float) -> bool:
    """Whether a node's values are a fused chip's held values: its gyro is smoother on the fused
    value instants (the latest fusion tick before each stamp) than on the stamps themselves.
    A BNO055 in NDOF mode shows it clearly (the roughness drops 5-70x on its own data); values
    sampled at their stamps (a simulation, another sensor, resampled logs) get 4-30x rougher on
    held instants, and pretending they were held misplaces them by up to one fusion period."""
    max_step = 2.5 / node.rate_hz
    # judged around the fastest swing (30 s): at rest, noise alone is rougher on held instants
    half = int(HOLD_TEST_S * node.rate_hz / 2)
    fastest = int(np.argmax(np.einsum("ij,ij->i", node.gyro, node.gyro)))
    near = slice(max(fastest - half, 0), fastest + half)
    stamp, gyro = node.stamp[near], node.gyro[near]
    held = roughness(fused_value_instants(stamp, fusion_rate_hz, phase_s), gyro, max_step)
    return held < roughness(stamp, gyro, max_step)


def _prepare(samples: NodeSamples, index: int) -> _Node:
    log = np.asarray(samples.log_t_s, dtype=float)
    n = len(log)
    shapes = {"quat_wxyz": (n, 4), "gyro_rad_s": (n, 3), "accel_m_s2": (n, 3)}
    for name, shape in shapes.items():
        if np.shape(getattr(samples, name)) != shape:
            got = np.shape(getattr(samples, name))
            raise ParameterError(f"node M{index + 1}: {name} must have shape {shape}, got {got}")
    if n < 100:
        raise RecordingError(f"node M{index + 1} has {n} samples; too few to align")
    stamp = log if samples.stamp_s is None else np.asarray(samples.stamp_s, dtype=float)
    order: slice | np.ndarray = slice(None)  # stamps increasing (the usual case): no copies
    if not np.all(np.diff(stamp) > 0):
        order = np.argsort(stamp, kind="stable")
        keep = np.ones(n, dtype=bool)
        keep[1:] = np.diff(stamp[order]) > 0  # duplicates: the first copy
        order = order[keep]
        stamp, log = stamp[order], log[order]
    clock = fit_clock(stamp, log) if samples.stamp_s is not None else None
    t = clock.to_recorder(stamp) if clock is not None else log
    if clock is None:
        stamp = log
    cov = samples.gyro_covariance
    sigma = float(ImuNoise().gyro_sigma_rad_s[2])
    node = _Node(
        t=t,
        stamp=stamp,
        clock=clock,
        quat=_floating(samples.quat_wxyz)[order],
        gyro=_floating(samples.gyro_rad_s)[order],
        accel=_floating(samples.accel_m_s2)[order],
        sigma=sigma,
        rate_hz=nominal_rate_hz(t),
    )
    if cov is not None and np.any(cov):
        return dataclasses.replace(node, sigma=-1.0)  # from the covariance once the hinge axis is known
    return node


def _gyro_sigma(node: _Node, cov: Floats | None) -> float:
    if node.sigma > 0 or cov is None or node.frame is None:
        return node.sigma
    a = node.frame.hinge_axis
    return float(math.sqrt(max(float(a @ np.asarray(cov) @ a), 1e-12)))


def _detect_start(nodes: Sequence[_Node]) -> tuple[StartKind, float]:
    """('release', coarse release instant) or ('in motion', first common instant)."""
    speeds = [np.linalg.norm(n.gyro, axis=1) for n in nodes]
    top = [float(np.quantile(s, 0.99)) for s in speeds]
    if max(top) < MIN_MOTION_RAD_S:
        raise RecordingError(
            f"no motion found: both gyros stay below {MIN_MOTION_RAD_S} rad/s (99th percentile "
            f"{max(top):.3g} rad/s); a static recording has no swing to validate"
        )
    # The pendulum that swings most was let go: its motion marks the start (a held one's wobble
    # could otherwise be taken for it).
    k = int(np.argmax(top))
    node, s, peak = nodes[k], speeds[k], top[k]
    i_big = int(np.argmax(s > LARGE_SWING * peak))  # the large swing (a hand's wobble stays far below)
    pre = s[node.t <= node.t[i_big] - 0.2]
    level = max(1.5 * float(np.quantile(pre, 0.95)), 0.03) if len(pre) >= 8 else 0.03
    i = i_big
    while i > 0 and s[i - 1] > level:  # back to the level of what came before it
        i -= 1
    while i > 0 and s[i - 1] < s[i]:  # and down the release's rising rate to its foot
        i -= 1
    rested = node.t[i] - node.t[0] >= MIN_REST_S
    if rested:
        before = s[(node.t >= node.t[i] - 0.5) & (node.t < node.t[i])]
        rested = len(before) >= 8 and float(np.mean(before <= level)) >= 0.9
    t_onset = float(node.t[i])
    if rested:
        return "release", t_onset - 0.5 / node.rate_hz
    return "in motion", max(float(n.t[0]) for n in nodes)


def _frame_window(instants: Floats, start_s: float) -> slice:
    """The samples (a slice of the increasing ``instants``, s) whose instants lie within
    ``FRAME_FIT_S`` of the start ``start_s`` (s): what the swing frame is fitted on."""
    lo, hi = np.searchsorted(instants, [start_s - FRAME_FIT_S, start_s + FRAME_FIT_S], side="left")
    return slice(int(lo), int(hi))


def _drive_onset_s(drive_input: tuple[Floats, Floats]) -> float | None:
    """When the recorded drive starts: the first step with an input (recorder's clock, s), None
    if it never has one."""
    t, held = drive_input
    active = np.flatnonzero(np.any(np.asarray(held) != 0, axis=1))
    return float(t[active[0]]) if len(active) else None


def _detect_driven_start(nodes: Sequence[_Node], onset_s: float) -> tuple[StartKind, float]:
    """A driven run starts where its drive starts (``onset_s``): ('release', onset_s) if the
    pendulum that moves most rests (hand wobble allowed) for the MIN_REST_S before it, else
    ('in motion', first common instant). Its large swing may come long after the start (a
    resonance building up), so it does not mark the start as it does for a free decay."""
    speeds = [np.linalg.norm(n.gyro, axis=1) for n in nodes]
    top = [float(np.quantile(s, 0.99)) for s in speeds]
    k = int(np.argmax(top))
    node, s = nodes[k], speeds[k]
    level = max(0.1 * top[k], 0.03)
    rested = onset_s - float(node.t[0]) >= MIN_REST_S
    if rested:
        before = s[(node.t >= onset_s - 0.5) & (node.t < onset_s)]
        rested = len(before) >= 8 and float(np.mean(before <= level)) >= 0.9
    if rested:
        return "release", onset_s
    return "in motion", max(float(n.t[0]) for n in nodes)


def _orient(nodes: list[_Node], t0: float, kind: StartKind) -> list[_Node]:
    """Signs: M1's largest excursion over the first swing positive (for a release from rest that
    is its release angle: its held angle decides, not a comparison with the next, hardly
    smaller, excursion on the other side); M2 coupled to M1 as the springs couple them (alpha2
    rises with phi1)."""
    m1, m2 = nodes
    assert m1.frame is not None and m2.frame is not None
    phi1 = m1.phi
    first = (m1.t >= t0) & (m1.t <= t0 + FIRST_SWING_S)
    largest = phi1[first][np.argmax(np.abs(phi1[first]))] if first.any() else 0.0
    held = phi1[(m1.t >= t0 - 0.1) & (m1.t <= t0)]
    if kind == "release" and len(held) and abs(float(np.median(held))) >= 0.5 * abs(largest):
        largest = float(np.median(held))
    if largest < 0:
        m1 = m1.flipped()
        phi1 = m1.phi
    # M2's sign from the first FRAME_FIT_S after the start (as its frame: the hours at rest of a
    # long run would add only noise to the regression, and memory)
    lo, hi = np.searchsorted(m2.t, [t0, t0 + FRAME_FIT_S])
    near = slice(max(int(lo) - 1, 0), int(hi) + 1)
    t2, phi2, omega2 = m2.t[near], m2.phi[near], m2.omega[near]
    span = t2[2:] - t2[:-2]
    ok = (span > 0) & (span < 3.0 / m2.rate_hz) & (t2[1:-1] >= t0)
    alpha2 = (omega2[2:] - omega2[:-2]) / np.where(span > 0, span, 1.0)
    phi1_at = np.interp(t2[1:-1], m1.t, phi1)
    design = np.stack([phi2[1:-1], phi1_at, omega2[1:-1], np.ones(len(span))], axis=1)[ok]
    if len(design) > 10:
        coef, *_ = np.linalg.lstsq(design, alpha2[ok], rcond=None)
        if coef[1] < 0:
            m2 = m2.flipped()
    return [m1, m2]


@dataclasses.dataclass(frozen=True)
class _StartModel:
    """The model of the run's first seconds, parametrised for the start fit."""

    kind: StartKind
    t0: float  # the fixed start (in motion, given) or the first guess of the release
    params: RigParams
    engine: str
    horizon_s: float
    drive_input: tuple[Floats, Floats] | None = None  # (t_s on the recorder's clock, held (n, 4))

    @property
    def timed(self) -> bool:
        """The values' instants get a common shift fitted too (``shift_s``): a driven run that
        starts in motion. The drive is fixed on the recorder's clock, so a few ms error of the
        fused values' instants (the fusion phase) is no longer absorbed by the start state as it
        is in a free decay; a release fits its instant, which the drive starts with, instead."""
        return self.drive_input is not None and self.kind == "in motion"

    def shift_s(self, x: Floats) -> float:
        """The shift of the values' instants, s: a value at ``at`` belongs to at + shift."""
        return float(x[4]) if self.timed else 0.0

    def drive(self) -> Drive | None:
        """The recorded drive from t0 on (None: a free run). A driven release starts at t0, its
        drive's onset; the fitted release instant then moves the drive with it (it absorbs an
        error of the values' instants: ``align`` turns it into their shift)."""
        if self.drive_input is None:
            return None
        return recorded_drive(*self.drive_input, self.t0, until_s=self.horizon_s + 0.1)

    def states(self, x: Floats) -> tuple[Floats, Floats, float]:
        """(phi0 (2,), omega0 (2,), start instant) of a parameter vector."""
        if self.kind == "release":
            return x[1:3], np.zeros(2), float(x[0])
        return x[0:2], x[2:4], self.t0

    def rollouts(self, xs: Sequence[Floats]):
        phi0 = np.array([self.states(x)[0] for x in xs])
        omega0 = np.array([self.states(x)[1] for x in xs])
        drive = self.drive()
        duration = engines.whole_steps_s(self.horizon_s)
        return engines.run_batch(self.engine, self.params, phi0, omega0, duration, drive=drive)


def _predict(traj_t: Floats, phi: Floats, omega: Floats, at: Floats, rest_phi: float | None) -> tuple[Floats, Floats]:
    """A member's phi, omega (n,) at instants ``at`` since its start (at rest before it): cubic
    Hermite interpolation through phi and its derivative omega (and omega through its own
    derivative, by central differences), fourth order in the step."""
    h = float(traj_t[1] - traj_t[0])
    inside = np.clip(at, 0.0, traj_t[-1])
    i = np.clip((inside / h).astype(int), 0, len(traj_t) - 2)
    s = inside / h - i
    alpha = np.gradient(omega, h)
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    p = h00 * phi[i] + h10 * h * omega[i] + h01 * phi[i + 1] + h11 * h * omega[i + 1]
    w = h00 * omega[i] + h10 * h * alpha[i] + h01 * omega[i + 1] + h11 * h * alpha[i + 1]
    if rest_phi is not None:
        p = np.where(at < 0, rest_phi, p)
        w = np.where(at < 0, 0.0, w)
    return p, w


def _residuals(model: _StartModel, traj, member: int, x: Floats, data) -> Floats:
    phi0, _, start = model.states(x)
    start -= model.shift_s(x)
    out = []
    for k, (at, phi, omega, sigma) in enumerate(data):
        rest = float(phi0[k]) if model.kind == "release" else None
        p, w = _predict(traj.t_s, traj.phi_rad[member, :, k], traj.omega_rad_s[member, :, k], at - start, rest)
        out += [(p - phi) / ANGLE_SIGMA_RAD, (w - omega) / sigma]
    return np.concatenate(out)


def _fit_start(model: _StartModel, x0: Floats, data, *, iterations: int = 8) -> tuple[Floats, float, float]:
    """Gauss-Newton on the start parameters; the Jacobian by finite differences, one batch of
    rollouts per iteration (a shift of the release instant needs no rollout)."""
    x = np.asarray(x0, dtype=float)
    steps = np.full(len(x), 1e-5)
    rolled = list(range(len(x)))
    if model.kind == "release":
        steps[0] = 1e-4
        rolled = rolled[1:]
    if model.timed:  # the values' shift: no rollout either
        steps[4] = 1e-4
        rolled.remove(4)
    cost = math.inf
    previous = x
    for _ in range(iterations):
        xs = [x] + [x + steps[j] * np.eye(len(x))[j] for j in rolled]
        batch = model.rollouts(xs)
        r0 = _residuals(model, batch, 0, x, data)
        columns = []
        for j in range(len(x)):
            if j in rolled:
                rj = _residuals(model, batch, 1 + rolled.index(j), xs[1 + rolled.index(j)], data)
            else:
                rj = _residuals(model, batch, 0, x + steps[j] * np.eye(len(x))[j], data)
            columns.append((rj - r0) / steps[j])
        jac = np.stack(columns, axis=1)
        new_cost = float(r0 @ r0)
        if new_cost > cost * (1 + 1e-9):  # the last step overshot: go half way back
            x = 0.5 * (x + previous)
            continue
        cost, previous = new_cost, x
        delta, *_ = np.linalg.lstsq(jac, -r0, rcond=None)
        x = x + delta
        if np.all(np.abs(delta) < 1e-6):  # 1 us, 1 urad, 1 urad/s
            break
    batch = model.rollouts([x])
    r = _residuals(model, batch, 0, x, data)
    return x, float(np.sqrt(np.mean(r * r))), _unexplained(model, batch, x, data)


def _unexplained(model: _StartModel, traj, x: Floats, data) -> float:
    """rms of the model's angle residuals after the start over the rms of the measured angles'
    change since the start (both nodes): 0 a perfect fit, about 1 or more a model that does not
    describe what follows the start at all."""
    phi0, _, start = model.states(x)
    start -= model.shift_s(x)
    residual, motion = [], []
    for k, (at, phi, _omega, _sigma) in enumerate(data):
        after = at >= start
        p, _ = _predict(traj.t_s, traj.phi_rad[0, :, k], traj.omega_rad_s[0, :, k], at[after] - start, None)
        residual.append(p - phi[after])
        motion.append(phi[after] - phi0[k])
    r, m = np.concatenate(residual), np.concatenate(motion)
    if len(r) == 0:
        return math.inf
    return float(np.sqrt(np.mean(r * r)) / max(float(np.sqrt(np.mean(m * m))), 1e-9))


def _check_found_start(
    start: StartState,
    detected_s: float,
    nodes: Sequence[_Node],
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


def _fit_data(nodes: Sequence[_Node], instants: Sequence[Floats], lo: float, hi: float):
    """Per node (value instants, phi, omega, sigma) of the samples whose values lie in [lo, hi]."""
    out = []
    for node, at in zip(nodes, instants, strict=True):
        inside = (at >= lo) & (at <= hi)
        out.append((at[inside], node.phi[inside], node.omega[inside], node.sigma))
    return out


def _mirrored_differs(drive: Drive | None) -> bool:
    """The mirror image of the run (both angles negated) is driven differently: a hinge torque or
    a sideways support acceleration changes sign under it; a vertical one does not."""
    return drive is not None and any(t is not Target.PIVOT_Z for t in drive.targets)


def _start_fit(
    model: _StartModel,
    nodes: Sequence[_Node],
    instants: Sequence[Floats],
    start_fit_s: float,
    x0: Floats | None = None,
    iterations: int = 8,
) -> tuple[Floats, float, float]:
    """The start parameters fitted from the nodes' series at model.t0: (x, rms, unexplained) of
    ``_fit_start`` (at most ``iterations`` steps), from ``x0`` (None: from the series at t0)."""
    t0, kind = model.t0, model.kind
    lo = t0 - 0.3 if kind == "release" else t0
    hi = t0 + start_fit_s
    phi_now = [float(np.interp(t0, at, n.phi)) for n, at in zip(nodes, instants, strict=True)]
    omega_now = [float(np.interp(t0, at, n.omega)) for n, at in zip(nodes, instants, strict=True)]
    if kind == "release":
        held = [n.phi[(at >= t0 - 0.3) & (at <= t0)] for n, at in zip(nodes, instants, strict=True)]
        x = np.array([t0] + [float(np.mean(h)) if len(h) else p for h, p in zip(held, phi_now, strict=True)])
    else:
        x = np.array(phi_now + omega_now + ([0.0] if model.timed else []))
    return _fit_start(model, x if x0 is None else x0, _fit_data(nodes, instants, lo, hi), iterations=iterations)


def _relative_fusion_timing(
    model: _StartModel,
    nodes: Sequence[_Node],
    phases: Sequence[float],
    fusion_rate_hz: float,
    start_fit_s: float,
    fitted: tuple[Floats, float, float],
) -> tuple[list[float], list[Floats], tuple[Floats, float, float], tuple[float, float] | None]:
    """The nodes' fusion phases (s) within their stretches (``timing.fusion_phase_stretch``).

    A node's own data leave its phase open within its stretch (2.5 ms wide at 80 Hz sampling of
    100 Hz fusion, each estimate within 1.25 ms). A common shift of both nodes' values is absorbed
    by the start fit (the release instant, the state in motion, a driven run's fitted shift); the
    shift of one node's values against the other's is not, and it costs the damping fit (a ms
    reads as dry friction). So that relative shift, anywhere both stretches allow (up to 5 ms
    wide: node 1's phase is as open as node 2's), is chosen by the start fit over TIMING_FIT_S:
    its cost (mean square residual in sigmas, the start re-fitted) is quadratic in a shift of a few
    ms on swings of about a second, so three probes (one Gauss-Newton step from ``fitted`` each)
    give the parabola whose vertex, held inside that range, is taken. Each node then keeps the
    middle of the phases its stretch allows with that relative shift, and the start is fitted
    there as before. Only the value instants and the start fit change: a ms does not move the
    swing frames.

    Args:
      model, nodes, start_fit_s: as for ``_start_fit``.
      phases: (2,) each node's phase from its own data (``timing.fusion_phase``), s.
      fusion_rate_hz: the chips' fusion rate, Hz.
      fitted: ``_start_fit``'s (x, rms, unexplained) at those phases.

    Returns:
      The chosen phases (2,), s in [0, 1 / fusion_rate_hz); the value instants (recorder clock,
      s) at them; the start fit there (x, rms, unexplained); the shifts of node 2's values
      against node 1's that both stretches still allow about the choice, (lo_s < 0, hi_s > 0) s
      (None: the timing was pinned, nothing was chosen).
    """
    period = 1.0 / fusion_rate_hz
    # each node's phase may move by d with lo < d <= hi (its stretch about its phase); 1 us margins
    room = []
    for node, phase in zip(nodes, phases, strict=True):
        lo, hi = fusion_phase_stretch(node.stamp, fusion_rate_hz, phase)
        room.append((lo - phase + 1e-6, hi - phase - 1e-6))
    (lo1, hi1), (lo2, hi2) = room
    r_lo, r_hi = lo2 - hi1, hi2 - lo1  # node 2's shift against node 1's: d2 - d1

    def split(r: float) -> tuple[float, float]:
        d1 = 0.5 * (max(lo1, lo2 - r) + min(hi1, hi2 - r))  # the middle of what both stretches allow
        return d1, d1 + r

    def moved(r: float) -> list[Floats]:
        return [n.value_instants(fusion_rate_hz, p + d) for n, p, d in zip(nodes, phases, split(r), strict=True)]

    if not (r_lo < 0.0 < r_hi and r_hi - r_lo >= TIMING_MIN_RANGE_S):  # pinned by clocks sweeping the period
        given = [n.value_instants(fusion_rate_hz, p) for n, p in zip(nodes, phases, strict=True)]
        return list(phases), given, fitted, None
    window_s = max(start_fit_s, TIMING_FIT_S)
    longer = dataclasses.replace(model, horizon_s=model.horizon_s + window_s - start_fit_s)
    probe = TIMING_PROBE * (r_hi - r_lo)
    r = np.array([max(-probe, r_lo), 0.0, min(probe, r_hi)])
    # one Gauss-Newton step from the start fit's x: the cost with the start re-fitted, to second order
    cost = [_start_fit(longer, nodes, moved(float(v)), window_s, x0=fitted[0], iterations=1)[1] ** 2 for v in r]
    curvature, slope, _ = np.polyfit(r, cost, 2)
    best = float(np.clip(-slope / (2 * curvature), r_lo, r_hi)) if curvature > 0 else float(r[np.argmin(cost)])
    best = min(max(best, r_lo + 1e-6), r_hi - 1e-6)  # strictly inside: the damping fit refines it within
    instants = moved(best)
    chosen = _start_fit(model, nodes, instants, start_fit_s, x0=fitted[0])
    chosen_phases = [(p + d) % period for p, d in zip(phases, split(best), strict=True)]
    return chosen_phases, instants, chosen, (r_lo - best, r_hi - best)


def _owned(a: Floats, samples: NodeSamples) -> bool:
    """``a`` is an array alignment made itself (no view of the caller's sample times)."""
    theirs = [samples.log_t_s] + ([] if samples.stamp_s is None else [samples.stamp_s])
    return not any(np.may_share_memory(a, b) for b in theirs)


def _node_run(
    node: _Node,
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
    fusion_rate_hz: float | None = 100.0,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    start_fit_s: float = 1.0,
    engine: str = "mujoco",
    drive_input: tuple[Floats, Floats] | None = None,
    off_hinge: bool = True,
    float32_values: bool = False,
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

    Raises:
      RecordingError: too few samples, no motion, no swing to find a frame in.
      ParameterError: bad options (release_s outside the samples, shapes).
    """
    if len(nodes) != 2:
        raise ParameterError(f"align needs the two nodes (M1, M2), got {len(nodes)}")
    check_max_gap(max_gap_s)
    prepared = [_prepare(n, k) for k, n in enumerate(nodes)]
    onset_s = None
    if drive_input is not None:
        drive_input = (np.asarray(drive_input[0], dtype=float), np.asarray(drive_input[1], dtype=float))
        onset_s = _drive_onset_s(drive_input)
        if onset_s is None:  # a drive topic that never drives: a free run
            drive_input = None
    phases: list[float | None] = [None, None]
    timing_range: tuple[float, float] | None = None
    if fusion_rate_hz:  # where each chip's fusion ticks fall: the phase that makes its gyro smoothest
        estimated = [fusion_phase(n.stamp, n.gyro, fusion_rate_hz) for n in prepared]
        if any(_shows_fusion_hold(n, fusion_rate_hz, p) for n, p in zip(prepared, estimated, strict=True)):
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
        kind, t0 = _detect_driven_start(prepared, onset_s)
    else:
        kind, t0 = _detect_start(prepared)
    frames = []
    for k, node in enumerate(prepared):
        near = _frame_window(instants[k], t0)
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
    prepared = _orient(frames, t0, kind)
    prepared = [dataclasses.replace(n, sigma=_gyro_sigma(n, nodes[k].gyro_covariance)) for k, n in enumerate(prepared)]

    # Start state: least squares of the model's first seconds against both nodes.
    model = _StartModel(kind, t0, params, engine, start_fit_s + 0.6, drive_input)
    x, rms, unexplained = _start_fit(model, prepared, instants, start_fit_s)
    if drive_input is not None and _mirrored_differs(model.drive()):
        # the drive has a sense (a torque, a sideways support): the frames' sign must match it
        flipped = [n.with_frame(n.frame.flipped()) for n in prepared if n.frame is not None]
        x_f, rms_f, unexplained_f = _start_fit(model, flipped, instants, start_fit_s)
        if rms_f < rms:
            prepared, x, rms, unexplained = flipped, x_f, rms_f, unexplained_f
    if fusion_rate_hz:  # the nodes' relative fusion timing, which their own data leave open
        found = [p for p in phases if p is not None]
        chosen, instants, (x, rms, unexplained), timing_range = _relative_fusion_timing(
            model, prepared, found, fusion_rate_hz, start_fit_s, (x, rms, unexplained)
        )
        phases = list(chosen)
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
    )
