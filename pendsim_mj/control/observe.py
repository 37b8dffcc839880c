"""What a controller sees of the rig: the exact state, or what the two BNO055 nodes deliver.

``NodeObserver`` plays both nodes between control instants: each node samples at its rate (80 Hz
by default) the swing angle (the fused orientation's angle about the hinge) and the gyro's rate
about the hinge, with the sensor model's noise (``sensors.bno055``: the gyro's white noise of its
hinge axis, the orientation's quantisation and fusion error), each sample arriving after the
node's transport latency (exponential, its mean ``Imperfections.latency_s``) or never (lost:
a two-state burst process whose long-run share is ``Imperfections.packet_loss`` and mean burst
``loss_burst_samples``), so samples may also arrive out of order. At a control instant the
controller sees the newest sample (by its sampling instant) that has arrived, its angle carried
forward to the instant by its rate (phi + omega * age), and the age. Values between two control
instants come from the plant's states at both (cubic Hermite for the angle, linear for the rate).

Seeded (``seed``), so that a run repeats exactly.
"""

from __future__ import annotations

import dataclasses
import heapq
import math

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.errors import ParameterError
from pendsim_mj.sensors.bno055 import SWING_ANGLE_SIGMA_RAD, Bno055

Floats = NDArray[np.float64]
HINGE_AXIS = 2  # the sensor axis along the hinge (z) in the default mount


@dataclasses.dataclass(frozen=True)
class Observation:
    """What a controller sees at one control instant.

    Attributes:
      state: (4,) phi1, phi2 (rad), omega1, omega2 (rad/s) as the controller takes it.
      age_s: (2,) time since each node's newest arrived sample was taken, s (0 for the exact
        state; inf before a node's first sample).
    """

    state: Floats
    age_s: Floats


class StateObserver:
    """The exact state (a simulation's ideal sensor)."""

    name = "state"

    def reset(self, x0: Floats) -> Observation:
        return Observation(np.asarray(x0, dtype=float).copy(), np.zeros(2))

    def observe(self, t_s: float, x_prev: Floats, x_now: Floats) -> Observation:
        return Observation(np.asarray(x_now, dtype=float).copy(), np.zeros(2))


class NodeObserver:
    """Both nodes as the controller sees them (module docstring).

    Args:
      config: the node model (rate, noise, loss, latency).
      dt_s: the control period, s.
      seed: the noise, loss and latency draws.
    """

    name = "nodes"

    def __init__(self, config: Bno055 | None = None, *, dt_s: float = 0.01, seed: int = 0) -> None:
        config = config if config is not None else Bno055()
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise ParameterError(f"the control period must be > 0 s, got {dt_s!r}")
        self.config, self.dt_s, self.seed = config, float(dt_s), int(seed)
        imp = config.imperfections
        noisy = config.noise
        self.gyro_sigma_rad_s = float(config.noise_model.gyro_sigma_rad_s[HINGE_AXIS]) if noisy else 0.0
        # the quaternion's quantisation as a swing angle (bno055.SWING_ANGLE_SIGMA_RAD) and the
        # fusion error's rms
        quantisation = SWING_ANGLE_SIGMA_RAD if noisy else 0.0
        self.angle_sigma_rad = math.hypot(quantisation, imp.fusion_error_rad)
        self.latency_s = imp.latency_s
        self.loss_share = imp.packet_loss
        self.burst_samples = imp.loss_burst_samples
        self.period_s = 1.0 / config.sample_rate_hz
        self.reset(np.zeros(4))

    def reset(self, x0: Floats) -> Observation:
        self._rng = np.random.default_rng(self.seed)
        self._next_sample = 0  # index of the next sampling instant (both nodes sample together)
        self._pending: list[tuple[float, float, int, float, float]] = []  # (arrival, taken, node, phi, omega)
        self._lost = [False, False]
        self._newest: list[tuple[float, float, float] | None] = [None, None]  # (taken, phi, omega)
        self._t = 0.0
        return self.observe(0.0, np.asarray(x0, dtype=float), np.asarray(x0, dtype=float))

    def _lose(self, node: int) -> bool:
        """The burst process (``loss_chain``) of one node."""
        if self.loss_share <= 0:
            return False
        start, stay = loss_chain(self.loss_share, self.burst_samples)
        p = stay if self._lost[node] else start
        self._lost[node] = bool(self._rng.random() < p)
        return self._lost[node]

    def observe(self, t_s: float, x_prev: Floats, x_now: Floats) -> Observation:
        """The observation at ``t_s``, the plant having moved from ``x_prev`` (at t_s - dt) to
        ``x_now`` (at t_s) (at the first instant both are the start state)."""
        t0 = t_s - self.dt_s
        while self._next_sample * self.period_s <= t_s + 1e-12:
            taken = self._next_sample * self.period_s
            self._next_sample += 1
            s = 1.0 if t_s == 0 else min(max((taken - t0) / self.dt_s, 0.0), 1.0)
            phi, omega = between(x_prev, x_now, s, self.dt_s)
            for node in range(2):
                if self._lose(node):
                    continue
                delay = self._rng.exponential(self.latency_s) if self.latency_s > 0 else 0.0
                noise_phi = self._rng.normal(0.0, self.angle_sigma_rad) if self.angle_sigma_rad else 0.0
                noise_omega = self._rng.normal(0.0, self.gyro_sigma_rad_s) if self.gyro_sigma_rad_s else 0.0
                heapq.heappush(
                    self._pending, (taken + delay, taken, node, phi[node] + noise_phi, omega[node] + noise_omega)
                )
        while self._pending and self._pending[0][0] <= t_s + 1e-12:
            _, taken, node, phi_n, omega_n = heapq.heappop(self._pending)
            newest = self._newest[node]
            if newest is None or taken > newest[0]:
                self._newest[node] = (taken, phi_n, omega_n)
        state = np.full(4, np.nan)
        age = np.full(2, math.inf)
        for node in range(2):
            newest = self._newest[node]
            if newest is None:
                continue
            taken, phi_n, omega_n = newest
            age[node] = t_s - taken
            state[node] = phi_n + omega_n * age[node]
            state[2 + node] = omega_n
        return Observation(state, age)


def loss_chain(share: float, burst_samples: float) -> tuple[float, float]:
    """The two-state burst process of a node's losses (module docstring): (probability that a
    sample is lost after a received one, probability that it is lost after a lost one). A lost
    run then lasts ``burst_samples`` samples on average (stay = 1 - 1 / burst) and the long-run
    lost share is ``share`` (start = share (1 - stay) / (1 - share), at most 1)."""
    stay = 1.0 - 1.0 / burst_samples
    return min(share * (1.0 - stay) / (1.0 - share), 1.0), stay


def between(x0: Floats, x1: Floats, s: float | Floats, dt_s: float) -> tuple[Floats, Floats]:
    """Angles (cubic Hermite from both ends' angles and rates) and rates (linear) at the fraction
    s of a step from x0 to x1 (states (4,) with s a number, or columns (4, n) with s (n,))."""
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    phi = h00 * x0[:2] + h10 * dt_s * x0[2:] + h01 * x1[:2] + h11 * dt_s * x1[2:]
    omega = (1 - s) * x0[2:] + s * x1[2:]
    return phi, omega
