"""The fast planar engine's compiled functions (numba): the RK4 step of the force law of
``closed_form``, the batch kernel behind ``integrate`` and ``lyapunov``, and the kernel of
``rates_at`` / ``normal_equations_at`` with its exact sensitivities.

Drives: every RK4 step reads its inputs at its three stage instants, (H, NSTAGE, NINPUT, ...)
(start for k1, midpoint for k2 and k3, end for k4: ``drives.stage_inputs``, fourth order; an
input held over the step is three equal rows, MuJoCo's rule). The rates kernel's variational
step uses the same stage inputs, so its sensitivities stay the exact derivative of the step.

alone, in a SIMD lane or in the scalar remainder, so a member's result does not depend on the
batch it is in (bit for bit). A member that diverges (non-finite state) keeps NaN; ``integrate``
never raises for it, ``solve_batch`` does (as the reference).

Public entry points: ``solve`` / ``solve_batch`` (the reference's arguments, drives included, and

The kernels inline the same helpers (``_accel``, ``_member``, ``sincos``); ``summary_kernel``
(a sweep's summary pass) and ``step`` (the twin's sigma points) inline them from here too. numba's
``cache=True`` notices edits only in the file a cached function is defined in, and the constants
read from ``closed_form`` (the coefficient rows, ``NINPUT``, the friction smoothing) are frozen
into the cache when compiled; so pendsim's cache folder is named after a digest of this whole
package's sources (``pendsim_mj.compile_notice.cache_folder``: ``~/.cache/pendsim/numba-*``), and
an edit to any file here compiles everything again. With your own ``NUMBA_CACHE_DIR``, empty it
after editing these files.

Compile time: numba inlines a helper marked ``inline="always"`` into every call site at the level
of its own IR, which costs seconds per nested copy. The kernels inline only where it pays at run
time (the RK4 step into the batch loop, where the members vectorise; ``_trig``, ``_accel_at`` and
``_sens_derivative`` into the rates kernel, each written once in its loop over the RK4 stages).
The sensitivities' partials take the angles' sines and cosines from ``_trig`` (once per stage,
not per column) and are compiled on their own. The batch loop (``_integrate_chunk``)
is inlined into the parallel kernel and the serial twin: compiled on its own
and called from the parallel loop it ran 2.5-4x slower (the members vectorise only inside the
parallel loop, where numba marks the arrays as not aliased). The step reads its stage inputs
from twelve 1-D arrays: reading them from one (3, 4, m) array made the undriven batch 4.3x
slower (0.90 against 0.21 s CPU for 2000 cases of 3000 steps).
A cold compile of the rates kernel took 71 s of CPU before, 7 s after; the fit's pass runs at
the same speed (the calibration's, with every force-law sensitivity, within 10 %), with the
same bits (2026-11-26, 2 cores, load 4-6).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from pendsim_mj import compile_notice
from pendsim_mj.engines.fast_planar.closed_form import (
    _B1,
    _B2,
    _F1,
    _F2,
    _FC,
    _FS,
    _G1,
    _G2,
    _J1,
    _J2,
    _KC,
    _KS,
    _MOC1,
    _MOC2,
    _SMOOTH2,
    FloatArray,
)

compile_notice.watch()  # the cache folder; one line on a cold compile (the CLI prints it)

# fdlibm (Sun Microsystems, 1993) constants: pi/2 in three 33-bit pieces and the minimax
# polynomials of __kernel_sin / __kernel_cos on [-pi/4, pi/4].
_INV_PIO2 = 6.36619772367581382433e-01
_PIO2_1 = 1.57079632673412561417e00
_PIO2_2 = 6.07710050630396597660e-11
_PIO2_3 = 2.02226624871116645580e-21
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11


@numba.njit(inline="always", cache=True)
def sincos(x: float) -> tuple[float, float]:
    """(sin x, cos x) without a library call, so loops around it vectorise (see module notes)."""
    n = np.floor(x * _INV_PIO2 + 0.5)
    r = ((x - n * _PIO2_1) - n * _PIO2_2) - n * _PIO2_3  # n * _PIO2_k exact for |n| < 2**20
    z = r * r
    s = r + (z * r) * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    hz = 0.5 * z
    w = 1.0 - hz
    c = w + (((1.0 - w) - hz) + z * (z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))))
    q = n - 4.0 * np.floor(0.25 * n)  # quadrant 0..3
    odd = (q == 1.0) | (q == 3.0)
    sin_sign = -1.0 if q >= 2.0 else 1.0
    cos_sign = -1.0 if (q == 1.0) | (q == 2.0) else 1.0
    return sin_sign * (c if odd else s), cos_sign * (s if odd else c)


# A member's force-law constants travel through the kernel as one tuple of NCOEF floats, in the
# order of COEFFICIENTS: to add a term to the force law, add its constant(s) to COEFFICIENTS and
# ``coefficients``, load them in ``_chunk_coefficients`` / ``_member``, and use them in ``_accel``.


@numba.njit(inline="always", cache=True)
def _chunk_coefficients(k: FloatArray, lo: int, hi: int) -> tuple[FloatArray, ...]:
    """Members lo..hi-1's rows of k as NCOEF contiguous 1-D arrays (what lets the loop vectorise)."""
    return (
        k[0, lo:hi].copy(),
        k[1, lo:hi].copy(),
        k[2, lo:hi].copy(),
        k[3, lo:hi].copy(),
        k[4, lo:hi].copy(),
        k[5, lo:hi].copy(),
        k[6, lo:hi].copy(),
        k[7, lo:hi].copy(),
        k[8, lo:hi].copy(),
        k[9, lo:hi].copy(),
        k[10, lo:hi].copy(),
        k[11, lo:hi].copy(),
        k[12, lo:hi].copy(),
        k[13, lo:hi].copy(),
    )


