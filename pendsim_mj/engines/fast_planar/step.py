"""One RK4 step of a batch of rigs, each with its own constants and held inputs, compiled: what a
filter's sigma points (``pendsim_mj.twin.estimator``) take a few hundred times a second, where
numpy's per-call overhead on a few dozen members is most of the cost.

The step is ``kernel._rk4``'s (the reference's order of operations; the inputs held over the
step), so it equals ``control.plant.FastPlant``'s numpy step to rounding (tested).
"""

from __future__ import annotations

import numba

from pendsim_mj.engines.fast_planar.closed_form import FloatArray
from pendsim_mj.engines.fast_planar.kernel import _rk4


@numba.njit(cache=True)
def rk4_held(k: FloatArray, x: FloatArray, u: FloatArray, h: float, out: FloatArray) -> None:
    """x (4, n) (phi1, phi2 rad; omega1, omega2 rad/s) advanced by h (s) into out (4, n), member i
    with constants k[:, i] (``closed_form.COEFFICIENTS`` rows) and inputs u[:, i] = (tau1, tau2,
    a_h, a_v) held over the step."""
    n = x.shape[1]
    for i in range(n):
        c = (k[0, i], k[1, i], k[2, i], k[3, i], k[4, i], k[5, i], k[6, i], k[7, i], k[8, i], k[9, i], k[10, i],
             k[11, i], k[12, i], k[13, i])  # fmt: skip
        ui = (u[0, i], u[1, i], u[2, i], u[3, i])
        p1, p2, w1, w2, _ = _rk4(x[0, i], x[1, i], x[2, i], x[3, i], 0.0, h, c, ui, ui, ui)
        out[0, i] = p1
        out[1, i] = p2
        out[2, i] = w1
        out[3, i] = w2
