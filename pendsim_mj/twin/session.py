"""The twin beside the rig, sample by sample: what ``pendsim twin`` runs on live packets and on a
replayed recording alike (the caller puts both nodes' samples into one time order:
``merge.SampleMerger``).

For each node sample (its instant, orientation and gyro):

1. the node's measurement (``NodeMeasurement``): the swing angle about the hinge and the hinge
   rate from the node's swing frame, and the instant the value stands for (a BNO055 node's value
   is on average ``value_age_s`` older than its stamp);
2. the estimator (``estimator.RigEstimator``) starts once both nodes have given a sample (the
   state from their values), then takes each sample in (``Estimates``);
3. the health monitor (``health.HealthMonitor``) checks the tracked parameters once a second
   (``ParameterCheck``, ``Alarm``);
4. every ``forecast_every_s`` a forecast over ``forecast_horizon_s`` (``Forecast``), scored
   afterwards against what the nodes measured (``ForecastScore``: per horizon, the error's rms
   and the share of measurements within the forecast's 3-sigma band).

``drain()`` hands out what was produced since the last call; ``summary()`` gives the run's
figures (innovations' whiteness, forecast scores, alarms).
"""

from __future__ import annotations

import bisect
import collections
import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.engines.fast_planar.closed_form import accelerations, coefficients
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.swing_frame import SwingFrame
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import FUSION_RATE_HZ, Bno055
from pendsim_mj.sensors.imperfections import Imperfections
from pendsim_mj.twin.estimator import DIVERGED_RAD, NSTATE, TRACKABLE, Forecast, RigEstimator
from pendsim_mj.twin.health import DEFAULT_PERSIST_S, DEFAULT_THRESHOLD, Alarm, HealthMonitor
from pendsim_mj.twin.measurement import FALLBACK_S, TWIST_SIGMA_RAD, Learned, NodeMeasurement, NodeSample, Waiting
from pendsim_mj.twin.outputs import Estimates, ParameterCheck
from pendsim_mj.twin.unscented import accelerations_at
from pendsim_mj.twin.walks import DEFAULT_CALM_SCALE, AdaptiveWalks
from pendsim_mj.twin.whiteness import Whiteness

Floats = NDArray[np.float64]
NODE_PARAMETERS = ("offset_m1_rad", "offset_m2_rad", "offset_rate_m1_rad_s", "offset_rate_m2_rad_s",
                   "offset_accel_m1_rad_s2", "offset_accel_m2_rad_s2", "offset_jerk_m1_rad_s3", "offset_jerk_m2_rad_s3",
                   "delay_m2_s", "accel_turn_m1_rad", "accel_turn_m2_rad")  # fmt: skip
"""What real nodes need tracked, always: each node's mount offset with its first three derivatives
(rate, acceleration, jerk: a chain whose jerk walks follows the fused orientation's slow error;
docs/twin.md, Whiteness on the whole twin), M2's delay against M1 (``twin.measurement``), each
node's accelerometer turn (its learned frame's axes 0.1 deg off). Without them the learned frames'
half-degree offsets alone make the innovations hundreds of sigmas."""
RIG_PARAMETERS = tuple(name for name in TRACKABLE if name not in NODE_PARAMETERS)
"""The rig's own parameters that can drift: damping, dry friction, the coupling springs."""
DEFAULT_TRACK = RIG_PARAMETERS
NODE_DRIFT_PER_S = {"offset_m1_rad": 1e-7, "offset_m2_rad": 1e-7, "offset_rate_m1_rad_s": 0.0,
                    "offset_rate_m2_rad_s": 0.0, "offset_accel_m1_rad_s2": 0.0, "offset_accel_m2_rad_s2": 0.0,
                    "offset_jerk_m1_rad_s3": 1.2e-4, "offset_jerk_m2_rad_s3": 1.2e-4, "delay_m2_s": 3e-5}  # fmt: skip
# the random walks of the node states on real nodes: the offset's own 1e-7 rad/sqrt(s) (a step is the jump
# check's and the health monitor's), its chain's only at the jerk; M2's delay 3e-5 s/sqrt(s), which follows
# the learned fusion phase's slow error under a drifting clock (docs/twin.md, Whiteness on the whole twin)
NODE_SIGMA0 = {"offset_m1_rad": 0.01, "offset_m2_rad": 0.01, "offset_rate_m1_rad_s": 1e-3,
               "offset_rate_m2_rad_s": 1e-3, "delay_m2_s": 1e-3, "accel_turn_m1_rad": 0.01,
               "accel_turn_m2_rad": 0.01, "offset_accel_m1_rad_s2": 1e-3, "offset_accel_m2_rad_s2": 1e-3,
               "offset_jerk_m1_rad_s3": 5e-4, "offset_jerk_m2_rad_s3": 5e-4}  # fmt: skip
