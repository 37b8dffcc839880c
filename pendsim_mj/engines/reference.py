"""Independent planar reference: the paper's Newtonian equations and classical RK4, in numpy.

This module must not import MuJoCo: it exists to check the MuJoCo model. It follows the paper's
chain (spec RIG.md sections 2-4), in the paper frame (x down, y horizontal, z pivot axis):

    point coordinates -> spring lengths -> direction cosines -> force components -> moments

    J1 phi1'' + b1 phi1' = -m1 g OC1 sin phi1 + M1(phi1, phi2)
    J2 phi2'' + b2 phi2' = -m2 g OC2 sin phi2 + M2(phi1, phi2)

M1 is the moment about O (x Fy - y Fx) of the spring forces on points 2 and 3; M2 that of the
forces on point 1 (springs 1-2, 1-3) and point 5 (springs 5-6, 5-7). Springs have zero free
length, so a spring of length L pulls each end toward the other with c L.

Dry (Coulomb) friction F_n at each hinge adds -F_n s(phi_n') to the right-hand side, with
s(w) = w / sqrt(w^2 + w_s^2) the sign smoothed below w_s = ``params.FRICTION_SMOOTHING_RAD_S``
(MuJoCo's joint frictionloss, which this checks, is a soft constraint too).

The state integrated is (phi1, phi2, omega1, omega2, D) with D' = (b1 omega1 + F1 s(omega1)) omega1
+ (b2 omega2 + F2 s(omega2)) omega2, the energy dissipated so far, integrated by the same RK4
step. Everything is vectorised over a leading batch axis.

Drives (``pendsim_mj.rig.drives``) enter each RK4 stage at the stage's own time (t, t + h/2,
t + h: ``drives.Sampling.STAGES``, the default): the drive is part of the ODE and a driven run
converges at fourth order, as a free one. ``sampling=Sampling.HELD`` holds the step's midpoint
value over the step instead, exactly as MuJoCo holds ``ctrl`` (second order; the check of MuJoCo):

- a motor torque tau_n at hinge n adds + tau_n to the right-hand side of pendulum n;
- the support (pivot axis and fixed points 6, 7) accelerating by a_h horizontally (paper +y)
  and a_v vertically (upward, paper -x). Derivation: in the support's frame, which translates
  without rotating, every mass element dm feels the inertial force -dm a_s with
  a_s = (-a_v, a_h) in paper (x, y) components. Summed over a pendulum it acts at the centre of
  mass r_C = OC_n (cos phi_n, sin phi_n); its moment about O (x F_y - y F_x) is
  -m_n OC_n (a_h cos phi_n - (-a_v) sin phi_n) = -m_n OC_n (a_h cos phi_n + a_v sin phi_n).
  Added to gravity's -m_n g OC_n sin phi_n:

      J_n phi_n'' + b_n phi_n' = -m_n OC_n ((g + a_v) sin phi_n + a_h cos phi_n) + M_n + tau_n

  (an upward acceleration adds to gravity: the parametric excitation; a support accelerating
  toward +y leaves the pendulum behind, toward negative phi). The springs' moments do not change:
  both their ends are on the pendulums or on the support, so their lengths are relative.
  The accelerometer reads the specific force a - g of the inertial motion, so the support's
  acceleration appears in it: tangential r phi'' + (g + a_v) sin phi + a_h cos phi, toward the
  pivot r phi'^2 + (g + a_v) cos phi - a_h sin phi.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from pendsim_mj.engines.stability import step_advice
from pendsim_mj.engines.trajectory import Trajectory, planar_imu_readings
from pendsim_mj.errors import ParameterError, SimulationDiverged
from pendsim_mj.rig.checks import (
    broadcast_params,
    check_drives,
    check_energy_bounded,
    check_initial,
    check_params,
    check_step,
    first_nonfinite_run,
)
from pendsim_mj.rig.drives import (
    NSTAGE,
    Drive,
    Sampling,
    drive_stage_inputs,
    stage_inputs_at_samples,
    stage_support_motion,
    stages_of_held,
)
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams, friction_direction


class SpringState(NamedTuple):
    """Springs 1-2, 1-3, 5-6, 5-7 at one instant; each field (4, ...) over the batch."""

    length_m: np.ndarray
    force_n: np.ndarray


class _Coefficients(NamedTuple):
    """Parameter arrays broadcast over the batch: each (nbatch,)."""

    j1: np.ndarray
    j2: np.ndarray
    b1: np.ndarray
    b2: np.ndarray
    f1: np.ndarray  # dry friction F1, N m
    f2: np.ndarray
    gravity1: np.ndarray  # m1 g OC1, N m
    gravity2: np.ndarray  # m2 g OC2, N m
    moc1: np.ndarray  # m1 OC1, kg m (the inertial moment of a support acceleration)
    moc2: np.ndarray  # m2 OC2, kg m
    c1: np.ndarray
    c2: np.ndarray
    l01: np.ndarray
    l04: np.ndarray
    l24: np.ndarray
    l34: np.ndarray
    l05: np.ndarray
    x6: np.ndarray
    y6: np.ndarray
    x7: np.ndarray
    y7: np.ndarray


def _coefficients(params: Sequence[RigParams]) -> _Coefficients:
    def col(fn: Callable[[RigParams], float]) -> np.ndarray:
        return np.array([fn(p) for p in params], dtype=float)

    return _Coefficients(
        j1=col(lambda p: p.j1_kg_m2),
        j2=col(lambda p: p.j2_kg_m2),
        b1=col(lambda p: p.b1_n_m_s),
        b2=col(lambda p: p.b2_n_m_s),
        f1=col(lambda p: p.friction1_n_m),
        f2=col(lambda p: p.friction2_n_m),
        gravity1=col(lambda p: p.m1_kg * p.g_m_s2 * p.oc1_m),
        gravity2=col(lambda p: p.m2_kg * p.g_m_s2 * p.oc2_m),
        moc1=col(lambda p: p.m1_kg * p.oc1_m),
        moc2=col(lambda p: p.m2_kg * p.oc2_m),
        c1=col(lambda p: p.c1_n_m),
        c2=col(lambda p: p.c2_n_m),
        l01=col(lambda p: p.l01_m),
        l04=col(lambda p: p.l04_m),
        l24=col(lambda p: p.l24_m),
        l34=col(lambda p: p.l34_m),
        l05=col(lambda p: p.l05_m),
        x6=col(lambda p: p.l08_m),
        y6=col(lambda p: p.l68_m),
        x7=col(lambda p: p.l08_m),
        y7=col(lambda p: -p.l78_m),
    )


def _spring(
    xi: np.ndarray, yi: np.ndarray, xj: np.ndarray, yj: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Spring from point i to point j: length, direction cosines and the force on i (toward j)."""
    dx = xj - xi
    dy = yj - yi
    length = np.sqrt(dx * dx + dy * dy)
    cos_x = dx / length  # direction cosines of the spring axis, i -> j
    cos_y = dy / length
    force = c * length  # zero free length: tension proportional to the whole length
    return length, force, force * cos_x, force * cos_y


