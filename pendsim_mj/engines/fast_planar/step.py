"""What a node's accelerometer reads in each of a batch of rigs, each with its own constants and
held inputs, compiled (``accel_readings``): what a filter's sigma points
(``pendsim_mj.twin.estimator``) need a few hundred times a second, where numpy's per-call overhead
on a few dozen members is most of the cost. Their held-input RK4 step is
``pendsim_mj.twin.unscented.advanced`` (``kernel._rk4``'s, the reference's order of operations; it
equals ``control.plant.FastPlant``'s numpy step to rounding, tested).
"""

from __future__ import annotations

import math

import numba

from pendsim_mj.engines.fast_planar.closed_form import FloatArray
from pendsim_mj.engines.fast_planar.kernel import _accel

JERK_STEP_S = 1e-6  # the force law's rate along the motion, by a forward difference over this, s


@numba.njit(cache=True)
def accel_readings(
    k: FloatArray,
    x: FloatArray,
    u: FloatArray,
    node: int,
    radius_m: float,
    g_m_s2: float,
    delay_s: FloatArray,
    turn_rad: FloatArray,
    out: FloatArray,
) -> None:
    """What node ``node``'s accelerometer (at ``radius_m`` from the hinge) reads in each member of a
    batch, into out (2, n): the specific force along the swing's tangent and toward the pivot,
    r alpha + g sin phi and r omega^2 + g cos phi (m/s^2; alpha from the force law with member i's
    constants k[:, i] and inputs u[:, i] = (tau1, tau2, a_h, a_v)), read ``delay_s[i]`` earlier (first
    order: z - d dz/dt) and turned by ``turn_rad[i]`` about the hinge (the accelerometer's axes
    turned from the frame it is read in)."""
    n = x.shape[1]
    for i in range(n):
        c = (k[0, i], k[1, i], k[2, i], k[3, i], k[4, i], k[5, i], k[6, i], k[7, i], k[8, i], k[9, i], k[10, i],
             k[11, i], k[12, i], k[13, i])  # fmt: skip
        ui = (u[0, i], u[1, i], u[2, i], u[3, i])
        p1, p2, w1, w2 = x[0, i], x[1, i], x[2, i], x[3, i]
        a1, a2 = _accel(p1, p2, w1, w2, c, ui)
        phi, w, a = (p1, w1, a1) if node == 0 else (p2, w2, a2)
        sin, cos = math.sin(phi), math.cos(phi)
        tangential = radius_m * a + g_m_s2 * sin
        normal = radius_m * w * w + g_m_s2 * cos
        d = delay_s[i]
        if d != 0.0:
            e = JERK_STEP_S
            b1, b2 = _accel(p1 + e * w1, p2 + e * w2, w1 + e * a1, w2 + e * a2, c, ui)
            jerk = ((b1 if node == 0 else b2) - a) / e
            tangential -= d * (radius_m * jerk + g_m_s2 * cos * w)
            normal -= d * (2.0 * radius_m * w * a - g_m_s2 * sin * w)
        t = turn_rad[i]
        if t != 0.0:
            ct, st = math.cos(t), math.sin(t)
            tangential, normal = ct * tangential + st * normal, ct * normal - st * tangential
        out[0, i] = tangential
        out[1, i] = normal
