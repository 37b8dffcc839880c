"""The overlapping Allan deviation's sums, compiled by numba (``pendsim_mj.allan`` imports this
module only when it computes: numba and its compiled code stay out of a process until needed)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _oadev_at(x: np.ndarray, k: int) -> np.ndarray:  # pragma: no cover - compiled
    """The deviation at lag k for each column of the phase x (n+1, a); (a,)."""
    n1, a = x.shape
    rows = n1 - 2 * k
    total = np.zeros(a)
    for i in range(rows):
        for j in range(a):
            d = x[i + 2 * k, j] - 2.0 * x[i + k, j] + x[i, j]
            total[j] += d * d
    return np.sqrt(total / (2.0 * k * k * rows))


@numba.njit(cache=True, parallel=True)
def oadev_parallel(x: np.ndarray, m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """``oadev_serial`` with the taus spread over numba's threads (each tau summed in one thread,
    in the same order: the results equal the serial ones bit for bit)."""
    out = np.empty((len(m), x.shape[1]))
    for t in numba.prange(len(m)):
        out[t] = _oadev_at(x, m[t])
    return out


@numba.njit(cache=True)
def oadev_serial(x: np.ndarray, m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """sqrt(sum d^2 / (2 m^2 (n+1-2m))) per column of the phase x (n+1, a), d its second
    difference at lag m; (len(m), a). Phase in units of samples: the caller's units cancel."""
    out = np.empty((len(m), x.shape[1]))
    for t in range(len(m)):
        out[t] = _oadev_at(x, m[t])
    return out
