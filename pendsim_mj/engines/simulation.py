"""Run the MuJoCo model of the rig at a fixed step, without a per-step Python loop.

``mujoco.rollout`` steps the model in C. After a step MuJoCo's sensor values describe the state
*before* that step, and rollout stores them beside the state *after* it; we roll out one extra
step and re-pair them, so every row of the returned Trajectory belongs to one instant.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Iterator, Sequence

import mujoco
import numpy as np
from mujoco import rollout
from numpy.typing import ArrayLike

from pendsim_mj.engines.reference import diverged_advice
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.errors import ParameterError, SimulationDiverged
from pendsim_mj.rig import mujoco_warnings
from pendsim_mj.rig.checks import (
    broadcast_params,
    check_drives,
    check_energy_bounded,
    check_initial,
    check_params,
    check_step,
    first_nonfinite_run,
)
from pendsim_mj.rig.drives import Drive, Target, inputs_at_samples, stack_inputs, support_initial_velocity
from pendsim_mj.rig.model import (
    BODIES,
    HINGE_AXIS_WORLD,
    HINGES,
    IMU_SITES,
    PLANAR,
    SPRING_ENDS,
    SPRING_POINT_OWNER,
    SPRINGS,
    SUPPORT_JOINTS,
    TILTS,
    Clamp,
    Variant,
    build_model,
)
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams, friction_direction
from pendsim_mj.sensors import rotations

_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS
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
    drive: Drive | None = None,
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
      drive: torques and support motion (``pendsim_mj.rig.drives``); None drives nothing.

    Returns:
      A Trajectory with arrays of shape (n, ...).

    Raises:
      ParameterError: bad parameters or initial conditions.
      SimulationDiverged: the run reached non-finite or runaway values.
    """
    return simulate_batch(
        params,
        phi0_rad,
        omega0_rad_s,
        duration_s,
        dt_s,
        nthread=1,
        clamp=clamp,
        variant=variant,
        tilt0_rad=tilt0_rad,
        drive=drive,
    ).member(0)


