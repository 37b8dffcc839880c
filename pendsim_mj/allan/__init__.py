"""Allan deviation of static IMU records (IEEE 952).

Modules and their jobs:

- ``deviation``: the overlapping Allan deviation of each axis on a log-spaced tau grid with
  confidence intervals (``allan_curves``, ``AllanCurve``), the noise terms read from a curve
  (``noise_terms``, ``NoiseTerms``: white noise N, bias instability B, rate random walk K), the
  record's sampling (``check_sampling``, ``SamplingReport``), motion in a record that should be
  static (``gyro_motion``, ``Motion``) and the longest uniform stretch to analyse.
- ``kernel``: the deviations' sums compiled by numba (imported only when they run).

Importing this package imports none of them (no numba, scipy or allantools): each name below is
imported from its module on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

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

_HOME = {
    "AllanCurve": "deviation",
    "Motion": "deviation",
    "NoiseTerms": "deviation",
    "SamplingReport": "deviation",
    "allan_curves": "deviation",
    "check_sampling": "deviation",
    "gyro_motion": "deviation",
    "longest_uniform_segment": "deviation",
    "noise_terms": "deviation",
    "overlapping_adev": "deviation",
    "tau_grid": "deviation",
}

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


def __getattr__(name: str) -> Any:
    """A public name, imported from its module on first use (PEP 562) and kept here."""
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_HOME[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
