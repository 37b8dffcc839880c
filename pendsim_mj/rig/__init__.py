"""The rig itself: its physical parameters, the drives, and the MuJoCo model built from the MJCF.

- ``params``: ``RigParams`` (one frozen object, every field with unit and source; ``describe()``
  lists them), ``DEFAULT_PARAMS`` (the paper's rig), ``PARAMETER_LIMITS`` (the allowed range of
  each field, SI);
- ``drives``: ``Drive`` (one optional signal per target: ``torque_m1``, ``torque_m2`` in N m,
  ``support_x``, ``pivot_z`` in m/s^2) and its signals ``Sine``, ``SteppedSine``, ``Chirp``,
  ``TimeSeries`` (``read_time_series_csv``), ``Sampling`` (how an RK4 step sees the drive: at its
  stage times, fourth order, or held over the step as MuJoCo); imports no physics engine;
- ``model``: ``build_model`` (an ``mujoco.MjModel`` of the rig for a ``RigParams``), the
  variants ``PLANAR`` and ``SPATIAL``, ``Clamp``, the MJCF files; imports MuJoCo;
- ``checks`` (argument checks of the engines), ``mjcf_guard`` (MJCF from a recording, checked
  before MuJoCo sees it), ``mujoco_warnings`` (MuJoCo's warnings captured): internal.

Importing this package imports the parameters and drives; the model's names import MuJoCo when
first used (``pendsim_mj.lazy``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy
from pendsim_mj.rig.drives import (
    CHANNEL_LABELS,
    Chirp,
    Drive,
    Sampling,
    Signal,
    Sine,
    SteppedSine,
    Target,
    TimeSeries,
    read_time_series_csv,
)
from pendsim_mj.rig.params import DEFAULT_PARAMS, FIELD_NAMES, PARAMETER_LIMITS, RigParams

_LAZY = {
    "PENDULUMS_XML": "pendsim_mj.rig.model",
    "PLANAR": "pendsim_mj.rig.model",
    "SCENE_XML": "pendsim_mj.rig.model",
    "SPATIAL": "pendsim_mj.rig.model",
    "Clamp": "pendsim_mj.rig.model",
    "Variant": "pendsim_mj.rig.model",
    "build_model": "pendsim_mj.rig.model",
    "build_spec": "pendsim_mj.rig.model",
    "exact_mjcf": "pendsim_mj.rig.model",
}

if TYPE_CHECKING:
    from pendsim_mj.rig.model import (
        PENDULUMS_XML,
        PLANAR,
        SCENE_XML,
        SPATIAL,
        Clamp,
        Variant,
        build_model,
        build_spec,
        exact_mjcf,
    )
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = [
    "CHANNEL_LABELS",
    "DEFAULT_PARAMS",
    "FIELD_NAMES",
    "PARAMETER_LIMITS",
    "PENDULUMS_XML",
    "PLANAR",
    "SCENE_XML",
    "SPATIAL",
    "Chirp",
    "Clamp",
    "Drive",
    "RigParams",
    "Sampling",
    "Signal",
    "Sine",
    "SteppedSine",
    "Target",
    "TimeSeries",
    "Variant",
    "build_model",
    "build_spec",
    "exact_mjcf",
    "read_time_series_csv",
]
