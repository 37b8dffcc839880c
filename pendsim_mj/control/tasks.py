"""The tasks of the Gymnasium environments (``environment``, ``vector_env``): how an episode starts,
what the task drives by itself, and the reward.

Every reward has one form: per control step

    r = -sum_i ((a_i - a_i*) / A_REF)^2 - effort_weight * mean_c (u_c / limit_c)^2,

with a the task's two amplitudes (rad), a* their targets, A_REF = 10 deg and u the applied action
(each channel over its limit, so the effort term is at most ``effort_weight``). A step with both
amplitudes on target and no action earns 0; a swing 10 deg off target costs 1 per step.

The tasks (amplitudes a, their targets a*, the release):

- ``damp``: a = the normal modes' amplitudes (``LinearRig.mode_amplitudes_rad``), a* = (0, 0):
  damp both modes; phi_n uniform in +-``release_rad`` (30 deg).
- ``hold``: a = the normal modes' amplitudes, a* = ``target_amplitudes_rad`` (default mode 1 at
  10 deg, mode 2 at rest); released as ``damp``.
- ``still-m2``: a = each pendulum's own amplitude (below), a* = (M1's at the release, 0): M1
  swings on while M2 stays still; phi1 = +-(1/3 to 1) ``release_rad``, phi2 = 0.
- ``no-beating``: a = each pendulum's own amplitude, a* = both at the release: no energy moves
  between the pendulums (beating), none is lost; released as ``damp``.
- ``tongue``: a = the normal modes' amplitudes, a* = (0, 0) while the task drives ``pivot_z``
  inside a parametric tongue (below); phi_n uniform in +-1 deg.

Releases start at rest (omega = 0) unless the reset's options give the state. Each pendulum's own
amplitude is sqrt(phi_n^2 + (omega_n / w_n)^2) with w_n = sqrt(K_nn / J_n) its frequency while
the other is held at rest (``nonlinear.linear``: K the linearised stiffness of gravity and
springs): exact for a lone linear swing, and it stays constant exactly when no energy flows
through the coupling springs (no beating) and nothing damps it.

**The tongue.** The task accelerates the pivot vertically by a_v = level sin(2 pi f t) with f
twice mode ``tongue_mode``'s linear frequency, the principal parametric resonance, where the
Mathieu limit of ``nonlinear.tongues`` puts the tongue's tip (its lowest unstable level, 0.111
m/s^2 for mode 1 of the paper's rig) and the level ``TONGUE_LEVEL_FACTOR`` (10) times that tip
(1.11 m/s^2, 9 mm of pivot travel at 1.75 Hz): rest is unstable, an uncontrolled swing from
1 deg grows about 11-fold in 20 s (the fast engine), and the agent must hold it down. The drive is
held over each step at its midpoint value (``drives.Sampling.HELD``, MuJoCo's rule); the
observation then carries the drive's phase (cos, sin of 2 pi f t), so that it stays Markov.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.control.linear import linearise
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import RigParams

Floats = NDArray[np.float64]
TASKS = ("damp", "hold", "still-m2", "no-beating", "tongue")
"""The tasks by name (module docstring)."""
A_REF_RAD = math.radians(10.0)
"""The reward's angle scale: an amplitude this far off target costs 1 per step."""
DEFAULT_RELEASE_RAD = math.radians(30.0)
"""The largest release angle of each pendulum, rad (the paper's release)."""
TONGUE_RELEASE_RAD = math.radians(1.0)
"""The largest release angle in the tongue task, rad: a small disturbance of rest."""
DEFAULT_TARGET_AMPLITUDES_RAD = (math.radians(10.0), 0.0)
"""The hold task's targets: mode 1 swinging at 10 deg, mode 2 at rest."""
TONGUE_LEVEL_FACTOR = 10.0
"""The tongue task's pivot level over the tongue's tip level (the Mathieu limit at twice the mode's frequency)."""
DEFAULT_EFFORT_WEIGHT = 0.1
"""The weight of the effort term of every reward."""
_MODAL = ("damp", "hold", "tongue")  # the tasks scored on the normal modes' amplitudes


