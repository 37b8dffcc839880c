"""The rig's state at every instant from its nodes, as they arrive: an unscented Kalman filter on
the planar model (the live twin's estimator).

State x = (phi1, phi2, omega1, omega2) (rad, rad/s) with covariance P (4, 4).

- **Prediction** to each sample's instant: the sigma points (Merwe's scaled set, 2n + 1 = 9) are
  advanced by one classical RK4 step of the fast engine's force law (``control.plant.FastPlant``,
  the reference's equations in closed form) over the interval (at most one node period, 12.5 ms),
  with the motor torques applied over it (a controller's, or none). Process noise: an unknown
  white torque on each hinge of spectral density ``torque_noise_n_m`` ^2 per Hz (the model's error
  and the unmodelled disturbances), discretised over the interval (its exact covariance for a
  double integrator per hinge, scaled by 1/J).
- **Update** with one node's sample: its swing angle (the fused orientation's angle about the
  hinge) and its gyro's rate about the hinge, z = (phi_n, omega_n), linear in x: the Kalman update
  is exact (Joseph form). Noise: the BNO055 model's gyro sigma on the hinge axis and the
  orientation's quantisation plus its fusion error (``observe.NodeObserver``'s numbers).
- **Innovations** nu = z - H x and their covariance S are kept with each update: on a healthy rig
  nu is white with covariance S, and the normalised innovation squared nu' S^-1 nu has a chi^2
  distribution with 2 degrees of freedom (mean 2): the health monitor's input.

Samples must come in time order; a sample older than the filter's time (reordered in transport)
is refused (``StaleSample``), the caller decides (acquire's timeline orders them).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.control.plant import FastPlant
from pendsim_mj.errors import ParameterError, PendsimError
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import QUAT_LSB, Bno055

Floats = NDArray[np.float64]
NSTATE = 4
HINGE_AXIS = 2  # the sensor axis along the hinge (z) in the default mount
DEFAULT_TORQUE_NOISE_N_M = 2e-4  # N m / sqrt(Hz): white torque standing for the model's error


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
    """

    t_s: float
    node: int
    innovation: Floats
    covariance: Floats
    nis: float


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
      alpha, beta, kappa: the sigma points' spread (Merwe's scaled set).
    """

    def __init__(
        self,
        params: RigParams = DEFAULT_PARAMS,
        *,
        nodes: Bno055 | None = None,
        torque_noise_n_m: float = DEFAULT_TORQUE_NOISE_N_M,
        alpha: float = 1e-3,
        beta: float = 2.0,
        kappa: float = 0.0,
    ) -> None:
        if not (math.isfinite(torque_noise_n_m) and torque_noise_n_m > 0):
            raise ParameterError(f"torque_noise_n_m must be > 0, got {torque_noise_n_m!r}")
        nodes = nodes if nodes is not None else Bno055()
        self.params = params
        self.torque_noise_n_m = float(torque_noise_n_m)
        gyro = float(nodes.noise_model.gyro_sigma_rad_s[HINGE_AXIS]) if nodes.noise else 1e-6
        quantisation = 2 * QUAT_LSB / math.sqrt(12.0) if nodes.noise else 1e-7
        angle = math.hypot(quantisation, nodes.imperfections.fusion_error_rad)
        self.measurement_sigma = np.array([angle, gyro])
        self._scale, self._wm, self._wc = _sigma_weights(NSTATE, alpha, beta, kappa)
        self._plant = FastPlant(params, nenv=2 * NSTATE + 1)
        self._inertia = np.array([params.j1_kg_m2, params.j2_kg_m2])
        self.t_s = 0.0
        self.x = np.zeros(NSTATE)
        self.p = np.eye(NSTATE)

    def start(self, t_s: float, x0: ArrayLike, sigma0: ArrayLike = (0.05, 0.05, 0.2, 0.2)) -> None:
        """Start at ``t_s`` from x0 (4,) with standard deviations sigma0 (4,) (rad, rad/s)."""
        self.t_s = float(t_s)
        self.x = np.asarray(x0, dtype=float).copy()
        self.p = np.diag(np.square(np.asarray(sigma0, dtype=float)))
        if self.x.shape != (NSTATE,) or not np.all(np.isfinite(self.x)):
            raise ParameterError(f"the start state must be 4 finite numbers, got {x0!r}")

    def _process_noise(self, h: float) -> Floats:
        """Covariance added over h by a white torque on each hinge (double integrator per hinge)."""
        q = np.zeros((NSTATE, NSTATE))
        for k in range(2):
            s = (self.torque_noise_n_m / self._inertia[k]) ** 2  # rad^2/s^3
            q[k, k] = s * h**3 / 3.0
            q[k, 2 + k] = q[2 + k, k] = s * h**2 / 2.0
            q[2 + k, 2 + k] = s * h
        return q

    def predict(self, t_s: float, torques_n_m: ArrayLike = (0.0, 0.0)) -> None:
        """Advance the estimate to ``t_s`` (not before the filter's time) with the hinge torques
        (2,) held over the interval."""
        h = float(t_s) - self.t_s
        if h < -1e-12:
            raise StaleSample(f"a sample at {t_s:.6f} s is older than the estimate at {self.t_s:.6f} s")
        if h <= 0:
            return
        root = np.linalg.cholesky(self._scale * self.p + 1e-18 * np.eye(NSTATE))
        points = np.concatenate([self.x[None], self.x + root.T, self.x - root.T])  # (9, 4)
        tau = np.asarray(torques_n_m, dtype=float)
        u = np.zeros((4, len(points)))
        u[0], u[1] = tau[0], tau[1]
        plant = self._plant
        plant.dt_s = h
        plant.columns[:] = points.T
        plant.advance(u)
        moved = plant.columns.T  # (9, 4)
        mean = self._wm @ moved
        d = moved - mean
        self.x = mean
        self.p = (d.T * self._wc) @ d + self._process_noise(h)
        self.p = 0.5 * (self.p + self.p.T)
        self.t_s = float(t_s)

    def update(
        self, t_s: float, node: int, phi_rad: float, omega_rad_s: float, torques_n_m: ArrayLike = (0.0, 0.0)
    ) -> Update:
        """Take one node's sample (its swing angle and hinge rate at ``t_s``) into the estimate."""
        if node not in (0, 1):
            raise ParameterError(f"node must be 0 (M1) or 1 (M2), got {node!r}")
        self.predict(t_s, torques_n_m)
        index = [node, 2 + node]
        z = np.array([phi_rad, omega_rad_s], dtype=float)
        r = np.diag(self.measurement_sigma**2)
        nu = z - self.x[index]
        nu[0] = (nu[0] + math.pi) % (2 * math.pi) - math.pi  # an angle's innovation wraps
        s = self.p[np.ix_(index, index)] + r
        gain = np.linalg.solve(s, self.p[index, :]).T  # (4, 2) = P H' S^-1
        self.x = self.x + gain @ nu
        keep = np.eye(NSTATE)
        keep[:, index] -= gain
        self.p = keep @ self.p @ keep.T + gain @ r @ gain.T  # Joseph form
        return Update(self.t_s, node, nu, s, float(nu @ np.linalg.solve(s, nu)))

    @property
    def sigma(self) -> Floats:
        """(4,) the estimate's standard deviations, rad and rad/s."""
        return np.sqrt(np.diag(self.p))
