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
use. None imports MuJoCo.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

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

_HOME = {
    "MIN_MOTION_RAD_S": "bno055",
    "Bno055": "bno055",
    "ImuNoise": "bno055",
    "ImuSampler": "bno055",
    "ImuSamples": "bno055",
    "sample_imu": "bno055",
    "static_imu": "bno055",
    "Imperfections": "imperfections",
    "axis_remap_matrix": "imperfections",
    "random_mount": "imperfections",
}

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


def __getattr__(name: str) -> Any:
    """A public name, imported from its module on first use (PEP 562) and kept here."""
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_HOME[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