def spring_moments(phi1: np.ndarray, phi2: np.ndarray, k: _Coefficients) -> tuple[np.ndarray, np.ndarray, SpringState]:
    """Moments M1, M2 of the spring forces about O (N m) and the spring lengths and tensions."""
    s1, c1_ = np.sin(phi1), np.cos(phi1)
    s2, c2_ = np.sin(phi2), np.cos(phi2)
    # Point coordinates (spec section 2).
    x1, y1 = k.l01 * c2_, k.l01 * s2
    x2, y2 = k.l04 * c1_ - k.l24 * s1, k.l04 * s1 + k.l24 * c1_
    x3, y3 = k.l04 * c1_ + k.l34 * s1, k.l04 * s1 - k.l34 * c1_
    x5, y5 = k.l05 * c2_, k.l05 * s2
    # Springs: lengths, direction cosines, force components on the first-named end.
    len12, f12, f12x, f12y = _spring(x2, y2, x1, y1, k.c1)  # on point 2, toward 1
    len13, f13, f13x, f13y = _spring(x3, y3, x1, y1, k.c1)  # on point 3, toward 1
    len56, f56, f56x, f56y = _spring(x5, y5, k.x6, k.y6, k.c2)  # on point 5, toward 6
    len57, f57, f57x, f57y = _spring(x5, y5, k.x7, k.y7, k.c2)  # on point 5, toward 7
    # Moments about O, z component of r x F = x Fy - y Fx.
    moment1 = (x2 * f12y - y2 * f12x) + (x3 * f13y - y3 * f13x)
    moment2 = (
        (x1 * -f12y - y1 * -f12x)  # point 1 is pulled toward 2: the reaction of the force on 2
        + (x1 * -f13y - y1 * -f13x)
        + (x5 * f56y - y5 * f56x)
        + (x5 * f57y - y5 * f57x)
    )
    springs = SpringState(length_m=np.stack([len12, len13, len56, len57]), force_n=np.stack([f12, f13, f56, f57]))
    return moment1, moment2, springs


