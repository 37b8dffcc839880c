"""How large an RK4 step a rig takes: the largest step that keeps the rig linearised at rest from
growing under RK4 and what sets it, told to a run that diverged (``step_advice``). The engines
give the linearisation of their own equations (``reference.rest_jacobian``); nothing here imports
an engine."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.rig.params import RigParams


def rk4_stable_step_s(eigenvalues: ArrayLike) -> float:
    """The largest step h (s) at which RK4 keeps x' = lambda x from growing for every eigenvalue
    (1/s): |R(lambda h)| <= 1 with R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24, along each eigenvalue's
    ray (RK4's stability region: 2.785 on the negative real axis, 2 sqrt 2 on the imaginary
    one), by bisection to 1e-6 relative; inf where no eigenvalue limits the step (zero, or
    growing: an unstable rig is not the step's doing)."""

    def stable(z: complex) -> bool:
        return abs(1 + z + z * z / 2 + z**3 / 6 + z**4 / 24) <= 1 + 1e-12

    limit = math.inf
    for lam in np.asarray(eigenvalues, dtype=complex):
        size = abs(lam)
        if size == 0 or lam.real > 0:
            continue
        lo, hi = 0.0, 3.0 / size  # |z| = 3 lies outside RK4's region in every direction
        while hi - lo > 1e-6 * hi:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if stable(lam * mid) else (lo, mid)
        limit = min(limit, lo)
    return limit


def step_advice(params: RigParams, dt_s: float, jacobian: NDArray[np.float64]) -> str:
    """What to change after a run at ``dt_s`` (s) diverged, from ``jacobian`` (4, 4): the rig's
    d(phi1, phi2, omega1, omega2)/dt linearised at rest. The largest step RK4 keeps stable there
    (``rk4_stable_step_s``) and what sets it: a hinge's damping (when the fastest eigenvalue is
    mostly real; named by its b/J) or the springs and gravity (the fastest mode's frequency).
    Where the rig at rest is stable at ``dt_s``, the motion itself (large angles stretch the
    springs further) or an input set the limit: that is said instead."""
    eigenvalues = np.linalg.eigvals(jacobian)
    limit = rk4_stable_step_s(eigenvalues)
    if not limit < dt_s:
        return (
            f"reduce dt_s (now {dt_s:g} s): this rig at rest is stable for steps up to {limit:.3g} s, so the "
            "motion's large angles (the springs stretched further) set the limit"
        )
    fastest = eigenvalues[np.argmax(np.abs(eigenvalues))]
    if abs(fastest.real) > abs(fastest.imag):
        rates = [params.b1_n_m_s / params.j1_kg_m2, params.b2_n_m_s / params.j2_kg_m2]
        k = int(np.argmax(rates))
        b = (params.b1_n_m_s, params.b2_n_m_s)[k]
        cause = f"M{k + 1}'s damping (b{k + 1}_n_m_s = {b:g} N m s/rad: a decay rate b/J of {rates[k]:.3g} 1/s)"
    else:
        cause = f"the springs and gravity (the fastest mode at {abs(fastest.imag) / (2 * math.pi):.3g} Hz)"
    return f"reduce dt_s (now {dt_s:g} s) below {limit:.2g} s, the largest step RK4 keeps stable here, set by {cause}"