def _check_number(name: str, value: object, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not (math.isfinite(v) and low <= v <= high):
        raise ParameterError(f"{name} must be in [{low:g}, {high:g}], got {v!r}")
    return v


def check_targets(value: object) -> tuple[float, float]:
    """Two target amplitudes in [0, 1.5] rad (the range ``EnergyRegulator`` takes), or ParameterError."""
    arr = np.asarray(value, dtype=float) if isinstance(value, (list, tuple, np.ndarray)) else None
    if arr is None or arr.shape != (2,) or not np.all(np.isfinite(arr)) or np.any(arr < 0) or np.any(arr > 1.5):
        raise ParameterError(f"target_amplitudes_rad must be two numbers in [0, 1.5] rad, got {value!r}")
    return float(arr[0]), float(arr[1])


class Task:
    """One task on one rig (module docstring); every method works on a batch of members.

    Args:
      name: one of ``TASKS``.
      params: the rig (its linear modes set the amplitudes and the tongue).
      release_rad: the largest release angle, rad (default 30 deg; the tongue's 1 deg).
      target_amplitudes_rad: the hold task's (mode 1, mode 2) targets, rad.
      tongue_mode: the mode (1 or 2) whose principal tongue the tongue task drives.
      tongue_level_m_s2: the tongue task's pivot level, m/s^2 (default: ``TONGUE_LEVEL_FACTOR``
        times the tongue's tip).
      effort_weight: the weight of the effort term.

    Raises:
      ParameterError: a bad name or value, naming it.
    """

    def __init__(
        self,
        name: str,
        params: RigParams,
        *,
        release_rad: float | None = None,
        target_amplitudes_rad: Sequence[float] = DEFAULT_TARGET_AMPLITUDES_RAD,
        tongue_mode: int = 1,
        tongue_level_m_s2: float | None = None,
        effort_weight: float = DEFAULT_EFFORT_WEIGHT,
    ) -> None:
        if name not in TASKS:
            raise ParameterError(f"unknown task {name!r}; allowed: {', '.join(TASKS)}")
        self.name = name
        self.linear = linearise(params)
        modes = self.linear.modes
        default_release = TONGUE_RELEASE_RAD if name == "tongue" else DEFAULT_RELEASE_RAD
        self.release_rad = _check_number(
            "release_rad", default_release if release_rad is None else release_rad, 0.0, math.pi / 2
        )
        self.target_amplitudes_rad = check_targets(target_amplitudes_rad)
        self.effort_weight = _check_number("effort_weight", effort_weight, 0.0, 1e3)
        if tongue_mode not in (1, 2) or isinstance(tongue_mode, bool):
            raise ParameterError(f"tongue_mode must be 1 or 2, got {tongue_mode!r}")
        self.tongue_mode = int(tongue_mode)
        # each pendulum's frequency with the other held at rest, rad/s
        self.own_omega_rad_s = np.sqrt(np.diag(modes.stiffness_n_m) / np.diag(modes.mass_kg_m2))
        self.drive_frequency_hz = 0.0
        self.drive_level_m_s2 = 0.0
        if name == "tongue":
            from pendsim_mj.nonlinear.tongues import mathieu_boundary_m_s2  # start-up: loads MuJoCo

            self.drive_frequency_hz = float(modes.omega_rad_s[self.tongue_mode - 1] / math.pi)  # 2 f_i
            tip = float(mathieu_boundary_m_s2(modes, self.drive_frequency_hz, self.tongue_mode))
            level = TONGUE_LEVEL_FACTOR * tip if tongue_level_m_s2 is None else tongue_level_m_s2
            self.drive_level_m_s2 = _check_number("tongue_level_m_s2", level, 0.0, 50.0)
            self.tip_level_m_s2 = tip

    @property
    def modal(self) -> bool:
        """True when the task scores the normal modes' amplitudes (damp, hold, tongue)."""
        return self.name in _MODAL

    @property
    def drives_pivot(self) -> bool:
        """True when the task drives the pivot vertically (the tongue)."""
        return self.name == "tongue"

    def release(self, rng: np.random.Generator) -> Floats:
        """(4,) a random start state (module docstring's table), rad and rad/s."""
        r = self.release_rad
        if self.name == "still-m2":
            phi1 = rng.uniform(r / 3.0, r) * (1.0 if rng.random() < 0.5 else -1.0)
            return np.array([phi1, 0.0, 0.0, 0.0])
        phi = rng.uniform(-r, r, size=2)
        return np.array([phi[0], phi[1], 0.0, 0.0])

    def amplitudes(self, x: Floats) -> Floats:
        """(n, 2) the task's amplitudes (module docstring) of states x (n, 4), rad."""
        if self.name in _MODAL:
            return self.linear.mode_amplitudes_rad(x)
        return np.asarray(np.sqrt(x[:, :2] ** 2 + (x[:, 2:] / self.own_omega_rad_s) ** 2), dtype=np.float64)

    def targets(self, x0: Floats, override: tuple[float, float] | None = None) -> Floats:
        """(n, 2) the targets of members released at x0 (n, 4); ``override``: the hold task's
        targets given in a reset's options."""
        n = len(x0)
        if self.name == "hold":
            goal = self.target_amplitudes_rad if override is None else override
            return np.tile(np.asarray(goal, dtype=float), (n, 1))
        if self.name in _MODAL:
            return np.zeros((n, 2))
        own = self.amplitudes(x0)
        if self.name == "still-m2":
            own[:, 1] = 0.0
        return own

    def reward(self, amplitudes: Floats, targets: Floats, effort: Floats) -> Floats:
        """(n,) the reward (module docstring) from the amplitudes and targets (n, 2) and the
        effort (n,), the mean over channels of (u / limit)^2."""
        off = (amplitudes - targets) * (1.0 / A_REF_RAD)
        off *= off
        return np.asarray(-(off[:, 0] + off[:, 1]) - self.effort_weight * effort, dtype=np.float64)

    def pivot_m_s2(self, t_mid_s: Floats) -> Floats:
        """(n,) the pivot's vertical acceleration held over steps whose midpoints are t_mid_s, m/s^2."""
        return np.asarray(self.drive_level_m_s2 * np.sin(2.0 * math.pi * self.drive_frequency_hz * t_mid_s))

    def phase(self, t_s: Floats) -> Floats:
        """(n, 2) cos and sin of the drive's phase at t_s (the tongue task's extra observations)."""
        angle = 2.0 * math.pi * self.drive_frequency_hz * t_s
        return np.stack([np.cos(angle), np.sin(angle)], axis=-1)
