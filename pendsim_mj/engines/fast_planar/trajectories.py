"""The fast engine's Trajectory: ``solve``, ``solve_batch`` and ``solve_blocks``, with the
arguments of ``reference``'s and every derived array in closed form (``closed_form``)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Sequence

import numpy as np
from numpy.typing import ArrayLike

from pendsim_mj.engines.fast_planar.batch import _UNDRIVEN, _initial_state, _run, integrate
from pendsim_mj.engines.fast_planar.closed_form import (
    _G1,
    NINPUT,
    FloatArray,
    accelerations,
    coefficients,
    kinetic_energy,
    potential_energy,
    spring_lengths,
    spring_moments,
)
from pendsim_mj.engines.reference import diverged_advice
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
from pendsim_mj.rig.drives import Drive, Sampling, drive_stage_inputs, stage_inputs_at_samples, stage_support_motion
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams


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
    """Solve one initial condition; arguments and Trajectory as ``reference.solve``."""
    return solve_batch(params, phi0_rad, omega0_rad_s, duration_s, dt_s, drive=drive, sampling=sampling).member(0)


def solve_batch(
    params: RigParams | Sequence[RigParams] = DEFAULT_PARAMS,
    phi0_rad: ArrayLike = (math.pi / 6, 0.0),
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    drive: Drive | Sequence[Drive | None] | None = None,
    nthread: int | None = None,
    sampling: Sampling = Sampling.STAGES,
) -> Trajectory:
    """Solve a batch; arguments and Trajectory as ``reference.solve_batch`` (engine "fast"),
    drives included (the drives of one batch may drive different targets; ``sampling`` as there:
    each RK4 stage sees the drive at its own time, fourth order, or HELD as MuJoCo).

    Raises:
      ParameterError: bad arguments (the reference's messages).
      SimulationDiverged: a run became non-finite, or its energy grew without any input.
    """
    nstep = check_step(duration_s, dt_s)
    plist = check_params(params)
    phi0, omega0 = check_initial(phi0_rad, omega0_rad_s, len(plist) if len(plist) > 1 else None)
    plist = broadcast_params(plist, len(phi0))
    drives, targets = check_drives(drive, len(phi0), same_targets=False)
    stages = drive_stage_inputs(drives, nstep, dt_s, sampling) if targets else None  # (nbatch, nstep, NSTAGE, NINPUT)
    k = coefficients(plist)
    states = integrate(k, phi0, omega0, nstep, dt_s, inputs=stages, nthread=nthread)
    _check_finite(states, plist, dt_s)
    return _trajectory(plist, k, states, dt_s, stages, drives if targets else None, sampling)


def _check_finite(states: np.ndarray, plist: Sequence[RigParams], dt_s: float) -> None:
    """Raise SimulationDiverged where a run's states (n, 5, nbatch) are not all finite, with what
    to change for the first such run (``reference.diverged_advice``)."""
    if (bad := first_nonfinite_run(states, run_axis=2)) is not None:
        advice = diverged_advice(plist[bad], dt_s)
        raise SimulationDiverged(f"fast planar solver diverged (non-finite values); {advice}")


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
        _check_finite(states, plist, dt_s)
        y0 = np.ascontiguousarray(states[-1])
        block = _trajectory(plist, k, states, dt_s, None, None)
        yield first, dataclasses.replace(block, t_s=np.arange(first, first + len(states)) * dt_s).member(0)


def _trajectory(
    plist: list[RigParams],
    k: FloatArray,
    states: FloatArray,
    dt_s: float,
    stages: FloatArray | None,
    drives: list[Drive | None] | None,
    sampling: Sampling = Sampling.STAGES,
) -> Trajectory:
    """The Trajectory of integrated states (n, 5, nbatch) and stage inputs
    (nbatch, nstep, NSTAGE, NINPUT), every derived array in closed form; instants use the input at
    their own time (``drives.stage_inputs_at_samples``)."""
    phi1, phi2, omega1, omega2, dissipated = (states[:, i, :] for i in range(5))  # each (n, nbatch)
    nbatch, n = len(plist), states.shape[0]
    inputs = np.zeros((nbatch, n, NINPUT)) if stages is None else stage_inputs_at_samples(stages)  # (nbatch, n, NINPUT)
    u = None if stages is None else inputs.transpose(2, 1, 0)  # (NINPUT, n, nbatch)
    alpha1, alpha2 = accelerations(phi1, phi2, omega1, omega2, k, u)
    moment1, moment2 = spring_moments(phi1, phi2, k)
    lengths = spring_lengths(phi1, phi2, plist)  # (4, n, nbatch)
    stiffness = np.array([[p.c1_n_m, p.c1_n_m, p.c2_n_m, p.c2_n_m] for p in plist]).T  # (4, nbatch)
    kinetic = kinetic_energy(omega1, omega2, k)
    potential = potential_energy(phi1, phi2, k)
    if drives is None:  # a driven rig may gain energy from its input
        check_energy_bounded((kinetic + potential).T, k[_G1], dt_s, lambda i: diverged_advice(plist[i], dt_s))
    support = np.zeros((nbatch, n, 2))
    if stages is not None and np.any(stages[..., 2:]):
        support, _ = stage_support_motion(stages[..., 2:], dt_s)

    def per_run(*arrays: FloatArray) -> FloatArray:
        """(n, nbatch) arrays stacked on a last axis, batch first: (nbatch, n, len(arrays))."""
        return np.stack(arrays, axis=-1).transpose(1, 0, 2)

    phi = per_run(phi1, phi2)
    omega = per_run(omega1, omega2)
    alpha = per_run(alpha1, alpha2)
    radius = np.array([[p.om1_m, p.om2_m] for p in plist])[:, None, :]
    g = np.array([p.g_m_s2 for p in plist])[:, None, None]
    base_accel = (None, None) if stages is None else (inputs[..., 2:3], inputs[..., 3:4])  # a_h, a_v
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
        drive_sampling=sampling.value,
    )
