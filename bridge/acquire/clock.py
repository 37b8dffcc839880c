"""Clock quality of an acquisition: the delay of each packet beyond the fitted clock map and its
summary. The map itself is ``pendsim_mj.estimation.timing.ClockFit`` (the lower-envelope fit that network
jitter does not move), the same one validation uses on recorded stamps; the relation a recording
keeps is read back by ``pendsim_bridge.io.measured.recorded_stamp_clock``."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.estimation.timing import MAX_DRIFT_PPM, ClockFit, ClockRelation

__all__ = ["MAX_DRIFT_PPM", "ClockFit", "ClockRelation", "jitter_summary_ms", "residuals_s"]


def residuals_s(
    relation: ClockRelation, device_s: NDArray[np.float64], arrival_s: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Arrival time minus the mapped device time (s): the delay beyond the fitted minimum."""
    return np.asarray(arrival_s) - np.asarray(relation.to_recorder(device_s))


def jitter_summary_ms(residual_s: NDArray[np.float64]) -> tuple[float, float]:
    """(median, 99th percentile) of the residual delays, ms (NaN for no points)."""
    if len(residual_s) == 0:
        return math.nan, math.nan
    p50, p99 = np.percentile(residual_s, [50, 99])
    return float(p50) * 1e3, float(p99) * 1e3
