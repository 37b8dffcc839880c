"""Controllers of the rig: small typed classes that map the state the loop gives them to motor
torques, the same object in the Gymnasium environment, in a simulated closed loop and on the rig
over UDP.

Every controller (``Controller``):

- takes x = (phi1, phi2, omega1, omega2) in rad and rad/s, shape (4,) or (n, 4) (a batch of rigs:
  the vectorised environment), and returns the hinge torques (tau1, tau2) in N m, shape (2,) or
  (n, 2), each limited to +-``torque_limit_n_m`` (a motor that is absent gets 0);
- logs its internal state after each command (``log_names`` / ``log``: what the ``/control``
  topic of a recording carries), including the torques it asked for before the limit;
- is designed from a ``RigParams`` (the stated rig, or the calibrated one of ``pendsim calibrate``:
  ``retune`` redesigns it for new parameters, e.g. those a live estimator tracks).

Controllers:

- ``LQR``: discrete-time linear-quadratic regulator on the linearised rig (``linear``), held input
  over the control period (exact zero-order-hold discretisation), cost sum x' Q x + u' R u with
  Q the energy weight (the linearised mechanical energy) and R = ``input_weight`` I: active
  damping of both modes. A gain given from outside is checked first: it must make the linear
  closed loop stable (``check_stabilising``).
- ``ScheduledLQR``: LQR gains designed at several amplitudes, with the stiffness of gravity and of
  the springs replaced by its describing-function value at that amplitude (a restoring moment
  k sin(phi) acts on a swing of amplitude A like the linear stiffness k 2 J1(A)/A), chosen by the
  current largest modal amplitude (linear interpolation): the gain-scheduled variant.
- ``EnergyRegulator``: each normal mode's energy E_i driven to a target (0: damping; the energy of
  an amplitude A: holding it) by the modal force k (E_i* - E_i) q_i' (the energy's rate is then
  k (E_i* - E_i) q_i'^2 >= 0 toward the target), mapped back to the motors.
- ``BeatingSuppressor``: modal control against beating: each motor cancels the part of the
  coupling springs' moment that the other pendulum's angle causes (the closed form of
  ``fast_planar.closed_form``), so that no energy flows between the pendulums, and damps M2
  toward rest; M1 then swings as a lone pendulum.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import solve_discrete_are
from scipy.special import j1

from pendsim_mj.control.linear import LinearRig, linearise
from pendsim_mj.control.names import CONTROLLER_NAMES, MOTOR_NAMES
from pendsim_mj.engines.fast_planar.closed_form import coefficients, spring_moments
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.drives import Target
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams

Floats = NDArray[np.float64]
MOTORS = dict(zip(MOTOR_NAMES, (Target.TORQUE_M1, Target.TORQUE_M2), strict=True))
"""The motors a controller may use: one at each hinge."""
DEFAULT_TORQUE_LIMIT_N_M = 0.05
"""The default torque limit of each motor, N m (the issue's 0.05 N m)."""


class Controller(Protocol):
    """A state-feedback controller (module docstring)."""

    name: str
    motors: tuple[str, ...]
    torque_limit_n_m: float

    @property
    def log_names(self) -> tuple[str, ...]:
        """The columns of ``log``."""
        ...

    def reset(self) -> None:
        """Forget any internal state (a new run)."""
        ...

    def __call__(self, x: ArrayLike) -> Floats:
        """Torques (2,) or (n, 2), N m, limited, for states (4,) or (n, 4)."""
        ...

    def log(self) -> Floats:
        """(len(log_names),) the state after the last command (first row of a batch)."""
        ...

    def retune(self, params: RigParams) -> None:
        """Redesign for new rig parameters."""
        ...


def _check_motors(motors: Sequence[str]) -> tuple[str, ...]:
    chosen = tuple(motors)
    if not chosen or any(m not in MOTORS for m in chosen) or len(set(chosen)) != len(chosen):
        raise ParameterError(f"motors must be one or both of m1, m2, got {', '.join(chosen) or 'none'}")
    return tuple(m for m in MOTORS if m in chosen)


def _check_positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ParameterError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


def _states(x: ArrayLike) -> tuple[Floats, bool]:
    a = np.asarray(x, dtype=float)
    if a.shape[-1:] != (4,) or a.ndim not in (1, 2):
        raise ParameterError(f"a controller takes states of shape (4,) or (n, 4), got {a.shape}")
    return np.atleast_2d(a), a.ndim == 1


class _Base:
    """What every controller shares: motors, limit, the limited torques and the log."""

    name = "base"

    def __init__(self, params: RigParams, motors: Sequence[str], torque_limit_n_m: float, dt_s: float) -> None:
        self.params = params
        self.motors = _check_motors(motors)
        self.torque_limit_n_m = _check_positive("torque_limit_n_m", torque_limit_n_m)
        self.dt_s = _check_positive("dt_s", dt_s)
        self._mask = np.array([m in self.motors for m in MOTORS])
        self._last: Floats = np.zeros(0)

    def reset(self) -> None:
        self._last = np.zeros(0)

    def _limited(self, wanted: Floats, single: bool) -> Floats:
        """Zero for absent motors, clipped to the limit; remembers what was asked for the log."""
        wanted = np.where(self._mask, wanted, 0.0)
        out = np.clip(wanted, -self.torque_limit_n_m, self.torque_limit_n_m)
        self._record(wanted, out)
        return out[0] if single else out

    def _record(self, wanted: Floats, out: Floats) -> None:
        self._last = np.concatenate([wanted[0], out[0]])

    @property
    def log_names(self) -> tuple[str, ...]:
        return ("tau1_wanted_n_m", "tau2_wanted_n_m", "tau1_n_m", "tau2_n_m")

    def log(self) -> Floats:
        return self._last.copy() if len(self._last) else np.zeros(len(self.log_names))


def lqr_gain(a_d: Floats, b_d: Floats, q: Floats, r: Floats) -> Floats:
    """The discrete LQR gain K (u = -K x) of x[k+1] = Ad x[k] + Bd u[k] for the cost
    sum x' Q x + u' R u, from the discrete algebraic Riccati equation."""
    p = solve_discrete_are(a_d, b_d, q, r)
    gain: Floats = np.linalg.solve(r + b_d.T @ p @ b_d, b_d.T @ p @ a_d)
    return gain


def check_stabilising(a_d: Floats, b_d: Floats, gain: Floats) -> float:
    """The spectral radius of the linear closed loop Ad - Bd K; ParameterError where it is >= 1
    (the gain destabilises the linearised rig), naming the growing mode's rate."""
    radius = float(np.max(np.abs(np.linalg.eigvals(a_d - b_d @ gain))))
    if not radius < 1.0:
        raise ParameterError(
            f"the gains destabilise the linearised rig: closed-loop spectral radius {radius:.4f} >= 1 "
            "(a mode grows); give gains with every closed-loop eigenvalue inside the unit circle"
        )
    return radius


class LQR(_Base):
    """Active damping of both modes by a discrete LQR (module docstring).

    Args:
      params: the rig the design assumes.
      motors: "m1", "m2" or both.
      torque_limit_n_m: each motor's limit, N m.
      dt_s: control period, s.
      input_weight: R = input_weight I in the cost (J per (N m)^2 per step): larger is gentler.
      gain: (len(motors), 4) a gain to use instead of the design (checked to stabilise).
    """

    name = "lqr"

    def __init__(
        self,
        params: RigParams = DEFAULT_PARAMS,
        *,
        motors: Sequence[str] = ("m1", "m2"),
        torque_limit_n_m: float = DEFAULT_TORQUE_LIMIT_N_M,
        dt_s: float = 0.01,
        input_weight: float = 10.0,
        gain: ArrayLike | None = None,
    ) -> None:
        super().__init__(params, motors, torque_limit_n_m, dt_s)
        self.input_weight = _check_positive("input_weight", input_weight)
        self._given = None if gain is None else np.asarray(gain, dtype=float)
        self.retune(params)

    @property
    def channels(self) -> tuple[Target, ...]:
        return tuple(MOTORS[m] for m in self.motors)

    def retune(self, params: RigParams) -> None:
        self.params = params
        self.linear = linearise(params)
        self.gain = self._design(self.linear)

    def _design(self, linear: LinearRig) -> Floats:
        a_d, b_d = linear.discrete(self.dt_s, self.channels)
        if self._given is not None:
            if self._given.shape != (len(self.motors), 4) or not np.all(np.isfinite(self._given)):
                raise ParameterError(
                    f"the gain must be a finite ({len(self.motors)}, 4) matrix (one row per motor, columns "
                    f"phi1, phi2, omega1, omega2), got shape {self._given.shape}"
                )
            gain = self._given
        else:
            gain = lqr_gain(a_d, b_d, linear.energy_weight, self.input_weight * np.eye(len(self.motors)))
        self.spectral_radius = check_stabilising(a_d, b_d, gain)
        full = np.zeros((2, 4))
        full[self._mask] = gain
        return full

    def __call__(self, x: ArrayLike) -> Floats:
        states, single = _states(x)
        return self._limited(-states @ self.gain.T, single)


class ScheduledLQR(LQR):
    """LQR gains scheduled on the swing's amplitude (module docstring); arguments as ``LQR``,
    plus ``amplitudes_rad``, the design amplitudes (ascending, the first 0)."""

    name = "scheduled-lqr"

    def __init__(
        self,
        params: RigParams = DEFAULT_PARAMS,
        *,
        amplitudes_rad: Sequence[float] = tuple(np.radians([0, 15, 30, 45, 60, 75, 90])),
        **kwargs: object,
    ) -> None:
        amps = np.asarray(amplitudes_rad, dtype=float)
        if amps.ndim != 1 or len(amps) < 2 or amps[0] != 0 or np.any(np.diff(amps) <= 0) or amps[-1] >= 3.0:
            raise ParameterError("design amplitudes must start at 0 rad, ascend and stay below 3 rad")
        self.amplitudes_rad = amps
        self._amplitude = 0.0
        super().__init__(params, **kwargs)  # type: ignore[arg-type]

    def retune(self, params: RigParams) -> None:
        self.params = params
        self.linear = linearise(params)
        gains = []
        for amp in self.amplitudes_rad:
            factor = 1.0 if amp == 0 else float(2.0 * j1(amp) / amp)  # describing function of sin
            modes = self.linear.modes
            a = self.linear.a.copy()
            m_inv = np.diag(1.0 / np.diag(modes.mass_kg_m2))
            a[2:, :2] = -factor * (m_inv @ modes.stiffness_n_m)
            gains.append(self._design(LinearRig(a=a, b=self.linear.b, modes=modes)))
        self.gains = np.stack(gains)  # (namp, 2, 4)
        self.gain = self.gains[0]

    def __call__(self, x: ArrayLike) -> Floats:
        states, single = _states(x)
        amplitude = np.max(self.linear.mode_amplitudes_rad(states), axis=1)  # (n,)
        self._amplitude = float(amplitude[0])
        pos = np.interp(amplitude, self.amplitudes_rad, np.arange(len(self.amplitudes_rad)))
        lo = np.floor(pos).astype(int)
        hi = np.minimum(lo + 1, len(self.amplitudes_rad) - 1)
        w = (pos - lo)[:, None, None]
        gain = (1 - w) * self.gains[lo] + w * self.gains[hi]  # (n, 2, 4)
        return self._limited(-np.einsum("nij,nj->ni", gain, states), single)

    @property
    def log_names(self) -> tuple[str, ...]:
        return (*super().log_names, "amplitude_rad")

    def log(self) -> Floats:
        return np.append(super().log(), self._amplitude)


class EnergyRegulator(_Base):
    """Each normal mode's energy driven to a target (module docstring).

    Args:
      params: the rig.
      target_amplitudes_rad: (mode 1, mode 2) amplitudes to hold, rad of the pendulum moving most
        in each mode (``linear.LinearRig.mode_amplitudes_rad``); (0, 0) damps both.
      gain: k in the modal force k (E* - E) q', 1/(J s) scaled per mode by its modal mass.
      motors, torque_limit_n_m, dt_s: as ``LQR``.
    """

    name = "energy"

    def __init__(
        self,
        params: RigParams = DEFAULT_PARAMS,
        *,
        target_amplitudes_rad: Sequence[float] = (0.0, 0.0),
        gain: float = 50.0,
        motors: Sequence[str] = ("m1", "m2"),
        torque_limit_n_m: float = DEFAULT_TORQUE_LIMIT_N_M,
        dt_s: float = 0.01,
    ) -> None:
        super().__init__(params, motors, torque_limit_n_m, dt_s)
        targets = np.asarray(target_amplitudes_rad, dtype=float)
        if targets.shape != (2,) or not np.all(np.isfinite(targets)) or np.any(targets < 0) or np.any(targets > 1.5):
            raise ParameterError(
                f"target amplitudes must be two numbers in [0, 1.5] rad, got {target_amplitudes_rad!r}"
            )
        self.target_amplitudes_rad = targets
        self.energy_gain = _check_positive("gain", gain)
        self._energies = np.zeros(2)
        self.retune(params)

    def retune(self, params: RigParams) -> None:
        self.params = params
        self.linear = linearise(params)
        modes = self.linear.modes
        self._shapes = modes.shapes
        self._inv = np.linalg.inv(modes.shapes)
        self._modal_mass = np.einsum("im,ij,jm->m", modes.shapes, modes.mass_kg_m2, modes.shapes)
        self._omega = modes.omega_rad_s
        self.target_energies_j = 0.5 * self._modal_mass * (self._omega * self.target_amplitudes_rad) ** 2

    def modal_energies_j(self, states: Floats) -> Floats:
        """(n, 2) each mode's energy (linearised), J."""
        q = states[:, :2] @ self._inv.T
        qdot = states[:, 2:] @ self._inv.T
        energies: Floats = 0.5 * self._modal_mass * (qdot**2 + (self._omega * q) ** 2)
        return energies

    def __call__(self, x: ArrayLike) -> Floats:
        states, single = _states(x)
        energies = self.modal_energies_j(states)
        self._energies = energies[0]
        qdot = states[:, 2:] @ self._inv.T
        modal_force = self.energy_gain * self._modal_mass * (self.target_energies_j - energies) * qdot
        # generalised forces Q = Phi^T tau  ->  tau = Phi^-T Q
        torques = modal_force @ self._inv
        return self._limited(torques, single)

    @property
    def log_names(self) -> tuple[str, ...]:
        return (*super().log_names, "energy_mode1_j", "energy_mode2_j")

    def log(self) -> Floats:
        return np.append(super().log(), self._energies)


class BeatingSuppressor(_Base):
    """No energy exchange between the pendulums: each motor cancels the coupling moment that the
    other pendulum's angle causes, and M2 is damped toward rest (module docstring).

    Args:
      params: the rig.
      damping_n_m_s: the damping added at M2's hinge, N m s/rad.
      stiffness_n_m: the stiffness added at M2's hinge toward rest, N m/rad.
      torque_limit_n_m, dt_s: as ``LQR`` (both motors are used).
    """

    name = "beating"

    def __init__(
        self,
        params: RigParams = DEFAULT_PARAMS,
        *,
        damping_n_m_s: float = 0.05,
        stiffness_n_m: float = 0.2,
        torque_limit_n_m: float = DEFAULT_TORQUE_LIMIT_N_M,
        dt_s: float = 0.01,
        motors: Sequence[str] = ("m1", "m2"),
    ) -> None:
        super().__init__(params, motors, torque_limit_n_m, dt_s)
        self.damping_n_m_s = _check_positive("damping_n_m_s", damping_n_m_s)
        self.stiffness_n_m = _check_positive("stiffness_n_m", stiffness_n_m)
        self.retune(params)

    def retune(self, params: RigParams) -> None:
        self.params = params
        self._coef = coefficients([params])

    def _coupling_m1(self, phi1: Floats, phi2: Floats) -> Floats:
        """The inter-pendulum springs' moment on M1, N m (its negative acts on M2)."""
        m1, _ = spring_moments(phi1, phi2, self._coef)
        # spring_moments' M2 also holds the frame springs; the pair's moment on M1 is M1 itself
        return m1

    def __call__(self, x: ArrayLike) -> Floats:
        states, single = _states(x)
        phi1, phi2, omega2 = states[:, 0], states[:, 1], states[:, 3]
        zero = np.zeros_like(phi1)
        coupling = self._coupling_m1(phi1, phi2)
        tau1 = -(coupling - self._coupling_m1(phi1, zero))  # M2's angle no longer acts on M1
        tau2 = (coupling - self._coupling_m1(zero, phi2)) - self.stiffness_n_m * phi2 - self.damping_n_m_s * omega2
        return self._limited(np.stack([tau1, tau2], axis=1), single)


class OpenLoop(_Base):
    """No control: zero torque (the baseline the benchmarks compare against)."""

    name = "none"

    def __init__(
        self,
        params: RigParams = DEFAULT_PARAMS,
        *,
        motors: Sequence[str] = ("m1", "m2"),
        torque_limit_n_m: float = DEFAULT_TORQUE_LIMIT_N_M,
        dt_s: float = 0.01,
    ) -> None:
        super().__init__(params, motors, torque_limit_n_m, dt_s)

    def retune(self, params: RigParams) -> None:
        self.params = params

    def __call__(self, x: ArrayLike) -> Floats:
        states, single = _states(x)
        return self._limited(np.zeros((len(states), 2)), single)


CONTROLLERS: dict[str, type[_Base]] = {
    OpenLoop.name: OpenLoop,
    LQR.name: LQR,
    ScheduledLQR.name: ScheduledLQR,
    EnergyRegulator.name: EnergyRegulator,
    BeatingSuppressor.name: BeatingSuppressor,
}
"""The controllers by name (the names ``pendsim control`` takes)."""
assert tuple(CONTROLLERS) == CONTROLLER_NAMES, "names.CONTROLLER_NAMES lists CONTROLLERS' keys in order"
