"""Control of the rig: the plant stepped one control period at a time, the linearised rig for
design, controllers, what a controller sees (exact state or the nodes), and closed loops in
simulation. No I/O: the bridge's ``pendsim control`` runs them, records them and closes the loop
over UDP.

Modules and their jobs:

- ``plant``: the rig advanced one period per step with inputs chosen between steps (``FastPlant``:
  the fast engine's force law, a batch side by side in numpy; ``MujocoPlant``: MuJoCo's
  ``mj_step``), and the open-loop drive that replays a loop's inputs (``replay_drive``).
- ``linear``: the rig linearised about rest (``linearise``: A, B, the zero-order-hold
  discretisation, the energy weight, modal amplitudes) and ``decay_time_s``.
- ``controllers``: ``LQR``, ``ScheduledLQR``, ``EnergyRegulator``, ``BeatingSuppressor``,
  ``OpenLoop``, by name in ``CONTROLLERS``; ``check_stabilising`` for gains from outside.
- ``observe``: ``StateObserver`` (exact) and ``NodeObserver`` (the BNO055 nodes: 80 Hz, noise,
  latency, loss).
- ``loop``: ``closed_loop`` and its result ``ClosedLoop`` with ``LoopMetrics``.
- ``tasks``: the Gymnasium environments' tasks (``Task``: damp, hold, still-m2, no-beating,
  tongue), their releases and rewards.
- ``environment``: ``CoupledPendulumsEnv``, the rig as a Gymnasium environment, and the options
  and spaces it shares with the vector environment (``EnvConfig``).
- ``vector_env``: ``CoupledPendulumsVectorEnv``, many rigs stepped at once on the batched fast
  plant, with ``BatchNodes``.

Importing this package imports none of them (MuJoCo and scipy load on first use); it imports
Gymnasium's registry and registers the environment as ``ENV_ID`` (``gymnasium.make(ENV_ID)``,
``gymnasium.make_vec(ENV_ID, num_envs=...)``; or, without importing this package first,
``gymnasium.make("pendsim_mj.control:pendsim/CoupledPendulums-v0")``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from gymnasium.envs.registration import register, registry

from pendsim_mj import lazy

ENV_ID = "pendsim/CoupledPendulums-v0"
"""The environments' Gymnasium id."""

_LAZY = {
    "FastPlant": "pendsim_mj.control.plant",
    "MujocoPlant": "pendsim_mj.control.plant",
    "make_plant": "pendsim_mj.control.plant",
    "replay_drive": "pendsim_mj.control.plant",
    "LinearRig": "pendsim_mj.control.linear",
    "linearise": "pendsim_mj.control.linear",
    "decay_time_s": "pendsim_mj.control.linear",
    "CONTROLLERS": "pendsim_mj.control.controllers",
    "Controller": "pendsim_mj.control.controllers",
    "LQR": "pendsim_mj.control.controllers",
    "ScheduledLQR": "pendsim_mj.control.controllers",
    "EnergyRegulator": "pendsim_mj.control.controllers",
    "BeatingSuppressor": "pendsim_mj.control.controllers",
    "OpenLoop": "pendsim_mj.control.controllers",
    "check_stabilising": "pendsim_mj.control.controllers",
    "NodeObserver": "pendsim_mj.control.observe",
    "StateObserver": "pendsim_mj.control.observe",
    "Observation": "pendsim_mj.control.observe",
    "ClosedLoop": "pendsim_mj.control.loop",
    "LoopMetrics": "pendsim_mj.control.loop",
    "closed_loop": "pendsim_mj.control.loop",
    "Task": "pendsim_mj.control.tasks",
    "TASKS": "pendsim_mj.control.tasks",
    "CoupledPendulumsEnv": "pendsim_mj.control.environment",
    "EnvConfig": "pendsim_mj.control.environment",
    "CoupledPendulumsVectorEnv": "pendsim_mj.control.vector_env",
}

if TYPE_CHECKING:
    from pendsim_mj.control.controllers import (
        CONTROLLERS,
        LQR,
        BeatingSuppressor,
        Controller,
        EnergyRegulator,
        OpenLoop,
        ScheduledLQR,
        check_stabilising,
    )
    from pendsim_mj.control.environment import CoupledPendulumsEnv, EnvConfig
    from pendsim_mj.control.linear import LinearRig, decay_time_s, linearise
    from pendsim_mj.control.loop import ClosedLoop, LoopMetrics, closed_loop
    from pendsim_mj.control.observe import NodeObserver, Observation, StateObserver
    from pendsim_mj.control.plant import FastPlant, MujocoPlant, make_plant, replay_drive
    from pendsim_mj.control.tasks import TASKS, Task
    from pendsim_mj.control.vector_env import CoupledPendulumsVectorEnv
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

if ENV_ID not in registry:  # once, however often this package is imported or reloaded
    register(
        id=ENV_ID,
        entry_point="pendsim_mj.control.environment:CoupledPendulumsEnv",
        vector_entry_point="pendsim_mj.control.vector_env:CoupledPendulumsVectorEnv",
    )

__all__ = [
    "CONTROLLERS",
    "ENV_ID",
    "LQR",
    "TASKS",
    "BeatingSuppressor",
    "ClosedLoop",
    "Controller",
    "CoupledPendulumsEnv",
    "CoupledPendulumsVectorEnv",
    "EnergyRegulator",
    "EnvConfig",
    "FastPlant",
    "LinearRig",
    "LoopMetrics",
    "MujocoPlant",
    "NodeObserver",
    "Observation",
    "OpenLoop",
    "ScheduledLQR",
    "StateObserver",
    "Task",
    "check_stabilising",
    "closed_loop",
    "decay_time_s",
    "linearise",
    "make_plant",
    "replay_drive",
]
