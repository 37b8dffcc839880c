"""Time in two units, converted in one place: recordings and clocks count integer nanoseconds
(MCAP log times, ROS 2 stamps, ``time.monotonic_ns``), the physics counts float seconds.

``seconds`` multiplies by 1e-9 (the form every caller used, so results keep their bits);
``nanoseconds`` rounds to the nearest nanosecond (half to even, as ``round`` and ``np.rint``).
"""

from __future__ import annotations

from typing import Final, overload

import numpy as np
from numpy.typing import NDArray

NS_PER_S: Final = 1_000_000_000
"""Nanoseconds in a second."""


@overload
def seconds(t_ns: int | float) -> float: ...
@overload
def seconds(t_ns: NDArray[np.integer] | NDArray[np.float64]) -> NDArray[np.float64]: ...
def seconds(t_ns: int | float | NDArray[np.integer] | NDArray[np.float64]) -> float | NDArray[np.float64]:
    """Nanoseconds (int, float, or an array of integers or float64) in seconds: a float, or an
    array of float64."""
    if isinstance(t_ns, np.ndarray):
        in_s: NDArray[np.float64] = np.multiply(t_ns, 1e-9)
        return in_s
    return float(t_ns * 1e-9)


@overload
def nanoseconds(t_s: float) -> int: ...
@overload
def nanoseconds(t_s: NDArray[np.floating]) -> NDArray[np.int64]: ...
def nanoseconds(t_s: float | NDArray[np.floating]) -> int | NDArray[np.int64]:
    """Seconds (float or array) in whole nanoseconds, rounded to the nearest (array: int64)."""
    if isinstance(t_s, np.ndarray):
        in_ns: NDArray[np.int64] = np.rint(t_s * 1e9).astype(np.int64)
        return in_ns
    return round(t_s * 1e9)


def split_ns(t_ns: int) -> tuple[int, int]:
    """Nanoseconds as (whole seconds, nanoseconds 0..1e9-1), as ROS 2 stamps hold them."""
    sec, nanosec = divmod(int(t_ns), NS_PER_S)
    return sec, nanosec