@numba.njit(inline="always", cache=True)
def _chunk_state(y0: FloatArray, lo: int, hi: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Members lo..hi-1's state rows of y0 (5, nbatch) as five fresh 1-D arrays (phi1, phi2,
    omega1, omega2, D): copies, which the batch loop updates in place."""
    return y0[0, lo:hi].copy(), y0[1, lo:hi].copy(), y0[2, lo:hi].copy(), y0[3, lo:hi].copy(), y0[4, lo:hi].copy()


@numba.njit(inline="always", cache=True)
def _member(kc: tuple[FloatArray, ...], i: int) -> tuple[float, ...]:
    """Member i's constants from ``_chunk_coefficients``: a tuple of NCOEF floats."""
    return (
        kc[0][i], kc[1][i], kc[2][i], kc[3][i], kc[4][i], kc[5][i], kc[6][i], kc[7][i], kc[8][i], kc[9][i],
        kc[10][i], kc[11][i], kc[12][i], kc[13][i],
    )  # fmt: skip


@numba.njit(inline="always", cache=True)
def _resist(w1: float, w2: float, c: tuple[float, ...]) -> tuple[float, float]:
    """The hinges' resisting moments b_n w_n + F_n w_n / sqrt(w_n^2 + w_s^2), N m (the reference's
    ``damping1``, ``damping2``; with F_n = 0 exactly b_n w_n)."""
    return (
        c[_B1] * w1 + c[_F1] * (w1 / math.sqrt(w1 * w1 + _SMOOTH2)),
        c[_B2] * w2 + c[_F2] * (w2 / math.sqrt(w2 * w2 + _SMOOTH2)),
    )


@numba.njit(inline="always", cache=True)
def _trig(p1: float, p2: float) -> tuple[float, float, float, float, float, float]:
    """(sin phi1, cos phi1, sin phi2, cos phi2, sin(phi2 - phi1), cos(phi2 - phi1)), shared by
    ``_accel_at`` and the partials (computed once per stage, not per column)."""
    s1, c1 = sincos(p1)
    s2, c2 = sincos(p2)
    return s1, c1, s2, c2, s2 * c1 - c2 * s1, c2 * c1 + s2 * s1


@numba.njit(inline="always", cache=True)
def _accel(
    p1: float, p2: float, w1: float, w2: float, c: tuple[float, ...], u: tuple[float, float, float, float]
) -> tuple[float, float]:
    """phi1'', phi2'' with constants c (``_member``) and the inputs u = (tau1, tau2, a_h, a_v)
    (zeros when undriven: the drive terms then add exactly 0), in the reference's order of
    operations."""
    return _accel_at(_trig(p1, p2), w1, w2, c, u)


