"""The live twin: the rig's state estimated from its nodes as they arrive (issue 25; the
estimator so far: no change detection, command or live views yet).

- ``estimator``: ``RigEstimator``, an unscented Kalman filter on the planar model (sigma points
  advanced by the fast engine's force law, exact linear update with each node's swing angle and
  hinge rate), its innovations and their normalised squares (``Update``), and the parameters it
  can track as random walks with their intervals (``TRACKABLE``: damping, dry friction, the
  coupling springs, each node's mount offset).

Importing this package imports nothing heavy (the estimator loads on first use).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy

_LAZY = {
    "TRACKABLE": "pendsim_mj.twin.estimator",
    "RigEstimator": "pendsim_mj.twin.estimator",
    "StaleSample": "pendsim_mj.twin.estimator",
    "Update": "pendsim_mj.twin.estimator",
}

if TYPE_CHECKING:
    from pendsim_mj.twin.estimator import TRACKABLE, RigEstimator, StaleSample, Update
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = ["TRACKABLE", "RigEstimator", "StaleSample", "Update"]
