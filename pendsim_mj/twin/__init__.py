"""The live twin: the rig's state estimated from its nodes as they arrive (issue 25; the
estimator so far, without health monitoring or drifting parameters).

- ``estimator``: ``RigEstimator``, an unscented Kalman filter on the planar model (sigma points
  advanced by the fast engine's force law, exact linear update with each node's swing angle and
  hinge rate), its innovations and their normalised squares (``Update``).

Importing this package imports nothing heavy (the estimator loads on first use).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy

_LAZY = {
    "RigEstimator": "pendsim_mj.twin.estimator",
    "StaleSample": "pendsim_mj.twin.estimator",
    "Update": "pendsim_mj.twin.estimator",
}

if TYPE_CHECKING:
    from pendsim_mj.twin.estimator import RigEstimator, StaleSample, Update
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = ["RigEstimator", "StaleSample", "Update"]
