"""The planar MuJoCo model as a flow map for the analyses: batches of runs on ``mujoco.rollout``.

State x = (phi1, phi2, omega1, omega2) in rad and rad/s. Each member of a batch may have its own
step (the analyses use dt = T / N, a whole number N of steps per period T of the drive, so that
stroboscopic samples and periodicity conditions fall on steps) and its own held inputs
(``drives.held_inputs``). Sensors and energy are switched off: only the state is needed.

The support's position and velocity, where it is driven, start at zero in every call: the
pendulums feel only its acceleration (see ``pendsim_mj.rig.drives``), so they do not enter x.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Collection

import mujoco
import numpy as np
from mujoco import rollout
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.errors import SimulationDiverged
from pendsim_mj.rig.drives import Target
from pendsim_mj.rig.model import HINGES, build_model
from pendsim_mj.rig.params import RigParams

_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS
_BAD = (mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQVEL, mujoco.mjtWarning.mjWARN_BADQPOS)


class RigFlow:
    """Batched runs of the planar rig with the actuators of ``targets`` (a context manager that
    owns a rollout thread pool; ``close()`` ends it).

    Args:
      params: rig parameters.
      targets: the driven inputs (``drives.Target``); inputs to ``run`` hold all four channels.
      nthread: worker threads (default: the CPU count).
    """

    def __init__(self, params: RigParams, targets: Collection[Target] = (), *, nthread: int | None = None) -> None:
        self.params = params
        self.targets = tuple(t for t in Target if t in set(targets))
        base = build_model(params, drive_targets=self.targets)
        base.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
        base.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_ENERGY)
        self._base = base
        self._models: dict[float, mujoco.MjModel] = {}
        self.nthread = max(1, nthread or os.cpu_count() or 1)
        self._datas = [mujoco.MjData(base) for _ in range(self.nthread)]
        self._pool: rollout.Rollout | None = rollout.Rollout(nthread=self.nthread if self.nthread > 1 else 0)
        data = mujoco.MjData(base)
        self._template = np.empty(mujoco.mj_stateSize(base, _STATE))
        mujoco.mj_getState(base, data, self._template, _STATE)
        qpos_at = mujoco.mj_stateSize(base, mujoco.mjtState.mjSTATE_TIME)
        qvel_at = qpos_at + base.nq
        self._cols = np.array(
            [qpos_at + base.jnt_qposadr[base.joint(h).id] for h in HINGES]
            + [qvel_at + base.jnt_dofadr[base.joint(h).id] for h in HINGES]
        )
        self._channels = [t.index for t in self.targets]

    def __enter__(self) -> RigFlow:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """End the thread pool (idempotent)."""
        if self._pool is not None:
            self._pool.close()
            self._pool = None

    def _model(self, dt_s: float) -> mujoco.MjModel:
        key = float(dt_s)
        model = self._models.get(key)
        if model is None:
            if len(self._models) > 4096:
                self._models.clear()
            model = copy.copy(self._base)
            model.opt.timestep = key
            self._models[key] = model
        return model

    def run(
        self,
        x0: ArrayLike,
        dt_s: ArrayLike,
        nstep: int,
        inputs: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """Roll out a batch.

        Args:
          x0: (nbatch, 4) initial states (phi1, phi2, omega1, omega2).
          dt_s: step per member, scalar or (nbatch,), s.
          nstep: steps per member.
          inputs: (nbatch or 1, nstep, 4) held inputs in Target channel order, or None (zero).

        Returns:
          (nbatch, nstep + 1, 4) states at the steps' boundaries, the initial one first.

        Raises:
          SimulationDiverged: MuJoCo flagged a bad state or a value is not finite.
        """
        if self._pool is None:
            raise RuntimeError("RigFlow is closed")
        x = np.atleast_2d(np.asarray(x0, dtype=float))
        nbatch = len(x)
        dts = np.broadcast_to(np.asarray(dt_s, dtype=float), (nbatch,))
        initial = np.tile(self._template, (nbatch, 1))
        initial[:, self._cols] = x
        models = [self._model(d) for d in dts]
        control = None
        if self._channels:
            u = np.zeros((1, nstep, 4)) if inputs is None else np.asarray(inputs, dtype=float)
            shape = (nbatch, nstep, len(self._channels))
            control = np.ascontiguousarray(np.broadcast_to(u[..., self._channels], shape))
        for d in self._datas:
            mujoco.mj_resetData(self._base, d)
        states, _ = self._pool.rollout(models, self._datas, initial, control, nstep=nstep)
        bad = [mujoco.mjtWarning(w).name for d in self._datas for w in _BAD if d.warning[w].number > 0]
        out = np.concatenate([x[:, None, :], states[:, :, self._cols]], axis=1)
        if bad or not np.all(np.isfinite(out)):
            raise SimulationDiverged(
                f"the rig's motion diverged (MuJoCo {', '.join(sorted(set(bad))) or 'non-finite state'}); "
                "lower the drive level or the number of periods"
            )
        return out


def scaled_norm(dx: NDArray[np.float64], omega_ref_rad_s: float) -> NDArray[np.float64]:
    """Euclidean norm over the last axis of a state difference with rates divided by omega_ref
    (angles and rates/omega_ref are both radians), shape dx.shape[:-1]."""
    w = np.array([1.0, 1.0, 1.0 / omega_ref_rad_s, 1.0 / omega_ref_rad_s])
    return np.sqrt(np.sum((dx * w) ** 2, axis=-1))
