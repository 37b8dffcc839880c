"""The fast planar engine's force law: its constants per parameter set (``coefficients``) and its
closed forms in numpy, which the compiled kernel (``kernel``) evaluates member by member.

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
D' = the hinges' dissipated power, exactly as in ``reference``: one RK4 step of the kernel (``kernel``)
equals the reference's to about 1e-16 rad (tests: 1e-12).

Drives (``pendsim_mj.rig.drives``) enter as in ``reference``, each RK4 stage with the drive at
the stage's own time (start, midpoint, end of the step: ``drives.Sampling.STAGES``, fourth order),
or, on request (``Sampling.HELD``), with the step's midpoint value held over the whole step as
MuJoCo holds ``ctrl`` (second order): hinge torques tau_n, and the support's
horizontal and upward accelerations a_h, a_v as the inertial moment
-m_n OC_n (a_v sin phi_n + a_h cos phi_n) on pendulum n (derivation in ``reference``):

    J_n phi_n'' = (... the right-hand side above ...) - m_n OC_n (a_v sin phi_n + a_h cos phi_n) + tau_n

"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.checks import energy_grew
from pendsim_mj.rig.params import FRICTION_SMOOTHING_RAD_S, ParamColumns, RigParams, friction_direction

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


def _check_coef(coef: FloatArray, nbatch: int) -> FloatArray:
    k = np.ascontiguousarray(coef, dtype=np.float64)
    if k.shape != (NCOEF, nbatch):
        raise ParameterError(f"coef must have shape ({NCOEF}, {nbatch}) (from coefficients()), got {k.shape}")
    return k