# ... and their start: the learned frames' offsets are good to about 0.5 deg
NODE_BASELINE_S = 10.0  # the node states' references: their estimates this long after the start (the
# learned frames leave each offset about 0.5 deg uncertain; the rig's own parameters keep the stated rig)
NODE_FUSION_ERROR_RAD = math.radians(0.5)  # the nodes' fused orientation's slowly varying error, rms, that
# the mount offsets may wander within without a change (the health monitor's reference spread)
LATE_S = 0.0125  # the two nodes' value instants cross by up to one fusion period (10 ms): taken late
HORIZON_BINS_S = (0.25, 0.5, 1.0, 2.0, 5.0)  # forecast scores per horizon up to each of these
TICK_NEAR_S = 0.5e-3  # a sample this close to a fusion tick (at least; ``_on_its_tick``) is checked
TICK_MISS_Z = 6.0  # ... and moved to the other tick when its angle misses by more than this many sigmas
TICK_BETTER = 4.0  # ... and the other tick explains it this many times better
HOLD_NIS = 20.0  # a node's recent mean NIS above this holds the health checks (``_checks_held``)
HOLD_EVERY_S = 0.25
FITTED_S = 5.0  # a run whose model fitted (recent NIS within MISFIT_NIS) this long before a hold: it changed
RUN_MISFIT_NIS = 3.0  # a node's mean NIS over a whole run above this: its summary warns
MISFIT_NIS = 6.0  # a node's recent mean NIS above this (three times chi^2's mean): the model does not fit
RECENT_NIS = 160  # the status line's recent NIS: each node's last 2 s of updates at 80 Hz
FREE_WINDOW = 8  # samples per node (0.1 s at 80 Hz) over which a node's motion is compared with free motion
HELD_ALPHA_RAD_S2 = 0.5  # a node whose free acceleration would exceed this but whose measured one is
# less than half of it is held (a hand, a stop)
INTERVENTION_NIS = 200.0  # the rate innovations' mean normalised square over INTERVENTION_WINDOW updates
INTERVENTION_WINDOW = 40  # above this: the rig was touched (its motion is not the model's)
JUMP_Z = 20.0  # a node whose angle innovations all exceed this many sigmas over JUMP_SAMPLES samples while
JUMP_SAMPLES = 6  # its rate agrees with the model has turned on its mount (or its orientation jumped)
JUMP_RATE_Z = 5.0
FORECAST_STEP_S = 0.025  # the forecasts' grid, s: RK4 at this step is within 1e-6 rad of a finer one over 2 s,
# and cubic Hermite interpolation between its points (angle and rate) within 1e-6 rad
SNAPSHOT_S = 1.0  # the tracked parameters are kept this often, to go back to after an intervention


@dataclasses.dataclass(frozen=True)
class ForecastScore:
    """How the forecasts held, per horizon bin (``HORIZON_BINS_S``: up to each bound).

    Attributes:
      horizon_s: (k,) each bin's upper bound, s.
      count: (k,) measurements scored in it.
      rms_error_rad: (k,) rms of measured minus forecast swing angle.
      within_3_sigma: (k,) share of those within the forecast's 3-sigma band (its standard
        deviation and the measurement's together).
    """

    horizon_s: tuple[float, ...]
    count: tuple[int, ...]
    rms_error_rad: tuple[float, ...]
    within_3_sigma: tuple[float, ...]


@dataclasses.dataclass(frozen=True)
class TwinOutput:
    """What the twin produced since the last ``drain``."""

    estimates: Estimates
    forecasts: tuple[tuple[float, Forecast], ...]  # (made at, s; the forecast)
    checks: tuple[ParameterCheck, ...]
    alarms: tuple[Alarm, ...]
    events: tuple[tuple[float, str], ...] = ()  # (t_s, "tracking" | "held" | "released" | "touched")


@dataclasses.dataclass(frozen=True)
class TwinSummary:
    """A run's figures.

    Attributes:
      samples: per node, samples taken in.
      started_s: when the estimator started (NaN: never).
      nis_mean: per node, the mean normalised innovation squared (2 on a healthy rig).
      whiteness_p: per node, the Ljung-Box p-values of its normalised angle and rate innovations
        from ``whiteness_from_s`` on (``whiteness.Whiteness``, 20 lags, over the whole run; NaN: too few).
      accel_nis_mean: per node, the accelerometer's mean normalised innovation squared (2 on a
        healthy rig; NaN: none fused).
      stated: each tracked rig parameter's value in the rig the twin was given (its model's).
      accel_whiteness_p: per node, the Ljung-Box p-values of its normalised tangential and normal
        accelerometer innovations.
      forecast: the forecasts' scores.
      alarms: the alarms raised.
      parameters: each tracked parameter's final (value, sigma).
      events: (t_s, what) the estimate started, a node held, the rig touched, a node's angle
        jumped, what the caller noted.
      phase_drift_ppm: per node, how fast its chip's fusion ticks move on the twin's clock, ppm
        (``measurement.Learned.phase_drift_ppm``; 0: they stay put; NaN: no phase learned).
      phase_moving_unfollowed: per node, (ppm, ms) a found phase that moves too unsteadily to
        follow (``measurement.Learned.phase_moving_unfollowed``), else None.
    """

    samples: tuple[int, int]
    started_s: float
    nis_mean: tuple[float, float]
    whiteness_p: tuple[tuple[float, float], tuple[float, float]]
    forecast: ForecastScore
    alarms: tuple[Alarm, ...]
    parameters: dict[str, tuple[float, float]]
    events: tuple[tuple[float, str], ...] = ()
    monitored_from_s: float = math.nan  # the first health check against the references (NaN: none)
    accel_nis_mean: tuple[float, float] = (math.nan, math.nan)
    accel_whiteness_p: tuple[tuple[float, float], tuple[float, float]] = ((math.nan, math.nan), (math.nan, math.nan))
    stated: dict[str, float] = dataclasses.field(default_factory=dict)  # the rig's value of each tracked rig parameter
    phase_drift_ppm: tuple[float, float] = (math.nan, math.nan)
    phase_moving_unfollowed: tuple[tuple[float, float] | None, tuple[float, float] | None] = (None, None)


