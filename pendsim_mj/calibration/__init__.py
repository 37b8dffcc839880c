"""Calibration: the rig's physical parameters learnt from its recordings (docs/calibration.md).

Modules and their jobs:

- ``parameters``: the free parameters in relative units around the stated rig, the planar
  model's force-law constants as their functions, and the ratios a gyro sees (``QUANTITIES``).
- ``information``: what the recordings determine: the Fisher information about the free
  parameters, its eigen-directions and intervals, and a quantity's bias from the held ones.
- ``fit``: the joint fit of several recordings (``calibrate``, ``CalibrationRun``,
  ``Calibration``).
- ``design``: which further recording would determine best what is left open.
- ``spatial``: the same on the spatial model, the support's tilt fitted with the rig
  (``calibrate_spatial``, ``SpatialRun``).

Importing this package imports none of them (no numba or scipy): each name below is imported
from its module on first use (``pendsim_mj.lazy``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy

_LAZY = {
    "Calibration": "pendsim_mj.calibration.fit",
    "CalibrationRun": "pendsim_mj.calibration.fit",
    "Determination": "pendsim_mj.calibration.fit",
    "calibrate": "pendsim_mj.calibration.fit",
    "DEFAULT_FREE": "pendsim_mj.calibration.parameters",
    "PLANAR_PARAMETERS": "pendsim_mj.calibration.parameters",
    "QUANTITIES": "pendsim_mj.calibration.parameters",
    "SPATIAL_PARAMETERS": "pendsim_mj.calibration.parameters",
    "SpatialRun": "pendsim_mj.calibration.spatial",
    "calibrate_spatial": "pendsim_mj.calibration.spatial",
}

if TYPE_CHECKING:
    from pendsim_mj.calibration.fit import Calibration, CalibrationRun, Determination, calibrate
    from pendsim_mj.calibration.parameters import DEFAULT_FREE, PLANAR_PARAMETERS, QUANTITIES, SPATIAL_PARAMETERS
    from pendsim_mj.calibration.spatial import SpatialRun, calibrate_spatial
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = [
    "DEFAULT_FREE",
    "PLANAR_PARAMETERS",
    "QUANTITIES",
    "SPATIAL_PARAMETERS",
    "Calibration",
    "CalibrationRun",
    "Determination",
    "SpatialRun",
    "calibrate",
    "calibrate_spatial",
]