@numba.njit(inline="always", cache=True)
def _accel_at(
    trig: tuple[float, float, float, float, float, float],
    w1: float,
    w2: float,
    c: tuple[float, ...],
    u: tuple[float, float, float, float],
) -> tuple[float, float]:
    """``_accel`` with the angles' ``_trig`` given."""
    s1, c1, s2, c2, sd, cd = trig
    m1 = c[_KS] * sd - c[_KC] * cd
    m2 = -m1 - c[_FS] * s2 + c[_FC] * c2
    d1, d2 = _resist(w1, w2, c)
    t1 = -c[_G1] * s1 + m1 - d1
    t2 = -c[_G2] * s2 + m2 - d2
    t1 = t1 - c[_MOC1] * (u[3] * s1 + u[2] * c1) + u[0]
    t2 = t2 - c[_MOC2] * (u[3] * s2 + u[2] * c2) + u[1]
    return t1 / c[_J1], t2 / c[_J2]


@numba.njit(inline="always", cache=True)
def _power(w1: float, w2: float, c: tuple[float, ...]) -> float:
    """Power dissipated in the hinges, W: d1 w1 + d2 w2 (``_resist``), the reference's order."""
    d1, d2 = _resist(w1, w2, c)
    return d1 * w1 + d2 * w2


@numba.njit(inline="always", cache=True)
def _rk4(
    p1: float,
    p2: float,
    w1: float,
    w2: float,
    d: float,
    h: float,
    c: tuple[float, ...],
    u0: tuple[float, float, float, float],
    um: tuple[float, float, float, float],
    u1: tuple[float, float, float, float],
) -> tuple[float, float, float, float, float]:
    """One classical RK4 step of (phi1, phi2, omega1, omega2, D) with the inputs u0 at the step's
    start (k1), um at its midpoint (k2, k3) and u1 at its end (k4) (all three equal: an input held
    over the step), in the reference's order of operations: y + (h/2) k1, ...,
    y + (h/6)(k1 + 2 k2 + 2 k3 + k4)."""
    hh = 0.5 * h
    a1, a2 = _accel(p1, p2, w1, w2, c, u0)
    e1 = _power(w1, w2, c)
    q1, q2, v1, v2 = p1 + hh * w1, p2 + hh * w2, w1 + hh * a1, w2 + hh * a2
    f1, f2 = _accel(q1, q2, v1, v2, c, um)
    e2 = _power(v1, v2, c)
    r1, r2, x1, x2 = p1 + hh * v1, p2 + hh * v2, w1 + hh * f1, w2 + hh * f2
    g1, g2 = _accel(r1, r2, x1, x2, c, um)
    e3 = _power(x1, x2, c)
    s1, s2, y1, y2 = p1 + h * x1, p2 + h * x2, w1 + h * g1, w2 + h * g2
    i1, i2 = _accel(s1, s2, y1, y2, c, u1)
    e4 = _power(y1, y2, c)
    h6 = h / 6.0
    return (
        p1 + h6 * (((w1 + 2.0 * v1) + 2.0 * x1) + y1),
        p2 + h6 * (((w2 + 2.0 * v2) + 2.0 * x2) + y2),
        w1 + h6 * (((a1 + 2.0 * f1) + 2.0 * g1) + i1),
        w2 + h6 * (((a2 + 2.0 * f2) + 2.0 * g2) + i2),
        d + h6 * (((e1 + 2.0 * e2) + 2.0 * e3) + e4),
    )


