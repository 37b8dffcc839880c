"""What every engine is: ``Engine``, the one signature of a batch of runs, and ``EngineName``.

The MuJoCo model (``simulation.simulate_batch``), the planar reference (``reference.solve_batch``)
and the compiled planar kernel (``fast_planar.solve_batch``) all satisfy ``Engine``;
``dispatch.ENGINES`` names them for the command line (mypy checks each entry against the
protocol). An engine may take further keyword-only options after these, each with a default
(MuJoCo: ``variant``, ``clamp``, ``tilt0_rad``, ``nthread``). Imports no engine.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, Protocol

from numpy.typing import ArrayLike

from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.params import RigParams

EngineName = Literal["mujoco", "reference", "fast"]
"""The engines by the names the command line uses (``--engine``)."""


class Engine(Protocol):
    """A batch of runs of the rig at a fixed step (``run_batch`` picks one by name)."""

    def __call__(
        self,
        params: RigParams | Sequence[RigParams] = ...,
        phi0_rad: ArrayLike = ...,
        omega0_rad_s: ArrayLike = ...,
        duration_s: float = ...,
        dt_s: float = ...,
        *,
        drive: Drive | Sequence[Drive | None] | None = ...,
    ) -> Trajectory:
        """Run nbatch members from their start states.

        Args:
          params: one RigParams for every run, or a sequence of nbatch of them.
          phi0_rad: (2,) or (nbatch, 2) start angles, rad.
          omega0_rad_s: (2,) or (nbatch, 2) start angular velocities, rad/s.
          duration_s: simulated time, s.
          dt_s: the fixed step, s.
          drive: one Drive for every run, one per run, or None (``pendsim_mj.rig.drives``): hinge
            torques and support accelerations: at each RK4 stage's time in the planar engines
            (fourth order), held over a step at its midpoint value in MuJoCo (second order).

        Returns:
          A batch Trajectory: arrays of shape (nbatch, n, ...), n = steps + 1, t = 0 first;
          ``.member(i)`` gives one run.

        Raises:
          ParameterError: bad arguments.
          SimulationDiverged: a run became non-finite, or its energy grew without any input.
        """
        ...
