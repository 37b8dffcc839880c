"""The rig stepped one control period at a time, with inputs chosen between steps: the plant a
closed loop (``loop``) and the Gymnasium environments (``environment``) drive.

Two engines, one interface (``Plant``):

- ``FastPlant``: the fast planar engine's force law (``fast_planar.closed_form.accelerations``,
  the reference's equations in closed form) advanced by one classical RK4 step per period in
  numpy, for a batch of ``nenv`` rigs side by side (the vectorised environment's engine). Each
  input is held over the step, as MuJoCo holds ``ctrl`` (``drives.Sampling.HELD``), so that a
  closed loop replayed through its recorded inputs on either engine (``replay_drive``) gives
  the same states.
- ``MujocoPlant``: the MuJoCo model (``rig.model.build_model`` with the driven channels'
  actuators) advanced by ``mujoco.mj_step`` with ``ctrl`` set to the inputs.

The state is x = (phi1, phi2, omega1, omega2) in rad and rad/s; inputs are the drives' channels
(``drives.Target``: tau1, tau2 in N m, support_x, pivot_z in m/s^2), (nenv, 4), held over the
step. The step is the control period (10 ms by default, the rig's step).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.control.names import LOOP_ENGINES
from pendsim_mj.engines.fast_planar.closed_form import (
    accelerations,
    coefficients,
    kinetic_energy,
    potential_energy,
)
from pendsim_mj.errors import ParameterError, SimulationDiverged
from pendsim_mj.rig.drives import NCHANNEL, Drive, Target, drive_from_held_inputs
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams

Floats = NDArray[np.float64]
PLANT_ENGINES = LOOP_ENGINES
"""The engines a plant runs on: MuJoCo, or the fast planar engine's force law."""


class Plant(Protocol):
    """A batch of rigs advanced one control period per ``step``."""

    nenv: int
    dt_s: float
    t_s: float

    def reset(self, phi0_rad: ArrayLike, omega0_rad_s: ArrayLike = (0.0, 0.0)) -> Floats:
        """Start every member at the given state ((2,) or (nenv, 2)); returns the (nenv, 4) state."""
        ...

    def step(self, inputs: ArrayLike) -> Floats:
        """Hold ``inputs`` ((4,) or (nenv, 4)) over one period; returns the (nenv, 4) state after it."""
        ...

    @property
    def state(self) -> Floats:
        """(nenv, 4) phi1, phi2 (rad), omega1, omega2 (rad/s), a copy."""
        ...

    def energy_j(self) -> Floats:
        """(nenv,) mechanical energy above rest (kinetic + gravity + springs), J."""
        ...


def _check_dt(dt_s: float) -> float:
    if isinstance(dt_s, bool) or not isinstance(dt_s, (int, float)) or not (math.isfinite(dt_s) and 0 < dt_s <= 0.1):
        raise ParameterError(f"the control period must be a number in (0, 0.1] s, got {dt_s!r}")
    return float(dt_s)


def _initial(phi0_rad: ArrayLike, omega0_rad_s: ArrayLike, nenv: int) -> Floats:
    phi = np.asarray(phi0_rad, dtype=float)
    omega = np.asarray(omega0_rad_s, dtype=float)
    try:
        phi = np.broadcast_to(phi, (nenv, 2))
        omega = np.broadcast_to(omega, (nenv, 2))
    except ValueError:
        raise ParameterError(
            f"initial angles and rates must have shape (2,) or ({nenv}, 2), got {phi.shape} and {omega.shape}"
        ) from None
    if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(omega))):
        raise ParameterError("initial angles and rates must be finite")
    return np.ascontiguousarray(np.hstack([phi, omega]))


def _inputs(inputs: ArrayLike, nenv: int) -> Floats:
    u = np.asarray(inputs, dtype=float)
    try:
        u = np.broadcast_to(u, (nenv, NCHANNEL))
    except ValueError:
        raise ParameterError(f"inputs must have shape ({NCHANNEL},) or ({nenv}, {NCHANNEL}), got {u.shape}") from None
    if not np.all(np.isfinite(u)):
        raise ParameterError("inputs must be finite")
    return u


