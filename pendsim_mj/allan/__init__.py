"""Allan deviation of static IMU records (IEEE 952).

Modules and their jobs:

- ``deviation``: the overlapping Allan deviation of each axis on a log-spaced tau grid with
  confidence intervals (``allan_curves``, ``AllanCurve``), the noise terms read from a curve
  (``noise_terms``, ``NoiseTerms``: white noise N, bias instability B, rate random walk K), the
  record's sampling (``check_sampling``, ``SamplingReport``), motion in a record that should be
  static (``gyro_motion``, ``Motion``) and the longest uniform stretch to analyse.
- ``kernel``: the deviations' sums compiled by numba (imported only when they run).

Importing this package imports none of them (no numba, scipy or allantools): each name below is
imported from its module on first use (``pendsim_mj.lazy``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy

_LAZY = {
    "AllanCurve": "pendsim_mj.allan.deviation",
    "Motion": "pendsim_mj.allan.deviation",
    "NoiseTerms": "pendsim_mj.allan.deviation",
    "SamplingReport": "pendsim_mj.allan.deviation",
    "allan_curves": "pendsim_mj.allan.deviation",
    "check_sampling": "pendsim_mj.allan.deviation",
    "gyro_motion": "pendsim_mj.allan.deviation",
    "longest_uniform_segment": "pendsim_mj.allan.deviation",
    "noise_terms": "pendsim_mj.allan.deviation",
    "overlapping_adev": "pendsim_mj.allan.deviation",
    "tau_grid": "pendsim_mj.allan.deviation",
}

if TYPE_CHECKING:
    from pendsim_mj.allan.deviation import (
        AllanCurve,
        Motion,
        NoiseTerms,
        SamplingReport,
        allan_curves,
        check_sampling,
        gyro_motion,
        longest_uniform_segment,
        noise_terms,
        overlapping_adev,
        tau_grid,
    )
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = [
    "AllanCurve",
    "Motion",
    "NoiseTerms",
    "SamplingReport",
    "allan_curves",
    "check_sampling",
    "gyro_motion",
    "longest_uniform_segment",
    "noise_terms",
    "overlapping_adev",
    "tau_grid",
]