def derivative(y: np.ndarray, k: _Coefficients, u: np.ndarray | None = None) -> np.ndarray:
    """d/dt of the state (5, ...) = (phi1, phi2, omega1, omega2, dissipated), with the
    inputs u (4, ...) = (tau1, tau2 in N m, a_h, a_v in m/s^2; module docstring) or none."""
    phi1, phi2, omega1, omega2 = y[0], y[1], y[2], y[3]
    moment1, moment2, _ = spring_moments(phi1, phi2, k)
    damping1 = k.b1 * omega1 + k.f1 * friction_direction(omega1)
    damping2 = k.b2 * omega2 + k.f2 * friction_direction(omega2)
    s1, s2 = np.sin(phi1), np.sin(phi2)
    torque1 = -k.gravity1 * s1 + moment1 - damping1
    torque2 = -k.gravity2 * s2 + moment2 - damping2
    if u is not None:
        a_h, a_v = u[2], u[3]
        torque1 = torque1 - k.moc1 * (a_v * s1 + a_h * np.cos(phi1)) + u[0]
        torque2 = torque2 - k.moc2 * (a_v * s2 + a_h * np.cos(phi2)) + u[1]
    return np.stack([omega1, omega2, torque1 / k.j1, torque2 / k.j2, damping1 * omega1 + damping2 * omega2])


def integrate(
    params: Sequence[RigParams],
    phi0_rad: np.ndarray,
    omega0_rad_s: np.ndarray,
    nstep: int,
    dt_s: float,
    inputs: np.ndarray | None = None,
) -> np.ndarray:
    """Classical RK4 at a fixed step over a batch.

    Args:
      params: nbatch RigParams.
      phi0_rad, omega0_rad_s: (nbatch, 2) initial conditions.
      nstep: number of steps.
      dt_s: step, s.
      inputs: (nbatch, nstep, NSTAGE, 4) the inputs at each step's start, midpoint and end
        (``drives.stage_inputs``: k1 sees the start's, k2 and k3 the midpoint's, k4 the end's), or
        (nbatch, nstep, 4) inputs held over each step (``drives.held_inputs``, MuJoCo's rule), or
        None.

    Returns:
      (nstep + 1, 5, nbatch) states (phi1, phi2, omega1, omega2, dissipated_j) at t = k dt.

    Raises:
      SimulationDiverged: a state became non-finite.
    """
    k = _coefficients(params)
    nbatch = len(params)
    out = np.empty((nstep + 1, 5, nbatch))
    y = np.zeros((5, nbatch))
    y[0:2] = phi0_rad.T
    y[2:4] = omega0_rad_s.T
    out[0] = y
    h = dt_s
    stages = None
    if inputs is not None:
        u_in = np.asarray(inputs, dtype=float)
        u_in = stages_of_held(u_in) if u_in.shape == (nbatch, nstep, 4) else u_in
        if u_in.shape != (nbatch, nstep, NSTAGE, 4):
            raise ParameterError(f"inputs must have shape ({nbatch}, {nstep}, {NSTAGE}, 4) or ({nbatch}, {nstep}, 4)")
        stages = np.ascontiguousarray(np.transpose(u_in, (1, 2, 3, 0)))  # (nstep, NSTAGE, 4, nbatch)
    with np.errstate(over="ignore", invalid="ignore"):  # a run that diverges is said once, below
        for step in range(1, nstep + 1):  # the reference's own loop: numpy over the batch each step
            u0, um, u1 = (None, None, None) if stages is None else stages[step - 1]  # start, midpoint, end
            k1 = derivative(y, k, u0)
            k2 = derivative(y + (0.5 * h) * k1, k, um)
            k3 = derivative(y + (0.5 * h) * k2, k, um)
            k4 = derivative(y + h * k3, k, u1)
            y = y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            out[step] = y
            if step % 256 == 0 and not np.all(np.isfinite(y)):
                break
    if (bad := first_nonfinite_run(y, run_axis=1)) is not None:
        raise SimulationDiverged(f"reference solver diverged at t = {step * h:g} s; {diverged_advice(params[bad], h)}")
    if (bad := first_nonfinite_run(out, run_axis=2)) is not None:
        raise SimulationDiverged(f"reference solver produced non-finite values; {diverged_advice(params[bad], h)}")
    return out


