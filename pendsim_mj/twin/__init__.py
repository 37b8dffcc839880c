"""The live twin: the rig's state estimated from its nodes as they arrive, and its health (issue
25; ``pendsim twin`` runs it: ``bridge.acquire.twin``).

- ``estimator``: ``RigEstimator``, an unscented Kalman filter on the planar model (sigma points
  advanced by the fast engine's force law, exact linear update with each node's swing angle and
  hinge rate), its innovations and their normalised squares (``Update``), and the parameters it
  can track as random walks with their intervals (``TRACKABLE``: damping, dry friction, the
  coupling springs, each node's mount offset), and ``forecast`` (the motion over the next seconds
  with its uncertainty).
- ``measurement``: ``NodeMeasurement``, one node's samples turned into the estimator's
  measurements on real node data: each value's instant from the chip's fusion phase (learned from
  the gyro's smoothness, tracked as it drifts), the swing angle and hinge rate in the node's swing
  frame (learned from a second of swinging: heading, mount, axis remap), ``NodeSample`` or
  ``Waiting`` with the reason, and what it learned (``Learned``).
- ``health``: ``HealthMonitor``, detects a change by the likelihood ratio of one tracked parameter
  changed, and attributes it by a bank of filters, one per hypothesis, over the data that follow
  (``Alarm``: which parameter, what it means on the rig, since when, by how much, against what).
- ``walks``: ``AdaptiveWalks``, the rig's parameters' random walks slow while the rig looks healthy
  (white innovations) and fast from a suspicion of a change on (the monitor's speed and attribution).
- ``whiteness``: ``Whiteness``, the Ljung-Box test of a series that never ends (the innovations of
  a live run of any length) from running sums, in constant memory.
- ``merge``, ``session``, ``outputs``: both nodes in one time order, the twin sample by sample, what
  it puts out.

Importing this package imports nothing heavy (the estimator loads on first use).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy

_LAZY = {
    "Alarm": "pendsim_mj.twin.health",
    "HealthMonitor": "pendsim_mj.twin.health",
    "Learned": "pendsim_mj.twin.measurement",
    "NodeMeasurement": "pendsim_mj.twin.measurement",
    "NodeSample": "pendsim_mj.twin.measurement",
    "Waiting": "pendsim_mj.twin.measurement",
    "TRACKABLE": "pendsim_mj.twin.estimator",
    "Forecast": "pendsim_mj.twin.estimator",
    "RigEstimator": "pendsim_mj.twin.estimator",
    "Sample": "pendsim_mj.twin.estimator",
    "StaleSample": "pendsim_mj.twin.estimator",
    "Update": "pendsim_mj.twin.estimator",
    "Whiteness": "pendsim_mj.twin.whiteness",
}

if TYPE_CHECKING:
    from pendsim_mj.twin.estimator import TRACKABLE, Forecast, RigEstimator, Sample, StaleSample, Update
    from pendsim_mj.twin.health import Alarm, HealthMonitor
    from pendsim_mj.twin.measurement import Learned, NodeMeasurement, NodeSample, Waiting
    from pendsim_mj.twin.whiteness import Whiteness
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = [
    "TRACKABLE",
    "Alarm",
    "Forecast",
    "HealthMonitor",
    "Learned",
    "NodeMeasurement",
    "NodeSample",
    "RigEstimator",
    "Sample",
    "StaleSample",
    "Update",
    "Waiting",
    "Whiteness",
]
