"""``lyapunov``: the largest Lyapunov exponent of each member on the compiled kernel (Benettin's
two-trajectory method)."""

from __future__ import annotations

import math

import numpy as np

from pendsim_mj.engines.fast_planar.batch import _UNDRIVEN, _held, _initial_state, _run
from pendsim_mj.engines.fast_planar.closed_form import FloatArray, _check_coef
from pendsim_mj.errors import ParameterError


def lyapunov(
    coef: FloatArray,
    phi0_rad: FloatArray,
    omega0_rad_s: FloatArray,
    nstep: int,
    dt_s: float,
    *,
    inputs: FloatArray | None = None,
    renormalise_every: int = 100,
    separation: float = 1e-8,
    nthread: int | None = None,
) -> FloatArray:
    """Largest Lyapunov exponent of each member, 1/s, with its convergence (``inputs`` as in
    ``integrate``: a driven member and its shadow feel the same input).

    Benettin's method: a shadow of each member starts ``separation`` away along (1, 1, 1, 1)/2 in
    (phi1, phi2, omega1, omega2) (rad, rad/s); both run through the kernel as one batch, and every
    ``renormalise_every`` steps the shadow is pulled back to that distance. The exponent is the
    mean log growth of the distance per second. Positive: chaos; at an equilibrium of the damped
    rig it tends to the slowest decay rate of the linearised modes (negative).

    Returns:
      (nstep // renormalise_every, nbatch): the running estimate after each renormalisation; the
      last row is the estimate over the whole run. NaN for a member that diverged.
    """
    phi0 = np.asarray(phi0_rad, dtype=np.float64)
    omega0 = np.asarray(omega0_rad_s, dtype=np.float64)
    nbatch = len(phi0)
    k = _check_coef(coef, nbatch)
    every = renormalise_every
    if isinstance(every, bool) or not isinstance(every, int) or every < 1 or nstep < every:
        raise ParameterError(f"renormalise_every must be a whole number in 1..nstep = {nstep}, got {every!r}")
    if not (math.isfinite(separation) and separation > 0):
        raise ParameterError(f"separation must be > 0, got {separation!r}")
    pair = np.concatenate([k, k], axis=1)  # members, then their shadows
    held = _held(inputs, nbatch, nstep)
    held = np.ascontiguousarray(np.concatenate([held, held], axis=3)) if held.shape[0] else _UNDRIVEN
    y = np.concatenate([_initial_state(phi0, omega0), _initial_state(phi0, omega0)], axis=1)
    y[:4, nbatch:] += 0.5 * separation
    out = np.empty((nstep // every, nbatch))
    total = np.zeros(nbatch)
    for r in range(nstep // every):
        y = _run(pair, y, held, r * every, every, float(dt_s), every, nthread)[-1]
        gap = y[:4, nbatch:] - y[:4, :nbatch]
        dist = np.sqrt(np.sum(gap * gap, axis=0))
        with np.errstate(divide="ignore", invalid="ignore"):
            total += np.log(dist / separation)
            y[:4, nbatch:] = y[:4, :nbatch] + gap * (separation / dist)
        out[r] = total / ((r + 1) * every * dt_s)
    return out