def solve(
    params: RigParams = DEFAULT_PARAMS,
    phi0_rad: Sequence[float] = (math.pi / 6, 0.0),
    omega0_rad_s: Sequence[float] = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    drive: Drive | None = None,
    sampling: Sampling = Sampling.STAGES,
) -> Trajectory:
    """Solve one initial condition; same arguments and Trajectory as ``simulation.simulate``
    (``sampling``: as ``solve_batch``)."""
    return solve_batch(params, phi0_rad, omega0_rad_s, duration_s, dt_s, drive=drive, sampling=sampling).member(0)


def solve_batch(
    params: RigParams | Sequence[RigParams] = DEFAULT_PARAMS,
    phi0_rad: ArrayLike = (math.pi / 6, 0.0),
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    drive: Drive | Sequence[Drive | None] | None = None,
    sampling: Sampling = Sampling.STAGES,
) -> Trajectory:
    """Solve a batch; arguments and result as ``simulation.simulate_batch`` (the drives of one
    batch may drive different targets here: an undriven channel is a zero input).

    ``sampling``: how the RK4 stages see the drive (``drives.Sampling``): STAGES (default) each
    stage at its own time, fourth order; HELD the step's midpoint value over the whole step, as
    MuJoCo (second order; equals ``simulate_batch`` to 1e-9 rad)."""
    nstep = check_step(duration_s, dt_s)
    plist = check_params(params)
    phi0, omega0 = check_initial(phi0_rad, omega0_rad_s, len(plist) if len(plist) > 1 else None)
    plist = broadcast_params(plist, len(phi0))
    drives, targets = check_drives(drive, len(phi0), same_targets=False)
    stages = drive_stage_inputs(drives, nstep, dt_s, sampling) if targets else None  # (nbatch, nstep, NSTAGE, 4)
    states = integrate(plist, phi0, omega0, nstep, dt_s, stages)  # (n, 5, nbatch)
    return _trajectory(plist, states, dt_s, stages, drives if targets else None, sampling=sampling)


def solve_blocks(
    params: RigParams = DEFAULT_PARAMS,
    phi0_rad: ArrayLike = (math.pi / 6, 0.0),
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    block_steps: int = 3000,
) -> Iterator[tuple[int, Trajectory]]:
    """``solve`` in blocks of ``block_steps`` steps, each continued from the previous block's
    last state; as ``simulation.simulate_blocks`` (the RK4 step depends on phi and omega only,
    so the rows are those of one run)."""
    nstep = check_step(duration_s, dt_s)
    if block_steps < 1:
        raise ParameterError(f"block_steps must be >= 1, got {block_steps}")
    plist = check_params(params)[:1]
    phi0, omega0 = check_initial(phi0_rad, omega0_rad_s)
    dissipated0 = 0.0
    for first in range(0, nstep, block_steps):
        steps = min(block_steps, nstep - first)
        states = integrate(plist, phi0, omega0, steps, dt_s)
        states[:, 4] += dissipated0
        block = _trajectory(plist, states, dt_s, first_row=first)
        phi0, omega0 = states[-1, 0:2].T.copy(), states[-1, 2:4].T.copy()
        dissipated0 = float(states[-1, 4, 0])
        yield first, block.member(0)


def rest_jacobian(params: RigParams, eps: float = 1e-7) -> np.ndarray:
    """(4, 4) d(phi1, phi2, omega1, omega2)/dt of these equations linearised at rest (central
    differences of ``derivative``; dry friction's smoothed sign counts as the damping it is near
    zero rate): what ``stability.step_advice`` reads."""
    k = _coefficients([params])
    jacobian = np.zeros((4, 4))
    for j in range(4):
        plus, minus = np.zeros((5, 1)), np.zeros((5, 1))
        plus[j], minus[j] = eps, -eps
        jacobian[:, j] = (derivative(plus, k)[:4, 0] - derivative(minus, k)[:4, 0]) / (2 * eps)
    return jacobian


