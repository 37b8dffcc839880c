"""Alignment, node by node: each node's samples on the recorder's clock (``prepare_node``),
whether its values are a fused chip's held values (``shows_fusion_hold``), where the run starts
(``detect_start``, ``detect_driven_start``: steps 1-2 of ``pendsim_mj.estimation.alignment``),
and the samples its swing frame is fitted on and the frames' signs (``frame_window``,
``orient``: step 3). The parts of ``alignment.align``; no public API of their own.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.estimation.measured_run import Floats, NodeSamples, StartKind
from pendsim_mj.estimation.swing_frame import SwingFrame
from pendsim_mj.estimation.timing import (
    ClockRelation,
    ClockStep,
    clock_steps,
    fit_clock,
    fused_value_instants,
    nominal_rate_hz,
    roughness,
)
from pendsim_mj.sensors.bno055 import MIN_MOTION_RAD_S, ImuNoise

MIN_REST_S = 0.1  # rest this long before the motion makes it a release
FIRST_SWING_S = 1.5  # M1's sign: its largest excursion this long after the start is positive
LARGE_SWING = 0.5  # the large swing: gyro magnitude above this share of its 99th percentile
FRAME_FIT_S = 600.0
"""The swing frames are fitted on the samples within this long of the start (before and after it),
s. The motion is what carries the mounting; a long run's later hours at rest add only noise to the
fit's kinematic columns, enough to flip its choice of handedness (a 6 h free decay: M2 found
mirrored, 80 mm from its hinge), and memory that grows with the run."""


@dataclasses.dataclass(frozen=True)
class AlignedNode:
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
    steps: tuple[ClockStep, ...] = ()  # steps of a lab file's time column found and removed
    series: dict[str, Floats] = dataclasses.field(default_factory=dict, repr=False, compare=False)
    """phi and omega in ``frame`` once computed: shared by the copies ``dataclasses.replace``
    makes with the same frame (a long run's whole-run series computed and held once)."""

    def with_frame(self, frame: SwingFrame) -> AlignedNode:
        return dataclasses.replace(self, frame=frame, series={})

    def flipped(self) -> AlignedNode:
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


def shows_fusion_hold(node: AlignedNode, fusion_rate_hz: float, phase_s: float) -> bool:
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


def prepare_node(
    samples: NodeSamples, index: int, *, find_steps: bool = False, known_steps: Sequence[tuple[float, float]] = ()
) -> AlignedNode:
    """A node's samples sorted by stamp, on the recorder's clock (``fit_clock``); ``find_steps``:
    its times are a lab file's column, whose steps (a logging host's clock set back or forward)
    are found and removed (``timing.clock_steps``, ``known_steps`` its ``known``), kept in
    ``steps``."""
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
    steps: list[ClockStep] = []
    if find_steps:
        regular, steps = clock_steps(stamp, _floating(samples.gyro_rad_s)[order], known_steps)
        if steps:
            removed = stamp - regular
            stamp, log = regular, log - removed
    clock = fit_clock(stamp, log) if samples.stamp_s is not None else None
    t = clock.to_recorder(stamp) if clock is not None else log
    if clock is None:
        stamp = log
    cov = samples.gyro_covariance
    sigma = float(ImuNoise().gyro_sigma_rad_s[2])
    node = AlignedNode(
        t=t,
        stamp=stamp,
        clock=clock,
        quat=_floating(samples.quat_wxyz)[order],
        gyro=_floating(samples.gyro_rad_s)[order],
        accel=_floating(samples.accel_m_s2)[order],
        sigma=sigma,
        rate_hz=nominal_rate_hz(t),
        steps=tuple(steps),
    )
    if cov is not None and np.any(cov):
        return dataclasses.replace(node, sigma=-1.0)  # from the covariance once the hinge axis is known
    return node


def gyro_sigma(node: AlignedNode, cov: Floats | None) -> float:
    if node.sigma > 0 or cov is None or node.frame is None:
        return node.sigma
    a = node.frame.hinge_axis
    return float(math.sqrt(max(float(a @ np.asarray(cov) @ a), 1e-12)))


def detect_start(nodes: Sequence[AlignedNode]) -> tuple[StartKind, float]:
    """('release', coarse release instant) or ('in motion', first common instant)."""
    speeds = [np.linalg.norm(n.gyro, axis=1) for n in nodes]
    top = [float(np.quantile(s, 0.99)) for s in speeds]
    if max(top) < MIN_MOTION_RAD_S:
        raise RecordingError(
            f"no motion found: both gyros stay below {MIN_MOTION_RAD_S} rad/s (99th percentile "
            f"{max(top):.3g} rad/s); a static recording has no swing to fit or compare (its noise: 'pendsim allan')"
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


def frame_window(instants: Floats, start_s: float) -> slice:
    """The samples (a slice of the increasing ``instants``, s) whose instants lie within
    ``FRAME_FIT_S`` of the start ``start_s`` (s): what the swing frame is fitted on."""
    lo, hi = np.searchsorted(instants, [start_s - FRAME_FIT_S, start_s + FRAME_FIT_S], side="left")
    return slice(int(lo), int(hi))


def drive_onset_s(drive_input: tuple[Floats, Floats]) -> float | None:
    """When the recorded drive starts: the first step with an input (recorder's clock, s), None
    if it never has one."""
    t, held = drive_input
    active = np.flatnonzero(np.any(np.asarray(held) != 0, axis=1))
    return float(t[active[0]]) if len(active) else None


def detect_driven_start(nodes: Sequence[AlignedNode], onset_s: float) -> tuple[StartKind, float]:
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


def orient(nodes: list[AlignedNode], t0: float, kind: StartKind) -> list[AlignedNode]:
    """Signs: M1's largest excursion over the first swing positive (for a release from rest that
    is its release angle: its held angle decides, not a comparison with the next, hardly
    smaller, excursion on the other side); M2 coupled to M1 as the springs couple them (alpha2
    rises with phi1) as a first guess only: after a release in mode 1 the regression's two angle
    columns are nearly collinear and it can read M2 mirrored, so ``start_fit.sense_and_timing``
    decides M2's sense by the fit of the model."""
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
