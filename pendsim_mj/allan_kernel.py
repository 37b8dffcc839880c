"""The overlapping Allan deviation's sums, compiled by numba (``pendsim_mj.allan`` imports this
module only when it computes: numba and its compiled code stay out of a process until needed)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, parallel=True)
def oadev_parallel(x: np.ndarray, m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """``oadev_serial`` with the taus spread over numba's threads (each tau summed in one thread,
    in the same order: the results equal the serial ones bit for bit)."""
    n1, a = x.shape
    out = np.empty((len(m), a))
    for t in numba.prange(len(m)):
        k = m[t]
        rows = n1 - 2 * k
        total = np.zeros(a)
        for i in range(rows):
            for j in range(a):
                d = x[i + 2 * k, j] - 2.0 * x[i + k, j] + x[i, j]
                total[j] += d * d
        for j in range(a):
            out[t, j] = np.sqrt(total[j] / (2.0 * k * k * rows))
    return out


@numba.njit(cache=True)
def oadev_serial(x: np.ndarray, m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """sqrt(sum d^2 / (2 m^2 (n+1-2m))) per column of the phase x (n+1, a), d its second
    difference at lag m; (len(m), a). Phase in units of samples: the caller's units cancel."""
    n1, a = x.shape
    out = np.empty((len(m), a))
    for t in range(len(m)):
        k = m[t]
        rows = n1 - 2 * k
        total = np.zeros(a)
        for i in range(rows):
            for j in range(a):
                d = x[i + 2 * k, j] - 2.0 * x[i + k, j] + x[i, j]
                total[j] += d * d
        for j in range(a):
            out[t, j] = np.sqrt(total[j] / (2.0 * k * k * rows))
    return out