def diverged_advice(params: RigParams, dt_s: float) -> str:
    """What a run of this rig at ``dt_s`` (s) that diverged is told (``stability.step_advice`` on
    ``rest_jacobian``); the MuJoCo and compiled engines say the same (the same planar equations)."""
    return step_advice(params, dt_s, rest_jacobian(params))


def _trajectory(
    plist: list[RigParams],
    states: np.ndarray,
    dt_s: float,
    stages: np.ndarray | None = None,
    drives: list[Drive | None] | None = None,
    *,
    first_row: int = 0,
    sampling: Sampling = Sampling.STAGES,
) -> Trajectory:
    """Build the Trajectory from integrated states (n, 5, nbatch) and stage inputs
    (nbatch, nstep, NSTAGE, 4); the rows are the run's from ``first_row`` on."""
    k = _coefficients(plist)
    y = states.transpose(1, 0, 2)  # (5, n, nbatch): every quantity below is (n, nbatch)
    moment1, moment2, springs = spring_moments(y[0], y[1], k)
    nbatch, n = len(plist), states.shape[0]
    inputs = np.zeros((nbatch, n, 4)) if stages is None else stage_inputs_at_samples(stages)  # (nbatch, n, 4)
    u = None if stages is None else inputs.transpose(2, 1, 0)  # (4, n, nbatch)
    deriv = derivative(y, k, u)
    _, _, rest = spring_moments(np.zeros(len(plist)), np.zeros(len(plist)), k)

    def per_run(*arrays: np.ndarray) -> np.ndarray:
        """Stack (n, nbatch) arrays on a last axis and put the batch first: (nbatch, n, k)."""
        return np.stack(arrays, axis=-1).transpose(1, 0, 2)

    phi = per_run(y[0], y[1])
    omega = per_run(y[2], y[3])
    alpha = per_run(deriv[2], deriv[3])
    radius = np.array([[p.om1_m, p.om2_m] for p in plist])[:, None, :]  # (nbatch, 1, 2)
    g = np.array([p.g_m_s2 for p in plist])[:, None, None]
    base_accel = (None, None) if stages is None else (inputs[..., 2:3], inputs[..., 3:4])  # a_h, a_v (nbatch, n, 1)
    accel, gyro, quat, angacc = planar_imu_readings(
        phi, omega, alpha, radius, g, support_h_m_s2=base_accel[0], support_v_m_s2=base_accel[1]
    )

    stiffness = np.stack([k.c1, k.c1, k.c2, k.c2])  # (4, nbatch)
    spring_energy = 0.5 * np.sum(stiffness[:, None, :] * springs.length_m**2, axis=0)  # (n, nbatch)
    rest_spring_energy = 0.5 * np.sum(stiffness * rest.length_m**2, axis=0)  # (nbatch,)
    potential = k.gravity1 * (1 - np.cos(y[0])) + k.gravity2 * (1 - np.cos(y[1])) + spring_energy - rest_spring_energy
    kinetic = 0.5 * (k.j1 * y[2] ** 2 + k.j2 * y[3] ** 2)
    if drives is None:  # a driven rig may gain energy from its input
        check_energy_bounded((kinetic + potential).T, k.gravity1, dt_s, lambda i: diverged_advice(plist[i], dt_s))
    support = np.zeros((nbatch, n, 2))
    if stages is not None and np.any(stages[..., 2:]):
        support, _ = stage_support_motion(stages[..., 2:], dt_s)

    return Trajectory(
        t_s=np.arange(first_row, first_row + states.shape[0]) * dt_s,
        phi_rad=phi,
        omega_rad_s=omega,
        alpha_rad_s2=alpha,
        imu_accel_m_s2=accel,
        imu_gyro_rad_s=gyro,
        imu_quat_wxyz=quat,
        imu_angacc_rad_s2=angacc,
        tilt_rad=np.zeros_like(phi),
        spring_length_m=per_run(*springs.length_m),
        spring_force_n=per_run(*springs.force_n),
        spring_moment_n_m=per_run(moment1, moment2),
        kinetic_j=kinetic.T,
        potential_j=potential.T,
        dissipated_j=y[4].T,
        engine="reference",
        dt_s=dt_s,
        params=tuple(plist),
        drive_input=inputs,
        support_m=support,
        drive=tuple(drives) if drives is not None else None,
        drive_sampling=sampling.value,
    )
