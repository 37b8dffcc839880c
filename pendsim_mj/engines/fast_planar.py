"""The fast planar engine: the rig's planar equations in closed form, classical RK4, compiled by numba.

Same equations, same fixed-step RK4 and the same Trajectory as ``reference`` (which stays the
paper-faithful check and is what this module is tested against), many times faster: the batch is
split into chunks that run on every core (``prange``) and, inside a chunk, the members are
integrated side by side so the compiler vectorises the step (SIMD). Imports no MuJoCo.

Closed form of the spring moments (paper frame: x down, y horizontal, z the pivot axis)
-------------------------------------------------------------------------------------------
Write e_n = (cos phi_n, sin phi_n) for the unit vector along pendulum n and
n_n = (-sin phi_n, cos phi_n) for the one across it; with a x b = a_x b_y - a_y b_x (the z
component of the cross product),

    e1 x e2 = sin(phi2 - phi1),   n1 x e2 = -cos(phi2 - phi1),   e1 . e2 = cos(phi2 - phi1),
    n1 . e2 = sin(phi2 - phi1),   e2 x (1, 0) = -sin phi2,       e2 x (0, 1) = cos phi2.

The anchor points (spec RIG.md section 2) are P1 = l01 e2, P2 = l04 e1 + l24 n1,
P3 = l04 e1 - l34 n1, P5 = l05 e2, P6 = (l08, +l68), P7 = (l08, -l78). A zero-free-length spring
of stiffness c between P_i and P_j pulls P_i with F = c (P_j - P_i), whose moment about O is
P_i x F = c (P_i x P_j), because P_i x P_i = 0. Hence, exactly:

    M1 = c1 (P2 x P1) + c1 (P3 x P1) = c1 (P2 + P3) x P1,   P2 + P3 = 2 l04 e1 + (l24 - l34) n1
       = c1 l01 [2 l04 sin(phi2 - phi1) - (l24 - l34) cos(phi2 - phi1)]
    M2 = c1 (P1 x P2) + c1 (P1 x P3) + c2 P5 x (P6 + P7),   P6 + P7 = (2 l08, l68 - l78)
       = -M1 - 2 c2 l05 l08 sin phi2 + c2 l05 (l68 - l78) cos phi2

The springs 1-2 and 1-3 are internal to the pair M1-M2, so their moments are equal and opposite:
a coupling proportional to sin(phi2 - phi1). The frame springs 5-6 and 5-7 act on M2 like extra
gravity, 2 c2 l05 l08 sin phi2. The lengths l24 = l34 and l68 = l78 of the paper's rig enter only
through their differences (the cosine terms vanish on the paper's rig). With the four constants

    K_s = 2 c1 l01 l04,  K_c = c1 l01 (l24 - l34),  F_s = 2 c2 l05 l08,  F_c = c2 l05 (l68 - l78)  (N m)

the equations of motion (spec section 4) read

    J1 phi1'' = -m1 g OC1 sin phi1 + K_s sin(phi2 - phi1) - K_c cos(phi2 - phi1) - b1 phi1' - F1 s(phi1')
    J2 phi2'' = -m2 g OC2 sin phi2 - K_s sin(phi2 - phi1) + K_c cos(phi2 - phi1)
                - F_s sin phi2 + F_c cos phi2 - b2 phi2' - F2 s(phi2')

with F_n the hinges' dry friction and s(w) = w / sqrt(w^2 + w_s^2) the smoothed sign of the
reference (``params.friction_direction``).

The spring potential follows from the squared lengths (|P_i - P_j|^2 = |P_i|^2 + |P_j|^2
- 2 P_i . P_j): above its value at phi1 = phi2 = 0 it is

    V_springs = K_s (1 - cos(phi2 - phi1)) - K_c sin(phi2 - phi1) + F_s (1 - cos phi2) - F_c sin phi2

and -dV/dphi_n gives M1, M2 back. The state integrated is (phi1, phi2, omega1, omega2, D) with
D' = the hinges' dissipated power, exactly as in ``reference``: one RK4 step of this module equals
the reference's to about 1e-16 rad (tests: 1e-12).

Drives (``pendsim_mj.rig.drives``) enter as in ``reference``, held constant over each step (the
value at the step's midpoint, as MuJoCo holds ``ctrl``): hinge torques tau_n, and the support's
horizontal and upward accelerations a_h, a_v as the inertial moment
-m_n OC_n (a_v sin phi_n + a_h cos phi_n) on pendulum n (derivation in ``reference``):

    J_n phi_n'' = (... the right-hand side above ...) - m_n OC_n (a_v sin phi_n + a_h cos phi_n) + tau_n

Kernel notes: sin and cos are evaluated by an inlined fdlibm-style routine (Cody-Waite reduction
by pi/2, the fdlibm minimax polynomials on [-pi/4, pi/4]), within 1 ulp of libm for |x| < 1e5 rad,
so that the loop over members vectorises; every member's arithmetic is the same whether it runs
alone, in a SIMD lane or in the scalar remainder, so a member's result does not depend on the
batch it is in (bit for bit). A member that diverges (non-finite state) keeps NaN; ``integrate``
never raises for it, ``solve_batch`` does (as the reference).

Public entry points: ``solve`` / ``solve_batch`` (the reference's arguments, drives included, and
its Trajectory), ``integrate`` (states only, optionally every k-th step: what a sweep needs),
``lyapunov`` (largest Lyapunov exponent, Benettin's two-trajectory method), ``diverged``,
``rates_at`` (one run's rates at given instants with exact sensitivities) and
``normal_equations_at`` (the same pass summing a fit's J^T J, J^T r, r.r), and the closed
forms ``spring_moments``, ``accelerations``, ``spring_lengths``, ``potential_energy``.

To extend the force law (e.g. hinge friction): add its constants to ``COEFFICIENTS`` and
``coefficients``, load them in ``_chunk_coefficients`` / ``_member``, use them in ``_accel``
(and in the power of ``_rk4`` if they dissipate), mirror it in ``accelerations``, and test one
step against ``reference`` to 1e-12 rad.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterator, Sequence

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.engines.trajectory import Trajectory, planar_imu_readings
from pendsim_mj.errors import ParameterError, SimulationDiverged
from pendsim_mj.rig.checks import (
    broadcast_params,
    check_drives,
    check_energy_bounded,
    check_initial,
    check_params,
    check_step,
    energy_grew,
)
from pendsim_mj.rig.drives import Drive, inputs_at_samples, stack_inputs, support_initial_velocity, support_motion
from pendsim_mj.rig.params import DEFAULT_PARAMS, FRICTION_SMOOTHING_RAD_S, ParamColumns, RigParams, friction_direction

FloatArray = NDArray[np.float64]

# Rows of the coefficient array (NCOEF, nbatch): everything the force law needs, SI units.
COEFFICIENTS = (
    "j1_kg_m2",  # J1
    "j2_kg_m2",  # J2
    "b1_n_m_s",  # b1
    "b2_n_m_s",  # b2
    "gravity1_n_m",  # m1 g OC1
    "gravity2_n_m",  # m2 g OC2
    "coupling_sin_n_m",  # K_s = 2 c1 l01 l04
    "coupling_cos_n_m",  # K_c = c1 l01 (l24 - l34)
    "frame_sin_n_m",  # F_s = 2 c2 l05 l08
    "frame_cos_n_m",  # F_c = c2 l05 (l68 - l78)
    "moc1_kg_m",  # m1 OC1: the inertial moment of a support acceleration
    "moc2_kg_m",  # m2 OC2
    "friction1_n_m",  # F1: dry friction at hinge 1
    "friction2_n_m",  # F2
)
NCOEF = len(COEFFICIENTS)
_J1, _J2, _B1, _B2, _G1, _G2, _KS, _KC, _FS, _FC, _MOC1, _MOC2, _F1, _F2 = range(NCOEF)
_SMOOTH2 = FRICTION_SMOOTHING_RAD_S * FRICTION_SMOOTHING_RAD_S  # (rad/s)^2 of the dry-friction law
NINPUT = 4  # held inputs per step: tau1, tau2 (N m), a_h, a_v (m/s^2), the channels of drives.Target

# Members integrated side by side in one chunk (a multiple of the 8-wide AVX-512 vector); chunks
# are spread over the cores.
CHUNK = 64


def coefficients(params: Sequence[RigParams] | ParamColumns) -> FloatArray:
    """The force-law constants of each parameter set: (NCOEF, nbatch), rows as ``COEFFICIENTS``."""
    cols = params if isinstance(params, ParamColumns) else ParamColumns.from_params(params)
    c = cols.column
    return np.ascontiguousarray(
        np.stack(
            [
                c("j1_kg_m2"),
                c("j2_kg_m2"),
                c("b1_n_m_s"),
                c("b2_n_m_s"),
                c("m1_kg") * c("g_m_s2") * c("oc1_m"),
                c("m2_kg") * c("g_m_s2") * c("oc2_m"),
                2.0 * c("c1_n_m") * c("l01_m") * c("l04_m"),
                c("c1_n_m") * c("l01_m") * (c("l24_m") - c("l34_m")),
                2.0 * c("c2_n_m") * c("l05_m") * c("l08_m"),
                c("c2_n_m") * c("l05_m") * (c("l68_m") - c("l78_m")),
                c("m1_kg") * c("oc1_m"),
                c("m2_kg") * c("oc2_m"),
                c("friction1_n_m"),
                c("friction2_n_m"),
            ]
        )
    )


# --- closed forms in numpy (any shape broadcasting against the coefficient rows) -----------------


def spring_moments(phi1: FloatArray, phi2: FloatArray, coef: FloatArray) -> tuple[FloatArray, FloatArray]:
    """M1, M2: moments of the spring forces about O on M1 and M2, N m (closed form above).

    Args:
      phi1, phi2: angles, rad, any shape broadcasting against one coefficient row (nbatch,).
      coef: (NCOEF, nbatch) from ``coefficients``.
    """
    delta = phi2 - phi1
    m1 = coef[_KS] * np.sin(delta) - coef[_KC] * np.cos(delta)
    m2 = -m1 - coef[_FS] * np.sin(phi2) + coef[_FC] * np.cos(phi2)
    return m1, m2


def accelerations(
    phi1: FloatArray,
    phi2: FloatArray,
    omega1: FloatArray,
    omega2: FloatArray,
    coef: FloatArray,
    inputs: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Angular accelerations phi1'', phi2'' (rad/s^2) of the equations of motion above, with the
    held inputs (NINPUT, ...) = (tau1, tau2, a_h, a_v) broadcasting against the angles, or none."""
    m1, m2 = spring_moments(phi1, phi2, coef)
    torque1 = -coef[_G1] * np.sin(phi1) + m1 - (coef[_B1] * omega1 + coef[_F1] * friction_direction(omega1))
    torque2 = -coef[_G2] * np.sin(phi2) + m2 - (coef[_B2] * omega2 + coef[_F2] * friction_direction(omega2))
    if inputs is not None:
        a_h, a_v = inputs[2], inputs[3]
        torque1 = torque1 - coef[_MOC1] * (a_v * np.sin(phi1) + a_h * np.cos(phi1)) + inputs[0]
        torque2 = torque2 - coef[_MOC2] * (a_v * np.sin(phi2) + a_h * np.cos(phi2)) + inputs[1]
    return torque1 / coef[_J1], torque2 / coef[_J2]