@numba.njit(inline="always", cache=True)
def _integrate_chunk(
    k: FloatArray,
    y0: FloatArray,
    held: FloatArray,
    step0: int,
    nstep: int,
    h: float,
    every: int,
    out: FloatArray,
    lo: int,
    hi: int,
) -> None:
    """Members lo..hi-1 side by side (SIMD), as ``_integrate_kernel`` describes, for both kernels.
    Inlined into each: called as a function compiled on its own, the parallel loop ran 2.5-4x
    slower (LLVM vectorised the members only inside numba's parallel loop; measured 2026-11-26,
    numba 0.68). The stage inputs live in twelve separate 1-D arrays (zeros when undriven): one
    (3, 4, m) array made the loop scalar, 4.3x slower."""
    m = hi - lo
    driven = held.shape[0] > 0
    kc = _chunk_coefficients(k, lo, hi)
    p1, p2, w1, w2, d = _chunk_state(y0, lo, hi)
    a0, a1, a2, a3 = np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m)  # start of the step
    b0, b1, b2, b3 = np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m)  # midpoint
    c0, c1, c2, c3 = np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m)  # end
    for i in range(m):
        for q in range(5):
            out[0, q, lo + i] = y0[q, lo + i]
    for step in range(nstep):
        if driven:
            t = step0 + step
            for i in range(m):
                a0[i], a1[i], a2[i], a3[i] = (
                    held[t, 0, 0, lo + i],
                    held[t, 0, 1, lo + i],
                    held[t, 0, 2, lo + i],
                    held[t, 0, 3, lo + i],
                )
                b0[i], b1[i], b2[i], b3[i] = (
                    held[t, 1, 0, lo + i],
                    held[t, 1, 1, lo + i],
                    held[t, 1, 2, lo + i],
                    held[t, 1, 3, lo + i],
                )
                c0[i], c1[i], c2[i], c3[i] = (
                    held[t, 2, 0, lo + i],
                    held[t, 2, 1, lo + i],
                    held[t, 2, 2, lo + i],
                    held[t, 2, 3, lo + i],
                )
        for i in range(m):
            u0 = (a0[i], a1[i], a2[i], a3[i])
            um = (b0[i], b1[i], b2[i], b3[i])
            u1 = (c0[i], c1[i], c2[i], c3[i])
            pa, pb, pc, pe, pf = _rk4(p1[i], p2[i], w1[i], w2[i], d[i], h, _member(kc, i), u0, um, u1)
            p1[i] = pa
            p2[i] = pb
            w1[i] = pc
            w2[i] = pe
            d[i] = pf
        if (step + 1) % every == 0:
            row = (step + 1) // every
            for i in range(m):
                out[row, 0, lo + i] = p1[i]
                out[row, 1, lo + i] = p2[i]
                out[row, 2, lo + i] = w1[i]
                out[row, 3, lo + i] = w2[i]
                out[row, 4, lo + i] = d[i]


@numba.njit(inline="always", cache=True)
def _integrate_chunk_undriven(
    k: FloatArray,
    y0: FloatArray,
    held: FloatArray,
    step0: int,
    nstep: int,
    h: float,
    every: int,
    out: FloatArray,
    lo: int,
    hi: int,
) -> None:
    """``_integrate_chunk`` without inputs: constant zero inputs, so the drive terms fold away and
    the members vectorise (4.3x faster than reading zeros from the input arrays, 0.21 against
    0.90 s CPU for 2000 cases of 3000 steps). A kernel of its own, so each compiles only the
    path it runs (both paths in one kernel took 122 s of CPU to compile)."""
    m = hi - lo
    kc = _chunk_coefficients(k, lo, hi)
    p1, p2, w1, w2, d = _chunk_state(y0, lo, hi)
    zero = (0.0, 0.0, 0.0, 0.0)
    for i in range(m):
        for q in range(5):
            out[0, q, lo + i] = y0[q, lo + i]
    for step in range(nstep):
        for i in range(m):
            pa, pb, pc, pe, pf = _rk4(p1[i], p2[i], w1[i], w2[i], d[i], h, _member(kc, i), zero, zero, zero)
            p1[i] = pa
            p2[i] = pb
            w1[i] = pc
            w2[i] = pe
            d[i] = pf
        if (step + 1) % every == 0:
            row = (step + 1) // every
            for i in range(m):
                out[row, 0, lo + i] = p1[i]
                out[row, 1, lo + i] = p2[i]
                out[row, 2, lo + i] = w1[i]
                out[row, 3, lo + i] = w2[i]
                out[row, 4, lo + i] = d[i]


