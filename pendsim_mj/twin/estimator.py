"""The rig's state at every instant from its nodes, as they arrive: an unscented Kalman filter on
the planar model (the live twin's estimator).

State x = (phi1, phi2, omega1, omega2) (rad, rad/s), followed by the tracked parameters
(``TRACKABLE``, any of them: the hinges' damping b1, b2 in N m s/rad and dry friction F1, F2 in
N m, the coupling springs' moment constant K_s = 2 c1 l01 l04 in N m, and each node's angle offset
on its mount in rad), with covariance P. A tracked parameter is a random walk (its rate of change
``drift_per_s`` per sqrt(s)): the filter follows a slow drift or a step, with its interval.

- **Prediction** to each sample's instant: the sigma points (Merwe's scaled set, 2n + 1) are
  advanced by one classical RK4 step of the fast engine's force law (``control.plant.FastPlant``,
  the reference's equations in closed form, each point with its own tracked parameters) over the
  interval (at most one node period, 12.5 ms),
  with the motor torques applied over it (a controller's, or none). Process noise: an unknown
  white torque on each hinge of spectral density ``torque_noise_n_m`` ^2 per Hz (the model's error
  and the unmodelled disturbances), discretised over the interval (its exact covariance for a
  double integrator per hinge, scaled by 1/J).
- **Update** with one node's sample: its swing angle (the fused orientation's angle about the
  hinge) and its gyro's rate about the hinge, z = (phi_n + offset_n, omega_n), linear in x: the
  Kalman update is exact (``unscented.swing_moments`` and ``corrected``: P - K S K', kept
  symmetric). Noise: the BNO055 model's gyro sigma on the hinge axis and the orientation's
  quantisation plus its fusion error (``observe.NodeObserver``'s numbers).
- **Innovations** nu = z - H x and their covariance S are kept with each update: on a healthy rig
  nu is white with covariance S, and the normalised innovation squared nu' S^-1 nu has a chi^2
  distribution with 2 degrees of freedom (mean 2): the health monitor's input.

The last ``keep_s`` seconds of samples are kept (``recent``, ``Sample``; none by default) for a
health monitor that re-runs them under competing hypotheses.

Samples must come in time order; a sample older than the filter's time (reordered in transport)
is refused (``StaleSample``), the caller decides (acquire's timeline orders them). Only a sample at
most ``late_s`` older (``update``'s keyword; the two nodes' value instants, ``twin.measurement``,
interleave out of order by up to a fusion period) is taken, by an unscented update through the
model run back to its instant. The unscented update also serves M2's tracked delay against M1
(``delay_m2_s``: its angle and rate read d earlier, phi - d omega and omega - d alpha); a node's
tracked offset rate makes its offset a smooth drift (the BNO055's fusion error).
"""

from __future__ import annotations

import collections
import copy
import dataclasses
import itertools
import math
from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.control.plant import FastPlant
from pendsim_mj.engines.fast_planar.closed_form import COEFFICIENTS
from pendsim_mj.errors import ParameterError, PendsimError
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import FUSION_RATE_HZ, SAMPLE_RATE_HZ, SWING_ANGLE_SIGMA_RAD, Bno055
from pendsim_mj.twin.measurement import FusionPhase
from pendsim_mj.twin.unscented import (
    ACCEL,
    SWING,
    accelerations_at,
    add_process_noise,
    advanced,
    corrected,
    predict,
    readings,
    swing_moments,
    update_moments,
)

Floats = NDArray[np.float64]
_T = TypeVar("_T")
NSTATE = 4
HINGE_AXIS = 2  # the sensor axis along the hinge (z) in the default mount
DEFAULT_TORQUE_NOISE_N_M = 1e-6  # N m / sqrt(Hz): white torque standing for the model's error. On the
# sensor model's data of a MuJoCo run (60 s, 4800 samples per node) the innovations are white at
# this level, on ideal and on fusion-timed values; 5e-6 left lag 1-8 autocorrelations of -0.02 to
# -0.04 on the angle, 2e-5 -0.04 on both channels, 1e-4 -0.14 to -0.18 on the rate (a filter that
# believes in more process noise than there is follows the measurement noise: docs/twin.md)