def potential_energy(phi1: FloatArray, phi2: FloatArray, coef: FloatArray) -> FloatArray:
    """Gravity + spring potential energy above the pose phi1 = phi2 = 0, J (closed form above)."""
    delta = phi2 - phi1
    springs = (
        coef[_KS] * (1.0 - np.cos(delta))
        - coef[_KC] * np.sin(delta)
        + coef[_FS] * (1.0 - np.cos(phi2))
        - coef[_FC] * np.sin(phi2)
    )
    return coef[_G1] * (1.0 - np.cos(phi1)) + coef[_G2] * (1.0 - np.cos(phi2)) + springs


def kinetic_energy(omega1: FloatArray, omega2: FloatArray, coef: FloatArray) -> FloatArray:
    """(J1 omega1^2 + J2 omega2^2) / 2, J."""
    return 0.5 * (coef[_J1] * omega1**2 + coef[_J2] * omega2**2)


def diverged(states: FloatArray, coef: FloatArray, driven: NDArray[np.bool_] | None = None) -> NDArray[np.bool_]:
    """(nbatch,) True for each member of ``integrate``'s states (nsave, 5, nbatch) that became
    non-finite or, unless ``driven`` (nbatch,) says it has an input, whose energy grew
    (``checks.energy_grew``: the test that makes ``solve_batch`` and the reference raise
    SimulationDiverged)."""
    total = kinetic_energy(states[:, 2], states[:, 3], coef) + potential_energy(states[:, 0], states[:, 1], coef)
    grew = energy_grew(total.T, coef[_G1])
    if driven is not None:
        grew &= ~driven
    return grew | ~np.all(np.isfinite(states), axis=(0, 1))


