"""Clock quality of an acquisition: the delay of each packet beyond the fitted clock map and its
summary. The map itself is ``pendsim_mj.estimation.timing.ClockFit`` (the lower-envelope fit that network
jitter does not move), the same one validation uses on recorded stamps."""

from __future__ import annotations

import json
import math

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.estimation.timing import MAX_DRIFT_PPM, ClockFit, ClockRelation

__all__ = ["MAX_DRIFT_PPM", "ClockFit", "ClockRelation", "jitter_summary_ms", "recorded_stamp_clock", "residuals_s"]


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


def recorded_stamp_clock(metadata: dict[str, dict[str, str]], node: str, start_time_ns: int) -> ClockRelation | None:
    """The clock relation ``pendsim acquire`` fitted over every packet's arrival, from a node's
    header stamps to its log times (both s since the recording's ``start_time_ns``), as its
    metadata keeps it (``pendsim/acquisition_result``, ``NODE.stamp_clock``); None when absent or
    unreadable (another recorder, a restarted node): then the stamps are fitted to the log times."""
    text = metadata.get("pendsim/acquisition_result", {}).get(f"{node}.stamp_clock")
    start = metadata.get("pendsim/acquisition", {}).get("start_time_ns", "")
    if text is None or not start.isdigit():
        return None
    try:
        value = json.loads(text)
        offset_s, rate, stamp0_s = (float(value[k]) for k in ("offset_s", "rate", "stamp0_s"))
    except (ValueError, TypeError, KeyError):
        return None
    if not all(map(math.isfinite, (offset_s, rate, stamp0_s))) or abs(rate - 1.0) > MAX_DRIFT_PPM * 2e-6:
        return None
    shift_s = (int(start) - start_time_ns) * 1e-9  # acquisition start on the recording's time axis
    return ClockRelation(offset_s + shift_s, rate, stamp0_s + shift_s)