# name -> (the force law's coefficient it sets, or None for a node's angle offset; its unit; the
# default drift per sqrt(s): a step of the size is followed within tens of seconds). Damping
# and dry friction drift slowly (4e-6 N m s/rad and 6e-6 N m per sqrt(s), 0.6 % of b1 and 3 % of
# the 2e-4 N m per sqrt(s)): a faster walk forgets the amplitude's decay, which is what
# tells the two apart, and at 5 times these rates dry friction of 2e-4 N m stayed below 6 sigma.
TRACKABLE: dict[str, tuple[str | None, str, float]] = {
    "b1_n_m_s": ("b1_n_m_s", "N m s/rad", 4e-6),
    "b2_n_m_s": ("b2_n_m_s", "N m s/rad", 4e-6),
    "friction1_n_m": ("friction1_n_m", "N m", 6e-6),
    "friction2_n_m": ("friction2_n_m", "N m", 6e-6),
    "coupling_sin_n_m": ("coupling_sin_n_m", "N m", 5e-4),
    "offset_m1_rad": (None, "rad", 1e-3),
    "offset_m2_rad": (None, "rad", 1e-3),
    "offset_rate_m1_rad_s": (None, "rad/s", 1e-4),
    "offset_rate_m2_rad_s": (None, "rad/s", 1e-4),
    "offset_accel_m1_rad_s2": (None, "rad/s^2", 1e-5),
    "offset_accel_m2_rad_s2": (None, "rad/s^2", 1e-5),
    "offset_jerk_m1_rad_s3": (None, "rad/s^3", 1e-5),
    "offset_jerk_m2_rad_s3": (None, "rad/s^3", 1e-5),
    "delay_m2_s": (None, "s", 1e-5),
    "accel_turn_m1_rad": (None, "rad", 1e-6),
    "accel_turn_m2_rad": (None, "rad", 1e-6),
}
"""The parameters the estimator can track: name -> (coefficient of ``fast_planar.closed_form``,
unit, default drift per sqrt(s)). M2's delay: how much older M2's values are than the instants
they are given, beyond M1's (``twin.measurement`` knows each node's fusion phase only to a
quarter fusion period). The difference of the two nodes' delays shows through the coupled model;
their common part never does (it only shifts the estimate's time), so M1 is the reference. A
node's offset rate: its offset then moves at this rate, itself a random walk (a smooth offset: the
BNO055's slowly varying fusion error, ``Imperfections.fusion_error_rad``; it needs the offset
tracked too). A node's accelerometer turn: how far its accelerometer's axes are turned about the
hinge from the swing frame it is read in (``update_accel``): the frame's own error (its fit leaves
the in-plane axes about 0.1 deg off: 0.02 m/s^2 on the tangential reading, twice its noise), and a
turn on the mount after it was found; the fused orientation's slow error, which the offset also
carries, the accelerometer does not share."""
OFFSET_CHAIN = ("offset", "offset_rate", "offset_accel", "offset_jerk")
OFFSET_CHAIN_UNITS = ("rad", "rad_s", "rad_s2", "rad_s3")
DIVERGED_RAD = 1.0
"""An angle estimate that moves further than this in one sample (12.5 ms: 80 rad/s), or a
hypothesis whose angles are this far from the estimate's, has diverged: seen, 207 rad (33 whole
turns) on a node whose fusion timing was not followed, where the angle's innovation wraps and the
filter went on as if it fitted. The session restarts its estimate; the health monitor does not
take such a hypothesis as the explanation of a change."""
DELAY_SIGMA0_S = 0.25e-2 / math.sqrt(6.0)  # the start: two nodes' errors, each uniform over a 2.5 ms stretch, s


class _Terms:
    """A matrix that is a sum of terms coefficient * h**power * scale, each at a flat index into
    (n, n); built from rows (flat index, power, coefficient, which scale)."""

    def __init__(self, rows: Floats) -> None:
        self.size = len(rows)
        self.flat = rows[:, 0].astype(np.intp)
        self.power, self.coefficient = rows[:, 1], rows[:, 2]
        self.which = rows[:, 3].astype(np.intp)
        self.arrays = (self.flat, np.ascontiguousarray(self.power), np.ascontiguousarray(self.coefficient), self.which)

    def matrix(self, h: float, n: int, scale: Floats | float = 1.0) -> Floats:
        w = self.coefficient * h**self.power * scale
        return np.asarray(np.bincount(self.flat, w, minlength=n * n), dtype=np.float64).reshape(n, n)


class Sample(NamedTuple):
    """One node's sample as the estimator took it in (``RigEstimator.recent``): its instant (s),
    node (0 M1, 1 M2), swing angle (rad), hinge rate (rad/s), the hinge torques held (N m) and its
    accelerometer's tangential and normal reading (m/s^2; None: not taken in)."""

    t_s: float
    node: int
    phi_rad: float
    omega_rad_s: float
    torques_n_m: tuple[float, float]
    accel_m_s2: tuple[float, float] | None = None


class StaleSample(PendsimError):
    """A sample older than the filter's time (it arrived out of order)."""


@dataclasses.dataclass(frozen=True)
class Update:
    """One node's sample taken into the estimate.

    Attributes:
      t_s: its instant, s. node: 0 (M1) or 1 (M2).
      innovation: (2,) measured minus predicted (angle rad, rate rad/s).
      covariance: (2, 2) the innovation's predicted covariance S.
      nis: the normalised innovation squared nu' S^-1 nu (chi^2 with 2 degrees of freedom).
      applied: False when the sample was held out (``update``'s ``gate_angle_z``).
    """

    t_s: float
    node: int
    innovation: Floats
    covariance: Floats
    nis: float
    applied: bool = True