def simulate_batch(
    params: RigParams | Sequence[RigParams] = DEFAULT_PARAMS,
    phi0_rad: ArrayLike = (math.pi / 6, 0.0),
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    nthread: int | None = None,
    clamp: Clamp = Clamp.NONE,
    variant: Variant = PLANAR,
    tilt0_rad: ArrayLike = (0.0, 0.0),
    drive: Drive | Sequence[Drive | None] | None = None,
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
      drive: one Drive for all runs, or nbatch of them driving the same targets (``drives``):
        motors at the hinges and the support on slides, each input held over a step at its
        value at the step's midpoint (``rollout`` holds ``ctrl`` over the four RK4 stages: second
        order in dt, where the planar engines' stage rule is fourth; ``drives``, "Sampling"). The
        support starts at 0 with the velocity that gives its
        motion no drift (``drives.support_initial_velocity``).

    Returns:
      A batch Trajectory: arrays of shape (nbatch, n, ...); ``.member(i)`` gives one run.
    """
    run = _rolled_out(params, phi0_rad, omega0_rad_s, duration_s, dt_s, nthread, clamp, variant, tilt0_rad, drive)
    return _trajectory(
        run.models, run.unique, run.param_list, run.states, run.sensordata, dt_s, run.nstep, clamp, run.inputs,
        run.drives,
    )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class SampledMotion:
    """What a sweep needs of a batch of MuJoCo runs, at every ``every``-th step (nsave samples,
    from t = 0): no IMU, spring or per-step field is built (``simulate_batch_sampled``).

    Attributes:
      phi_rad, omega_rad_s, alpha_rad_s2: (nbatch, nsave, 2) as in Trajectory.
      total_energy_j: (nbatch, nsave) kinetic + potential energy above rest, J (Trajectory's).
      dissipated_j: (nbatch, nsave) energy taken by the hinge damping since t = 0, J, integrated
        over every step (Trajectory's, at the saved samples).
    """

    phi_rad: np.ndarray
    omega_rad_s: np.ndarray
    alpha_rad_s2: np.ndarray
    total_energy_j: np.ndarray
    dissipated_j: np.ndarray


def simulate_batch_sampled(
    params: RigParams | Sequence[RigParams] = DEFAULT_PARAMS,
    phi0_rad: ArrayLike = (math.pi / 6, 0.0),
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    every: int = 1,
    nthread: int | None = None,
    variant: Variant = PLANAR,
    drive: Drive | Sequence[Drive | None] | None = None,
) -> SampledMotion:
    """``simulate_batch`` reduced to the angles, rates, accelerations and energies at every
    ``every``-th step, computed from the rollout's states and sensors at those rows only (the
    dissipated energy over every step): the values ``simulate_batch``'s Trajectory has there, at
    a fraction of its cost (no IMU, spring or per-step energy arrays). A run whose energy grows
    without input is not raised here: its ``total_energy_j`` shows it (``checks.energy_grew``).

    Raises:
      ParameterError: bad parameters, initial conditions or ``every``.
      SimulationDiverged: a run reached non-finite values.
    """
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ParameterError(f"every must be a whole number >= 1, got {every!r}")
    run = _rolled_out(params, phi0_rad, omega0_rad_s, duration_s, dt_s, nthread, Clamp.NONE, variant, (0.0, 0.0), drive)
    model = run.models[0]
    phi, omega, _, tilt_rate = _hinge_states(model, run.states)
    alpha = _hinge_accelerations(model, run.sensordata)
    dissipated = _dissipated(run.param_list, Clamp.NONE, omega, alpha, tilt_rate, dt_s)
    rows = slice(None, None, every)
    support_pos, support_vel = _support_state(model, run.states[:, rows])
    kinetic, potential = _energies(run.models, run.unique, run.sensordata[:, rows], support_pos, support_vel)
    return SampledMotion(
        phi_rad=phi[:, rows],
        omega_rad_s=omega[:, rows],
        alpha_rad_s2=alpha[:, rows],
        total_energy_j=kinetic + potential,
        dissipated_j=dissipated[:, rows],
    )


@dataclasses.dataclass(frozen=True)
class _Rollout:
    """A batch rolled out (``_rolled_out``): what ``_trajectory`` reads."""

    models: list[mujoco.MjModel]
    unique: dict[RigParams, mujoco.MjModel]
    param_list: list[RigParams]
    states: np.ndarray
    sensordata: np.ndarray
    inputs: np.ndarray
    drives: Sequence[Drive | None] | None
    nstep: int


def _rolled_out(
    params: RigParams | Sequence[RigParams],
    phi0_rad: ArrayLike,
    omega0_rad_s: ArrayLike,
    duration_s: float,
    dt_s: float,
    nthread: int | None,
    clamp: Clamp,
    variant: Variant,
    tilt0_rad: ArrayLike,
    drive: Drive | Sequence[Drive | None] | None,
) -> _Rollout:
    """The checked batch on ``mujoco.rollout`` (``simulate_batch``'s arguments): its states
    paired with their sensor rows, (nbatch, nstep + 1, ...)."""
    nstep = check_step(duration_s, dt_s)
    param_list = check_params(params)
    phi0, omega0 = check_initial(phi0_rad, omega0_rad_s, len(param_list) if len(param_list) > 1 else None)
    nbatch = len(phi0)
    param_list = broadcast_params(param_list, nbatch)
    if clamp is not Clamp.NONE:
        k = 0 if clamp is Clamp.M1 else 1
        if np.any(phi0[:, k] != 0) or np.any(omega0[:, k] != 0):
            raise ParameterError(f"clamped pendulum {clamp.value} must start at phi = omega = 0")

    drives, targets = check_drives(drive, nbatch)
    if clamp is not Clamp.NONE and any(t.value == f"torque_{clamp.value}" for t in targets):
        raise ParameterError(f"pendulum {clamp.value} is clamped: it cannot carry a torque drive")
    held = stack_inputs(drives, nstep, dt_s)  # (nbatch, nstep, 4)
    inputs = inputs_at_samples(held)  # (nbatch, nstep + 1, 4): the extra step repeats the last input

    # One compiled model per distinct parameter set.
    unique: dict[RigParams, mujoco.MjModel] = {}
    for p in param_list:
        if p not in unique:
            unique[p] = build_model(p, timestep_s=dt_s, clamp=clamp, variant=variant, drive_targets=targets)
    models = [unique[p] for p in param_list]
    model = models[0]

    nthread = max(1, min(nthread or os.cpu_count() or 1, nbatch))
    datas = [mujoco.MjData(model) for _ in range(nthread)]
    tilt0 = np.broadcast_to(np.asarray(tilt0_rad, dtype=float), (nbatch, 2))
    if np.any(tilt0 != 0) and not variant.tilt:
        raise ParameterError("tilt0_rad needs the spatial variant (tilt freedoms)")
    initial = _initial_states(model, phi0, omega0, tilt0)
    support = [t for t in targets if t.is_support]
    if support:
        v0 = support_initial_velocity(held[..., [t.index for t in support]], dt_s)
        _, qvel_at = _state_offsets(model)
        for k, t in enumerate(support):
            initial[:, qvel_at + model.jnt_dofadr[model.joint(SUPPORT_JOINTS[t][0]).id]] = v0[:, k]
    # ctrl: the driven channels, in Target order (the model's actuator order).
    control = inputs[..., [t.index for t in targets]] if targets else None
    # nstep + 1 steps: sensors of row k belong to the state before step k, i.e. at t_k.
    with mujoco_warnings.captured() as warnings:
        states, sensordata = rollout.rollout(
            models if len(unique) > 1 else model, datas, initial, control, nstep=nstep + 1, persistent_pool=False
        )
    _check_warnings(
        datas, dt_s, warnings, lambda: _advice(model, param_list[first_nonfinite_run(states, 0) or 0], dt_s)
    )
    states = _pair(initial, states, sensordata, dt_s)
    return _Rollout(models, unique, list(param_list), states, sensordata, inputs, drives if targets else None, nstep)


def _check_warnings(
    datas: list[mujoco.MjData], dt_s: float, warnings: mujoco_warnings.Captured, advice: Callable[[], str]
) -> None:
    """Raise SimulationDiverged where a rollout's MjData warned of a bad state; ``advice``: what to
    change (``reference.diverged_advice`` of the run that diverged)."""
    for d in datas:
        bad = [mujoco.mjtWarning(w).name for w in _BAD_STATE_WARNINGS if d.warning[w].number > 0]
        if bad:
            said = f" (MuJoCo: {warnings.summary()})" if warnings.messages else ""
            raise SimulationDiverged(
                f"simulation diverged (MuJoCo {', '.join(bad)}): the state left the finite range; {advice()}{said}"
            )


def _advice(model: mujoco.MjModel, params: RigParams, dt_s: float) -> str:
    """``reference.diverged_advice`` (the planar rig at rest), and for the spatial model that its
    tilts are not in it."""
    tilts = variant_has_tilt(model)
    return diverged_advice(params, dt_s) + (
        " (the spatial model's tilts are not in this estimate: the bearings' tilt_stiffness_n_m_rad and "
        "tilt_damping_n_m_s_rad limit the step too)"
        if tilts
        else ""
    )


def _pair(initial: np.ndarray, states: np.ndarray, sensordata: np.ndarray, dt_s: float) -> np.ndarray:
    """States at t_0..t_n (the initial one, then the post-step states of steps 0..n-1), paired
    with rollout's sensor rows (which describe the state before each step)."""
    states = np.concatenate([initial[:, None, :], states[:, :-1, :]], axis=1)
    if not (np.all(np.isfinite(states)) and np.all(np.isfinite(sensordata))):
        raise SimulationDiverged(f"simulation produced non-finite values; reduce dt_s (now {dt_s} s)")
    return states


def simulate_blocks(
    params: RigParams = DEFAULT_PARAMS,
    phi0_rad: ArrayLike = (math.pi / 6, 0.0),
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    block_steps: int = 3000,
    variant: Variant = PLANAR,
    drive: Drive | None = None,
) -> Iterator[tuple[int, Trajectory]]:
    """``simulate`` in blocks of ``block_steps`` steps, each continued from the previous
    block's full physics state: memory independent of the duration, rows identical to one run.

    Yields:
      (first_row, block): rows first_row .. first_row + block_steps of the run (the last block
      ends at the run's last row); consecutive blocks share their boundary row. t_s and
      dissipated_j are the run's own (dissipated carried over from the earlier blocks). A
      drive's held inputs are computed for the whole run at once (32 bytes per step).
    """
    nstep = check_step(duration_s, dt_s)
    if block_steps < 1:
        raise ParameterError(f"block_steps must be >= 1, got {block_steps}")
    (p,) = check_params(params)
    phi0, omega0 = check_initial(phi0_rad, omega0_rad_s)
    drives, targets = check_drives(drive, 1)
    # A drive's inputs for the whole run (32 bytes per step); none without a drive.
    held = stack_inputs(drives, nstep, dt_s) if targets else None  # (1, nstep, 4)
    inputs = inputs_at_samples(held) if held is not None else None  # (1, nstep + 1, 4)
    model = build_model(p, timestep_s=dt_s, variant=variant, drive_targets=targets)
    datas = [mujoco.MjData(model)]
    state = _initial_states(model, phi0, omega0, np.zeros((1, 2)))
    support = [t for t in targets if t.is_support]
    if support and held is not None:
        v0 = support_initial_velocity(held[..., [t.index for t in support]], dt_s)
        _, qvel_at = _state_offsets(model)
        for k, t in enumerate(support):
            state[:, qvel_at + model.jnt_dofadr[model.joint(SUPPORT_JOINTS[t][0]).id]] = v0[:, k]
    dissipated0 = 0.0
    for first in range(0, nstep, block_steps):
        steps = min(block_steps, nstep - first)
        block_inputs = inputs[:, first : first + steps + 1] if inputs is not None else np.zeros((1, steps + 1, 4))
        control = block_inputs[..., [t.index for t in targets]] if targets else None
        with mujoco_warnings.captured() as warnings:
            raw, sensordata = rollout.rollout(model, datas, state, control, nstep=steps + 1, persistent_pool=False)
        _check_warnings(datas, dt_s, warnings, lambda: _advice(model, p, dt_s))
        states = _pair(state, raw, sensordata, dt_s)
        block = _trajectory(
            [model], {p: model}, [p], states, sensordata, dt_s, steps, Clamp.NONE, block_inputs,
            drives if targets else None, first_row=first, dissipated0_j=dissipated0,
        )  # fmt: skip
        state = states[:, -1, :].copy()
        dissipated0 = float(block.dissipated_j[0, -1])
        yield first, block.member(0)


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


def variant_has_tilt(model: mujoco.MjModel) -> bool:
    """Whether the model has the spatial variant's tilt joints."""
    found: int = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, TILTS[0])
    return found >= 0


def _rest_potential_j(model: mujoco.MjModel, data: mujoco.MjData) -> float:
    """The potential energy (J) of the model's rest pose (``data``: one of its size, reset here)."""
    mujoco.mj_resetData(model, data)
    mujoco.mj_forward(model, data)
    return float(data.energy[0])


def _support_state(model: mujoco.MjModel, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World position and velocity (..., n, 3) of the support (zero where it does not move)."""
    qpos_at, qvel_at = _state_offsets(model)
    pos = np.zeros((*states.shape[:-1], 3))
    vel = np.zeros((*states.shape[:-1], 3))
    for target, (name, _) in SUPPORT_JOINTS.items():
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid >= 0:
            axis = 0 if target is Target.SUPPORT_X else 2
            pos[..., axis] = states[..., qpos_at + model.jnt_qposadr[jid]]
            vel[..., axis] = states[..., qvel_at + model.jnt_dofadr[jid]]
    return pos, vel


def _weight_on_support_n(model: mujoco.MjModel) -> float:
    """d(potential energy)/d(support height), N: the weight that rises with the support."""
    jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, SUPPORT_JOINTS[Target.PIVOT_Z][0])
    if jid < 0:
        return 0.0
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    e0 = float(data.energy[0])
    data.qpos[model.jnt_qposadr[jid]] = 1.0
    mujoco.mj_forward(model, data)
    return float(data.energy[0]) - e0


def _hinge_states(model: mujoco.MjModel, states: np.ndarray) -> tuple[np.ndarray, ...]:
    """phi, omega, tilt, tilt rate (..., n, 2) from full physics states (..., n, size); zero
    for a joint the model lacks (a clamped hinge, the planar variant's tilts)."""
    qpos_at, qvel_at = _state_offsets(model)
    out = [np.zeros((*states.shape[:-1], 2)) for _ in range(4)]
    for k, joints in enumerate(zip(HINGES, TILTS, strict=True)):
        for j, name in enumerate(joints):
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid >= 0:
                out[2 * j][..., k] = states[..., qpos_at + model.jnt_qposadr[jid]]
                out[2 * j + 1][..., k] = states[..., qvel_at + model.jnt_dofadr[jid]]
    phi, omega, tilt, tilt_rate = out
    return phi, omega, tilt, tilt_rate


def _hinge_accelerations(model: mujoco.MjModel, sensordata: np.ndarray) -> np.ndarray:
    """(..., n, 2) each body's angular acceleration about the hinge axis, rad/s^2."""
    return np.stack([_sensor(model, sensordata, f"{b}_angacc") @ HINGE_AXIS_WORLD for b in BODIES], axis=-1)


def _energies(
    models: Sequence[mujoco.MjModel],
    unique: dict[RigParams, mujoco.MjModel],
    sensordata: np.ndarray,
    support_pos: np.ndarray,
    support_vel: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Kinetic and potential energy (nbatch, n), J, relative to the support (its velocity
    subtracted, its height removed from the potential, the potential above the rest pose): the
    same in a driven and an undriven run, and the reference's.

    The kinetic energy is sum 1/2 m v_com^2 + 1/2 w^T I w from per-body sensors at the same
    instant (not MuJoCo's e_kinetic sensor, which it reads before mj_energyVel: one evaluation
    stale)."""
    model = models[0]
    kinetic = np.zeros(sensordata.shape[:2])
    for b in BODIES:
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b)
        mass = np.array([m.body_mass[bid] for m in models])[:, None]
        inertia = np.array([m.body_inertia[bid] for m in models])[:, None, :]  # principal, body axes
        v = _sensor(model, sensordata, f"{b}_com_linvel") - support_vel
        w_body = rotations.rotate_into_frame(
            _sensor(model, sensordata, f"{b}_quat"), _sensor(model, sensordata, f"{b}_angvel")
        )
        kinetic += 0.5 * mass * np.sum(v * v, axis=-1) + 0.5 * np.sum(inertia * w_body * w_body, axis=-1)
    data = mujoco.MjData(model)  # every model of a batch has the same sizes (rollout's own premise)
    rest_energy = {id(m): _rest_potential_j(m, data) for m in unique.values()}
    rest = np.array([rest_energy[id(m)] for m in models])
    potential = _sensor(model, sensordata, "energy_potential")[..., 0] - rest[:, None]
    if np.any(support_pos[..., 2]):
        weight = np.array([_weight_on_support_n(m) for m in models])[:, None]
        potential = potential - weight * support_pos[..., 2]
    return kinetic, potential


def _dissipated(
    param_list: Sequence[RigParams],
    clamp: Clamp,
    omega: np.ndarray,
    alpha: np.ndarray,
    tilt_rate: np.ndarray,
    dt_s: float,
    dissipated0_j: float = 0.0,
) -> np.ndarray:
    """(nbatch, n) energy taken by the hinges' damping and dry friction (and the tilt damping)
    since the first row, J, from rates and accelerations (nbatch, n, 2) at every step.

    The integral of the damping power P = sum b omega^2 by the corrected trapezoid rule
    h/2 (P_k + P_k+1) + h^2/12 (P'_k - P'_k+1), P' = sum 2 b omega alpha (MuJoCo's own alpha at
    the same instants): fourth order, like the RK4 step. Dry friction's power F omega s(omega)
    (``friction_direction``: the reference's law; MuJoCo's frictionloss is a soft constraint
    close to it) by the trapezoid rule: the energy balance then closes to about 2e-4 of m1 g OC1
    at F = 1e-2 N m (tested), where it was off by the friction's whole work."""
    damping = np.array([[p.b1_n_m_s, p.b2_n_m_s] for p in param_list])
    if clamp is not Clamp.NONE:
        damping[:, 0 if clamp is Clamp.M1 else 1] = 0.0
    nbatch = len(omega)
    power = np.einsum("bk,bnk->bn", damping, omega**2)
    dpower = np.einsum("bk,bnk->bn", 2.0 * damping, omega * alpha)
    interval = 0.5 * dt_s * (power[:, :-1] + power[:, 1:]) + dt_s**2 / 12.0 * (dpower[:, :-1] - dpower[:, 1:])
    friction = np.array([[p.friction1_n_m, p.friction2_n_m] for p in param_list])
    if np.any(friction):  # a clamped hinge does not turn: its term is zero
        friction_power = np.einsum("bk,bnk->bn", friction, omega * friction_direction(omega))
        interval = interval + 0.5 * dt_s * (friction_power[:, :-1] + friction_power[:, 1:])
    if np.any(tilt_rate):  # tilt damping: trapezoid (no tilt acceleration sensor), second order
        tilt_b = np.array([p.tilt_damping_n_m_s_rad for p in param_list])[:, None, None]
        tilt_power = np.sum(tilt_b * tilt_rate**2, axis=-1)
        interval = interval + 0.5 * dt_s * (tilt_power[:, :-1] + tilt_power[:, 1:])
    return dissipated0_j + np.concatenate([np.zeros((nbatch, 1)), np.cumsum(interval, axis=1)], axis=1)


def _trajectory(
    models: Sequence[mujoco.MjModel],
    unique: dict[RigParams, mujoco.MjModel],
    param_list: Sequence[RigParams],
    states: np.ndarray,
    sensordata: np.ndarray,
    dt_s: float,
    nstep: int,
    clamp: Clamp,
    inputs: np.ndarray,
    drives: Sequence[Drive | None] | None,
    *,
    first_row: int = 0,
    dissipated0_j: float = 0.0,
) -> Trajectory:
    model = models[0]
    nbatch, n = states.shape[:2]
    support_pos, support_vel = _support_state(model, states)  # (nbatch, n, 3) world
    phi, omega, tilt, tilt_rate = _hinge_states(model, states)

    def sens(name: str) -> np.ndarray:
        return _sensor(model, sensordata, name)

    alpha = _hinge_accelerations(model, sensordata)
    accel = np.stack([sens(f"{s}_accel") for s in IMU_SITES], axis=-2)
    gyro = np.stack([sens(f"{s}_gyro") for s in IMU_SITES], axis=-2)
    quat = np.stack([sens(f"{s}_quat") for s in IMU_SITES], axis=-2)
    angacc_world = np.stack([sens(f"{b}_angacc") for b in BODIES], axis=-2)
    angacc = rotations.rotate_into_frame(quat, angacc_world)
    length = np.concatenate([sens(f"{s}_length") for s in SPRINGS], axis=-1)

    # Per-run spring stiffness (nbatch, 4).
    tendon_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, s) for s in SPRINGS]
    stiffness_of = {id(m): m.tendon_stiffness[tendon_ids] for m in unique.values()}
    stiffness = np.array([stiffness_of[id(m)] for m in models])

    force = stiffness[:, None, :] * length
    moment = np.zeros((nbatch, n, 2))
    for i, (a, b) in enumerate(SPRING_ENDS):
        pa, pb = sens(f"{a}_pos"), sens(f"{b}_pos")
        f_on_a = stiffness[:, None, i, None] * (pb - pa)  # zero free length: c * (p_b - p_a)
        for point, p_point, f in ((a, pa, f_on_a), (b, pb, -f_on_a)):
            owner = SPRING_POINT_OWNER.get(point)
            if owner is not None:  # about the pivot O, which moves with the support
                moment[..., owner] += np.cross(p_point - support_pos, f) @ HINGE_AXIS_WORLD

    kinetic, potential = _energies(models, unique, sensordata, support_pos, support_vel)
    dissipated = _dissipated(param_list, clamp, omega, alpha, tilt_rate, dt_s, dissipated0_j)

    scale = np.array([p.m1_kg * p.g_m_s2 * p.oc1_m for p in param_list])
    if drives is None:  # a driven rig may gain energy from its input
        check_energy_bounded(kinetic + potential, scale, dt_s, lambda i: diverged_advice(param_list[i], dt_s))
    return Trajectory(
        t_s=np.arange(first_row, first_row + n) * dt_s,
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
        tilt_rate_rad_s=tilt_rate if variant_has_tilt(model) else None,
        drive_input=inputs,
        support_m=support_pos[..., [0, 2]],
        drive=tuple(drives) if drives is not None else None,
    )