class FastPlant:
    """``nenv`` rigs on the fast engine's force law, one RK4 step per period (module docstring).

    Args:
      params: one rig for every member, or ``nenv`` of them.
      nenv: members.
      dt_s: control period (= the RK4 step), s.
    """

    def __init__(self, params: RigParams | Sequence[RigParams] = DEFAULT_PARAMS, *, nenv: int = 1, dt_s: float = 0.01):
        if isinstance(nenv, bool) or not isinstance(nenv, int) or nenv < 1:
            raise ParameterError(f"nenv must be an integer >= 1, got {nenv!r}")
        plist = [params] * nenv if isinstance(params, RigParams) else list(params)
        if len(plist) != nenv:
            raise ParameterError(f"give one rig or {nenv} of them, got {len(plist)}")
        self.nenv, self.dt_s, self.t_s = nenv, _check_dt(dt_s), 0.0
        self.params = plist
        self.coef = coefficients(plist)  # (NCOEF, nenv)
        self._coef_one = self.coef[:, 0].copy()  # (NCOEF,): one rig's constants as scalars
        self._x = np.zeros((4, nenv))  # rows: phi1, phi2, omega1, omega2 (columns are members)

    def reset(self, phi0_rad: ArrayLike, omega0_rad_s: ArrayLike = (0.0, 0.0)) -> Floats:
        self._x = np.ascontiguousarray(_initial(phi0_rad, omega0_rad_s, self.nenv).T)
        self.t_s = 0.0
        return self.state

    def reset_members(self, mask: NDArray[np.bool_], phi0_rad: Floats, omega0_rad_s: Floats) -> None:
        """Start the members where ``mask`` (nenv,) is set at (m, 2) angles and rates (m = mask's count)."""
        self._x[:2, mask] = phi0_rad.T
        self._x[2:, mask] = omega0_rad_s.T

    def _rates(self, x: Floats, u: Floats) -> Floats:
        a1, a2 = accelerations(x[0], x[1], x[2], x[3], self.coef, u)
        return np.stack([x[2], x[3], a1, a2])

    def step(self, inputs: ArrayLike) -> Floats:
        self.advance(_inputs(inputs, self.nenv).T)
        return self.state

    def advance(self, u: Floats) -> None:
        """One RK4 step with inputs ``u`` (4, nenv) held over it, unchecked (the vectorised
        environment's inner loop)."""
        if self.nenv == 1:
            self._advance_one(u[:, 0])
            return
        h = self.dt_s
        x = self._x
        k1 = self._rates(x, u)
        k2 = self._rates(x + (0.5 * h) * k1, u)
        k3 = self._rates(x + (0.5 * h) * k2, u)
        k4 = self._rates(x + h * k3, u)
        self._x = x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
        self.t_s += h

    def _advance_one(self, u: Floats) -> None:
        """The same step for one rig on scalars (the same closed forms; six times less numpy
        overhead per call than on arrays of one member)."""
        h, c = self.dt_s, self._coef_one
        p1, p2, w1, w2 = (float(v) for v in self._x[:, 0])

        def rates(a: float, b: float, wa: float, wb: float) -> tuple[float, float, float, float]:
            acc1, acc2 = accelerations(a, b, wa, wb, c, u)  # type: ignore[arg-type]
            return wa, wb, float(acc1), float(acc2)

        k1 = rates(p1, p2, w1, w2)
        k2 = rates(p1 + 0.5 * h * k1[0], p2 + 0.5 * h * k1[1], w1 + 0.5 * h * k1[2], w2 + 0.5 * h * k1[3])
        k3 = rates(p1 + 0.5 * h * k2[0], p2 + 0.5 * h * k2[1], w1 + 0.5 * h * k2[2], w2 + 0.5 * h * k2[3])
        k4 = rates(p1 + h * k3[0], p2 + h * k3[1], w1 + h * k3[2], w2 + h * k3[3])
        x = (p1, p2, w1, w2)
        self._x[:, 0] = [x[i] + (h / 6.0) * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]) for i in range(4)]
        self.t_s += h

    @property
    def columns(self) -> Floats:
        """The state as (4, nenv), not copied (rows phi1, phi2, omega1, omega2)."""
        return self._x

    @property
    def state(self) -> Floats:
        return self._x.T.copy()  # a copy (a (4, 1) transpose is already contiguous: no copy otherwise)

    def energy_j(self) -> Floats:
        x = self._x
        total: Floats = kinetic_energy(x[2], x[3], self.coef) + potential_energy(x[0], x[1], self.coef)
        return total