def spring_lengths(phi1: FloatArray, phi2: FloatArray, params: Sequence[RigParams]) -> FloatArray:
    """Lengths of springs 1-2, 1-3, 5-6, 5-7 (m), shape (4, *phi1.shape), from the squared lengths
    |P_i - P_j|^2 = |P_i|^2 + |P_j|^2 - 2 P_i . P_j with the dot products of the docstring."""
    p = {name: np.array([getattr(q, name) for q in params]) for name in ("l01_m", "l04_m", "l24_m", "l34_m")}
    f = {name: np.array([getattr(q, name) for q in params]) for name in ("l05_m", "l08_m", "l68_m", "l78_m")}
    delta = phi2 - phi1
    cd, sd = np.cos(delta), np.sin(delta)
    l01, l04, l24, l34 = p["l01_m"], p["l04_m"], p["l24_m"], p["l34_m"]
    l05, l08, l68, l78 = f["l05_m"], f["l08_m"], f["l68_m"], f["l78_m"]
    sq12 = l04**2 + l24**2 + l01**2 - 2.0 * l01 * (l04 * cd + l24 * sd)
    sq13 = l04**2 + l34**2 + l01**2 - 2.0 * l01 * (l04 * cd - l34 * sd)
    sq56 = l05**2 + l08**2 + l68**2 - 2.0 * l05 * (l08 * np.cos(phi2) + l68 * np.sin(phi2))
    sq57 = l05**2 + l08**2 + l78**2 - 2.0 * l05 * (l08 * np.cos(phi2) - l78 * np.sin(phi2))
    return np.sqrt(np.maximum(np.stack([sq12, sq13, sq56, sq57]), 0.0))


