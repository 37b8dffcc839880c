"""One node's samples turned into what the twin's estimator takes: the instant its value stands
for, its swing angle about the hinge and its hinge rate (the live twin's measurement front end).

A real BNO055 node differs from the model's ideal one in two ways this module learns from the
node's own samples, as they come:

- **Fusion timing.** The chip fuses at 100 Hz on its own clock; the node samples at 80 Hz on
  its clock and reads the latest fused value, so each value is 0-10 ms older than its sample's
  instant, in a pattern that repeats every four samples and is set by where the fusion ticks
  fall (the fusion phase). The phase is found by the values' own smoothness (as
  ``estimation.timing.fusion_phase`` does for a recording): for each candidate phase on a grid
  over one fusion period, the gyro's second divided differences over the value instants that
  phase gives, squared and summed with exponential forgetting (``phase_memory_s``) over the
  samples taken while the node swings. Wrong instants make the gyro rough; the true phase makes
  it smooth. A drifting phase (the chip's oscillator against the twin's clock) is followed by a
  second grid that moves at the drift the found phase shows (``FusionPhase``). The data
  decide the phase only up to a *stretch*: between two of the samples'
  own phases in the fusion period every value instant moves alike, so the values fit all of
  them equally (80 Hz samples of 100 Hz fusion on one clock: a stretch 2.5 ms wide, one quarter
  of the period; a drift between the clocks narrows it). The middle is taken, within half the
  stretch of the truth. Each value's instant is then the latest fusion tick at or before its
  sample's instant.
- **Frames.** The NDOF heading is arbitrary, the node is glued on by hand (mount
  misalignment), its axes may be remapped, the fused orientation drifts slowly (fusion error).
  The node's swing frame is found from a window of its samples while it swings (``learn_s`` of
  samples whose hinge rate reaches ``swing_rad_s``), at their value instants, by
  ``estimation.swing_frame.fit_swing_frame``: the hinge axis from the gyro, the reference
  orientation from the window's first sample (the heading drops out: angles are twists from a
  reference), and where phi = 0 from the accelerometer (gravity against the swing's
  kinematics). Its sense is the start frame's (the model's mount by default): the found hinge
  axis is turned to agree with the start frame's hinge axis.

Until both are known a sample gives a ``Waiting`` with the reason; from then on each sample gives
a ``NodeSample`` at once (nothing is held back: latency is the caller's transport alone). The
learned timing and frame are reported by ``NodeMeasurement.learned`` (``Learned``), for the
twin's recording. No I/O.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections import deque

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj import compile_notice
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.estimation.swing_frame import SwingFrame, dominant_axis, fit_swing_frame
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import FUSION_RATE_HZ, QUAT_LSB, SAMPLE_RATE_HZ

Floats = NDArray[np.float64]

compile_notice.watch()  # the cache folder; one line on a cold compile (the CLI prints it)

# The swing angle's noise on a node at any orientation: the twist is read from all four quantised
# components of conj(reference) q, whose rounding (variance LSB^2/12 each) is isotropic in the
# quaternion's 4 dimensions, and the angle is twice the displacement along the swing's tangent:
# sigma = 2 LSB / sqrt(12) = LSB / sqrt(3) = 3.5e-5 rad (measured on the sensor model with a 2 deg
# mount misalignment and a heading: the innovations' spread 0.93-1.0 of it). The model's own mount
# leaves two components exactly zero, which gives LSB sqrt(2/3) (``bno055.SWING_ANGLE_SIGMA_RAD``);
# a heading, a fusion error or a mount askew by a fraction of a degree makes them nonzero
# (``NodeMeasurement.angle_sigma_rad`` tells the two apart from the node's own quaternions).
TWIST_SIGMA_RAD = QUAT_LSB / math.sqrt(3.0)
TIED_SAMPLES = 80  # the last second of quaternions the angle's rounding noise is averaged over
PHASE_STEP_S = 0.25e-3  # the fusion phase's grid, s (40 candidates over a 10 ms period)
PHASE_MOTION_RAD_S = 0.2  # only samples turning faster than this tell the phase (at rest: noise alone)
PHASE_SAMPLES = 60  # swinging samples (forgetting weighted) before the phase is taken, 0.75 s at 80 Hz
DEFAULT_LEARN_S = 1.0  # the frame is fitted on this long of samples, s (most of a 1.3 s swing)
DEFAULT_SWING_RAD_S = 0.5  # ... once the node's rate reaches this within them (10x the rest threshold)
DEFAULT_PHASE_MEMORY_S = 10.0  # the phase's roughness sums forget with this time constant, s
ESTIMATE_EVERY_S = 0.1  # the phase's estimate is found anew this often, s
RATE_WINDOW_S = 30.0  # the phase's drift is fitted to at most this long of its estimates, s ...
RATE_MIN_SPAN_S = 5.0  # ... and at least this long ...
RATE_SLOPE_Z = 3.0  # ... and followed when its slope is this many of its standard errors ...
RATE_MIN_S_S = 2e-6  # ... and at least this (2 ppm: 0.5 grid steps a minute) ...
RATE_MAX_S_S = 2e-3  # ... up to this (a 2000 ppm oscillator); the fit's rms about its line below ...
RATE_FIT_RMS_S = 0.5 * PHASE_STEP_S  # ... this (a steady drift, not a stretch that jumped), s
SWITCH_MARGIN = 0.01  # the estimate changes grid when the other's roughness is this share lower
GAP_PERIODS = 2.5  # triples spanning more than this many sample periods (a loss) are skipped
MOVING_SHARE = 0.75  # the frame's window: this share of its samples turning faster than PHASE_MOTION_RAD_S
RADIUS_TOLERANCE = 0.3  # a fitted frame more than this share off the start frame's radius is refused
RETRY_S = 0.25  # a refused fit is tried again this long after, s
AXIS_MOTION_RAD_S = 0.05  # the gravity frame's hinge axis from the gyro: samples turning faster than this
AXIS_SAMPLES = 40  # ... at least this many of them in the last window (half a second at 80 Hz)
AXIS_MAX_DEG = 10.0  # ... and within this of the start frame's axis (a node glued on by hand)
FALLBACK_S = 3.0  # the twin's session falls a node back on the gravity frame (``fall_back``) when it
# still has none this long after the other node measures: a node that barely swings (M2 when M1
# alone is released) never gives a window to fit


def gravity_frame(start: SwingFrame, quat_wxyz: Floats) -> SwingFrame:
    """The start frame's axes with its reference orientation taken from one sample: the swing
    angle at that sample read from gravity in the node's frame (its fused orientation's world z is
    up, whatever its heading), phi = atan2(-g . tangential, -g . toward_pivot), and the reference
    the orientation turned back by phi about the hinge. The heading drops out; what the mount's
    misalignment leaves is a small constant offset (the twin tracks each node's offset)."""
    q = np.asarray(quat_wxyz, dtype=float)
    g = rotations.to_matrix(q).T @ np.array([0.0, 0.0, -1.0])  # gravity's direction in the node's axes
    phi = math.atan2(-float(g @ start.tangential), -float(g @ start.toward_pivot))
    reference = rotations.multiply(q, rotations.from_rotvec(np.asarray(start.quat_axis) * -phi))
    return dataclasses.replace(start, reference_quat_wxyz=reference / np.linalg.norm(reference), angle_offset_rad=0.0)


def model_mount_frame(radius_m: float) -> SwingFrame:
    """The swing frame of a node mounted as the model mounts it (x tangential, y toward the pivot,
    z along the hinge; the reference the site's orientation at phi = 0, heading 0): the start
    frame (``bridge.acquire.udp_loop.node_view.model_frames`` gives the same for both nodes)."""
    z, y, x = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])
    return SwingFrame(
        hinge_axis=z, toward_pivot=y, tangential=x, radius_m=float(radius_m), quat_axis=z,
        reference_quat_wxyz=rotations.IMU_SITE_QUAT_WXYZ.copy(), angle_offset_rad=0.0, mirrored=False,
        fit_rms_m_s2=0.0,
    )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Learned:
    """What a node's measurement has learned (for the twin's recording).

    Attributes:
      node: 0 (M1) or 1 (M2).
      fusion_phase_s: where the chip's fusion ticks fall on the twin's clock, s in [0, period)
        (None: not yet, or a node without fusion timing).
      phase_stretch_s: (lo, hi) the phases the data cannot tell apart, s (hi - lo: twice the
        phase's largest error; lo may be negative and hi past the period: not reduced).
      phase_drift_ppm: how fast the ticks move on the twin's clock, ppm (us per s; negative: the
        chip's clock runs fast against the twin's); 0 while the fixed grid explains the data
        better (``FusionPhase``); None with the phase.
      phase_moving_unfollowed: (ppm, ms) where the phase found over the last 30 s moves (its line's
        slope at least 3 standard errors) but scatters about that line by more than half a grid
        step, so that no rate is followed: the ticks drift too fast for the roughness sums (seen
        from about 300 ppm) or jumped (the twin's clock for that node moved); the slope of the
        most precise such line since the phase last held steady, ppm, and its scatter's rms, ms.
        None otherwise.
      frame: the node's swing frame (None: not yet).
      frame_t_s: the instant of the last sample of the window the frame was fitted on, s.
      hinge_to_start_deg: the angle between the found hinge axis and the start frame's, deg.
      sense_from_start: the frame's sense was taken from the start frame (False: the hinge axis
        was found more than 60 deg from it, and the fit's own sense kept).
    """

    node: int
    fusion_phase_s: float | None
    phase_stretch_s: tuple[float, float] | None
    phase_drift_ppm: float | None
    frame: SwingFrame | None
    frame_t_s: float | None
    hinge_to_start_deg: float | None
    sense_from_start: bool | None
    phase_moving_unfollowed: tuple[float, float] | None = None