def _gated(gate_angle_z: float, gate_rate_z: float) -> Callable[[float, float, float, float], bool]:
    """Whether a swing sample is held out: its angle's innovation nu0 beyond ``gate_angle_z``
    sigmas (of its variance s00) while its rate's nu1 is within ``gate_rate_z`` (of s11): the
    node's angle jumped (its mount), not the rig's motion."""

    def held(nu0: float, nu1: float, s00: float, s11: float) -> bool:
        return abs(nu0) > gate_angle_z * math.sqrt(s00) and abs(nu1) <= gate_rate_z * math.sqrt(s11)

    return held


def _beyond(gate_z: float) -> Callable[[float, float, float, float], bool]:
    """Whether a reading is held out: its innovation (nu0, nu1) beyond ``gate_z`` sigmas (of its
    variances s00, s11) on either axis."""

    def held(nu0: float, nu1: float, s00: float, s11: float) -> bool:
        return abs(nu0) > gate_z * math.sqrt(s00) or abs(nu1) > gate_z * math.sqrt(s11)

    return held


@dataclasses.dataclass(frozen=True)
class Forecast:
    """The predicted motion.

    Attributes:
      t_s: (k,) instants from the estimate's time on, s.
      mean: (k, 4) predicted phi1, phi2 (rad), omega1, omega2 (rad/s).
      sigma: (k, 4) their standard deviations.
    """

    t_s: Floats
    mean: Floats
    sigma: Floats


def _sigma_weights(n: int, alpha: float, beta: float, kappa: float) -> tuple[float, Floats, Floats]:
    lam = alpha * alpha * (n + kappa) - n
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = lam / (n + lam) + (1.0 - alpha * alpha + beta)
    return n + lam, wm, wc