# --- the compiled kernel ----------------------------------------------------------------------

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
def _accel(
    p1: float, p2: float, w1: float, w2: float, c: tuple[float, ...], u: tuple[float, float, float, float]
) -> tuple[float, float]:
    """phi1'', phi2'' with constants c (``_member``) and the held inputs u = (tau1, tau2, a_h, a_v)
    (zeros when undriven: the drive terms then add exactly 0), in the reference's order of
    operations."""
    s1, c1 = sincos(p1)
    s2, c2 = sincos(p2)
    sd = s2 * c1 - c2 * s1  # sin(phi2 - phi1)
    cd = c2 * c1 + s2 * s1  # cos(phi2 - phi1)
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
    u: tuple[float, float, float, float],
) -> tuple[float, float, float, float, float]:
    """One classical RK4 step of (phi1, phi2, omega1, omega2, D) with the inputs u held over it, in
    the reference's order of operations: y + (h/2) k1, ..., y + (h/6)(k1 + 2 k2 + 2 k3 + k4)."""
    hh = 0.5 * h
    a1, a2 = _accel(p1, p2, w1, w2, c, u)
    e1 = _power(w1, w2, c)
    q1, q2, v1, v2 = p1 + hh * w1, p2 + hh * w2, w1 + hh * a1, w2 + hh * a2
    f1, f2 = _accel(q1, q2, v1, v2, c, u)
    e2 = _power(v1, v2, c)
    r1, r2, x1, x2 = p1 + hh * v1, p2 + hh * v2, w1 + hh * f1, w2 + hh * f2
    g1, g2 = _accel(r1, r2, x1, x2, c, u)
    e3 = _power(x1, x2, c)
    s1, s2, y1, y2 = p1 + h * x1, p2 + h * x2, w1 + h * g1, w2 + h * g2
    i1, i2 = _accel(s1, s2, y1, y2, c, u)
    e4 = _power(y1, y2, c)
    h6 = h / 6.0
    return (
        p1 + h6 * (((w1 + 2.0 * v1) + 2.0 * x1) + y1),
        p2 + h6 * (((w2 + 2.0 * v2) + 2.0 * x2) + y2),
        w1 + h6 * (((a1 + 2.0 * f1) + 2.0 * g1) + i1),
        w2 + h6 * (((a2 + 2.0 * f2) + 2.0 * g2) + i2),
        d + h6 * (((e1 + 2.0 * e2) + 2.0 * e3) + e4),
    )


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

    y0 (5, nbatch) is the state at t = step0 h; held (H, NINPUT, nbatch) the inputs held over
    steps 0..H-1 (H = 0: undriven); out[r] = the state after r * every steps, (nsave, 5, nbatch).
    """
    n = y0.shape[1]
    driven = held.shape[0] > 0
    for ci in numba.prange((n + chunk - 1) // chunk):
        lo = ci * chunk
        hi = min(n, lo + chunk)
        m = hi - lo
        kc = _chunk_coefficients(k, lo, hi)
        p1 = y0[0, lo:hi].copy()
        p2 = y0[1, lo:hi].copy()
        w1 = y0[2, lo:hi].copy()
        w2 = y0[3, lo:hi].copy()
        d = y0[4, lo:hi].copy()
        tau1 = np.zeros(m)
        tau2 = np.zeros(m)
        acc_h = np.zeros(m)
        acc_v = np.zeros(m)
        for i in range(m):
            for q in range(5):
                out[0, q, lo + i] = y0[q, lo + i]
        for step in range(nstep):
            if driven:
                for i in range(m):
                    tau1[i] = held[step0 + step, 0, lo + i]
                    tau2[i] = held[step0 + step, 1, lo + i]
                    acc_h[i] = held[step0 + step, 2, lo + i]
                    acc_v[i] = held[step0 + step, 3, lo + i]
            for i in range(m):
                u = (tau1[i], tau2[i], acc_h[i], acc_v[i])
                a, b, c, e, f = _rk4(p1[i], p2[i], w1[i], w2[i], d[i], h, _member(kc, i), u)
                p1[i] = a
                p2[i] = b
                w1[i] = c
                w2[i] = e
                d[i] = f
            if (step + 1) % every == 0:
                row = (step + 1) // every
                for i in range(m):
                    out[row, 0, lo + i] = p1[i]
                    out[row, 1, lo + i] = p2[i]
                    out[row, 2, lo + i] = w1[i]
                    out[row, 3, lo + i] = w2[i]
                    out[row, 4, lo + i] = d[i]


def _initial_state(phi0_rad: FloatArray, omega0_rad_s: FloatArray) -> FloatArray:
    y0 = np.zeros((5, len(phi0_rad)))
    y0[0:2] = phi0_rad.T
    y0[2:4] = omega0_rad_s.T
    return y0


def _chunk(nbatch: int, nthread: int) -> int:
    """Members per chunk: CHUNK, or fewer so that a small batch still spreads over the threads;
    a multiple of 8 (one AVX-512 vector), so a batch of 8 or fewer stays on one thread."""
    per_thread = -(-nbatch // max(1, nthread))
    return min(CHUNK, -(-per_thread // 8) * 8)


def _threads(nthread: int | None) -> int:
    limit: int = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
    if nthread is None:
        return min(limit, os.cpu_count() or 1)
    if isinstance(nthread, bool) or not isinstance(nthread, int) or nthread < 1:
        raise ParameterError(f"nthread must be a whole number >= 1, got {nthread!r}")
    return min(nthread, limit)


_UNDRIVEN = np.zeros((0, NINPUT, 0))


def _run(
    k: FloatArray,
    y0: FloatArray,
    held: FloatArray,
    step0: int,
    nstep: int,
    h: float,
    every: int,
    nthread: int | None,
) -> FloatArray:
    """The kernel on min(chunks, threads) threads, from state y0 (5, nbatch) at t = step0 h with
    the held inputs (H, NINPUT, nbatch) (H = 0: undriven): a batch that fits one chunk runs on the
    calling thread alone (no pool wake-up: batch size 1 costs only the integration). Returns
    (nstep // every + 1, 5, nbatch)."""
    nbatch = y0.shape[1]
    threads = _threads(nthread)
    chunk = _chunk(nbatch, threads)
    out = np.empty((nstep // every + 1, 5, nbatch))
    previous = numba.get_num_threads()
    numba.set_num_threads(max(1, min(threads, -(-nbatch // chunk))))
    try:
        _integrate_kernel(k, y0, held, step0, nstep, h, every, out, chunk)
    finally:
        numba.set_num_threads(previous)
    return out


def _check_coef(coef: FloatArray, nbatch: int) -> FloatArray:
    k = np.ascontiguousarray(coef, dtype=np.float64)
    if k.shape != (NCOEF, nbatch):
        raise ParameterError(f"coef must have shape ({NCOEF}, {nbatch}) (from coefficients()), got {k.shape}")
    return k


def _held(inputs: FloatArray | None, nbatch: int, nstep: int) -> FloatArray:
    """Held inputs (nbatch, nstep, NINPUT) as the kernel reads them, (nstep, NINPUT, nbatch)."""
    if inputs is None:
        return _UNDRIVEN
    u = np.asarray(inputs, dtype=np.float64)
    if u.shape != (nbatch, nstep, NINPUT):
        raise ParameterError(
            f"inputs must have shape ({nbatch}, {nstep}, {NINPUT}) (drives.held_inputs), got {u.shape}"
        )
    return np.ascontiguousarray(u.transpose(1, 2, 0))


def integrate(
    coef: FloatArray,
    phi0_rad: FloatArray,
    omega0_rad_s: FloatArray,
    nstep: int,
    dt_s: float,
    *,
    inputs: FloatArray | None = None,
    save_every: int = 1,
    nthread: int | None = None,
) -> FloatArray:
    """Classical RK4 over a batch, states only: the lean entry point for sweeps.

    Args:
      coef: (NCOEF, nbatch) from ``coefficients``.
      phi0_rad, omega0_rad_s: (nbatch, 2) initial conditions.
      nstep: number of RK4 steps.
      dt_s: step, s.
      inputs: (nbatch, nstep, NINPUT) inputs held over each step (``drives.stack_inputs``), or
        None (undriven); the layout of ``reference.integrate``'s ``inputs``.
      save_every: keep the state every this many steps (nstep must be a multiple of it).
      nthread: threads (default: every core numba may use).

    Returns:
      (nstep // save_every + 1, 5, nbatch): (phi1, phi2, omega1, omega2, dissipated_j) at
      t = i * save_every * dt_s, the layout of ``reference.integrate``. A member that diverged holds
      non-finite values from then on; nothing is raised here.
    """
    phi0 = np.asarray(phi0_rad, dtype=np.float64)
    omega0 = np.asarray(omega0_rad_s, dtype=np.float64)
    nbatch = len(phi0)
    k = _check_coef(coef, nbatch)
    if isinstance(save_every, bool) or not isinstance(save_every, int) or save_every < 1 or nstep % save_every:
        raise ParameterError(f"save_every must be a whole number >= 1 that divides nstep = {nstep}, got {save_every!r}")
    held = _held(inputs, nbatch, nstep)
    return _run(k, _initial_state(phi0, omega0), held, 0, int(nstep), float(dt_s), save_every, nthread)


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
    held = np.ascontiguousarray(np.concatenate([held, held], axis=2)) if held.shape[0] else _UNDRIVEN
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


# --- rates at given instants, with their exact sensitivities (the damping fit) -----------------

_UNDRIVEN_STEPS = np.zeros((0, NINPUT))  # ``rates_at`` without inputs

# Unknowns whose sensitivity ``rates_at`` can return (``wrt`` codes): the start state, then the
# hinge losses (rows _B1, _B2, _F1, _F2 of the coefficients).
SENSITIVITY_NAMES = (
    "phi1_0",
    "phi2_0",
    "omega1_0",
    "omega2_0",
    "b1_n_m_s",
    "b2_n_m_s",
    "friction1_n_m",
    "friction2_n_m",
)


@numba.njit(inline="always", cache=True)
def _accel_partials(
    p1: float, p2: float, w1: float, w2: float, c: tuple[float, ...], u: tuple[float, float, float, float]
) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """d(phi1'', phi2'')/d(phi1, phi2, omega_n) and the direct derivatives by b_n, F_n with the held
    inputs u (``_accel``; the torques add no partial, a support acceleration adds
    -m_n OC_n (a_v cos phi_n - a_h sin phi_n) / J_n to d phi_n'' / d phi_n):
    (a1_p1, a1_p2, a1_w1, a2_p1, a2_p2, a2_w2, a1_b1, a2_b2, a1_F1, a2_F2), from the equations of
    the module docstring (d = phi2 - phi1; s(w) = w / sqrt(w^2 + w_s^2), s'(w) = w_s^2 / (w^2 +
    w_s^2)^(3/2))."""
    s1, c1 = sincos(p1)
    s2, c2 = sincos(p2)
    sd = s2 * c1 - c2 * s1
    cd = c2 * c1 + s2 * s1
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


@numba.njit(inline="always", cache=True)
def _sens_derivative(
    p1: float, p2: float, w1: float, w2: float, c: tuple[float, ...], u: tuple[float, float, float, float],
    wrt: NDArray[np.int64], s: FloatArray, out: FloatArray,
) -> None:  # fmt: skip
    """d/dt of the sensitivities s (4, P) of (phi1, phi2, omega1, omega2) at the state given, into
    out (4, P): the variational equations of the rig with the held inputs u."""
    a1p1, a1p2, a1w1, a2p1, a2p2, a2w2, a1b1, a2b2, a1f1, a2f2 = _accel_partials(p1, p2, w1, w2, c, u)
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
    then RK4 steps of h, step j holding the inputs held[j] (held: (H >= nstep, NINPUT), or H = 0:
    undriven; the drive's time 0 is tau): each node's rate at its instants at_n (ascending, s) by
    cubic Hermite through omega and alpha at the step ends (alpha of the step's own inputs), its
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
    inp = zero
    driven = held.shape[0] > 0
    npar = len(wrt)
    s = np.zeros((4, npar))
    for col in range(npar):
        if wrt[col] < 4:
            s[wrt[col], col] = 1.0
    ks = np.zeros((4, 4, npar))  # the four stages' d/dt of s
    st = np.zeros((4, npar))  # a stage's s
    p1, p2, w1, w2 = y0[0], y0[1], y0[2], y0[3]
    a1, a2 = _accel(p1, p2, w1, w2, c, zero)
    _sens_derivative(p1, p2, w1, w2, c, zero, wrt, s, ks[0])
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
    for step in range(nstep):
        if driven:  # this step's inputs: the start's alpha and the variational slope with them
            inp = (held[step, 0], held[step, 1], held[step, 2], held[step, 3])
            a1, a2 = _accel(p1, p2, w1, w2, c, inp)
            if npar:
                _sens_derivative(p1, p2, w1, w2, c, inp, wrt, s, ks[0])
        # RK4 of the state, in _rk4's order of operations, and of s alongside
        q1, q2, v1, v2 = p1 + hh * w1, p2 + hh * w2, w1 + hh * a1, w2 + hh * a2
        f1, f2 = _accel(q1, q2, v1, v2, c, inp)
        r1, r2, x1, x2 = p1 + hh * v1, p2 + hh * v2, w1 + hh * f1, w2 + hh * f2
        g1, g2 = _accel(r1, r2, x1, x2, c, inp)
        t1, t2, y1, y2 = p1 + h * x1, p2 + h * x2, w1 + h * g1, w2 + h * g2
        i1, i2 = _accel(t1, t2, y1, y2, c, inp)
        np1 = p1 + h6 * (((w1 + 2.0 * v1) + 2.0 * x1) + y1)
        np2 = p2 + h6 * (((w2 + 2.0 * v2) + 2.0 * x2) + y2)
        nw1 = w1 + h6 * (((a1 + 2.0 * f1) + 2.0 * g1) + i1)
        nw2 = w2 + h6 * (((a2 + 2.0 * f2) + 2.0 * g2) + i2)
        na1, na2 = _accel(np1, np2, nw1, nw2, c, inp)
        if npar:
            for col in range(npar):
                for r in range(4):
                    st[r, col] = s[r, col] + hh * ks[0, r, col]
            _sens_derivative(q1, q2, v1, v2, c, inp, wrt, st, ks[1])
            for col in range(npar):
                for r in range(4):
                    st[r, col] = s[r, col] + hh * ks[1, r, col]
            _sens_derivative(r1, r2, x1, x2, c, inp, wrt, st, ks[2])
            for col in range(npar):
                for r in range(4):
                    st[r, col] = s[r, col] + h * ks[2, r, col]
            _sens_derivative(t1, t2, y1, y2, c, inp, wrt, st, ks[3])
            for col in range(npar):
                for n in range(2):
                    ends[n, 0, col] = s[2 + n, col]
                    ends[n, 1, col] = ks[0, 2 + n, col]
                for r in range(4):
                    s[r, col] = s[r, col] + h6 * (
                        ((ks[0, r, col] + 2.0 * ks[1, r, col]) + 2.0 * ks[2, r, col]) + ks[3, r, col]
                    )
            _sens_derivative(np1, np2, nw1, nw2, c, inp, wrt, s, ks[0])
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


_NOTHING = np.zeros(0)  # the kernel's arrays a mode does not use
_NOTHING_2D = np.zeros((0, 0))


def _rates_setup(
    coef: FloatArray,
    phi0_rad: Sequence[float] | FloatArray,
    omega0_rad_s: Sequence[float] | FloatArray,
    at_s: tuple[FloatArray, FloatArray],
    dt_s: float,
    release_s: float,
    wrt: Sequence[str],
    inputs: FloatArray | None,
) -> tuple[FloatArray, FloatArray, int, FloatArray, NDArray[np.int64], tuple[FloatArray, ...]]:
    """The checked arguments of ``_rates_kernel`` shared by ``rates_at`` and
    ``normal_equations_at``: (k, y0, nstep, held, wrt codes, instants)."""
    k = _check_coef(coef, 1)
    unknown = [name for name in wrt if name not in SENSITIVITY_NAMES]
    if unknown:
        raise ParameterError(f"rates_at: unknown sensitivity {unknown[0]!r}; allowed: {', '.join(SENSITIVITY_NAMES)}")
    codes = np.array([SENSITIVITY_NAMES.index(name) for name in wrt], dtype=np.int64)
    at = tuple(np.ascontiguousarray(a, dtype=np.float64) for a in at_s)
    end = max((float(a[-1]) for a in at if len(a)), default=0.0) - release_s
    nstep = max(1, math.ceil(end / dt_s) + 1)
    y0 = np.array([*np.asarray(phi0_rad, dtype=float), *np.asarray(omega0_rad_s, dtype=float)])
    held = _UNDRIVEN_STEPS
    if inputs is not None:
        held = np.ascontiguousarray(inputs, dtype=np.float64)
        if held.ndim != 2 or held.shape[1] != NINPUT or held.shape[0] < nstep:
            raise ParameterError(f"rates_at: inputs must have shape (>= {nstep}, {NINPUT}), got {held.shape}")
    return k, y0, nstep, held, codes, at


def normal_equations_at(
    coef: FloatArray,
    phi0_rad: Sequence[float] | FloatArray,
    omega0_rad_s: Sequence[float] | FloatArray,
    at_s: tuple[FloatArray, FloatArray],
    observed_rad_s: tuple[FloatArray, FloatArray],
    sigma_rad_s: Sequence[float] | FloatArray,
    dt_s: float,
    *,
    release_s: float = 0.0,
    wrt: Sequence[str] = (),
    release_column: bool = False,
    timing_column: bool = False,
    inputs: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, float]:
    """The normal equations of a least-squares fit of the rates of ``rates_at`` to observed rates,
    summed over the instants in one kernel pass: memory independent of the number of instants
    (nothing of size m_n is stored; the same integration as ``rates_at``, its accumulate mode).

    Each instant i of node n contributes the normalised residual r_i = (rate - observed) / sigma_n
    and the Jacobian row J_i = (d rate / d wrt, [d rate / d release_s], [0 for node 1,
    -d rate / d release_s for node 2]) / sigma_n: the sensitivities of ``rates_at``, then the
    release offset's column where ``release_column``, then, where ``timing_column``, that of a
    shift of node 2's instants (a later instant: d rate / d t = -d rate / d release_s). Instants
    before the release: rate 0, a zero row.

    Args:
      coef, phi0_rad, omega0_rad_s, at_s, dt_s, release_s, wrt, inputs: as ``rates_at``.
      observed_rad_s: each node's observed rate at its instants, rad/s: (m1,), (m2,).
      sigma_rad_s: (2,) each node's noise sigma, rad/s.
      release_column, timing_column: add those columns (above).

    Returns:
      (J^T J (Q, Q), J^T r (Q,), r.r) with Q = len(wrt) + release_column + timing_column
      (J in 1/sigma per unit of each unknown, r dimensionless). Summed in the instants' order
      (not BLAS's blocked order: equal to it to rounding, ~1e-13 relative).
    """
    k, y0, nstep, held, codes, at = _rates_setup(coef, phi0_rad, omega0_rad_s, at_s, dt_s, release_s, wrt, inputs)
    observed = tuple(np.ascontiguousarray(o, dtype=np.float64) for o in observed_rad_s)
    if any(o.shape != a.shape for o, a in zip(observed, at, strict=True)):
        raise ParameterError("normal_equations_at: each node's observed rates must match its instants' shape")
    sigma = np.ascontiguousarray(sigma_rad_s, dtype=np.float64)
    if sigma.shape != (2,) or not np.all(sigma > 0):
        raise ParameterError(f"normal_equations_at: sigma_rad_s must be two positive values, got {sigma_rad_s!r}")
    nq = len(codes) + int(release_column) + int(timing_column)
    jtj, jtr, rr = np.zeros((nq, nq)), np.zeros(nq), np.zeros(1)
    if nq == 0:  # the kernel's accumulate mode needs a column; r.r alone from the rates
        (r1, r2), _, _ = rates_at(coef, phi0_rad, omega0_rad_s, at_s, dt_s, release_s=release_s, inputs=inputs)
        res = np.concatenate([(r1 - observed[0]) / sigma[0], (r2 - observed[1]) / sigma[1]])
        return jtj, jtr, float(res @ res)
    none, no_sens = _NOTHING, np.zeros((0, len(codes)))
    _rates_kernel(k, y0, float(release_s), float(dt_s), nstep, held, codes, at[0], at[1], none, none, no_sens,
                  no_sens, none, none, observed[0], observed[1], sigma, bool(release_column), bool(timing_column),
                  jtj, jtr, rr)  # fmt: skip
    upper = np.triu(jtj)
    return upper + np.triu(upper, 1).T, jtr, float(rr[0])


def rates_at(
    coef: FloatArray,
    phi0_rad: Sequence[float] | FloatArray,
    omega0_rad_s: Sequence[float] | FloatArray,
    at_s: tuple[FloatArray, FloatArray],
    dt_s: float,
    *,
    release_s: float = 0.0,
    wrt: Sequence[str] = (),
    sensitivities_out: tuple[FloatArray, FloatArray] | None = None,
    inputs: FloatArray | None = None,
    slopes: bool = True,
) -> tuple[tuple[FloatArray, FloatArray], tuple[FloatArray, FloatArray], tuple[FloatArray, FloatArray]]:
    """One run's omega1, omega2 at given instants, with exact sensitivities: what a least-squares
    fit needs, without storing the trajectory.

    The member rests at (phi0, omega0 = 0) until ``release_s`` (or moves from omega0 if it is 0),
    then RK4 steps of ``dt_s`` (the kernel's arithmetic: rates equal ``integrate``'s states at the
    steps); between steps the rate is the cubic Hermite of omega and its closed-form derivative.

    Args:
      coef: (NCOEF, 1) from ``coefficients``.
      phi0_rad, omega0_rad_s: (2,) the start state.
      at_s: each node's instants since the start, ascending, s: (m1,), (m2,).
      dt_s: the step, s.
      release_s: the instant the member starts to move, s.
      wrt: names from ``SENSITIVITY_NAMES``: the unknowns to differentiate by.
      sensitivities_out: two (m_n, P) float64 arrays (views allowed) to write the sensitivities
        into, e.g. the columns of a Jacobian (no copy); returned as the sensitivities.
      inputs: (H, NINPUT) the inputs held over the steps from the release on (``drives.held_inputs``
        with the drive's time 0 at ``release_s``; H at least the steps the instants need), or
        None (undriven).
      slopes: compute d rate / d release_s (False: empty slopes, no (m_n,) arrays for them).

    Returns:
      (rates, sensitivities, slopes): each a pair over the nodes: rate (m_n,) rad/s (0 before the
      release); d rate / d wrt (m_n, P); d rate / d release_s (m_n,) (or (0,): ``slopes`` False).
    """
    k, y0, nstep, held, codes, at = _rates_setup(coef, phi0_rad, omega0_rad_s, at_s, dt_s, release_s, wrt, inputs)
    rate = tuple(np.zeros(len(a)) for a in at)
    if sensitivities_out is None:
        sens = tuple(np.zeros((len(a), len(codes))) for a in at)
    else:
        sens = sensitivities_out
        if any(o.shape != (len(a), len(codes)) or o.dtype != np.float64 for o, a in zip(sens, at, strict=True)):
            raise ParameterError(f"rates_at: sensitivities_out must be float64 arrays of shape (m_n, {len(codes)})")
        for o in sens:
            o[...] = 0.0
    slope = tuple(np.zeros(len(a) if slopes else 0) for a in at)
    none = _NOTHING
    _rates_kernel(k, y0, float(release_s), float(dt_s), nstep, held, codes, at[0], at[1], rate[0], rate[1], sens[0],
                  sens[1], slope[0], slope[1], none, none, none, False, False, _NOTHING_2D, none, none)  # fmt: skip
    return (rate[0], rate[1]), (sens[0], sens[1]), (slope[0], slope[1])


def solve(
    params: RigParams = DEFAULT_PARAMS,
    phi0_rad: Sequence[float] = (math.pi / 6, 0.0),
    omega0_rad_s: Sequence[float] = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    drive: Drive | None = None,
) -> Trajectory:
    """Solve one initial condition; arguments and Trajectory as ``reference.solve``."""
    return solve_batch(params, phi0_rad, omega0_rad_s, duration_s, dt_s, drive=drive).member(0)


def solve_batch(
    params: RigParams | Sequence[RigParams] = DEFAULT_PARAMS,
    phi0_rad: ArrayLike = (math.pi / 6, 0.0),
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    drive: Drive | Sequence[Drive | None] | None = None,
    nthread: int | None = None,
) -> Trajectory:
    """Solve a batch; arguments and Trajectory as ``reference.solve_batch`` (engine "fast"),
    drives included (the drives of one batch may drive different targets).

    Raises:
      ParameterError: bad arguments (the reference's messages).
      SimulationDiverged: a run became non-finite, or its energy grew without any input.
    """
    nstep = check_step(duration_s, dt_s)
    plist = check_params(params)
    phi0, omega0 = check_initial(phi0_rad, omega0_rad_s, len(plist) if len(plist) > 1 else None)
    plist = broadcast_params(plist, len(phi0))
    drives, targets = check_drives(drive, len(phi0), same_targets=False)
    held = stack_inputs(drives, nstep, dt_s) if targets else None  # (nbatch, nstep, NINPUT)
    k = coefficients(plist)
    states = integrate(k, phi0, omega0, nstep, dt_s, inputs=held, nthread=nthread)
    if not np.all(np.isfinite(states)):
        raise SimulationDiverged(f"fast planar solver diverged (non-finite values); reduce dt_s (now {dt_s} s)")
    return _trajectory(plist, k, states, dt_s, held, drives if targets else None)


def solve_blocks(
    params: RigParams = DEFAULT_PARAMS,
    phi0_rad: ArrayLike = (math.pi / 6, 0.0),
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    block_steps: int = 3000,
) -> Iterator[tuple[int, Trajectory]]:
    """``solve`` (undriven) in blocks of ``block_steps`` steps, each continued from the previous
    block's last state (phi, omega and the dissipated energy: the kernel's whole state, so the
    rows equal one run's bit for bit); memory independent of the duration. Yields (first row,
    block) as ``reference.solve_blocks``; consecutive blocks share their boundary row."""
    nstep = check_step(duration_s, dt_s)
    if isinstance(block_steps, bool) or not isinstance(block_steps, int) or block_steps < 1:
        raise ParameterError(f"block_steps must be a whole number >= 1, got {block_steps!r}")
    plist = check_params(params)[:1]
    phi0, omega0 = check_initial(phi0_rad, omega0_rad_s)
    k = coefficients(plist)
    y0 = _initial_state(phi0, omega0)
    for first in range(0, nstep, block_steps):
        steps = min(block_steps, nstep - first)
        states = _run(k, y0, _UNDRIVEN, first, steps, float(dt_s), 1, 1)
        if not np.all(np.isfinite(states)):
            raise SimulationDiverged(f"fast planar solver diverged (non-finite values); reduce dt_s (now {dt_s} s)")
        y0 = np.ascontiguousarray(states[-1])
        block = _trajectory(plist, k, states, dt_s, None, None)
        yield first, dataclasses.replace(block, t_s=np.arange(first, first + len(states)) * dt_s).member(0)


def _trajectory(
    plist: list[RigParams],
    k: FloatArray,
    states: FloatArray,
    dt_s: float,
    held: FloatArray | None,
    drives: list[Drive | None] | None,
) -> Trajectory:
    """The Trajectory of integrated states (n, 5, nbatch) and held inputs (nbatch, nstep, NINPUT),
    every derived array in closed form; instants use the input of the step that starts there."""
    phi1, phi2, omega1, omega2, dissipated = (states[:, i, :] for i in range(5))  # each (n, nbatch)
    nbatch, n = len(plist), states.shape[0]
    inputs = np.zeros((nbatch, n, NINPUT)) if held is None else inputs_at_samples(held)  # (nbatch, n, NINPUT)
    u = None if held is None else inputs.transpose(2, 1, 0)  # (NINPUT, n, nbatch)
    alpha1, alpha2 = accelerations(phi1, phi2, omega1, omega2, k, u)
    moment1, moment2 = spring_moments(phi1, phi2, k)
    lengths = spring_lengths(phi1, phi2, plist)  # (4, n, nbatch)
    stiffness = np.array([[p.c1_n_m, p.c1_n_m, p.c2_n_m, p.c2_n_m] for p in plist]).T  # (4, nbatch)
    kinetic = kinetic_energy(omega1, omega2, k)
    potential = potential_energy(phi1, phi2, k)
    if drives is None:  # a driven rig may gain energy from its input
        check_energy_bounded((kinetic + potential).T, k[_G1], dt_s)
    support = np.zeros((nbatch, n, 2))
    if held is not None and np.any(held[..., 2:]):
        support, _ = support_motion(held[..., 2:], dt_s, support_initial_velocity(held[..., 2:], dt_s))

    def per_run(*arrays: FloatArray) -> FloatArray:
        """(n, nbatch) arrays stacked on a last axis, batch first: (nbatch, n, len(arrays))."""
        return np.stack(arrays, axis=-1).transpose(1, 0, 2)

    phi = per_run(phi1, phi2)
    omega = per_run(omega1, omega2)
    alpha = per_run(alpha1, alpha2)
    radius = np.array([[p.om1_m, p.om2_m] for p in plist])[:, None, :]
    g = np.array([p.g_m_s2 for p in plist])[:, None, None]
    base_accel = (None, None) if held is None else (inputs[..., 2:3], inputs[..., 3:4])  # a_h, a_v
    accel, gyro, quat, angacc = planar_imu_readings(
        phi, omega, alpha, radius, g, support_h_m_s2=base_accel[0], support_v_m_s2=base_accel[1]
    )
    return Trajectory(
        t_s=np.arange(states.shape[0]) * dt_s,
        phi_rad=phi,
        omega_rad_s=omega,
        alpha_rad_s2=alpha,
        imu_accel_m_s2=accel,
        imu_gyro_rad_s=gyro,
        imu_quat_wxyz=quat,
        imu_angacc_rad_s2=angacc,
        tilt_rad=np.zeros_like(phi),
        spring_length_m=per_run(*lengths),
        spring_force_n=per_run(*(stiffness[:, None, :] * lengths)),
        spring_moment_n_m=per_run(moment1, moment2),
        kinetic_j=kinetic.T,
        potential_j=potential.T,
        dissipated_j=dissipated.T,
        engine="fast",
        dt_s=dt_s,
        params=tuple(plist),
        drive_input=inputs,
        support_m=support,
        drive=tuple(drives) if drives is not None else None,
    )