@numba.njit(parallel=True, cache=True)
def _integrate_kernel(
    k: FloatArray,
    y0: FloatArray,
    held: FloatArray,
    step0: int,
    nstep: int,
    h: float,
    every: int,
    out: FloatArray,
    chunk: int,
) -> None:
    """Chunks of ``chunk`` members over the threads, the members of a chunk side by side (SIMD).

    y0 (5, nbatch) is the state at t = step0 h; held (H, NSTAGE, NINPUT, nbatch) the inputs at the
    start, midpoint and end of steps 0..H-1 (``_rk4``; H = 0: undriven); out[r] = the state after
    r * every steps, (nsave, 5, nbatch).
    """
    n = y0.shape[1]
    for ci in numba.prange((n + chunk - 1) // chunk):
        _integrate_chunk(k, y0, held, step0, nstep, h, every, out, ci * chunk, min(n, ci * chunk + chunk))


@numba.njit(parallel=True, cache=True)
def _integrate_kernel_undriven(
    k: FloatArray,
    y0: FloatArray,
    held: FloatArray,
    step0: int,
    nstep: int,
    h: float,
    every: int,
    out: FloatArray,
    chunk: int,
) -> None:
    """``_integrate_kernel`` for undriven batches (held empty)."""
    n = y0.shape[1]
    for ci in numba.prange((n + chunk - 1) // chunk):
        _integrate_chunk_undriven(k, y0, held, step0, nstep, h, every, out, ci * chunk, min(n, ci * chunk + chunk))


@numba.njit(cache=True)
def _integrate_serial(
    k: FloatArray,
    y0: FloatArray,
    held: FloatArray,
    step0: int,
    nstep: int,
    h: float,
    every: int,
    out: FloatArray,
    chunk: int,
) -> None:
    """``_integrate_kernel`` on the calling thread, chunk after chunk (the same arithmetic, bit for
    bit): what a run on one thread calls. numba compiles it in about a third of the parallel
    kernel's time (no parallel loop to lower), and calling it starts no thread pool."""
    n = y0.shape[1]
    for ci in range((n + chunk - 1) // chunk):
        _integrate_chunk(k, y0, held, step0, nstep, h, every, out, ci * chunk, min(n, ci * chunk + chunk))


@numba.njit(cache=True)
def _integrate_serial_undriven(
    k: FloatArray,
    y0: FloatArray,
    held: FloatArray,
    step0: int,
    nstep: int,
    h: float,
    every: int,
    out: FloatArray,
    chunk: int,
) -> None:
    """``_integrate_serial`` for undriven batches (held empty)."""
    n = y0.shape[1]
    for ci in range((n + chunk - 1) // chunk):
        _integrate_chunk_undriven(k, y0, held, step0, nstep, h, every, out, ci * chunk, min(n, ci * chunk + chunk))


# --- rates at given instants, with their exact sensitivities (the damping fit) -----------------


@numba.njit(cache=True)
def _accel_partials(
    trig: tuple[float, float, float, float, float, float],
    w1: float,
    w2: float,
    c: tuple[float, ...],
    u: tuple[float, float, float, float],
) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """d(phi1'', phi2'')/d(phi1, phi2, omega_n) and the direct derivatives by b_n, F_n with the held
    inputs u (``_accel``; the torques add no partial, a support acceleration adds
    -m_n OC_n (a_v cos phi_n - a_h sin phi_n) / J_n to d phi_n'' / d phi_n):
    (a1_p1, a1_p2, a1_w1, a2_p1, a2_p2, a2_w2, a1_b1, a2_b2, a1_F1, a2_F2), from the equations of
    the module docstring (d = phi2 - phi1; s(w) = w / sqrt(w^2 + w_s^2), s'(w) = w_s^2 / (w^2 +
    w_s^2)^(3/2)); trig: ``_trig`` of the state's angles."""
    s1, c1, s2, c2, sd, cd = trig
    coupling = c[_KS] * cd + c[_KC] * sd  # d M1 / d phi2 = -d M1 / d phi1
    q1 = w1 * w1 + _SMOOTH2
    q2 = w2 * w2 + _SMOOTH2
    r1 = math.sqrt(q1)
    r2 = math.sqrt(q2)
    j1 = 1.0 / c[_J1]
    j2 = 1.0 / c[_J2]
    return (
        (-c[_G1] * c1 - coupling - c[_MOC1] * (u[3] * c1 - u[2] * s1)) * j1,
        coupling * j1,
        -(c[_B1] + c[_F1] * _SMOOTH2 / (q1 * r1)) * j1,
        coupling * j2,
        (-c[_G2] * c2 - coupling - c[_FS] * c2 - c[_FC] * s2 - c[_MOC2] * (u[3] * c2 - u[2] * s2)) * j2,
        -(c[_B2] + c[_F2] * _SMOOTH2 / (q2 * r2)) * j2,
        -w1 * j1,
        -w2 * j2,
        -(w1 / r1) * j1,
        -(w2 / r2) * j2,
    )


@numba.njit(cache=True)
def _coef_partial(
    trig: tuple[float, float, float, float, float, float],
    a1: float,
    a2: float,
    c: tuple[float, ...],
    u: tuple[float, float, float, float],
    code: int,
) -> tuple[float, float]:
    """The direct derivative of (phi1'', phi2'') by one force-law constant, ``wrt`` code 8 + its
    index in COEF_SENSITIVITIES (J1, J2, m1 g OC1, m2 g OC2, K_s, K_c, F_s, F_c, m1 OC1, m2 OC2),
    from the equations of ``closed_form`` (d = phi2 - phi1): d phi_n'' / d J_n = -phi_n'' / J_n;
    the others enter phi_n'' linearly, divided by J_n. trig: ``_trig`` of the state's angles;
    a1, a2: ``_accel`` at the state (with u)."""
    s1, c1, s2, c2, sd, cd = trig
    j1 = 1.0 / c[_J1]
    j2 = 1.0 / c[_J2]
    if code == 8 or code == 9:
        return (-a1 * j1, 0.0) if code == 8 else (0.0, -a2 * j2)
    if code == 10:
        return -s1 * j1, 0.0
    if code == 11:
        return 0.0, -s2 * j2
    if code == 12:
        return sd * j1, -sd * j2
    if code == 13:
        return -cd * j1, cd * j2
    if code == 14:
        return 0.0, -s2 * j2
    if code == 15:
        return 0.0, c2 * j2
    if code == 16:
        return -(u[3] * s1 + u[2] * c1) * j1, 0.0
    return 0.0, -(u[3] * s2 + u[2] * c2) * j2


@numba.njit(inline="always", cache=True)
def _sens_derivative(
    trig: tuple[float, float, float, float, float, float], w1: float, w2: float, c: tuple[float, ...],
    u: tuple[float, float, float, float], a1: float, a2: float, wrt: NDArray[np.int64], s: FloatArray,
    out: FloatArray,
) -> None:  # fmt: skip
    """d/dt of the sensitivities s (4, P) of (phi1, phi2, omega1, omega2) at the state given, into
    out (4, P): the variational equations of the rig with the held inputs u (trig: ``_trig`` of
    the state's angles; a1, a2: ``_accel`` there, which the caller has computed)."""
    a1p1, a1p2, a1w1, a2p1, a2p2, a2w2, a1b1, a2b2, a1f1, a2f2 = _accel_partials(trig, w1, w2, c, u)
    for col in range(s.shape[1]):
        out[0, col] = s[2, col]
        out[1, col] = s[3, col]
        out[2, col] = a1p1 * s[0, col] + a1p2 * s[1, col] + a1w1 * s[2, col]
        out[3, col] = a2p1 * s[0, col] + a2p2 * s[1, col] + a2w2 * s[3, col]
        code = wrt[col]
        if code == 4:
            out[2, col] += a1b1
        elif code == 5:
            out[3, col] += a2b2
        elif code == 6:
            out[2, col] += a1f1
        elif code == 7:
            out[3, col] += a2f2
        elif code >= 8:  # a force-law constant (calibration): its direct derivative of the accelerations
            d1, d2 = _coef_partial(trig, a1, a2, c, u, code)
            out[2, col] += d1
            out[3, col] += d2


@numba.njit(cache=True)
def _rates_kernel(
    k: FloatArray,
    y0: FloatArray,
    tau: float,
    h: float,
    nstep: int,
    held: FloatArray,
    wrt: NDArray[np.int64],
    at1: FloatArray,
    at2: FloatArray,
    rate1: FloatArray,
    rate2: FloatArray,
    sens1: FloatArray,
    sens2: FloatArray,
    slope1: FloatArray,
    slope2: FloatArray,
    observed1: FloatArray,
    observed2: FloatArray,
    sigma: FloatArray,
    release_column: bool,
    timing_column: bool,
    jtj: FloatArray,
    jtr: FloatArray,
    rr: FloatArray,
) -> None:
    """One member (k: (NCOEF, 1)) from y0 = (phi1, phi2, omega1, omega2) at rest until ``tau``,
    then RK4 steps of h, step j with the inputs held[j] at its start, midpoint and end (``_rk4``;
    held: (H >= nstep, NSTAGE, NINPUT), or H = 0: undriven; the drive's time 0 is tau): each node's
    rate at its instants at_n (ascending, s) by cubic Hermite through omega and alpha at the step
    ends (alpha with the inputs at the step's start and end), its
    sensitivities (m_n, P) to the ``wrt`` unknowns (RK4 on the variational equations: the exact
    derivative of the discrete solution), and d rate / d tau (m_n,). Instants before tau: rate 0
    (at rest), no sensitivity. An empty slope_n (0,): node n's slopes are not written.

    Accumulate mode (jtj of shape (Q, Q), Q > 0): nothing is written to rate/sens/slope (pass
    empty arrays); instead each instant's Jacobian row J_i = (sensitivities, [d rate / d tau if
    release_column], [0 for node 1, -d rate / d tau for node 2 if timing_column]) / sigma_n and
    residual r_i = (rate - observed_n) / sigma_n (observed_n: (m_n,), sigma: (2,)) are added into
    the upper triangle of jtj (Q, Q), jtr (Q,) and rr (1,): J^T J, J^T r and r.r, summed in the
    instants' order."""
    accumulate = jtj.shape[0] > 0
    nq = jtj.shape[0]
    row = np.zeros(nq)
    c = _member(_chunk_coefficients(k, 0, 1), 0)
    zero = (0.0, 0.0, 0.0, 0.0)
    inp = zero  # the inputs at the step's start, midpoint (inp) and end
    inp0 = zero
    inp1 = zero
    driven = held.shape[0] > 0
    npar = len(wrt)
    s = np.zeros((4, npar))
    for col in range(npar):
        if wrt[col] < 4:
            s[wrt[col], col] = 1.0
    ks = np.zeros((4, 4, npar))  # the four stages' d/dt of s
    st = np.zeros((4, npar))  # a stage's s
    p1, p2, w1, w2 = y0[0], y0[1], y0[2], y0[3]
    tp = _trig(p1, p2)
    a1, a2 = _accel_at(tp, w1, w2, c, zero)
    _sens_derivative(tp, w1, w2, c, zero, a1, a2, wrt, s, ks[0])
    n1 = np.searchsorted(at1, tau)
    n2 = np.searchsorted(at2, tau)
    m1, m2 = len(at1), len(at2)
    if accumulate:  # at rest before tau: rate 0, a zero row
        for i in range(n1):
            res = -observed1[i] / sigma[0]
            rr[0] += res * res
        for i in range(n2):
            res = -observed2[i] / sigma[1]
            rr[0] += res * res
    hh = 0.5 * h
    h6 = h / 6.0
    ends = np.zeros((2, 2, npar))  # at the step's start: each node's s of omega and of alpha
    v1 = v2 = f1 = f2 = x1 = x2 = g1 = g2 = y1 = y2 = i1 = i2 = 0.0  # the stages' rates and accelerations
    np1, np2, nw1, nw2, na1, na2 = p1, p2, w1, w2, a1, a2  # the step's end: state and acceleration
    for step in range(nstep):
        if driven:  # this step's inputs
            inp0 = (held[step, 0, 0], held[step, 0, 1], held[step, 0, 2], held[step, 0, 3])
            inp = (held[step, 1, 0], held[step, 1, 1], held[step, 1, 2], held[step, 1, 3])
            inp1 = (held[step, 2, 0], held[step, 2, 1], held[step, 2, 2], held[step, 2, 3])
        # RK4 of the state, in _rk4's order of operations, and of s alongside (each stage with the
        # inputs at its time: the variational step is the exact derivative of this step). One
        # evaluation per stage, written once (numba compiles each written call site): 0 the step's
        # start (driven only: undriven, the previous step's end holds it), 1 and 2 the midpoints,
        # 3 the end, 4 the new state (the start of the next step).
        for stage in range(0 if driven else 1, 5):
            if stage == 0:
                e1, e2, o1, o2, u = p1, p2, w1, w2, inp0
            elif stage == 1:
                e1, e2, o1, o2, u = p1 + hh * w1, p2 + hh * w2, w1 + hh * a1, w2 + hh * a2, inp
            elif stage == 2:
                e1, e2, o1, o2, u = p1 + hh * v1, p2 + hh * v2, w1 + hh * f1, w2 + hh * f2, inp
            elif stage == 3:
                e1, e2, o1, o2, u = p1 + h * x1, p2 + h * x2, w1 + h * g1, w2 + h * g2, inp1
            else:
                e1 = p1 + h6 * (((w1 + 2.0 * v1) + 2.0 * x1) + y1)
                e2 = p2 + h6 * (((w2 + 2.0 * v2) + 2.0 * x2) + y2)
                o1 = w1 + h6 * (((a1 + 2.0 * f1) + 2.0 * g1) + i1)
                o2 = w2 + h6 * (((a2 + 2.0 * f2) + 2.0 * g2) + i2)
                u = inp1
            trig = _trig(e1, e2)
            b1, b2 = _accel_at(trig, o1, o2, c, u)
            if stage == 0:
                a1, a2 = b1, b2
            elif stage == 1:
                v1, v2, f1, f2 = o1, o2, b1, b2
            elif stage == 2:
                x1, x2, g1, g2 = o1, o2, b1, b2
            elif stage == 3:
                y1, y2, i1, i2 = o1, o2, b1, b2
            else:
                np1, np2, nw1, nw2, na1, na2 = e1, e2, o1, o2, b1, b2
            if not npar:
                continue
            if 1 <= stage <= 3:  # the stage's s from the previous stage's slope
                frac = h if stage == 3 else hh
                for col in range(npar):
                    for r in range(4):
                        st[r, col] = s[r, col] + frac * ks[stage - 1, r, col]
            elif stage == 4:  # the step's s
                for col in range(npar):
                    for n in range(2):
                        ends[n, 0, col] = s[2 + n, col]
                        ends[n, 1, col] = ks[0, 2 + n, col]
                    for r in range(4):
                        s[r, col] = s[r, col] + h6 * (
                            ((ks[0, r, col] + 2.0 * ks[1, r, col]) + 2.0 * ks[2, r, col]) + ks[3, r, col]
                        )
            _sens_derivative(trig, o1, o2, c, u, b1, b2, wrt, st if 1 <= stage <= 3 else s, ks[stage % 4])
        last = step == nstep - 1
        for node in range(2):
            at = at1 if node == 0 else at2
            rate = rate1 if node == 0 else rate2
            sens = sens1 if node == 0 else sens2
            slope = slope1 if node == 0 else slope2
            idx = n1 if node == 0 else n2
            m = m1 if node == 0 else m2
            w0, wn, a0, an = (w1, nw1, a1, na1) if node == 0 else (w2, nw2, a2, na2)
            while idx < m:
                u = (at[idx] - tau) / h - step
                if u >= 1.0 and not last:
                    break
                f = min(u, 1.0) if last else u  # the last step: no extrapolation
                f2 = f * f
                f3 = f2 * f
                h00, h10, h01, h11 = 2 * f3 - 3 * f2 + 1, f3 - 2 * f2 + f, -2 * f3 + 3 * f2, f3 - f2
                rate_i = h00 * w0 + h10 * h * a0 + h01 * wn + h11 * h * an
                slope_i = -((1 - f) * a0 + f * an)
                if accumulate:
                    sg = sigma[node]
                    for col in range(npar):
                        row[col] = (
                            h00 * ends[node, 0, col]
                            + h10 * h * ends[node, 1, col]
                            + h01 * s[2 + node, col]
                            + h11 * h * ks[0, 2 + node, col]
                        ) / sg
                    q = npar
                    if release_column:
                        row[q] = slope_i / sg
                        q += 1
                    if timing_column:  # M2's instants shift: its rate moves by -slope per second
                        row[q] = 0.0 if node == 0 else -slope_i / sg
                    res = (rate_i - (observed1[idx] if node == 0 else observed2[idx])) / sg
                    rr[0] += res * res
                    for a in range(nq):
                        jtr[a] += row[a] * res
                        for b in range(a, nq):
                            jtj[a, b] += row[a] * row[b]
                else:
                    rate[idx] = rate_i
                    if len(slope) == m:  # (an empty slope: not asked for)
                        slope[idx] = slope_i
                    for col in range(npar):
                        sens[idx, col] = (
                            h00 * ends[node, 0, col]
                            + h10 * h * ends[node, 1, col]
                            + h01 * s[2 + node, col]
                            + h11 * h * ks[0, 2 + node, col]
                        )
                idx += 1
            if node == 0:
                n1 = idx
            else:
                n2 = idx
        p1, p2, w1, w2, a1, a2 = np1, np2, nw1, nw2, na1, na2