@dataclasses.dataclass(frozen=True)
class NodeSample:
    """One sample, ready for ``RigEstimator.update(t_s, node, phi_rad, omega_rad_s)`` and
    ``RigEstimator.update_accel(t_s, node, accel_tangential_m_s2, accel_normal_m_s2)``.

    Attributes:
      t_s: the instant its value stands for (the twin's clock), s.
      phi_rad: the swing angle, rad. omega_rad_s: the hinge rate, rad/s.
      sample_t_s: the instant the node took it, s (t_s <= sample_t_s).
      accel_tangential_m_s2, accel_normal_m_s2: the accelerometer (gravity included) along the
        swing frame's tangent and toward the pivot, m/s^2 (r alpha + g sin phi, r omega^2 + g cos phi).
    """

    t_s: float
    phi_rad: float
    omega_rad_s: float
    sample_t_s: float
    accel_tangential_m_s2: float = math.nan
    accel_normal_m_s2: float = math.nan


@dataclasses.dataclass(frozen=True)
class Waiting:
    """A sample that gives no measurement yet; ``reason`` says what is still being learned."""

    reason: str


@numba.njit(cache=True, error_model="numpy")
def add_roughness(
    cost: Floats,
    phases_s: Floats,
    shift_s: float,
    period_s: float,
    t0_s: float,
    t1_s: float,
    t2_s: float,
    d11: float,
    d12: float,
    d22: float,
    forget: float,
) -> None:
    """``FusionPhase.add``'s sums, in place: cost (2 k,) (the fixed grid's k candidate phases
    ``phases_s``, then the moving grid's, shifted by ``shift_s``) forgotten by ``forget`` and each
    candidate's squared second divided difference of the gyro added over three samples at t0, t1,
    t2 (s), their values at the ticks at or before them: |d2 / h2 - d1 / h1|^2 (2 / (h1 + h2))^2
    with the gyro's differences' dot products d1.d1, d1.d2, d2.d2 ((rad/s)^2) and the value
    instants' spacings h1, h2 (two samples on one tick: an infinite roughness, that phase ruled
    out)."""
    k = phases_s.shape[0]
    for j in range(2 * k):
        phase = phases_s[j % k] + (shift_s if j >= k else 0.0)
        v0 = phase + period_s * math.floor((t0_s - phase) / period_s + 1e-9)
        v1 = phase + period_s * math.floor((t1_s - phase) / period_s + 1e-9)
        v2 = phase + period_s * math.floor((t2_s - phase) / period_s + 1e-9)
        h1, h2 = v1 - v0, v2 - v1
        second = d22 / (h2 * h2) - 2.0 * d12 / (h1 * h2) + d11 / (h1 * h1)
        scale = 2.0 / (h1 + h2)
        cost[j] = cost[j] * forget + second * (scale * scale)