class RigEstimator:
    """The unscented Kalman filter of the module docstring.

    Args:
      params: the rig (e.g. ``pendsim calibrate``'s).
      nodes: the node model (its noise sets the measurement noise).
      torque_noise_n_m: process noise, N m / sqrt(Hz) on each hinge.
      track: names of ``TRACKABLE`` to follow as states (none: the rig's parameters are known).
      drift_per_s: each tracked parameter's random-walk rate, unit per sqrt(s) (default: TRACKABLE's).
      alpha, beta, kappa: the sigma points' spread (Merwe's scaled set).
      angle_sigma_rad: the swing angle's white noise, rad (default: the quaternion's quantisation
        and the node model's fusion error together; a twin that tracks the fusion error as the
        nodes' offsets gives the quantisation alone, ``twin.measurement.TWIST_SIGMA_RAD``).
      keep_s: how many seconds of samples to keep in ``recent`` (0: none; a monitor may raise it).

    Attributes:
      fusion_error_rad: the nodes' slowly varying orientation error, rms, rad (``nodes``'
        imperfections; in the angle's noise, and a spread the health monitor allows the offsets).
      count: samples taken in since construction.
      recent: the last ``keep_s`` seconds of samples (``Sample``), oldest first.
    """

    def __init__(
        self,
        params: RigParams = DEFAULT_PARAMS,
        *,
        nodes: Bno055 | None = None,
        torque_noise_n_m: float = DEFAULT_TORQUE_NOISE_N_M,
        track: tuple[str, ...] = (),
        drift_per_s: dict[str, float] | None = None,
        alpha: float = 1e-3,
        beta: float = 2.0,
        kappa: float = 0.0,
        angle_sigma_rad: float | None = None,
        keep_s: float = 0.0,
    ) -> None:
        if not (math.isfinite(keep_s) and keep_s >= 0):
            raise ParameterError(f"keep_s must be a finite number >= 0 s, got {keep_s!r}")
        if not (math.isfinite(torque_noise_n_m) and torque_noise_n_m > 0):
            raise ParameterError(f"torque_noise_n_m must be > 0, got {torque_noise_n_m!r}")
        nodes = nodes if nodes is not None else Bno055()
        self.params = params
        self.torque_noise_n_m = float(torque_noise_n_m)
        gyro = float(nodes.noise_model.gyro_sigma_rad_s[HINGE_AXIS]) if nodes.noise else 1e-6
        quantisation = SWING_ANGLE_SIGMA_RAD if nodes.noise else 1e-7
        self.fusion_error_rad = float(nodes.imperfections.fusion_error_rad)
        angle = math.hypot(quantisation, self.fusion_error_rad)
        if angle_sigma_rad is not None:
            if not (math.isfinite(angle_sigma_rad) and angle_sigma_rad > 0):
                raise ParameterError(f"angle_sigma_rad must be > 0, got {angle_sigma_rad!r}")
            angle = float(angle_sigma_rad)
        self.measurement_sigma = np.array([[angle, gyro], [angle, gyro]])  # per node (M1, M2): angle rad, rate rad/s
        accel = nodes.noise_model.accel_sigma_m_s2 if nodes.noise else (1e-4, 1e-4, 1e-4)
        self.accel_axis_sigma_m_s2 = np.array(accel, dtype=float)  # (3,) the node model's, per sensor axis
        self.accel_sigma_m_s2 = np.array([[accel[0], accel[1]], [accel[0], accel[1]]])  # per node: tangential, normal
        # (the model's mount: x, y; ``set_accel_frame`` for another)
        self.accel_radius_m = np.array([params.om1_m, params.om2_m])  # each node's distance from the hinge, m
        unknown = [name for name in track if name not in TRACKABLE]
        if unknown or len(set(track)) != len(track):
            raise ParameterError(f"cannot track {unknown or track}; trackable: {', '.join(TRACKABLE)}")
        self.track = tuple(track)
        drift = {name: TRACKABLE[name][2] for name in self.track} | (drift_per_s or {})
        self.drift_per_s = np.array([drift[name] for name in self.track])
        self.n = NSTATE + len(self.track)
        self._rows = [COEFFICIENTS.index(TRACKABLE[name][0] or "") if TRACKABLE[name][0] else -1 for name in self.track]
        self._row_of = np.array(self._rows, dtype=np.intp)  # each tracked parameter's force-law row, -1: none
        self._offsets = {
            int(name[8]) - 1: NSTATE + i for i, name in enumerate(self.track) if name.startswith("offset_m")
        }
        self._delays = {int(name[7]) - 1: NSTATE + i for i, name in enumerate(self.track) if name.startswith("delay")}
        self._chains = [self._chain(k) for k in self._offsets]  # each node's offset and its derivatives' indices
        self._chain_terms()
        self._turns = {
            int(name[12]) - 1: NSTATE + i for i, name in enumerate(self.track) if name.startswith("accel_turn")
        }
        self._scale, self._wm, self._wc = _sigma_weights(self.n, alpha, beta, kappa)
        self._plant = FastPlant(params, nenv=2 * self.n + 1)
        self._coef = self._plant.coef.copy()
        self._inertia = np.array([params.j1_kg_m2, params.j2_kg_m2])
        self._density_of: float | None = None  # the torque noise ``_hinge_density`` was found for
        self._density = np.zeros(2)
        self.t_s = 0.0
        self.x = np.zeros(self.n)
        self.p = np.eye(self.n)
        self.keep_s = float(keep_s)
        self.count = 0
        self.repaired = 0  # times P was found indefinite and replaced by its nearest PSD matrix
        self.recent: collections.deque[Sample] = collections.deque()

    def _chain(self, node: int) -> list[int]:
        """The node's offset and the derivatives tracked with it (``OFFSET_CHAIN``): their indices in
        the state, lowest first; each derivative needs the ones below it."""
        chain: list[int] = []
        for level, stem in enumerate(OFFSET_CHAIN):
            name = f"{stem}_m{node + 1}_{OFFSET_CHAIN_UNITS[level]}"
            if name in self.track:
                if len(chain) != level:
                    raise ParameterError(f"{name} needs the node's {OFFSET_CHAIN[len(chain)]} tracked too")
                chain.append(NSTATE + self.track.index(name))
        return chain

    def _chain_terms(self) -> None:
        """The offset chains over a step h as sums of terms coefficient * h**power: the transition
        (``_taylor``: each level's Taylor series in those above it) and the covariance added by
        each derivative's random walk integrated into those below it (``_walk``, with the walking
        parameter's index in ``track``); each term's place is a flat index into the chains' block
        (``_chain_cols``, c of them: (c, c))."""
        ordered = sorted(i for chain in self._chains for i in chain)
        at = {i: j for j, i in enumerate(ordered)}  # a state's place in the block
        c = self._chain_size = len(ordered)
        self._chain_cols: Any = np.array(ordered, dtype=np.intp)
        self._chain_index = self._chain_cols.copy()  # always indices (the compiled prediction's)
        self._chain_block: Any = np.ix_(self._chain_cols, self._chain_cols)
        if c and ordered[-1] - ordered[0] == c - 1:  # one run of states: views
            self._chain_cols = slice(ordered[0], ordered[-1] + 1)
            self._chain_block = (self._chain_cols, self._chain_cols)
        self._parameter_diagonal = np.arange(NSTATE, self.n)
        taylor, walk = [], []
        for chain in self._chains:
            for level in range(len(chain)):
                for j in range(1, len(chain) - level):
                    taylor.append((at[chain[level + j]] * c + at[chain[level]], j, 1.0 / math.factorial(j), 0))
                for i, k in itertools.product(range(level + 1), repeat=2):
                    if level > 0 and (i != level or k != level):  # the walk's own variance: the diagonal
                        a, b = level - i, level - k
                        coefficient = 1.0 / (math.factorial(a) * math.factorial(b) * (a + b + 1))
                        walk.append((at[chain[i]] * c + at[chain[k]], a + b + 1, coefficient, chain[level] - NSTATE))
        self._taylor, self._walk = (_Terms(np.array(t, dtype=float).reshape(-1, 4)) for t in (taylor, walk))

    def copy(self, *, drift_per_s: ArrayLike | None = None) -> RigEstimator:
        """An independent copy of the filter (its rig, settings, estimate and covariance), without
        its kept samples; ``drift_per_s`` (one per tracked parameter) replaces the random walks'
        rates (0 holds a parameter constant)."""
        other = copy.copy(self)
        other._plant = FastPlant(self.params, nenv=2 * self.n + 1)
        other._plant.coef[:] = self._plant.coef
        other.x, other.p = self.x.copy(), self.p.copy()
        other.accel_radius_m, other.accel_sigma_m_s2 = self.accel_radius_m.copy(), self.accel_sigma_m_s2.copy()
        if drift_per_s is not None:
            drift = np.asarray(drift_per_s, dtype=float)
            if drift.shape != (len(self.track),) or not np.all(np.isfinite(drift) & (drift >= 0)):
                raise ParameterError(f"drift_per_s must be {len(self.track)} numbers >= 0, got {drift_per_s!r}")
            other.drift_per_s = drift
        other.keep_s, other.count, other.recent = 0.0, 0, collections.deque()
        return other

    def stated(self, name: str) -> float:
        """A tracked parameter's value in the rig the estimator was given (0 for an offset)."""
        row = TRACKABLE[name][0]
        return 0.0 if row is None else float(self._coef[COEFFICIENTS.index(row), 0])

    def start(
        self,
        t_s: float,
        x0: ArrayLike,
        sigma0: ArrayLike = (0.05, 0.05, 0.2, 0.2),
        parameter_sigma0: ArrayLike | None = None,
        *,
        parameter0: ArrayLike | None = None,
    ) -> None:
        """Start at ``t_s`` from x0 (4,) with standard deviations sigma0 (4,) (rad, rad/s); the
        tracked parameters start at ``parameter0`` (default: the rig's values; one per tracked
        parameter, ``track``'s order and units) with ``parameter_sigma0`` (default: 20 s of
        drift; a delay at least ``DELAY_SIGMA0_S``)."""
        x = np.asarray(x0, dtype=float)
        if x.shape != (NSTATE,) or not np.all(np.isfinite(x)):
            raise ParameterError(f"the start state must be 4 finite numbers, got {x0!r}")
        if parameter_sigma0 is None:
            spread = self.drift_per_s * math.sqrt(20.0)
            for i in self._delays.values():
                spread[i - NSTATE] = max(spread[i - NSTATE], DELAY_SIGMA0_S)
        else:
            spread = np.asarray(parameter_sigma0, dtype=float)
        self.t_s = float(t_s)
        theta = [self.stated(name) for name in self.track] if parameter0 is None else parameter0
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (len(self.track),) or not np.all(np.isfinite(theta)):
            raise ParameterError(f"parameter0 must be {len(self.track)} finite numbers, got {parameter0!r}")
        self.x = np.concatenate([x, theta])
        self.p = np.diag(np.square(np.concatenate([np.asarray(sigma0, dtype=float), spread])))

    def _process_noise(self, h: float) -> Floats:
        """Covariance added over h by a white torque on each hinge (double integrator per hinge)
        and by the tracked parameters' random walks (compiled: ``unscented.add_process_noise``,
        which ``predict`` adds in its own call)."""
        q = np.zeros((self.n, self.n))
        add_process_noise(q, h, np.ascontiguousarray(self.drift_per_s, dtype=float), self._chain_index,
                          self._walk.arrays, self._hinge_density())  # fmt: skip
        return np.triu(q) + np.triu(q, 1).T

    def _hinge_density(self) -> Floats:
        """(2,) the white torque's spectral density over each hinge's inertia squared, rad^2/s^3
        (kept while ``torque_noise_n_m`` stays what it was)."""
        if self._density_of != self.torque_noise_n_m:
            self._density = np.square(self.torque_noise_n_m / self._inertia)
            self._density_of = self.torque_noise_n_m
        return self._density

    def _repaired(self, compute: Callable[[], _T]) -> _T:
        """``compute()`` (a compiled step that factors P), once more after ``_repair`` where P was
        found indefinite (numpy's LinAlgError from the Cholesky factor)."""
        try:
            return compute()
        except np.linalg.LinAlgError:
            self._repair()
            return compute()

    def _repair(self) -> None:
        """Rounding left P indefinite: the nearest PSD correlation instead, counted (``repaired``)."""
        self.repaired += 1
        d = np.sqrt(np.maximum(np.diag(self.p), 1e-300))
        w, v = np.linalg.eigh(0.5 * (self.p + self.p.T) / np.outer(d, d))
        self.p = np.outer(d, d) * ((v * np.maximum(w, 1e-9)) @ v.T)

    def _kept(self, t_s: float, node: int, phi_rad: float, omega_rad_s: float, torques_n_m: ArrayLike) -> None:
        """Count a sample taken in, and keep it for ``keep_s`` (``recent``)."""
        self.count += 1
        if self.keep_s > 0:
            tau = torques_n_m if isinstance(torques_n_m, tuple) else np.asarray(torques_n_m, dtype=float).tolist()
            self.recent.append(Sample(t_s, node, float(phi_rad), float(omega_rad_s), (float(tau[0]), float(tau[1]))))
            while self.recent[0].t_s < self.t_s - self.keep_s:
                self.recent.popleft()

    def _advance(self, points: Floats, h: float, torques_n_m: ArrayLike) -> Floats:
        """The sigma points (2n + 1, n) moved by one RK4 step of h (s; negative: back in time)
        with the torques (2,) held over it; the tracked parameters ride along unchanged (compiled:
        ``unscented.advanced``, which ``predict`` calls in its own)."""
        tau = np.asarray(torques_n_m, dtype=float)
        return advanced(np.ascontiguousarray(points), self._plant.coef, self._row_of, tau, float(h), self._chain_index,
                        self._taylor.arrays)  # fmt: skip

    def predict(self, t_s: float, torques_n_m: ArrayLike = (0.0, 0.0)) -> None:
        """Advance the estimate to ``t_s`` (not before the filter's time) with the hinge torques
        (2,) held over the interval."""
        h = float(t_s) - self.t_s
        if h < -1e-12:
            raise StaleSample(f"a sample at {t_s:.6f} s is older than the estimate at {self.t_s:.6f} s")
        if h <= 0:
            return
        tau = np.asarray(torques_n_m, dtype=float)
        hinge = self._hinge_density()
        # compiled: the sigma points, their step, the moments and the process noise in one call
        self.x, self.p = self._repaired(lambda: predict(
            self.x, np.ascontiguousarray(self.p), self._scale, self._wm, self._wc, self._plant.coef, self._row_of,
            tau, h, self._chain_index, self._taylor.arrays, self._walk.arrays,
            np.ascontiguousarray(self.drift_per_s, dtype=float), hinge,
        ))  # fmt: skip
        self.t_s = float(t_s)

    def update(
        self,
        t_s: float,
        node: int,
        phi_rad: float,
        omega_rad_s: float,
        torques_n_m: ArrayLike = (0.0, 0.0),
        *,
        late_s: float = 0.0,
        gate_angle_z: float = math.inf,
        gate_rate_z: float = 5.0,
    ) -> Update:
        """Take one node's sample (its swing angle and hinge rate at ``t_s``) into the estimate.

        ``late_s``: a sample up to this much older than the estimate (s) is still taken, through
        the model run back to its instant (``_late_update``): two nodes' value instants
        (``twin.measurement``) interleave out of order by up to one fusion period. Older ones
        are refused (``StaleSample``).

        ``gate_angle_z``: a sample whose angle innovation exceeds this many sigmas while its rate's
        stays within ``gate_rate_z`` is held out (``Update.applied`` False; the estimate is only
        predicted to its instant): a node that turned on its mount must not drag the state with
        it (the caller decides what the jump is)."""
        if node not in (0, 1):
            raise ParameterError(f"node must be 0 (M1) or 1 (M2), got {node!r}")
        a, b = self.measurement_sigma[node].tolist()
        late = 0 < self.t_s - float(t_s) <= late_s
        if not late:
            self.predict(t_s, torques_n_m)
        held = _gated(gate_angle_z, gate_rate_z)
        if late or node in self._delays:
            r = np.array([[a * a, 0.0], [0.0, b * b]])
            update = self._unscented_update(
                float(t_s), node, float(phi_rad), float(omega_rad_s), r, torques_n_m, SWING, wraps=True, held=held
            )
        else:  # linear in the state: the angle x[node] (plus the mount's offset), the rate x[2 + node]
            z_mean, s, pxz = swing_moments(self.x, self.p, node, self._offsets.get(node, -1), a * a, b * b)
            update = self._corrected(self.t_s, node, float(phi_rad), float(omega_rad_s), z_mean, s, pxz, True, held)
        if update.applied:
            self._kept(update.t_s, node, phi_rad, omega_rad_s, torques_n_m)
        return update

    def set_accel_frame(self, node: int, radius_m: float, sigma_m_s2: ArrayLike) -> None:
        """A node's accelerometer as its swing frame found it (``twin.measurement``): its distance
        from the hinge axis (m) and its noise (2,) along the swing's tangent and toward the pivot
        (m/s^2)."""
        sigma = np.asarray(sigma_m_s2, dtype=float)
        if not (math.isfinite(radius_m) and 0 < radius_m < 10):
            raise ParameterError(f"a node's radius must be in (0, 10) m, got {radius_m!r}")
        if sigma.shape != (2,) or not np.all(np.isfinite(sigma) & (sigma > 0)):
            raise ParameterError(f"the accelerometer's noise must be 2 numbers > 0, got {sigma_m_s2!r}")
        self.accel_radius_m[node], self.accel_sigma_m_s2[node] = radius_m, sigma

    def update_accel(
        self,
        t_s: float,
        node: int,
        tangential_m_s2: float,
        normal_m_s2: float,
        torques_n_m: ArrayLike = (0.0, 0.0),
        *,
        late_s: float = 0.0,
        gate_z: float = math.inf,
    ) -> Update:
        """Take one node's accelerometer reading at ``t_s``: the specific force (gravity included,
        m/s^2) along the swing's tangent and toward the pivot, in the node's swing frame.

        What a node at radius r reads (spec RIG.md section 6): z = (r alpha + g sin phi, r omega^2 +
        g cos phi), alpha from the force law at each sigma point (the tracked parameters' too),
        turned by the node's tracked accelerometer turn (``accel_turn_mN_rad``: the accelerometer
        turns with the node; the fused orientation's slowly varying error, the rest of the tracked
        offset, it does not share). Nonlinear in x: the unscented update. M2's tracked delay d:
        z - d dz/dt (dz/dt from the state and the force law's rate along the motion). Called
        after ``update`` with the same sample (sequential updates: the two sensors' noises are
        independent). ``gate_z``: a reading whose innovation exceeds this many
        sigmas on either axis is held out (``Update.applied`` False)."""
        if node not in (0, 1):
            raise ParameterError(f"node must be 0 (M1) or 1 (M2), got {node!r}")
        z0, z1 = float(tangential_m_s2), float(normal_m_s2)
        a, b = self.accel_sigma_m_s2[node].tolist()
        r = np.array([[a * a, 0.0], [0.0, b * b]])
        if not 0 < self.t_s - float(t_s) <= late_s:
            self.predict(t_s, torques_n_m)
        update = self._unscented_update(
            float(t_s), node, z0, z1, r, torques_n_m, ACCEL, wraps=False, held=_beyond(gate_z)
        )
        kept = self.recent[-1] if self.recent else None
        if update.applied and kept is not None and kept.node == node and kept.t_s == float(t_s):
            self.recent[-1] = kept._replace(accel_m_s2=(z0, z1))
        return update

    def _columns(self, node: int) -> tuple[int, int, int]:
        """The node's tracked delay's, offset's and accelerometer turn's states (-1: not tracked)."""
        return self._delays.get(node, -1), self._offsets.get(node, -1), self._turns.get(node, -1)

    def _readings(self, kind: int, at: Floats, node: int, torques_n_m: ArrayLike) -> Floats:
        """(m, 2) the node's readings at each point of at (m, n): ``kind`` ``unscented.SWING``, its swing
        angle and hinge rate (a tracked delay d: its values d older, first order, d^2 alpha / 2 <
        1e-5 rad for d < 2 ms; a tracked offset added to the angle), or ``ACCEL``, what its
        accelerometer reads (``update_accel``); compiled: ``unscented.readings``."""
        return readings(np.ascontiguousarray(at), kind, node, *self._columns(node), float(self.accel_radius_m[node]),
                        float(self.params.g_m_s2), self._plant.coef, self._row_of,
                        np.asarray(torques_n_m, dtype=float))  # fmt: skip

    def _unscented_update(
        self,
        t_s: float,
        node: int,
        z0: float,
        z1: float,
        r: Floats,
        torques_n_m: ArrayLike,
        kind: int,
        *,
        wraps: bool,
        held: Callable[[float, float, float, float], bool],
    ) -> Update:
        """The update through the sigma points, where the measurement (z0, z1) is not linear in the
        state: a sample from before the estimate's time (the state run back to its instant, one
        RK4 step of t_s - self.t_s per sigma point; the estimate's time stays), a node with a
        tracked delay, the accelerometer (``_readings``); ``kind``
        (``unscented.SWING`` or ``ACCEL``) names which; r (2, 2) its noise. ``wraps``: its first component is an angle
        (its innovation wraps); ``held(nu0, nu1, s00, s11)``: the sample is held out. The torque noise over a
        late sample's gap (at most a fusion period: 1e-4 rad/s at the default level, a tenth of the
        gyro's noise) is neglected."""
        gap = t_s - self.t_s
        # compiled: the sigma points, run back by a late sample's gap, their readings, the moments
        z_mean, s, pxz = self._repaired(lambda: update_moments(
            self.x, np.ascontiguousarray(self.p), self._scale, self._wm, self._wc, self._plant.coef, self._row_of,
            np.asarray(torques_n_m, dtype=float), gap, self._chain_index, self._taylor.arrays, kind, node,
            *self._columns(node), float(self.accel_radius_m[node]), float(self.params.g_m_s2), r,
        ))  # fmt: skip
        return self._corrected(t_s, node, z0, z1, z_mean, s, pxz, wraps, held)

    def _corrected(
        self,
        t_s: float,
        node: int,
        z0: float,
        z1: float,
        z_mean: Floats,
        s: Floats,
        pxz: Floats,
        wraps: bool,
        held: Callable[[float, float, float, float], bool],
    ) -> Update:
        """The measurement (z0, z1) against its prediction: z_mean (2,), its covariance s (2, 2) and
        the cross covariance pxz (n, 2); the estimate corrected (``unscented.corrected``) unless
        ``held``. In floats: numpy's per-call overhead on 2-vectors is most of their cost."""
        m0, m1 = z_mean.tolist()
        (s00, s01), (s10, s11) = s.tolist()
        nu0, nu1 = z0 - m0, z1 - m1
        if wraps:  # an angle's innovation wraps
            nu0 = (nu0 + math.pi) % (2 * math.pi) - math.pi
        nis = (nu0 * (s11 * nu0 - s01 * nu1) + nu1 * (s00 * nu1 - s10 * nu0)) / (s00 * s11 - s01 * s10)
        nu = np.array([nu0, nu1])
        if held(nu0, nu1, s00, s11):
            return Update(t_s, node, nu, s, nis, applied=False)
        self.x, self.p = corrected(self.x, self.p, s, pxz, nu)  # new arrays: those handed out before stay
        return Update(t_s, node, nu, s, nis)

    @property
    def sigma(self) -> Floats:
        """(n,) the estimate's standard deviations (the state's rad and rad/s, then the tracked
        parameters' units)."""
        return np.sqrt(self.p.diagonal())

    def forecast(
        self, horizon_s: float, *, step_s: float = 0.0125, drive: Callable[[float], tuple[float, float]] | None = None
    ) -> Forecast:
        """The motion predicted from now over ``horizon_s`` with its uncertainty: the filter's
        prediction carried on without measurements, every ``step_s``, with the hinge torques
        ``drive`` gives (s -> (2,) N m, held at the middle of each step; None: no torques); the
        estimate itself is left as it is."""
        if not (math.isfinite(horizon_s) and 0 < horizon_s <= 600):
            raise ParameterError(f"the forecast horizon must be in (0, 600] s, got {horizon_s!r}")
        if not (math.isfinite(step_s) and 0 < step_s <= 0.05):
            raise ParameterError(f"the forecast step must be in (0, 0.05] s, got {step_s!r}")
        saved = (self.t_s, self.x.copy(), self.p.copy())
        n = max(1, math.ceil(horizon_s / step_s - 1e-9))
        times, means, sigmas = [self.t_s], [self.x[:NSTATE].copy()], [self.sigma[:NSTATE]]
        try:
            for k in range(1, n + 1):
                t_s = saved[0] + min(k * step_s, horizon_s)
                self.predict(t_s, (0.0, 0.0) if drive is None else drive(0.5 * (self.t_s + t_s)))
                times.append(self.t_s)
                means.append(self.x[:NSTATE].copy())
                sigmas.append(self.sigma[:NSTATE])
        finally:
            self.t_s, self.x, self.p = saved
        return Forecast(np.array(times), np.array(means), np.array(sigmas))

    def parameters(self) -> dict[str, tuple[float, float]]:
        """Each tracked parameter's estimate and standard deviation, its unit (``TRACKABLE``)."""
        sigma = self.sigma
        return {name: (float(self.x[NSTATE + i]), float(sigma[NSTATE + i])) for i, name in enumerate(self.track)}


