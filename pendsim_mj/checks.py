"""Argument checks shared by both engines; each error names the argument and what is allowed.

Imports no physics engine, so the reference solver can use it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pendsim_mj.errors import ParameterError, SimulationDiverged
from pendsim_mj.params import RigParams


def check_step(duration_s: float, dt_s: float) -> int:
    """Validate duration and step (s); return the number of steps."""
    for name, value in (("duration_s", duration_s), ("dt_s", dt_s)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise ParameterError(f"{name} must be a finite number > 0 s, got {value!r}")
    if dt_s > duration_s:
        raise ParameterError(f"dt_s = {dt_s} s must not exceed duration_s = {duration_s} s")
    nstep = round(duration_s / dt_s)
    if abs(nstep * dt_s - duration_s) > 1e-9 * max(1.0, duration_s):
        raise ParameterError(f"duration_s = {duration_s} s must be a whole number of steps of dt_s = {dt_s} s")
    return nstep


def check_params(params: RigParams | Sequence[RigParams]) -> list[RigParams]:
    """One RigParams or a non-empty sequence of them, as a list."""
    if isinstance(params, RigParams):
        return [params]
    plist = list(params) if isinstance(params, Sequence) else []
    if not plist or not all(isinstance(p, RigParams) for p in plist):
        raise ParameterError("params must be a RigParams or a non-empty sequence of RigParams")
    return plist


def check_initial(phi0_rad: object, omega0_rad_s: object, nbatch: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Initial angles (rad) and velocities (rad/s) as (nbatch, 2) float arrays, checked."""
    out = []
    for name, value in (("phi0_rad", phi0_rad), ("omega0_rad_s", omega0_rad_s)):
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise ParameterError(f"{name} must be numbers, got {value!r}") from None
        if arr.ndim == 1:
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise ParameterError(f"{name} must have shape (2,) or (nbatch, 2), got {np.shape(value)}")
        if not np.all(np.isfinite(arr)):
            raise ParameterError(f"{name} must be finite, got {arr.tolist() if arr.size <= 8 else 'non-finite values'}")
        out.append(arr)
    phi, omega = out
    n = max(len(phi), len(omega), nbatch or 1)
    for name, arr in (("phi0_rad", phi), ("omega0_rad_s", omega)):
        if len(arr) not in (1, n):
            raise ParameterError(f"{name} has {len(arr)} rows; expected 1 or {n}")
    return np.broadcast_to(phi, (n, 2)).copy(), np.broadcast_to(omega, (n, 2)).copy()


def broadcast_params(plist: list[RigParams], nbatch: int) -> list[RigParams]:
    """Repeat a single parameter set over the batch, or check the counts match."""
    if len(plist) == 1:
        return plist * nbatch
    if len(plist) != nbatch:
        raise ParameterError(f"got {len(plist)} parameter sets for {nbatch} initial conditions")
    return plist


# An unforced rig with non-negative damping cannot gain energy; RK4 at a stable step keeps the
# energy error near 1e-5 of the energy (measured in tests/test_physics.py). A growth above this
# share of (initial energy + one pendulum's gravity scale m g OC) means the step is unstable.
ENERGY_GROWTH_LIMIT = 0.01


def check_energy_bounded(total_energy_j: np.ndarray, energy_scale_j: np.ndarray, dt_s: float) -> None:
    """Raise SimulationDiverged where the total energy (..., n) grew past the limit.

    Args:
      total_energy_j: (nbatch, n) kinetic + potential energy above rest, J.
      energy_scale_j: (nbatch,) a natural energy scale of each run (m1 g OC1), J.
      dt_s: the step, named in the message.
    """
    e0 = total_energy_j[:, 0]
    growth = np.max(total_energy_j, axis=1) - e0
    limit = ENERGY_GROWTH_LIMIT * (np.abs(e0) + energy_scale_j)
    bad = ~(growth <= limit)  # also catches NaN
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise SimulationDiverged(
            f"simulation diverged: the energy of run {i} grew from {e0[i]:.4g} J to {e0[i] + growth[i]:.4g} J "
            f"without any input; reduce dt_s (now {dt_s} s) or the stiffness"
        )