class FusionPhase:
    """The chip's fusion phase on the twin's clock, tracked sample by sample (module docstring).

    Two grids of candidate phases take every sample: one fixed on the twin's clock (a chip
    fusing on the clock the samples' instants are on) and one that moves with the phase's drift
    as the data show it (``rate_s_s``: a chip fusing on its own oscillator, or on the node's
    clock while the instants are the host's: tens of ppm move the ticks 0.5 ms every 10 s at 50
    ppm, which the sums' memory alone follows a memory behind, M2's NIS 24 on a 90 s replay).
    The estimate is the grid whose smallest roughness is lower (by ``SWITCH_MARGIN`` to change):
    a moving grid where the ticks stay put is rougher (a node whose samples drift across fixed
    ticks made it follow -29 ppm), and a fixed one where they move.

    Args:
      fusion_rate_hz: the chip's fusion rate, Hz.
      sample_rate_hz: the node's nominal rate, Hz.
      memory_s: the roughness sums' forgetting time constant, s.
    """

    def __init__(self, fusion_rate_hz: float, sample_rate_hz: float, *, memory_s: float = DEFAULT_PHASE_MEMORY_S):
        self.period_s = 1.0 / fusion_rate_hz
        self.phases_s = np.arange(0.0, self.period_s - 1e-12, PHASE_STEP_S)
        self.max_span_s = GAP_PERIODS / sample_rate_hz
        self.memory_s = float(memory_s)
        n = len(self.phases_s)
        self.cost = np.zeros(2 * n)  # the fixed grid's candidates, then the moving grid's
        self.weight = 0.0
        self._last: deque[tuple[float, tuple[float, float, float]]] = deque(maxlen=2)  # (t_s, gyro rad/s)
        self._estimate: tuple[float, tuple[float, float]] | None = None
        self._estimate_t_s = -math.inf
        # the moving grid's candidate j stands for the phase phases_s[j] + shift_s(t),
        # shift_s(t) = anchor shift + rate_s_s (t - anchor t)
        self.rate_s_s = 0.0
        self.moving = False  # the estimate is the moving grid's
        self._anchor = (0.0, 0.0)  # (t_s, shift_s)
        self._history: deque[tuple[float, float]] = deque()  # (t_s, the moving grid's phase on the twin's clock)
        # (slope s/s, rms s) of a phase that moves but too unsteadily to follow (``_follow_drift``), else None
        self.unfollowed: tuple[float, float] | None = None
        self._unfollowed_sigma = math.inf  # that line's slope's standard error, s/s

    def value_instants(self, t_s: Floats | float, phase_s: Floats | float) -> Floats:
        """The latest fusion tick (ticks at phase_s + k period) at or before each t_s, s."""
        return phase_s + self.period_s * np.floor((np.asarray(t_s) - phase_s) / self.period_s + 1e-9)

    def add(self, t_s: float, gyro_rad_s: Floats) -> None:
        """One sample (instant on the twin's clock, s; gyro (3,), rad/s)."""
        last = self._last
        x, y, z = np.asarray(gyro_rad_s, dtype=float).tolist()  # floats: numpy's calls on 3-vectors cost more
        if len(last) == 2 and t_s - last[0][0] <= self.max_span_s and math.hypot(*last[1][1]) > PHASE_MOTION_RAD_S:
            (x0, y0, z0), (x1, y1, z1) = last[0][1], last[1][1]
            a, b, c = x1 - x0, y1 - y0, z1 - z0
            d, e, f = x - x1, y - y1, z - z1
            forget = math.exp(-(t_s - last[1][0]) / self.memory_s)
            add_roughness(self.cost, self.phases_s, self.shift_s(t_s), self.period_s, last[0][0], last[1][0], t_s,
                          a * a + b * b + c * c, a * d + b * e + c * f, d * d + e * e + f * f, forget)  # fmt: skip
            self.weight = self.weight * forget + 1.0
            if self._estimate is None or t_s - self._estimate_t_s >= ESTIMATE_EVERY_S:
                self._estimate = self._choose(t_s)
                self._estimate_t_s = t_s
        last.append((float(t_s), (x, y, z)))

    def shift_s(self, t_s: float) -> float:
        """Where the moving grid's phase 0 is at ``t_s`` (s on the twin's clock), s."""
        t0, shift = self._anchor
        return shift + self.rate_s_s * (t_s - t0)

    def _choose(self, t_s: float) -> tuple[float, tuple[float, float]]:
        """Both grids' phases found at ``t_s``, the moving grid's drift followed; the estimate
        (on its grid: ``estimate`` places it) from the grid whose smallest roughness is lower."""
        n = len(self.phases_s)
        fixed, moving = self.cost[:n], self.cost[n:]
        on_fixed, on_moving = self._find(fixed), self._find(moving)
        if self.ready:
            self._follow_drift(t_s, on_moving[0])
        lowest_fixed, lowest_moving = float(fixed.min()), float(moving.min())
        if self.moving and lowest_fixed < lowest_moving * (1.0 - SWITCH_MARGIN):
            self.moving = False
        elif not self.moving and lowest_moving < lowest_fixed * (1.0 - SWITCH_MARGIN):
            self.moving = True
        return on_moving if self.moving else on_fixed

    def _follow_drift(self, t_s: float, found: float) -> None:
        """The moving grid's rate: the slope of a line through the last ``RATE_WINDOW_S`` (at
        least ``RATE_MIN_SPAN_S``) of the phase it found, on the twin's clock (unwrapped), where
        that slope is steady (rms about the line under ``RATE_FIT_RMS_S``) and at least
        ``RATE_SLOPE_Z`` standard errors and ``RATE_MIN_S_S``. A new rate applies from this
        instant on (the grid's place now is kept: its sums stay where they are). Where the rate
        is wrong the grid's phase lags the ticks by a steady amount, so the found phase still
        moves at the ticks' rate."""
        found = found + self.shift_s(t_s)
        history = self._history
        if history:  # unwrapped against where the last one has moved to at the rate in use (a node
            # quiet for 20 s at 200 ppm: 4 ms, near half a period)
            t_last, last = history[-1]
            expected = last + self.rate_s_s * (t_s - t_last)
            found = expected + ((found - expected + 0.5 * self.period_s) % self.period_s - 0.5 * self.period_s)
        history.append((t_s, found))
        while history and t_s - history[0][0] > RATE_WINDOW_S:
            history.popleft()
        if t_s - history[0][0] < RATE_MIN_SPAN_S:
            return
        t, phase = np.fromiter(itertools.chain.from_iterable(history), float, 2 * len(history)).reshape(-1, 2).T
        t = t - t_s
        dt = t - t.mean()
        spread = float(dt @ dt)
        slope = float(dt @ (phase - phase.mean())) / spread  # the least-squares line, in closed form
        residual = phase - phase.mean() - slope * dt
        rms = math.sqrt(float(residual @ residual) / len(t))
        slope_sigma = math.sqrt(float(residual @ residual) / max(len(t) - 2, 1) / spread)
        rate = float(np.clip(slope, -RATE_MAX_S_S, RATE_MAX_S_S))
        moves = abs(slope) >= max(RATE_MIN_S_S, RATE_SLOPE_Z * slope_sigma)
        if rms <= RATE_FIT_RMS_S:  # a steady phase, still or followed
            self.unfollowed, self._unfollowed_sigma = None, math.inf
        elif moves and slope_sigma < self._unfollowed_sigma:  # the most precise line of an unsteady phase
            self.unfollowed, self._unfollowed_sigma = (slope, rms), slope_sigma
        if moves and rms <= RATE_FIT_RMS_S:
            self._anchor = (t_s, self.shift_s(t_s))
            self.rate_s_s = rate

    @property
    def ready(self) -> bool:
        return self.weight >= PHASE_SAMPLES

    def estimate(self, t_s: float | None = None) -> tuple[float, tuple[float, float]]:
        """(phase s in [0, period), (lo, hi) its stretch) at ``t_s`` (s on the twin's clock;
        default: the last sample's instant), found anew every ``ESTIMATE_EVERY_S`` while the node
        swings; the moving grid's phase carried on at its rate in between (a node that turns
        slower than ``PHASE_MOTION_RAD_S`` adds nothing to the sums, while its ticks drift on)."""
        at = (self._last[-1][0] if self._last else 0.0) if t_s is None else float(t_s)
        if self._estimate is None:
            self._estimate = self._choose(at)
        mid, (lo, hi) = self._estimate
        shift = self.shift_s(at) if self.moving else 0.0
        return ((mid + shift) % self.period_s, (lo + shift, hi + shift))

    @staticmethod
    def _find(cost: Floats) -> tuple[float, tuple[float, float]]:
        """On one grid (its roughness ``cost``): the middle of the run of grid phases whose
        roughness equals the smallest (to 1e-9 relative), wrapping round the period, and that
        run's stretch, s on the grid."""
        n, step = len(cost), PHASE_STEP_S
        best = int(np.argmin(cost))
        flat = cost <= cost[best] * (1.0 + 1e-9) + 1e-300
        lo = hi = best
        while flat[(lo - 1) % n] and hi - lo < n - 1:
            lo -= 1
        while flat[(hi + 1) % n] and hi - lo < n - 1:
            hi += 1
        # the stretch ends half a grid step beyond the last flat phase on each side
        mid = 0.5 * (lo + hi) * step
        return (mid % (n * step), ((lo - 0.5) * step, (hi + 0.5) * step))


