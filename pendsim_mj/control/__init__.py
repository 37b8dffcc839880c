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

Importing this package imports none of them (MuJoCo and scipy load on first use).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy

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
    from pendsim_mj.control.linear import LinearRig, decay_time_s, linearise
    from pendsim_mj.control.loop import ClosedLoop, LoopMetrics, closed_loop
    from pendsim_mj.control.observe import NodeObserver, Observation, StateObserver
    from pendsim_mj.control.plant import FastPlant, MujocoPlant, make_plant, replay_drive
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = [
    "CONTROLLERS",
    "LQR",
    "BeatingSuppressor",
    "ClosedLoop",
    "Controller",
    "EnergyRegulator",
    "FastPlant",
    "LinearRig",
    "LoopMetrics",
    "MujocoPlant",
    "NodeObserver",
    "Observation",
    "OpenLoop",
    "ScheduledLQR",
    "StateObserver",
    "check_stabilising",
    "closed_loop",
    "decay_time_s",
    "linearise",
    "make_plant",
    "replay_drive",
]
