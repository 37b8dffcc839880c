"""The rig's BNO055 nodes, simulated from a run.

Modules and their jobs:

- ``bno055``: the sensor model (``Bno055`` configuration, ``ImuNoise`` sigmas): 80 Hz samples of
  the 100 Hz fused values, noise, bias processes, clipping and quantisation, from a whole run
  (``sample_imu``), a static record (``static_imu``) or a run simulated block by block
  (``ImuSampler``); ``ImuSamples`` holds both nodes' outputs.
- ``imperfections``: what real nodes on a hand-built rig add (``Imperfections``: heading, mount,
  axis remap, fusion error and phase, packet loss, clocks, hand wobble), all off by default.
- ``rotations``: quaternion helpers (w, x, y, z), vectorised.

Importing this package imports none of them (``engines.trajectory`` imports ``rotations``, and
``bno055`` imports ``engines.trajectory``): each name below is imported from its module on first
use (``pendsim_mj.lazy``). None imports MuJoCo.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy

_LAZY = {
    "MIN_MOTION_RAD_S": "pendsim_mj.sensors.bno055",
    "Bno055": "pendsim_mj.sensors.bno055",
    "ImuNoise": "pendsim_mj.sensors.bno055",
    "ImuSampler": "pendsim_mj.sensors.bno055",
    "ImuSamples": "pendsim_mj.sensors.bno055",
    "sample_imu": "pendsim_mj.sensors.bno055",
    "static_imu": "pendsim_mj.sensors.bno055",
    "Imperfections": "pendsim_mj.sensors.imperfections",
    "axis_remap_matrix": "pendsim_mj.sensors.imperfections",
    "random_mount": "pendsim_mj.sensors.imperfections",
}

if TYPE_CHECKING:
    from pendsim_mj.sensors.bno055 import (
        MIN_MOTION_RAD_S,
        Bno055,
        ImuNoise,
        ImuSampler,
        ImuSamples,
        sample_imu,
        static_imu,
    )
    from pendsim_mj.sensors.imperfections import Imperfections, axis_remap_matrix, random_mount
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = [
    "MIN_MOTION_RAD_S",
    "Bno055",
    "Imperfections",
    "ImuNoise",
    "ImuSampler",
    "ImuSamples",
    "axis_remap_matrix",
    "random_mount",
    "sample_imu",
    "static_imu",
]
