"""Run one task of a sweep: a group of cases through an engine, to their features. No I/O.

This is the function a Dask worker calls (the sweep runner of the bridge sends it the plan once
and each task its rows of the case table), and the serial path calls it the same way, so a case's
result does not depend on where or with which other cases it ran: the fast kernel integrates
every member alone (bit for bit, see ``fast_planar``) and every feature is computed per row.

Engines: ``fast`` (``fast_planar``, all cores through numba), ``mujoco`` (the planar MuJoCo
model) and ``spatial`` (the spatial variant), both through ``simulation.simulate_batch_sampled``,
i.e. ``mujoco.rollout`` with one MjData per thread, one thread per core and one compiled model per
distinct parameter set, reduced to the saved samples without a Trajectory. MuJoCo is imported
only for those two.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import os

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.engines import fast_planar
from pendsim_mj.errors import SimulationDiverged
from pendsim_mj.rig.checks import energy_grew
from pendsim_mj.rig.drives import Drive, drive_stage_inputs, stage_inputs_at_samples
from pendsim_mj.rig.params import ParamColumns
from pendsim_mj.sweep.features import (
    Features,
    Motion,
    MotionSummary,
    compute,
    compute_summary,
    head_samples,
    with_balance,
)
from pendsim_mj.sweep.plan import CaseTable, SweepPlan

FloatArray = NDArray[np.float64]
LYAPUNOV_RENORMALISE_STEPS = 100  # Benettin renormalisation every 100 steps (1 s at 10 ms)


@dataclasses.dataclass(frozen=True)
class TaskResult:
    """What one task returns.

    Attributes:
      case_ids: (k,) the cases, in the order of every array here.
      features: their features.
      trajectories: (k, nsave, 4) phi1, phi2 (rad), omega1, omega2 (rad/s) at the saved samples,
        when asked for; NaN for a run that diverged on a MuJoCo engine.
    """

    case_ids: NDArray[np.int64]
    features: Features
    trajectories: FloatArray | None


def run_task(
    plan: SweepPlan,
    cases: CaseTable,
    case_ids: NDArray[np.int64],
    *,
    nthread: int | None = None,
    keep_trajectories: bool = False,
) -> TaskResult:
    """Features of the cases ``case_ids`` whose inputs are the rows of ``cases`` (same order).

    Args:
      plan: the sweep definition (engine, duration, step, features, base values).
      cases: k rows of the sweep's case table (``CaseTable`` with only these rows).
      case_ids: (k,) their numbers in the whole sweep.
      nthread: threads for the engine (default: every core).
      keep_trajectories: also return the sampled trajectories.
    """
    ids = np.asarray(case_ids, dtype=np.int64)
    rows = np.arange(len(cases))
    params, phi0, omega0 = plan.case_inputs(cases, rows)
    drives = plan.case_drives(cases, rows)
    # (k, nstep, NSTAGE, 4): the drive at each RK4 stage's time (the fast engine, fourth order; MuJoCo
    # holds each step's midpoint value: only whether a case is driven is read from these there)
    held = drive_stage_inputs(drives, plan.nstep, plan.dt_s) if drives[0] is not None else None
    lyapunov = _fast_lyapunov(plan, params, phi0, omega0, nthread) if "lyapunov" in plan.features else None
    # the energy balance is checked where every loss and input is counted: undriven runs
    checked = ~_driven(held, len(phi0))
    scale = params.column("m1_kg") * params.column("g_m_s2") * params.column("oc1_m")
    if light_path(plan) and not keep_trajectories:
        summary = _fast_summary(plan, params, phi0, omega0, held, nthread)
        features = compute_summary(summary, plan.features, lyapunov_per_s=lyapunov, nthread=nthread)
        features = with_balance(
            features, summary.energy_start_j, summary.energy_end_j, summary.dissipated_j, scale, checked
        )
        return TaskResult(case_ids=ids, features=features, trajectories=None)
    if plan.engine == "fast":
        motion = _fast_motion(plan, params, phi0, omega0, held, nthread)
    else:
        motion = _mujoco_motion(plan, params, phi0, omega0, drives, held, nthread)
    features = compute(motion, plan.features, lyapunov_per_s=lyapunov)
    energy = motion.total_energy_j
    features = with_balance(features, energy[:, 0], energy[:, -1], motion.dissipated_j[:, -1], scale, checked)
    traj = None
    if keep_trajectories:
        traj = np.concatenate([motion.phi_rad, motion.omega_rad_s], axis=2)
    return TaskResult(case_ids=ids, features=features, trajectories=traj)


def light_path(plan: SweepPlan) -> bool:
    """Whether the plan's tasks take the light path: the fast engine reduces each run on the fly
    (``fast_planar.summarise``) and no trajectory is stored. Poincare samples, kept trajectories
    and the MuJoCo engines need the sampled motion."""
    return plan.engine == "fast" and "poincare" not in plan.features and not plan.trajectories


def _driven(held: FloatArray | None, k: int) -> NDArray[np.bool_]:
    """(k,) cases with a non-zero input: their energy may grow, so only non-finite is divergence."""
    return np.zeros(k, dtype=bool) if held is None else np.any(held != 0, axis=(1, 2, 3))


def _fast_motion(
    plan: SweepPlan,
    params: ParamColumns,
    phi0: FloatArray,
    omega0: FloatArray,
    held: FloatArray | None,
    nthread: int | None,
) -> Motion:
    coef = fast_planar.coefficients(params)
    states = fast_planar.integrate(
        coef, phi0, omega0, plan.nstep, plan.dt_s, inputs=held, save_every=plan.save_every, nthread=nthread
    )
    diverged = fast_planar.diverged(states, coef, _driven(held, len(phi0)))
    phi1, phi2, omega1, omega2, dissipated = (states[:, i, :] for i in range(5))  # (nsave, k) each
    u = (
        None if held is None else stage_inputs_at_samples(held)[:, :: plan.save_every].transpose(2, 1, 0)
    )  # (4, nsave, k)
    alpha1, alpha2 = fast_planar.accelerations(phi1, phi2, omega1, omega2, coef, u)
    energy = fast_planar.kinetic_energy(omega1, omega2, coef) + fast_planar.potential_energy(phi1, phi2, coef)

    def pair(a: FloatArray, b: FloatArray) -> FloatArray:
        return np.stack([a.T, b.T], axis=-1)  # (k, nsave, 2)

    motion = Motion(
        t_s=np.asarray(np.arange(states.shape[0]) * (plan.dt_s * plan.save_every), dtype=np.float64),
        phi_rad=pair(phi1, phi2),
        omega_rad_s=pair(omega1, omega2),
        alpha_rad_s2=pair(alpha1, alpha2),
        total_energy_j=energy.T,
        dissipated_j=dissipated.T,
        diverged=diverged,
    )
    return motion


def _fast_lyapunov(
    plan: SweepPlan, params: ParamColumns, phi0: FloatArray, omega0: FloatArray, nthread: int | None
) -> FloatArray:
    """(k,) largest Lyapunov exponents, 1/s, on the fast kernel (every engine's sweep gets them
    from it: ``check`` refuses the feature on the MuJoCo engines)."""
    every = min(LYAPUNOV_RENORMALISE_STEPS, plan.nstep)
    lyapunov: FloatArray = fast_planar.lyapunov(
        fast_planar.coefficients(params), phi0, omega0, plan.nstep - plan.nstep % every, plan.dt_s,
        renormalise_every=every, nthread=nthread,
    )[-1]  # fmt: skip
    return lyapunov


def _fast_summary(
    plan: SweepPlan,
    params: ParamColumns,
    phi0: FloatArray,
    omega0: FloatArray,
    held: FloatArray | None,
    nthread: int | None,
) -> MotionSummary:
    """The light path: the fast kernel's pass reduced on the fly (``fast_planar.summarise``), no
    stored trajectory; the same features as ``_fast_motion`` + ``compute``."""
    coef = fast_planar.coefficients(params)
    nsave = plan.nstep // plan.save_every + 1
    stats, phi = fast_planar.summarise(
        coef, phi0, omega0, plan.nstep, plan.dt_s, head_samples=head_samples(nsave), inputs=held,
        save_every=plan.save_every, keep_phi="frequency" in plan.features, nthread=nthread,
    )  # fmt: skip
    row = {name: stats[i] for i, name in enumerate(fast_planar.SUMMARY_ROWS)}

    def pair(a: str, b: str) -> FloatArray:
        return np.stack([row[a], row[b]], axis=1)

    start_and_peak = np.stack([row["energy_start"], row["energy_max"]], axis=1)
    grew = energy_grew(start_and_peak, coef[fast_planar.COEFFICIENTS.index("gravity1_n_m")]) & ~_driven(held, len(phi0))
    return MotionSummary(
        t_s=np.asarray(np.arange(nsave) * (plan.dt_s * plan.save_every), dtype=np.float64),
        phi_rad=phi,
        amp_rad=pair("amp1", "amp2"),
        head_amp_rad=pair("head1", "head2"),
        head_index=pair("head1_index", "head2_index").astype(np.int64),
        tail_amp_rad=pair("tail1", "tail2"),
        tail_index=pair("tail1_index", "tail2_index").astype(np.int64),
        energy_start_j=row["energy_start"],
        energy_end_j=row["energy_end"],
        dissipated_j=row["dissipated_end"],
        diverged=grew | (row["nonfinite"] > 0) | ~np.isfinite(row["dissipated_end"]),
    )


def _mujoco_motion(
    plan: SweepPlan,
    columns: ParamColumns,
    phi0: FloatArray,
    omega0: FloatArray,
    drives: list[Drive | None],
    held: FloatArray | None,
    nthread: int | None,
) -> Motion:
    """Run the batch on ``mujoco.rollout``, reduced to the saved samples as it comes out
    (``simulation.simulate_batch_sampled``: no per-case Trajectory); where it diverges, run the
    cases one by one to flag exactly the ones that do (their motion is NaN).

    The cases are split into one share per thread, each built, rolled out on one MuJoCo thread and
    reduced in a Python thread of its own: MuJoCo and numpy release the GIL, so the model builds
    and the reductions (a third of a task run serially) overlap the other share's rollout instead
    of leaving a core idle."""
    from pendsim_mj.engines.simulation import simulate_batch_sampled  # start-up: MuJoCo, only for its engines
    from pendsim_mj.rig.model import PLANAR, SPATIAL

    variant = SPATIAL if plan.engine == "spatial" else PLANAR
    params = columns.to_params()
    k = len(params)
    nsave = plan.nstep // plan.save_every + 1
    arrays = {name: np.full((k, nsave, 2), np.nan) for name in ("phi", "omega", "alpha")}
    energy = np.full((k, nsave), np.nan)
    dissipated = np.full((k, nsave), np.nan)
    diverged = np.zeros(k, dtype=bool)

    def run(rows: NDArray[np.int64]) -> None:
        motion = simulate_batch_sampled(
            [params[i] for i in rows],
            phi0[rows],
            omega0[rows],
            plan.duration_s,
            plan.dt_s,
            every=plan.save_every,
            nthread=1,
            variant=variant,
            drive=None if drives[0] is None else [drives[i] for i in rows],
        )
        arrays["phi"][rows] = motion.phi_rad
        arrays["omega"][rows] = motion.omega_rad_s
        arrays["alpha"][rows] = motion.alpha_rad_s2
        energy[rows] = motion.total_energy_j
        dissipated[rows] = motion.dissipated_j

    def share(rows: NDArray[np.int64]) -> None:
        try:
            run(rows)
        except SimulationDiverged:
            for i in rows:
                try:
                    run(np.array([i]))
                except SimulationDiverged:
                    diverged[i] = True

    shares = np.array_split(np.arange(k), max(1, min(nthread or os.cpu_count() or 1, k)))
    if len(shares) == 1:
        share(shares[0])
    else:
        with concurrent.futures.ThreadPoolExecutor(len(shares), thread_name_prefix="pendsim-mujoco") as pool:
            for done in [pool.submit(share, rows) for rows in shares]:
                done.result()
    scale = columns.column("m1_kg") * columns.column("g_m_s2") * columns.column("oc1_m")
    diverged |= energy_grew(energy, scale) & ~_driven(held, k)
    for values in (*arrays.values(), energy, dissipated):  # a diverged run's motion is NaN
        values[diverged] = np.nan
    return Motion(
        t_s=np.asarray(np.arange(nsave) * (plan.dt_s * plan.save_every), dtype=np.float64),
        phi_rad=arrays["phi"],
        omega_rad_s=arrays["omega"],
        alpha_rad_s2=arrays["alpha"],
        total_energy_j=energy,
        dissipated_j=dissipated,
        diverged=diverged,
    )
