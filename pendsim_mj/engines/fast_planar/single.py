"""One undriven run on the calling thread, compiled for a short first run: what a single
trajectory (``validate``'s model series, ``simulate`` with the fast engine) calls instead of the
batch's serial kernel.

The batch kernels inline ``kernel._rk4`` into a loop over members (which vectorise), so numba
compiles four copies of the force law per kernel: the serial undriven batch kernel took 13.4 s of
CPU on a cold cache. Here the RK4 stages are a loop with one call of the force law (as
``kernel._rates_kernel`` writes them), in ``_rk4``'s order of operations: 3.0 s to compile, the
same bits as the batch kernel (tested), 0.05 s for an hour of 10 ms steps (2026-11-27, 2 cores,
load 2-3).
"""

from __future__ import annotations

import numba

from pendsim_mj.engines.fast_planar.closed_form import FloatArray
from pendsim_mj.engines.fast_planar.kernel import _accel, _chunk_coefficients, _member, _power


@numba.njit(cache=True)
def integrate_one_undriven(k: FloatArray, y0: FloatArray, nstep: int, h: float, every: int, out: FloatArray) -> None:
    """One member (k: (NCOEF, 1)) from y0 (5,) = (phi1, phi2, omega1, omega2, D) over nstep RK4 steps
    of h (s), no inputs; out[r] (nstep // every + 1, 5) = the state after r * every steps (row 0: y0),
    as ``kernel._integrate_serial_undriven`` writes a batch's column."""
    c = _member(_chunk_coefficients(k, 0, 1), 0)
    zero = (0.0, 0.0, 0.0, 0.0)
    p1, p2, w1, w2, d = y0[0], y0[1], y0[2], y0[3], y0[4]
    for q in range(5):
        out[0, q] = y0[q]
    hh = 0.5 * h
    h6 = h / 6.0
    for step in range(nstep):
        a1 = a2 = f1 = f2 = g1 = g2 = i1 = i2 = 0.0  # each stage's accelerations, rates, powers
        v1 = v2 = x1 = x2 = y1 = y2 = 0.0
        e1 = e2 = e3 = e4 = 0.0
        for stage in range(4):  # _rk4's stages, one written call of the force law
            if stage == 0:
                q1, q2, o1, o2 = p1, p2, w1, w2
            elif stage == 1:
                q1, q2, o1, o2 = p1 + hh * w1, p2 + hh * w2, w1 + hh * a1, w2 + hh * a2
            elif stage == 2:
                q1, q2, o1, o2 = p1 + hh * v1, p2 + hh * v2, w1 + hh * f1, w2 + hh * f2
            else:
                q1, q2, o1, o2 = p1 + h * x1, p2 + h * x2, w1 + h * g1, w2 + h * g2
            b1, b2 = _accel(q1, q2, o1, o2, c, zero)
            e = _power(o1, o2, c)
            if stage == 0:
                a1, a2, e1 = b1, b2, e
            elif stage == 1:
                v1, v2, f1, f2, e2 = o1, o2, b1, b2, e
            elif stage == 2:
                x1, x2, g1, g2, e3 = o1, o2, b1, b2, e
            else:
                y1, y2, i1, i2, e4 = o1, o2, b1, b2, e
        p1, p2, w1, w2, d = (
            p1 + h6 * (((w1 + 2.0 * v1) + 2.0 * x1) + y1),
            p2 + h6 * (((w2 + 2.0 * v2) + 2.0 * x2) + y2),
            w1 + h6 * (((a1 + 2.0 * f1) + 2.0 * g1) + i1),
            w2 + h6 * (((a2 + 2.0 * f2) + 2.0 * g2) + i2),
            d + h6 * (((e1 + 2.0 * e2) + 2.0 * e3) + e4),
        )
        if (step + 1) % every == 0:
            row = (step + 1) // every
            out[row, 0] = p1
            out[row, 1] = p2
            out[row, 2] = w1
            out[row, 3] = w2
            out[row, 4] = d