class MujocoPlant:
    """One rig on the MuJoCo model, ``mj_step`` per period with ``ctrl`` = the driven inputs.

    Args:
      params: the rig.
      dt_s: control period (= MuJoCo's timestep), s.
      targets: the channels that can be driven (actuators compiled into the model); inputs on
        other channels must be zero.
    """

    nenv = 1

    def __init__(
        self,
        params: RigParams = DEFAULT_PARAMS,
        *,
        dt_s: float = 0.01,
        targets: Sequence[Target] = (Target.TORQUE_M1, Target.TORQUE_M2),
    ) -> None:
        import mujoco  # start-up: MuJoCo loads only for this engine

        from pendsim_mj.rig.model import HINGES, build_model

        self._mujoco = mujoco
        self.params, self.dt_s, self.t_s = params, _check_dt(dt_s), 0.0
        self.targets = tuple(t for t in Target if t in set(targets))
        self.model = build_model(params, timestep_s=self.dt_s, drive_targets=self.targets)
        self.data = mujoco.MjData(self.model)
        ids = [self.model.joint(h).id for h in HINGES]
        self._qpos = np.array([self.model.jnt_qposadr[j] for j in ids])
        self._qvel = np.array([self.model.jnt_dofadr[j] for j in ids])
        self._channels = np.array([t.index for t in self.targets], dtype=int)
        self._undriven = np.array([t.index for t in Target if t not in self.targets], dtype=int)

    def reset(self, phi0_rad: ArrayLike, omega0_rad_s: ArrayLike = (0.0, 0.0)) -> Floats:
        x = _initial(phi0_rad, omega0_rad_s, 1)[0]
        mujoco = self._mujoco
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self._qpos] = x[:2]
        self.data.qvel[self._qvel] = x[2:]
        mujoco.mj_forward(self.model, self.data)
        self.t_s = 0.0
        return self.state

    def step(self, inputs: ArrayLike) -> Floats:
        u = _inputs(inputs, 1)[0]
        if np.any(u[self._undriven] != 0):
            names = ", ".join(list(Target)[i].value for i in self._undriven if u[i] != 0)
            raise ParameterError(f"this plant has no actuator for {names}")
        self.data.ctrl[:] = u[self._channels]
        self._mujoco.mj_step(self.model, self.data)
        self.t_s += self.dt_s
        if not np.all(np.isfinite(self.data.qvel)):
            raise SimulationDiverged(f"the MuJoCo model diverged at t = {self.t_s:.3f} s")
        return self.state

    @property
    def state(self) -> Floats:
        return np.concatenate([self.data.qpos[self._qpos], self.data.qvel[self._qvel]])[None, :]

    def energy_j(self) -> Floats:
        """Mechanical energy above rest, J: the fast engine's closed forms at MuJoCo's state (the
        same energy as ``FastPlant``'s, so that rewards and logs agree between engines)."""
        x = self.state[0]
        coef = coefficients([self.params])
        total: Floats = kinetic_energy(x[2:3], x[3:4], coef) + potential_energy(x[0:1], x[1:2], coef)
        return total


def make_plant(
    engine: str,
    params: RigParams = DEFAULT_PARAMS,
    *,
    dt_s: float = 0.01,
    targets: Sequence[Target] = (Target.TORQUE_M1, Target.TORQUE_M2),
) -> FastPlant | MujocoPlant:
    """One rig on the named engine ("fast" or "mujoco")."""
    if engine == "fast":
        return FastPlant(params, dt_s=dt_s)
    if engine == "mujoco":
        return MujocoPlant(params, dt_s=dt_s, targets=targets)
    raise ParameterError(f"unknown engine {engine!r} for a closed loop; allowed: {', '.join(PLANT_ENGINES)}")


def replay_drive(held_inputs: Floats, dt_s: float) -> Drive:
    """The open-loop drive that reproduces a closed loop's held inputs (nstep, 4) on any engine
    under ``Sampling.HELD`` (``drives.drive_from_held_inputs``), e.g. to record or validate it."""
    held = np.asarray(held_inputs, dtype=float)
    if held.ndim != 2 or held.shape[1] != NCHANNEL or len(held) < 2:
        raise ParameterError(f"held inputs must have shape (nstep >= 2, {NCHANNEL}), got {held.shape}")
    return drive_from_held_inputs(np.arange(len(held)) * dt_s, held)