class TwinSession:
    """The twin of the module docstring.

    Args:
      params: the rig (e.g. ``pendsim calibrate``'s).
      frames: each node's swing frame.
      nodes: the node model (its noise sets the measurement noise).
      track: the rig's parameters to track and monitor (``RIG_PARAMETERS``: any of them, or ()); the
        node states (``NODE_PARAMETERS``) are tracked and monitored always.
      forecast_horizon_s: how far each forecast reaches, s (0: none).
      forecast_every_s: how often a forecast is made, s.
      threshold, persist_s, baseline_s: the health monitor's (``HealthMonitor``).
      settle_s: innovations before this long after the start are left out of the mean NIS and the
        model-fit checks.
      whiteness_from_s: ... and out of the whiteness tests before this long (at least ``settle_s``):
        the start's settling (the learned frame's, M2's delay's prior) ends by the time the node
        states take their references (``NODE_BASELINE_S``). From 2 s M2's angle was white on 17 of 24
        healthy seeds (its delay swinging from +8 to -1 ms in the first 2.5 s, NIS about 100), from
        10 s on 22 (docs/twin.md, Whiteness on the whole twin).
      calm_walks: the rig's parameters' random walks while the rig looks healthy, over their own
        (``twin.walks.AdaptiveWalks``: their own from a suspicion of a change on; 1: always their own).
      start_frames: each node's frame to start from (default: the model's mount); the measurement
        learns the real one from the first second of swinging (``measurement.NodeMeasurement``).
      fusion_rate_hz: the nodes' fusion rate (their values' timing is learned); None for nodes
        that stamp their values' own instants.
      fusion_error_rad: the nodes' fused orientation's slowly varying error, rms, rad: the mount
        offsets wander within it without counting as a change.
      nodes: the node model (its noise sets the measurement noise; default the BNO055's with
        ``fusion_error_rad``).
    """

    def __init__(
        self,
        params: RigParams = DEFAULT_PARAMS,
        *,
        start_frames: Sequence[SwingFrame] | None = None,
        fusion_rate_hz: float | None = FUSION_RATE_HZ,
        fusion_error_rad: float = NODE_FUSION_ERROR_RAD,
        nodes: Bno055 | None = None,
        track: tuple[str, ...] = DEFAULT_TRACK,
        forecast_horizon_s: float = 2.0,
        forecast_every_s: float = 1.0,
        threshold: float = DEFAULT_THRESHOLD,
        persist_s: float = DEFAULT_PERSIST_S,
        baseline_s: float = 0.0,
        settle_s: float = 2.0,
        whiteness_from_s: float = NODE_BASELINE_S,
        calm_walks: float = DEFAULT_CALM_SCALE,
    ) -> None:
        if start_frames is not None and len(start_frames) != 2:
            raise ParameterError(f"the twin needs both nodes' frames, got {len(start_frames)}")
        if not (math.isfinite(forecast_horizon_s) and 0 <= forecast_horizon_s <= 60):
            raise ParameterError(f"the forecast horizon must be in [0, 60] s, got {forecast_horizon_s!r}")
        if not (math.isfinite(forecast_every_s) and 0.1 <= forecast_every_s <= 3600):
            raise ParameterError(f"the forecast period must be in [0.1, 3600] s, got {forecast_every_s!r}")
        self.params = params
        unknown = [name for name in track if name not in RIG_PARAMETERS]
        if unknown:
            raise ParameterError(
                f"cannot track {', '.join(unknown)}; the rig's parameters: {', '.join(RIG_PARAMETERS)}"
            )
        track = tuple(track) + NODE_PARAMETERS
        drift = dict(NODE_DRIFT_PER_S)
        if nodes is None:
            if not (math.isfinite(fusion_error_rad) and 0 <= fusion_error_rad <= 0.2):
                raise ParameterError(f"fusion_error_rad must be in [0, 0.2] rad, got {fusion_error_rad!r}")
            nodes = Bno055(imperfections=Imperfections(fusion_error_rad=fusion_error_rad))
        self.estimator = RigEstimator(params, nodes=nodes, track=track, drift_per_s=drift,
                                      angle_sigma_rad=TWIST_SIGMA_RAD)  # fmt: skip
        self._parameter_sigma0 = self.estimator.drift_per_s * math.sqrt(20.0)
        for i, name in enumerate(track):
            if name in NODE_SIGMA0:
                self._parameter_sigma0[i] = NODE_SIGMA0[name]
        self.measurements = [
            NodeMeasurement(n, start_frame=None if start_frames is None else start_frames[n], params=params,
                            fusion_rate_hz=fusion_rate_hz)
            for n in range(2)
        ]  # fmt: skip
        self.threshold, self.persist_s, self.baseline_s = threshold, persist_s, baseline_s
        self.monitor: HealthMonitor | None = None
        if not (math.isfinite(calm_walks) and 0 < calm_walks <= 1):
            raise ParameterError(f"calm_walks must be in (0, 1], got {calm_walks!r}")
        self.calm_walks = float(calm_walks)
        self._walks: AdaptiveWalks | None = None  # the rig's parameters' walks, calm or alert (``twin.walks``)
        self.forecast_horizon_s, self.forecast_every_s = float(forecast_horizon_s), float(forecast_every_s)
        self.settle_s = float(settle_s)
        if not (math.isfinite(whiteness_from_s) and whiteness_from_s >= 0):
            raise ParameterError(f"whiteness_from_s must be a finite number >= 0, got {whiteness_from_s!r}")
        self.whiteness_from_s = max(float(whiteness_from_s), self.settle_s)
        self.started_s = math.nan
        self._recent: list[collections.deque[tuple[float, float, float]]] = [
            collections.deque(maxlen=FREE_WINDOW) for _ in range(2)
        ]
        self._recent_nis: collections.deque[float] = collections.deque(maxlen=INTERVENTION_WINDOW)
        self._recent_z: list[collections.deque[tuple[float, float, float]]] = [
            collections.deque(maxlen=JUMP_SAMPLES) for _ in range(2)
        ]  # per node: the samples held out in a row (angle innovation, -, -)
        self._snapshots: collections.deque[tuple[float, Floats, Floats]] = collections.deque(maxlen=3)
        self.events: list[tuple[float, str]] = []  # (t_s, what happened): held, released, touched
        self._events_out: list[tuple[float, str]] = []
        self._tracking = False
        self._checks_from_s = -math.inf
        self._measuring_since: list[float | None] = [None, None]
        self._waiting: list[str | None] = [None, None]  # each node's last reason to wait (``waiting_text``)
        self._node_baseline_done = False
        self._rows: list[tuple] = []
        self._forecasts: list[tuple[float, Forecast]] = []
        self._drive: Callable[[float], tuple[float, float]] | None = None
        self._checks: list[ParameterCheck] = []
        self._alarms: list[Alarm] = []
        self._all_alarms: list[Alarm] = []
        self._next_forecast_s = math.inf
        self._open_forecasts: list[Forecast] = []
        self._samples = [0, 0]
        self._nis_sum, self._nis_count = [0.0, 0.0], [0, 0]  # per node, after the settling (a run of any length)
        self._nis: tuple[collections.deque[float], ...] = tuple(collections.deque(maxlen=RECENT_NIS) for _ in range(2))
        self._whiteness = [(Whiteness(), Whiteness()), (Whiteness(), Whiteness())]  # node: (angle, rate)
        self._accel_whiteness = [(Whiteness(), Whiteness()), (Whiteness(), Whiteness())]  # node: (tangential, normal)
        self._accel_nis_sum, self._accel_nis_count = [0.0, 0.0], [0, 0]
        self._accel_frames: list[SwingFrame | None] = [None, None]  # the frame each node's accelerometer is read in
        self._holding, self._hold_checked_s = False, -math.inf  # health checks held (``_checks_held``)
        self._fitted_s = 0.0  # how long the model has fitted the data (``_checks_held``), s
        self._ticks_moved = [0, 0]  # samples whose value was moved to the tick on the sample's other side
        self._stated_coef = coefficients([params])[:, 0].copy()  # (NCOEF,): the stated rig's force law
        nbins = len(HORIZON_BINS_S)
        self._score_n, self._score_sq, self._score_in = np.zeros(nbins), np.zeros(nbins), np.zeros(nbins)

    def take(
        self,
        node: int,
        t_s: float,
        quat_wxyz: ArrayLike,
        gyro_rad_s: ArrayLike,
        accel_m_s2: ArrayLike,
        torques_n_m: ArrayLike | Callable[[float], tuple[float, float]] = (0.0, 0.0),
    ) -> bool:
        """One node's sample taken at ``t_s`` (s; each node's samples in time order, the two nodes
        merged in time order): orientation (4,), gyro (3,) rad/s, acceleration with gravity (3,)
        m/s^2; False if it was not taken in (still learning, before the start, too old).

        ``torques_n_m``: the hinge torques (2,) held since the last sample (a controller's
        command), or the drive as a function of time (s -> (2,) N m: a recording's ``/drive``),
        which the estimator holds at the middle of each interval it predicts over (the value's
        instant is up to a fusion period before the sample: a sine drive of 3 mN m at 0.87 Hz held
        at the sample's instant left a mean NIS of 3.2 and false alarms; at the middle, 2.0). The
        forecasts carry a drive given as a function on over their horizon (a programmed drive is
        known ahead); held torques are not carried on (a controller's next command is not)."""
        if node not in (0, 1):
            raise ParameterError(f"node must be 0 (M1) or 1 (M2), got {node!r}")
        self._drive = torques_n_m if callable(torques_n_m) else None  # the forecasts' torques
        self._samples[node] += 1
        got = self.measurements[node].add(t_s, quat_wxyz, gyro_rad_s, accel_m_s2)
        self._waiting[node] = got.reason if isinstance(got, Waiting) else None
        if isinstance(got, Waiting):
            measuring = self._measuring_since[1 - node]
            if measuring is not None and t_s - measuring >= FALLBACK_S:
                self.measurements[node].fall_back()  # the other node measures, this one barely swings
            return False
        if self._measuring_since[node] is None:
            self._measuring_since[node] = t_s
        t_v, phi, omega = got.t_s, got.phi_rad, got.omega_rad_s
        if self._tracking:
            t_v = self._on_its_tick(node, got, torques_n_m)
        self._recent[node].append((t_v, phi, omega))
        if not self._tracking:
            return self._start_when_free(t_v)
        if t_v < self.estimator.t_s - LATE_S:
            return False
        self._score(node, t_v, phi)
        if callable(torques_n_m):
            torques_n_m = torques_n_m(0.5 * (max(self.estimator.t_s, t_v - LATE_S) + t_v))
        before1, before2 = self.estimator.x[:2].tolist()
        update = self.estimator.update(
            t_v, node, phi, omega, torques_n_m=torques_n_m, late_s=LATE_S, gate_angle_z=JUMP_Z, gate_rate_z=JUMP_RATE_Z
        )
        if not update.applied:  # the node's angle jumped: held out until it has for JUMP_SAMPLES samples
            self._recent_z[node].append((float(update.innovation[0]), math.inf, 0.0))
            self._jumped(node, t_v)
            return False
        self._recent_z[node].clear()
        if self._walks is not None:
            self._walks.take(t_v, node, update.nis)
        accel = self._take_accel(node, t_v, got, torques_n_m)
        after1, after2 = self.estimator.x[:2].tolist()
        moved = max(abs(after1 - before1), abs(after2 - before2))
        if not moved <= DIVERGED_RAD:  # (NaN too) no swing moves that far between two samples
            self._touched(t_v, f"the estimate diverged (an angle moved {moved:.3g} rad at one sample): restarted")
            return False
        x, sigma = self.estimator.x, self.estimator.sigma
        innovation = update.innovation.tolist()
        (s00, _), (_, s11) = update.covariance.tolist()
        s_sigma = (math.sqrt(s00), math.sqrt(s11))
        seen = phi - self._offset(node)  # what the node measured, its mount's offset (as estimated) taken out
        state, spread = x[:NSTATE].tolist(), sigma[:NSTATE].tolist()
        self._rows.append((t_v, node, seen, omega, *state, *spread, *innovation, *s_sigma, update.nis, *accel))
        if t_v - self.started_s >= self.settle_s:
            self._nis[node].append(update.nis)
            self._nis_sum[node] += update.nis
            self._nis_count[node] += 1
            white = t_v - self.started_s >= self.whiteness_from_s
            if white:
                for series, nu, s in zip(self._whiteness[node], innovation, s_sigma, strict=True):
                    series.add(nu / s)
            if math.isfinite(accel[-1]):
                self._accel_nis_sum[node] += accel[-1]
                self._accel_nis_count[node] += 1
                if white:
                    for series, nu, s in zip(self._accel_whiteness[node], accel[2:4], accel[4:6], strict=True):
                        series.add(nu / s)
        z_rate = innovation[1] / s_sigma[1]
        self._recent_nis.append(z_rate * z_rate)
        recent = self._recent_nis
        if len(recent) == INTERVENTION_WINDOW and sum(recent) > INTERVENTION_NIS * INTERVENTION_WINDOW:
            self._touched(t_v)
            return True
        if not self._snapshots or t_v - self._snapshots[-1][0] >= SNAPSHOT_S:
            self._snapshots.append((t_v, self.estimator.x[NSTATE:].copy(), self.estimator.p[NSTATE:, NSTATE:].copy()))
        if (
            self.monitor is not None
            and self.monitor.reference is not None
            and not self._node_baseline_done
            and t_v - self.started_s < NODE_BASELINE_S
        ):
            for name in NODE_PARAMETERS:  # the node states' references follow them until the baseline
                if name in self.monitor.reference:
                    self.monitor.reference[name] = float(self.estimator.x[NSTATE + self.estimator.track.index(name)])
        if self.monitor is not None and t_v >= self._checks_from_s and not self._checks_held(t_v):
            before, impossible = len(self.monitor.history), len(self.monitor.impossible)
            alarms = self.monitor.check()
            for found in self.monitor.impossible[impossible:]:
                self._event(
                    t_v,
                    f"not alarmed: {found.parameter} found at {found.value:.4g} {TRACKABLE[found.parameter][1]}, "
                    "a value the rig cannot have (the model does not fit the data)",
                )
            self._alarms += alarms
            self._all_alarms += alarms
            if len(self.monitor.history) > before:
                self._checks.append(self._parameter_check())
                if self._walks is not None:
                    self._walks.at_check(t_v)
        if t_v >= self._next_forecast_s:
            self._next_forecast_s = t_v + self.forecast_every_s
            forecast = self.estimator.forecast(self.forecast_horizon_s, step_s=FORECAST_STEP_S, drive=self._drive)
            self._forecasts.append((t_v, forecast))
            self._open_forecasts.append(forecast)
        return True

    def _held(self) -> bool:
        """Whether a node is held: over the last ``FREE_WINDOW`` samples its rate changes much less
        than the free rig's would (a pendulum held away from rest by a hand or a stop)."""
        means = []
        for recent in self._recent:
            r = np.array(recent)
            means.append(r.mean(axis=0))
        c = self.estimator._coef[:, :1]
        alpha = accelerations(
            np.array([means[0][1]]), np.array([means[1][1]]), np.array([means[0][2]]), np.array([means[1][2]]), c
        )
        for k, recent in enumerate(self._recent):
            r = np.array(recent)
            measured = np.polyfit(r[:, 0] - r[0, 0], r[:, 2], 1)[0]
            free = float(alpha[k][0])
            if abs(free) > HELD_ALPHA_RAD_S2 and abs(measured - free) > 0.5 * abs(free):
                return True
        return False

    def _start_when_free(self, t_v: float) -> bool:
        """Start (or restart) the estimate from the nodes' newest values once neither is held."""
        if any(len(r) < FREE_WINDOW for r in self._recent):
            return False
        if self._held():
            if not self.events or self.events[-1][1] != "held":
                self._event(t_v, "held")
            return False
        (t1, phi1, omega1), (t2, phi2, omega2) = self._recent[0][-1], self._recent[1][-1]
        t0 = max(t1, t2)
        x0 = [phi1 + omega1 * (t0 - t1), phi2 + omega2 * (t0 - t2), omega1, omega2]
        restart = not math.isnan(self.started_s)
        kept = self._snapshots[0] if restart and self._snapshots else None
        self.estimator.start(t0, x0, sigma0=np.radians([2.0, 2.0, 5.0, 5.0]), parameter_sigma0=self._parameter_sigma0)
        for k, m in enumerate(self.measurements):  # each node's angle quantisation (``angle_sigma_rad``)
            self.estimator.measurement_sigma[k, 0] = m.angle_sigma_rad
        if kept is not None:
            self.estimator.x[NSTATE:], self.estimator.p[NSTATE:, NSTATE:] = kept[1], kept[2]
        self._tracking = True
        self._recent_nis.clear()
        # "released" after a hold or a touch; the first start is "tracking", whatever events a
        # caller noted before it (a replay notes the recorded run's clock jumps at its start)
        held_before = any(what == "held" for _, what in self.events)
        self._event(t0, "released" if restart or held_before else "tracking")
        if not restart:
            self.started_s = t0
            if self.estimator.track:
                self.monitor = HealthMonitor(
                    self.estimator, baseline_s=self.baseline_s, threshold=self.threshold, persist_s=self.persist_s
                )
                adapted = tuple(name for name in self.estimator.track if name in RIG_PARAMETERS)
                if adapted and self.calm_walks < 1:
                    self._walks = AdaptiveWalks(self.monitor, adapted, self.calm_walks)
        else:
            self._checks_from_s = t0 + 1.0  # the health checks wait for the estimate to settle again
        if self.forecast_horizon_s > 0:
            self._next_forecast_s = t0 + self.forecast_every_s
        return True

    def _take_accel(
        self, node: int, t_v: float, got: NodeSample, torques_n_m: ArrayLike
    ) -> tuple[float, float, float, float, float, float, float]:
        """The node's accelerometer taken into the estimate after its angle and rate
        (``RigEstimator.update_accel``), read in its learned frame (its noise along the frame's
        axes: the node model's per sensor axis, projected), at the rig's mount radius (OM1, OM2:
        the frame's own radius comes from a second of swinging, in which r alpha and g sin phi are
        nearly proportional: 1 % off, 4 mm on M1, which left a mean NIS of 14); (measured tangential and
        normal, their innovations and the innovations' sigmas, m/s^2, and the NIS), NaN where none
        was taken (no reading, or one held out beyond ``JUMP_Z`` sigmas)."""
        none = (math.nan,) * 7
        if not math.isfinite(got.accel_tangential_m_s2):
            return none
        frame = self.measurements[node].frame
        if frame is not None and frame is not self._accel_frames[node]:
            variance = self.estimator.accel_axis_sigma_m_s2**2
            sigma = np.sqrt([variance @ np.square(frame.tangential), variance @ np.square(frame.toward_pivot)])
            radius = self.params.om1_m if node == 0 else self.params.om2_m
            self.estimator.set_accel_frame(node, radius, sigma)
            self._accel_frames[node] = frame
        measured = (got.accel_tangential_m_s2, got.accel_normal_m_s2)
        update = self.estimator.update_accel(t_v, node, *measured, torques_n_m, late_s=LATE_S, gate_z=JUMP_Z)
        if not update.applied:
            return (*measured, *none[2:])
        (s00, _), (_, s11) = update.covariance.tolist()
        return (*measured, *update.innovation.tolist(), math.sqrt(s00), math.sqrt(s11), update.nis)

    def _jumped(self, node: int, t_v: float) -> bool:
        """A node's angle jumped while its rate still follows the model (it turned on its mount):
        its offset's variance takes the jump in, so that the offset follows at once."""
        recent = self._recent_z[node]
        if len(recent) < JUMP_SAMPLES:
            return False
        jump = float(np.mean([nu for nu, _, _ in recent]))
        name = f"offset_m{node + 1}_rad"
        if name in self.estimator.track:
            i = NSTATE + self.estimator.track.index(name)
            self.estimator.p[i, i] += jump * jump
        name = f"accel_turn_m{node + 1}_rad"
        if name in self.estimator.track:  # the accelerometer turned with the node
            i = NSTATE + self.estimator.track.index(name)
            self.estimator.x[i] += jump
            self.estimator.p[i, i] += (0.2 * jump) ** 2
        recent.clear()
        self._recent_nis.clear()
        self._node_baseline_done = True  # a slip before the node states' baseline: their references stay
        self._event(t_v, f"m{node + 1} angle jumped by {math.degrees(jump):+.2f} deg")
        return True

    def _touched(self, t_v: float, why: str = "touched") -> None:
        """The innovations say the rig no longer moves as the model does (a hand on it), or the
        estimate diverged (``why`` says which, as the event): stop the estimate until it is free
        again; the tracked parameters go back to before."""
        self._tracking = False
        self._open_forecasts = []
        self._next_forecast_s = math.inf
        self._event(t_v, why)

    def note(self, t_s: float, what: str) -> None:
        """An event the caller saw (e.g. a node's clock jumped), kept with the twin's own."""
        self._event(t_s, what)

    def _event(self, t_s: float, what: str) -> None:
        self.events.append((t_s, what))
        self._events_out.append((t_s, what))

    def _parameter_check(self) -> ParameterCheck:
        assert self.monitor is not None
        found = self.estimator.parameters()
        names = tuple(found)
        value = np.array([found[n][0] for n in names])
        sigma = np.array([found[n][1] for n in names])
        ref = self.monitor.reference
        reference = np.array([ref[n] for n in names]) if ref is not None else np.full(len(names), np.nan)
        return ParameterCheck(self.estimator.t_s, names, value, sigma, reference, (value - reference) / sigma)

    def _score(self, node: int, t_v: float, phi: float) -> None:
        """Score the open forecasts against this measurement (before it is taken in): the forecast
        angle at its instant by cubic Hermite interpolation (angle and rate) between grid points."""
        keep = []
        r = float(self.estimator.measurement_sigma[node, 0])
        offset = self._offset(node) if self._open_forecasts else 0.0
        t_v = t_v - self._delay(node)  # M2's values stand for an instant its tracked delay earlier
        for f in self._open_forecasts:
            t0, t_end = float(f.t_s[0]), float(f.t_s[-1])
            if t_v > t_end:
                continue
            keep.append(f)
            horizon = t_v - t0
            if horizon <= 0:
                continue
            k = min(int(horizon / FORECAST_STEP_S), len(f.t_s) - 2)
            ta, tb = float(f.t_s[k]), float(f.t_s[k + 1])
            h = tb - ta
            u = (t_v - ta) / h
            pa, pb = float(f.mean[k, node]), float(f.mean[k + 1, node])
            va, vb = float(f.mean[k, 2 + node]) * h, float(f.mean[k + 1, 2 + node]) * h
            u2, u3 = u * u, u * u * u
            mean = (2 * u3 - 3 * u2 + 1) * pa + (u3 - 2 * u2 + u) * va + (-2 * u3 + 3 * u2) * pb + (u3 - u2) * vb
            sd = math.hypot((1 - u) * float(f.sigma[k, node]) + u * float(f.sigma[k + 1, node]), r)
            error = phi - offset - mean
            b = bisect.bisect_left(HORIZON_BINS_S, horizon - 1e-9)
            if b < len(HORIZON_BINS_S):
                self._score_n[b] += 1
                self._score_sq[b] += error * error
                self._score_in[b] += abs(error) <= 3 * sd
        self._open_forecasts = keep

    def _on_its_tick(
        self, node: int, got: NodeSample, torques_n_m: ArrayLike | Callable[[float], tuple[float, float]]
    ) -> float:
        """The instant of a sample's value: as the node's measurement gives it, or the fusion tick
        on the other side of the sample where the learned phase has put it on the wrong side of a
        tick. A node whose clock drifts against its chip's fusion moves its samples across the
        ticks; as one crosses, the learned phase (its roughness sums remember 10 s) assigns its
        value to the tick a period away for a while, and the estimator would take a whole period
        (10 ms: 20 mrad at 2 rad/s) as a jump of the node's delay. Only a sample within the learned
        phase's stretch (at least ``TICK_NEAR_S``) of a tick is checked: its angle against the
        estimate carried to either instant (second order in time, the stated rig's force law at the
        estimate); the other tick (not after the sample) is taken when the given one misses by over
        ``TICK_MISS_Z`` sigmas and the other explains the angle ``TICK_BETTER`` times better."""
        m = self.measurements[node]
        if m.phase is None or not m.phase.ready:
            return got.t_s
        period = m.phase.period_s
        lo, hi = m.phase.estimate(got.sample_t_s)[1]
        near = max(TICK_NEAR_S, hi - lo)  # the learned phase is good to its stretch
        age = got.sample_t_s - got.t_s  # in [0, period)
        if near <= age <= period - near:
            return got.t_s
        other = min(got.t_s + period, got.sample_t_s) if age > period / 2 else got.t_s - period
        est = self.estimator
        x = est.x
        tau = np.asarray(torques_n_m(got.t_s) if callable(torques_n_m) else torques_n_m, dtype=float)
        alpha = accelerations_at(x, self._stated_coef, float(tau[0]), float(tau[1]))[node]
        sigma = math.sqrt(float(est.p[node, node]) + float(est.measurement_sigma[node, 0]) ** 2)

        def miss(t: float) -> float:
            dt = t - self._delay(node) - est.t_s
            return abs(got.phi_rad - self._offset(node) - (x[node] + x[2 + node] * dt + 0.5 * alpha * dt * dt)) / sigma

        given, alternative = miss(got.t_s), miss(other)
        if given > TICK_MISS_Z and alternative * TICK_BETTER < given and other >= est.t_s - LATE_S:
            self._ticks_moved[node] += 1
            return other
        return got.t_s

    def _delay(self, node: int) -> float:
        track = self.estimator.track
        return (
            float(self.estimator.x[NSTATE + track.index("delay_m2_s")]) if node == 1 and "delay_m2_s" in track else 0.0
        )

    def _offset(self, node: int) -> float:
        name = f"offset_m{node + 1}_rad"
        track = self.estimator.track
        return float(self.estimator.x[NSTATE + track.index(name)]) if name in track else 0.0

    def waiting_text(self) -> str:
        """Why the estimate has not started, for a status line: a node not heard from yet, or
        what each node's measurement still learns (its fusion timing and frame need it to swing)."""
        silent = [f"m{k + 1}" for k in range(2) if self._samples[k] == 0]
        if silent:
            return f"waiting for {' and '.join(silent)}'s samples"
        learning = [f"m{k + 1} {why}" for k, why in enumerate(self._waiting) if why is not None]
        if learning:
            return "learning (the nodes must swing): " + "; ".join(learning)
        return "waiting to start (both nodes measuring)"

    @property
    def samples(self) -> tuple[int, int]:
        """Each node's samples given so far."""
        return self._samples[0], self._samples[1]

    def _checks_held(self, t_v: float) -> bool:
        """Whether the health checks are held now: while a node's recent mean NIS exceeds
        ``HOLD_NIS`` (ten times a healthy rig's), the estimate, its parameters included, is not the
        rig's (a timing the twin does not follow, a drive it is not given, a rig unlike the model),
        and an alarm on a parameter would name a change that did not happen. Said once as an
        event each way, with what it most likely means: a model that fitted for ``FITTED_S`` or
        more before (its recent NIS within ``MISFIT_NIS``) met a change it does not track (a
        spring or inertia other than the tracked ones: no parameter alarms); one that never
        fitted, a rig unlike its stated parameters (calibrate it). Checked every ``HOLD_EVERY_S``."""
        if t_v < self._hold_checked_s + HOLD_EVERY_S:
            return self._holding
        self._hold_checked_s = t_v
        recent = self.recent_nis()
        worst = max(recent) if all(len(v) == RECENT_NIS for v in self._nis) else math.nan
        if worst <= MISFIT_NIS:
            self._fitted_s += HOLD_EVERY_S
        holding = worst > HOLD_NIS
        if holding != self._holding:
            self._holding = holding
            if holding:
                node = int(np.argmax(recent)) + 1
                why = (
                    f"after fitting it for {self._fitted_s:.0f} s: something the twin does not track changed (a "
                    "spring or inertia other than the tracked ones, a node's mount or timing), or a hand is on the rig"
                    if self._fitted_s >= FITTED_S
                    else (
                        f"and has fitted it for only {self._fitted_s:.0f} s"
                        if self._fitted_s
                        else "and has not fitted it"
                    )
                    + " since the start: the rig most likely differs from its stated parameters (calibrate it: "
                    "'pendsim calibrate' on a recording of it, then --params-file), or a node's timing the twin does "
                    "not follow"
                )
                self._event(
                    t_v, f"health checks held: the model does not fit the data (M{node}'s mean NIS {worst:.0f}) {why}"
                )
            else:
                self._event(t_v, "health checks resumed")
        return self._holding

    def misfit(self) -> str | None:
        """A line naming the nodes whose recent innovations are far larger than the filter predicts
        (mean NIS over the last ``RECENT_NIS`` updates above ``MISFIT_NIS``; 2 on a healthy rig),
        or None: the estimate of such a node is not to be trusted to its stated sigmas (a timing the
        twin does not follow, a drive it is not given, a rig unlike the model, a fault)."""
        bad = [(f"M{k + 1}", nis) for k, nis in enumerate(self.recent_nis()) if nis > MISFIT_NIS]
        if not bad:
            return None
        named = ", ".join(f"{name}'s mean NIS {nis:.1f}" for name, nis in bad)
        return f"the model does not fit the data ({named} over the last 2 s; 2 on a healthy rig)"

    def recent_nis(self) -> tuple[float, float]:
        """Each node's mean NIS over its last ``RECENT_NIS`` updates after the settling (NaN: none)."""
        first, second = (float(np.mean(v)) if v else math.nan for v in self._nis)
        return first, second

    def learned(self) -> tuple[Learned, Learned]:
        """What each node's measurement has learned (fusion phase, frame)."""
        return self.measurements[0].learned, self.measurements[1].learned

    def drain(self) -> TwinOutput:
        """What was produced since the last call."""
        rows = np.array(self._rows, dtype=float).reshape(-1, 24)
        est = (
            Estimates(
                t_s=rows[:, 0],
                node=rows[:, 1].astype(np.int64),
                measured=rows[:, 2:4],
                state=rows[:, 4:8],
                sigma=rows[:, 8:12],
                innovation=rows[:, 12:14],
                innovation_sigma=rows[:, 14:16],
                nis=rows[:, 16],
                accel_measured=rows[:, 17:19],
                accel_innovation=rows[:, 19:21],
                accel_innovation_sigma=rows[:, 21:23],
                accel_nis=rows[:, 23],
            )
            if len(rows)
            else Estimates.empty()
        )
        out = TwinOutput(est, tuple(self._forecasts), tuple(self._checks), tuple(self._alarms), tuple(self._events_out))
        self._rows, self._forecasts, self._checks, self._alarms, self._events_out = [], [], [], [], []
        return out

    def forecast_score(self) -> ForecastScore:
        n = self._score_n
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt(self._score_sq / n)
            within = self._score_in / n
        return ForecastScore(
            HORIZON_BINS_S, tuple(int(v) for v in n), tuple(float(v) for v in rms), tuple(float(v) for v in within)
        )

    def summary(self) -> TwinSummary:
        nis = tuple(t / n if n else math.nan for t, n in zip(self._nis_sum, self._nis_count, strict=True))
        (angle, rate), (angle2, rate2) = self._whiteness
        accel_nis = tuple(
            t / n if n else math.nan for t, n in zip(self._accel_nis_sum, self._accel_nis_count, strict=True)
        )
        (t1, n1), (t2, n2) = self._accel_whiteness
        learned = self.learned()
        drift = [math.nan if d.phase_drift_ppm is None else d.phase_drift_ppm for d in learned]
        return TwinSummary(
            samples=self.samples,
            started_s=self.started_s,
            nis_mean=(nis[0], nis[1]),
            whiteness_p=((angle.p_value(), rate.p_value()), (angle2.p_value(), rate2.p_value())),
            forecast=self.forecast_score(),
            alarms=tuple(self._all_alarms),
            parameters=self.estimator.parameters() if not math.isnan(self.started_s) else {},
            events=tuple(self.events),
            monitored_from_s=self.monitor.history[0][0]
            if self.monitor is not None and self.monitor.history
            else math.nan,
            accel_nis_mean=(accel_nis[0], accel_nis[1]),
            accel_whiteness_p=((t1.p_value(), n1.p_value()), (t2.p_value(), n2.p_value())),
            stated={name: self.estimator.stated(name) for name in self.estimator.track if name in RIG_PARAMETERS},
            phase_drift_ppm=(drift[0], drift[1]),
            phase_moving_unfollowed=(learned[0].phase_moving_unfollowed, learned[1].phase_moving_unfollowed),
        )
