"""Run the MuJoCo model of the rig at a fixed step, without a per-step Python loop.

``mujoco.rollout`` steps the model in C. After a step MuJoCo's sensor values describe the state
*before* that step, and rollout stores them beside the state *after* it; we roll out one extra
step and re-pair them, so every row of the returned Trajectory belongs to one instant.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import mujoco
import numpy as np
from mujoco import rollout

from pendsim_mj import rotations
from pendsim_mj.checks import broadcast_params, check_energy_bounded, check_initial, check_params, check_step
from pendsim_mj.errors import ParameterError, SimulationDiverged
from pendsim_mj.model import (
    BODIES,
    HINGE_AXIS_WORLD,
    HINGES,
    IMU_SITES,
    PLANAR,
    SPRING_ENDS,
    SPRINGS,
    TILTS,
    Clamp,
    Variant,
    build_model,
)
from pendsim_mj.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.trajectory import Trajectory

_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS
# Which pendulum carries each spring anchor point (None: the frame).
_POINT_OWNER = {"point_1": 1, "point_5": 1, "point_2": 0, "point_3": 0, "point_6": None, "point_7": None}
# MuJoCo resets a simulation whose state exceeds this (mjMAXVAL); we call that divergence.
_BAD_STATE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQPOS,
)


def simulate(
    params: RigParams = DEFAULT_PARAMS,
    phi0_rad: Sequence[float] = (math.pi / 6, 0.0),
    omega0_rad_s: Sequence[float] = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    clamp: Clamp = Clamp.NONE,
    variant: Variant = PLANAR,
    tilt0_rad: Sequence[float] = (0.0, 0.0),
) -> Trajectory:
    """Simulate the rig with MuJoCo (RK4, fixed step) from one initial condition.

    Args:
      params: rig parameters.
      phi0_rad: (2,) initial angles phi1, phi2, rad.
      omega0_rad_s: (2,) initial angular velocities, rad/s.
      duration_s: simulated time, s; the trajectory has duration_s/dt_s + 1 samples.
      dt_s: integration step, s.
      clamp: hold M1 or M2 at rest (its initial angle and velocity must then be 0).
      variant: PLANAR (default) or SPATIAL (tilt freedoms; see model.Variant).
      tilt0_rad: (2,) initial tilts of the spatial variant, rad.

    Returns:
      A Trajectory with arrays of shape (n, ...).

    Raises:
      ParameterError: bad parameters or initial conditions.
      SimulationDiverged: the run reached non-finite or runaway values.
    """
    return simulate_batch(
        params, phi0_rad, omega0_rad_s, duration_s, dt_s, nthread=1, clamp=clamp, variant=variant, tilt0_rad=tilt0_rad
    ).member(0)


def simulate_batch(
    params: RigParams | Sequence[RigParams] = DEFAULT_PARAMS,
    phi0_rad: object = (math.pi / 6, 0.0),
    omega0_rad_s: object = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    nthread: int | None = None,
    clamp: Clamp = Clamp.NONE,
    variant: Variant = PLANAR,
    tilt0_rad: object = (0.0, 0.0),
) -> Trajectory:
    """Simulate many runs at once on a thread pool (``mujoco.rollout``).

    Args:
      params: one RigParams for all runs, or a sequence of nbatch of them.
      phi0_rad: (2,) or (nbatch, 2) initial angles, rad.
      omega0_rad_s: (2,) or (nbatch, 2) initial angular velocities, rad/s.
      duration_s: simulated time, s.
      dt_s: integration step, s.
      nthread: worker threads (default: the CPU count, at most nbatch).
      clamp: hold M1 or M2 at rest in every run.
      variant: PLANAR or SPATIAL.
      tilt0_rad: (2,) or (nbatch, 2) initial tilts (spatial variant).

    Returns:
      A batch Trajectory: arrays of shape (nbatch, n, ...); ``.member(i)`` gives one run.
    """
    nstep = check_step(duration_s, dt_s)
    param_list = check_params(params)
    phi0, omega0 = check_initial(phi0_rad, omega0_rad_s, len(param_list) if len(param_list) > 1 else None)
    nbatch = len(phi0)
    param_list = broadcast_params(param_list, nbatch)
    if clamp is not Clamp.NONE:
        k = 0 if clamp is Clamp.M1 else 1
        if np.any(phi0[:, k] != 0) or np.any(omega0[:, k] != 0):
            raise ParameterError(f"clamped pendulum {clamp.value} must start at phi = omega = 0")

    # One compiled model per distinct parameter set.
    unique: dict[RigParams, mujoco.MjModel] = {}
    for p in param_list:
        if p not in unique:
            unique[p] = build_model(p, timestep_s=dt_s, clamp=clamp, variant=variant)
    models = [unique[p] for p in param_list]
    model = models[0]

    nthread = max(1, min(nthread or os.cpu_count() or 1, nbatch))
    datas = [mujoco.MjData(model) for _ in range(nthread)]
    tilt0 = np.broadcast_to(np.asarray(tilt0_rad, dtype=float), (nbatch, 2))
    if np.any(tilt0 != 0) and not variant.tilt:
        raise ParameterError("tilt0_rad needs the spatial variant (tilt freedoms)")
    initial = _initial_states(model, phi0, omega0, tilt0)
    # nstep + 1 steps: sensors of row k belong to the state before step k, i.e. at t_k.
    states, sensordata = rollout.rollout(
        models if len(unique) > 1 else model, datas, initial, nstep=nstep + 1, persistent_pool=False
    )
    for d in datas:
        bad = [mujoco.mjtWarning(w).name for w in _BAD_STATE_WARNINGS if d.warning[w].number > 0]
        if bad:
            raise SimulationDiverged(
                f"simulation diverged (MuJoCo {', '.join(bad)}): the state left the finite range; "
                f"reduce dt_s (now {dt_s} s) or the stiffness"
            )
    # States at t_0..t_n: the initial one, then the post-step states of steps 0..n-1.
    states = np.concatenate([initial[:, None, :], states[:, :-1, :]], axis=1)
    if not (np.all(np.isfinite(states)) and np.all(np.isfinite(sensordata))):
        raise SimulationDiverged(f"simulation produced non-finite values; reduce dt_s (now {dt_s} s)")
    return _trajectory(models, unique, param_list, states, sensordata, dt_s, nstep, clamp)


def evaluate_states(params: RigParams, phi_rad: np.ndarray, omega_rad_s: np.ndarray) -> dict[str, np.ndarray]:
    """MuJoCo's IMU sensors at arbitrary states, without stepping through time.

    Each state is rolled out by one step on the thread pool; the sensor row of that step
    describes the state itself (the same pairing as ``simulate``).

    Args:
      params: rig parameters.
      phi_rad, omega_rad_s: (m, 2) states.

    Returns:
      dict with ``imu_accel_m_s2``, ``imu_gyro_rad_s``, ``imu_angacc_rad_s2`` (m, 2, 3) and
      ``imu_quat_wxyz`` (m, 2, 4), as in Trajectory.
    """
    phi0, omega0 = check_initial(phi_rad, omega_rad_s)
    model = build_model(params)
    nthread = max(1, min(os.cpu_count() or 1, len(phi0)))
    datas = [mujoco.MjData(model) for _ in range(nthread)]
    _, sensordata = rollout.rollout(model, datas, _initial_states(model, phi0, omega0), nstep=1)
    sensordata = sensordata[:, 0, :]
    quat = np.stack([_sensor(model, sensordata, f"{s}_quat") for s in IMU_SITES], axis=-2)
    angacc_world = np.stack([_sensor(model, sensordata, f"{b}_angacc") for b in BODIES], axis=-2)
    return {
        "imu_accel_m_s2": np.stack([_sensor(model, sensordata, f"{s}_accel") for s in IMU_SITES], axis=-2),
        "imu_gyro_rad_s": np.stack([_sensor(model, sensordata, f"{s}_gyro") for s in IMU_SITES], axis=-2),
        "imu_quat_wxyz": quat,
        "imu_angacc_rad_s2": rotations.rotate_into_frame(quat, angacc_world),
    }


def _state_offsets(model: mujoco.MjModel) -> tuple[int, int]:
    qpos = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_TIME)
    qvel = qpos + model.nq
    return qpos, qvel


def _initial_states(
    model: mujoco.MjModel, phi0: np.ndarray, omega0: np.ndarray, tilt0: np.ndarray | None = None
) -> np.ndarray:
    data = mujoco.MjData(model)
    template = np.empty(mujoco.mj_stateSize(model, _STATE))
    mujoco.mj_getState(model, data, template, _STATE)
    states = np.tile(template, (len(phi0), 1))
    qpos_at, qvel_at = _state_offsets(model)
    for k, hinge in enumerate(HINGES):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, hinge)
        if jid >= 0:
            states[:, qpos_at + model.jnt_qposadr[jid]] = phi0[:, k]
            states[:, qvel_at + model.jnt_dofadr[jid]] = omega0[:, k]
        tid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, TILTS[k])
        if tid >= 0 and tilt0 is not None:
            states[:, qpos_at + model.jnt_qposadr[tid]] = tilt0[:, k]
    return states


def _sensor(model: mujoco.MjModel, sensordata: np.ndarray, name: str) -> np.ndarray:
    s = model.sensor(name)
    return sensordata[..., s.adr[0] : s.adr[0] + s.dim[0]]


def _rest_potential_j(model: mujoco.MjModel) -> float:
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return float(data.energy[0])


def _trajectory(models, unique, param_list, states, sensordata, dt_s, nstep, clamp) -> Trajectory:
    model = models[0]
    nbatch, n = states.shape[:2]
    qpos_at, qvel_at = _state_offsets(model)
    phi = np.zeros((nbatch, n, 2))
    omega = np.zeros((nbatch, n, 2))
    tilt = np.zeros((nbatch, n, 2))
    tilt_rate = np.zeros((nbatch, n, 2))
    for k, (hinge, tilt_joint) in enumerate(zip(HINGES, TILTS, strict=True)):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, hinge)
        if jid >= 0:
            phi[..., k] = states[..., qpos_at + model.jnt_qposadr[jid]]
            omega[..., k] = states[..., qvel_at + model.jnt_dofadr[jid]]
        tid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, tilt_joint)
        if tid >= 0:
            tilt[..., k] = states[..., qpos_at + model.jnt_qposadr[tid]]
            tilt_rate[..., k] = states[..., qvel_at + model.jnt_dofadr[tid]]

    def sens(name: str) -> np.ndarray:
        return _sensor(model, sensordata, name)

    alpha = np.stack([sens(f"{b}_angacc") @ HINGE_AXIS_WORLD for b in BODIES], axis=-1)
    accel = np.stack([sens(f"{s}_accel") for s in IMU_SITES], axis=-2)
    gyro = np.stack([sens(f"{s}_gyro") for s in IMU_SITES], axis=-2)
    quat = np.stack([sens(f"{s}_quat") for s in IMU_SITES], axis=-2)
    angacc_world = np.stack([sens(f"{b}_angacc") for b in BODIES], axis=-2)
    angacc = rotations.rotate_into_frame(quat, angacc_world)
    length = np.concatenate([sens(f"{s}_length") for s in SPRINGS], axis=-1)

    # Per-run constants: stiffness (nbatch, 4), damping (nbatch, 2), rest potential (nbatch,).
    tendon_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, s) for s in SPRINGS]
    stiffness_of = {id(m): m.tendon_stiffness[tendon_ids] for m in unique.values()}
    stiffness = np.array([stiffness_of[id(m)] for m in models])
    damping = np.array([[p.b1_n_m_s, p.b2_n_m_s] for p in param_list])
    if clamp is not Clamp.NONE:
        damping[:, 0 if clamp is Clamp.M1 else 1] = 0.0
    rest_energy = {id(m): _rest_potential_j(m) for m in unique.values()}
    rest = np.array([rest_energy[id(m)] for m in models])

    force = stiffness[:, None, :] * length
    moment = np.zeros((nbatch, n, 2))
    for i, (a, b) in enumerate(SPRING_ENDS):
        pa, pb = sens(f"{a}_pos"), sens(f"{b}_pos")
        f_on_a = stiffness[:, None, i, None] * (pb - pa)  # zero free length: c * (p_b - p_a)
        for point, p_point, f in ((a, pa, f_on_a), (b, pb, -f_on_a)):
            owner = _POINT_OWNER[point]
            if owner is not None:
                moment[..., owner] += np.cross(p_point, f) @ HINGE_AXIS_WORLD

    # Kinetic energy sum 1/2 m v_com^2 + 1/2 w^T I w from per-body sensors at the same instant
    # (not MuJoCo's e_kinetic sensor, which it reads before mj_energyVel: one evaluation stale).
    kinetic = np.zeros((nbatch, n))
    for b in BODIES:
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b)
        mass = np.array([m.body_mass[bid] for m in models])[:, None]
        inertia = np.array([m.body_inertia[bid] for m in models])[:, None, :]  # principal, body axes
        v = sens(f"{b}_com_linvel")
        w_body = rotations.rotate_into_frame(sens(f"{b}_quat"), sens(f"{b}_angvel"))
        kinetic += 0.5 * mass * np.sum(v * v, axis=-1) + 0.5 * np.sum(inertia * w_body * w_body, axis=-1)
    potential = sens("energy_potential")[..., 0] - rest[:, None]
    # Dissipated energy: integral of the damping power P = sum b omega^2 by the corrected
    # trapezoid rule h/2 (P_k + P_k+1) + h^2/12 (P'_k - P'_k+1), P' = sum 2 b omega alpha
    # (MuJoCo's own alpha at the same instants): fourth order, like the RK4 step.
    power = np.einsum("bk,bnk->bn", damping, omega**2)
    dpower = np.einsum("bk,bnk->bn", 2.0 * damping, omega * alpha)
    interval = 0.5 * dt_s * (power[:, :-1] + power[:, 1:]) + dt_s**2 / 12.0 * (dpower[:, :-1] - dpower[:, 1:])
    if np.any(tilt_rate):  # tilt damping: trapezoid (no tilt acceleration sensor), second order
        tilt_b = np.array([p.tilt_damping_n_m_s_rad for p in param_list])[:, None, None]
        tilt_power = np.sum(tilt_b * tilt_rate**2, axis=-1)
        interval = interval + 0.5 * dt_s * (tilt_power[:, :-1] + tilt_power[:, 1:])
    dissipated = np.concatenate([np.zeros((nbatch, 1)), np.cumsum(interval, axis=1)], axis=1)

    scale = np.array([p.m1_kg * p.g_m_s2 * p.oc1_m for p in param_list])
    check_energy_bounded(kinetic + potential, scale, dt_s)
    return Trajectory(
        t_s=np.arange(n) * dt_s,
        phi_rad=phi,
        omega_rad_s=omega,
        alpha_rad_s2=alpha,
        imu_accel_m_s2=accel,
        imu_gyro_rad_s=gyro,
        imu_quat_wxyz=quat,
        imu_angacc_rad_s2=angacc,
        tilt_rad=tilt,
        spring_length_m=length,
        spring_force_n=force,
        spring_moment_n_m=moment,
        kinetic_j=kinetic,
        potential_j=potential,
        dissipated_j=dissipated,
        engine="mujoco",
        dt_s=dt_s,
        params=tuple(param_list),
    )