class NodeMeasurement:
    """One node's samples, in time order, turned into the estimator's measurements (module
    docstring).

    Args:
      node: 0 (M1) or 1 (M2).
      start_frame: the frame whose sense the found frame takes (default: the model's mount,
        ``model_mount_frame``).
      params: the rig (gravity for the frame fit, the disk's radius for the default start frame).
      fusion_rate_hz: the chip's fusion rate, Hz; None for a node that stamps its values' own
        instants (no phase to learn).
      sample_rate_hz: the node's nominal rate, Hz.
      learn_s: how long a window of samples the frame is fitted on, s.
      swing_rad_s: the hinge rate the window must reach before the frame is fitted, rad/s.
      phase_memory_s: the fusion phase's forgetting time constant, s.
      frame: a known frame (e.g. from an earlier run): then only the phase is learned.
    """

    def __init__(
        self,
        node: int,
        *,
        start_frame: SwingFrame | None = None,
        params: RigParams = DEFAULT_PARAMS,
        fusion_rate_hz: float | None = FUSION_RATE_HZ,
        sample_rate_hz: float = SAMPLE_RATE_HZ,
        learn_s: float = DEFAULT_LEARN_S,
        swing_rad_s: float = DEFAULT_SWING_RAD_S,
        phase_memory_s: float = DEFAULT_PHASE_MEMORY_S,
        frame: SwingFrame | None = None,
    ) -> None:
        if node not in (0, 1):
            raise ParameterError(f"node must be 0 (M1) or 1 (M2), got {node!r}")
        _positive("sample_rate_hz", sample_rate_hz, 1e5)
        _positive("learn_s", learn_s, 60.0)
        _positive("swing_rad_s", swing_rad_s, 100.0)
        _positive("phase_memory_s", phase_memory_s, 1e5)
        if fusion_rate_hz is not None:
            _positive("fusion_rate_hz", fusion_rate_hz, 1e5)
        self.node = node
        self.params = params
        self.start_frame = start_frame or model_mount_frame(params.om1_m if node == 0 else params.om2_m)
        self.sample_rate_hz = float(sample_rate_hz)
        self.learn_s, self.swing_rad_s = float(learn_s), float(swing_rad_s)
        self.phase = FusionPhase(fusion_rate_hz, sample_rate_hz, memory_s=phase_memory_s) if fusion_rate_hz else None
        self.frame: SwingFrame | None = None
        self._frame_floats = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0)
        if frame is not None:
            self._set_frame(frame)
        self._frame_t_s: float | None = None
        self._hinge_deg: float | None = None
        self._sense: bool | None = None
        self._window: deque[tuple[float, Floats, Floats, Floats]] = deque()
        self._t_s = -math.inf
        self._tried_t_s = -math.inf
        self._phi: float | None = None
        self._first_t_s: float | None = None
        self._fall_back = False
        self._tied = np.ones((4, 4), dtype=bool)  # components of equal magnitude on every sample so far
        self._tied_pairs = [(i, j) for i in range(4) for j in range(i + 1, 4)]  # the pairs still tied
        self._quats: deque[Floats] = deque(maxlen=TIED_SAMPLES)
        self.from_gravity = False  # the frame is the gravity frame (the node did not swing enough to fit one)

    def add(
        self, t_s: float, quat_wxyz: ArrayLike, gyro_rad_s: ArrayLike, accel_m_s2: ArrayLike
    ) -> NodeSample | Waiting:
        """One sample taken at ``t_s`` (the twin's clock: its device time mapped to host time, s):
        fused orientation (4,) w, x, y, z; gyro (3,) rad/s; acceleration with gravity (3,) m/s^2.
        Samples come in time order (an older one is refused: ``ParameterError``)."""
        t = float(t_s)
        if not (math.isfinite(t) and t > self._t_s):
            raise ParameterError(f"samples must come in time order: {t_s!r} s after {self._t_s:.6f} s")
        quat = np.asarray(quat_wxyz, dtype=float)
        gyro = np.asarray(gyro_rad_s, dtype=float)
        accel = np.asarray(accel_m_s2, dtype=float)
        if quat.shape != (4,) or gyro.shape != (3,) or accel.shape != (3,):
            raise ParameterError(
                f"expected quat (4,), gyro (3,), accel (3,), got {quat.shape}, {gyro.shape}, {accel.shape}"
            )
        self._t_s = t
        q = quat.tolist()  # floats: numpy's calls on 3- and 4-vectors cost more than their arithmetic
        if not math.isfinite(sum(q) + sum(gyro.tolist())):  # a NaN or an infinity anywhere
            return Waiting("a sample whose orientation or gyro is not finite is left out")
        if not math.isfinite(sum(accel.tolist())):
            if self.frame is None:
                return Waiting("a sample without a finite accelerometer reading cannot teach the frame")
            accel = np.full(3, math.nan)  # the angle and rate are taken; the accelerometer is not
        for i, j in list(self._tied_pairs):
            if not abs(abs(q[i]) - abs(q[j])) < QUAT_LSB / 2:
                self._tied[i, j] = self._tied[j, i] = False
                self._tied_pairs.remove((i, j))
        self._quats.append(quat)
        if self._first_t_s is None:
            self._first_t_s = t
        if self.phase is not None:
            self.phase.add(t, gyro)
        quiet = self._fall_back
        if self.frame is None:
            waiting = self._learn_frame(t, quat, gyro, accel)
            if waiting is not None and not quiet:
                return waiting
            if waiting is not None:  # a node that does not swing enough to fit its frame
                self._set_frame(gravity_frame(self._start_on_gyro_axis(), quat))
                self._frame_t_s, self._hinge_deg, self._sense, self.from_gravity = t, 0.0, True, True
        elif self.phase is not None and not self.phase.ready and not quiet:
            return Waiting(f"fusion phase: {self.phase.weight:.0f} of {PHASE_SAMPLES} swinging samples")
        assert self.frame is not None
        phi = self._angle(quat)
        if self._phi is not None:  # continuous from the previous sample
            phi = self._phi + (phi - self._phi + math.pi) % math.tau - math.pi
        self._phi = phi
        (gx, gy, gz), (ax, ay, az) = gyro.tolist(), accel.tolist()
        (h0, h1, h2), (t0, t1, t2), (n0, n1, n2) = self._axes
        omega = gx * h0 + gy * h1 + gz * h2
        tangential, normal = ax * t0 + ay * t1 + az * t2, ax * n0 + ay * n1 + az * n2
        return NodeSample(self.value_instant(t), phi, omega, t, tangential, normal)

    def _start_on_gyro_axis(self) -> SwingFrame:
        """The start frame turned (the least rotation) so that its hinge axis is the one the
        gyro turned about over the last window, where it turned enough to tell (``AXIS_SAMPLES``
        samples faster than ``AXIS_MOTION_RAD_S``) and within ``AXIS_MAX_DEG`` of the start frame's:
        a node glued on 2 deg askew read about the start frame's axis would see its swing scaled by
        cos(2 deg), an error of 6e-4 of the angle at the swing's own frequency (a small swing of
        5 deg: 5e-5 rad, the angle's noise), which no offset follows. Otherwise the start frame."""
        start = self.start_frame
        gyro = np.array([w[2] for w in self._window]).reshape(-1, 3)
        moving = gyro[np.linalg.norm(gyro, axis=1) > AXIS_MOTION_RAD_S]
        if len(moving) < AXIS_SAMPLES:
            return start
        h = np.asarray(start.hinge_axis, dtype=float)
        a = dominant_axis(moving)
        a = a if a @ h >= 0 else -a
        turn = np.cross(h, a)
        angle = math.atan2(float(np.linalg.norm(turn)), float(a @ h))
        if angle > math.radians(AXIS_MAX_DEG):
            return start
        if angle > 0:
            r = rotations.to_matrix(rotations.from_rotvec(turn / np.linalg.norm(turn) * angle))
            start = dataclasses.replace(
                start,
                hinge_axis=a,
                toward_pivot=r @ np.asarray(start.toward_pivot),
                tangential=r @ np.asarray(start.tangential),
                quat_axis=r @ np.asarray(start.quat_axis),
            )
        return start

    def fall_back(self) -> None:
        """From the next sample on, measure without waiting: the gravity frame
        (``gravity_frame``) if no frame was fitted, and values half a fusion period old if the
        fusion phase is not known (a node that barely swings teaches neither)."""
        self._fall_back = True

    def value_instant(self, t_s: float) -> float:
        """The instant the value of a sample taken at ``t_s`` stands for, s (the phase's
        current estimate; ``t_s`` itself without fusion timing)."""
        if self.phase is None:
            return float(t_s)
        if not self.phase.ready:  # a quiet node: its values are on average half a fusion period old
            return float(t_s) - 0.5 * self.phase.period_s
        p, period = self.phase.estimate(t_s)[0], self.phase.period_s
        return p + period * math.floor((t_s - p) / period + 1e-9)

    def _angle(self, q: Floats) -> float:
        """``SwingFrame.angle`` of one orientation (4,) on floats: the twist about the frame's
        quat_axis from its reference (conj(reference) q), plus its offset, rad in (-pi, pi] + offset."""
        rw, rx, ry, rz, ax, ay, az, offset = self._frame_floats
        qw, qx, qy, qz = q.tolist()
        w = rw * qw - rx * qx - ry * qy - rz * qz
        x = rw * qx + rx * qw + ry * qz - rz * qy
        y = rw * qy - rx * qz + ry * qw + rz * qx
        z = rw * qz + rx * qy - ry * qx + rz * qw
        return 2.0 * math.atan2(x * ax + y * ay + z * az, w) + offset

    def _set_frame(self, frame: SwingFrame) -> None:
        self.frame = frame
        r, a = frame.reference_quat_wxyz, frame.quat_axis
        conj = (float(r[0]), -float(r[1]), -float(r[2]), -float(r[3]))
        self._frame_floats = (*conj, float(a[0]), float(a[1]), float(a[2]), float(frame.angle_offset_rad))
        self._axes = tuple(
            tuple(np.asarray(v, dtype=float).tolist()) for v in (frame.hinge_axis, frame.tangential, frame.toward_pivot)
        )  # fmt: skip

    def _learn_frame(self, t: float, quat: Floats, gyro: Floats, accel: Floats) -> Waiting | None:
        window = self._window
        window.append((t, quat, gyro, accel))
        while window and window[0][0] < t - self.learn_s:
            window.popleft()
        if self.phase is not None and not self.phase.ready:
            return Waiting(f"fusion phase: {self.phase.weight:.0f} of {PHASE_SAMPLES} swinging samples")
        rates = [float(np.linalg.norm(w[2])) for w in window]
        moving = sum(r > PHASE_MOTION_RAD_S for r in rates) / len(rates)
        if t - window[0][0] < 0.95 * self.learn_s or moving < MOVING_SHARE or max(rates) < self.swing_rad_s:
            return Waiting(
                f"frame: {100 * moving:.0f} % of the last {self.learn_s:g} s moving "
                f"(needs {100 * MOVING_SHARE:.0f} %), at most {max(rates):.2f} rad/s (needs {self.swing_rad_s:g})"
            )
        if t - self._tried_t_s < RETRY_S:
            return Waiting("frame: the last fit was refused; trying again soon")
        self._tried_t_s = t
        t_w = np.array([w[0] for w in window])
        instants = t_w if self.phase is None else self.phase.value_instants(t_w, self.phase.estimate(t)[0])
        try:
            frame = fit_swing_frame(
                instants, np.array([w[1] for w in window]), np.array([w[2] for w in window]),
                np.array([w[3] for w in window]), g_m_s2=self.params.g_m_s2,
                max_step_s=GAP_PERIODS / self.sample_rate_hz,
            )  # fmt: skip
        except RecordingError as exc:
            return Waiting(f"frame: {exc}")
        expected = self.start_frame.radius_m
        if abs(frame.radius_m - expected) > RADIUS_TOLERANCE * expected:
            return Waiting(
                f"frame: the fit puts the node {1000 * frame.radius_m:.0f} mm from the hinge, the start frame "
                f"{1000 * expected:.0f} mm: refused"
            )
        along = float(np.dot(frame.hinge_axis, self.start_frame.hinge_axis))
        self._hinge_deg = math.degrees(math.acos(min(1.0, abs(along))))
        self._sense = self._hinge_deg < 60.0
        if self._sense and along < 0:
            frame = frame.flipped()
        self._set_frame(frame)
        self._frame_t_s = t
        window.clear()
        return None

    @property
    def angle_sigma_rad(self) -> float:
        """The swing angle's noise from the quaternion's rounding, rad (``TWIST_SIGMA_RAD`` before
        a frame or a sample). Each component is rounded to an LSB (variance LSB^2/12); components
        that have had equal magnitudes on every sample (the model's own mount reads (a, a, -b, b))
        round alike, and exact zeros not at all, so the angle's variance is, over the last samples,
        the mean of LSB^2/12 times the sum over each group of tied components of the squared
        derivative of the angle along the group's signed direction (``_angle``, by central
        differences). Isotropic rounding gives ``TWIST_SIGMA_RAD``; the model's mount
        ``bno055.SWING_ANGLE_SIGMA_RAD``."""
        if self.frame is None or not self._quats:
            return TWIST_SIGMA_RAD
        groups, seen = [], set()
        for i in range(4):
            if i not in seen:
                members = [j for j in range(4) if self._tied[i, j]]
                seen.update(members)
                groups.append(members)
        step = 1e-7
        total = 0.0
        for q in self._quats:
            for members in groups:
                u = np.zeros(4)
                u[members] = np.sign(q[members])  # a zero component has no rounding error
                if not u.any():
                    continue
                slope = (self._angle(q + step * u) - self._angle(q - step * u)) / (2 * step)
                total += slope * slope
        return math.sqrt(QUAT_LSB * QUAT_LSB / 12.0 * total / len(self._quats))

    @property
    def learned(self) -> Learned:
        """The phase and frame learned so far."""
        phase = stretch = drift = unfollowed = None
        if self.phase is not None and self.phase.ready:
            phase, stretch = self.phase.estimate()
            drift = self.phase.rate_s_s * 1e6 if self.phase.moving else 0.0
            if self.phase.unfollowed is not None:
                slope, rms = self.phase.unfollowed
                unfollowed = (slope * 1e6, rms * 1e3)
        return Learned(
            self.node, phase, stretch, drift, self.frame, self._frame_t_s, self._hinge_deg, self._sense, unfollowed
        )


def _positive(name: str, value: float, high: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and 0 < value <= high):
        raise ParameterError(f"{name} must be a finite number in (0, {high:g}], got {value!r}")