def warm_up() -> None:
    """Call every compiled kernel the estimator uses once, in the forms it uses them (numba loads a
    kernel on its first call in a process: 0.3-0.5 s, more on a busy machine). A live twin does
    this before it listens: otherwise the samples that queue up behind its first estimate wait
    that long (a 16 s live run's 99th percentile latency was 279 ms from this alone)."""
    track = ("b1_n_m_s", "offset_m1_rad", "offset_rate_m1_rad_s", "delay_m2_s", "accel_turn_m2_rad")
    est = RigEstimator(track=track)
    est.start(0.0, [0.1, 0.05, 0.0, 0.0])
    est.update(0.0125, 0, 0.1, 0.0)
    est.update_accel(0.0125, 0, 1.0, 9.8)
    est.update(0.01, 1, 0.05, 0.0, late_s=0.0125)  # a late sample: the model run back to its instant
    est.update_accel(0.01, 1, 0.5, 9.8, late_s=0.0125)
    accelerations_at(est.x, est._plant.coef[:, 0].copy(), 0.0, 0.0)  # the session's tick check
    phase = FusionPhase(FUSION_RATE_HZ, SAMPLE_RATE_HZ)  # the measurement's front end
    for k, t in enumerate((0.0, 0.0125, 0.025)):
        phase.add(t, np.array([1.0 + k, 0.0, 0.0]))
