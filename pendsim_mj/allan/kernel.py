"""The overlapping Allan deviation's sums, compiled by numba (``pendsim_mj.allan.deviation`` imports this
module only when it computes: numba and its compiled code stay out of a process until needed).
The deviations release the GIL: a caller's thread goes on (imports, plots) while they run, and
``deviation.adev_of_phase`` spreads the taus over threads of its own, each calling
``oadev_serial`` (no ``parallel=True`` kernel: numba took 4-6 s of CPU to compile one, against
about 1 s for the serial kernel, on a first run whose target is 8 s)."""

from __future__ import annotations

import math

import numba
import numpy as np

from pendsim_mj import compile_notice

compile_notice.watch()  # the cache folder; one line on a cold compile (the CLI prints it)


@numba.njit(cache=True)
def _oadev_at(x: np.ndarray, k: int, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """The deviation at lag k for each column of the phase x (n+1, a), into out (a,) (scalar
    square roots, not an array expression: numba compiles this in a fraction of the time, and
    sqrt is correctly rounded either way)."""
    n1, a = x.shape
    rows = n1 - 2 * k
    if a == 6:
        total = _sums_at_six(x, k)
    else:
        total = np.zeros(a)
        for i in range(rows):
            for j in range(a):
                d = x[i + 2 * k, j] - 2.0 * x[i + k, j] + x[i, j]
                total[j] += d * d
    scale = 2.0 * k * k * rows
    for j in range(a):
        out[j] = math.sqrt(total[j] / scale)


@numba.njit(cache=True)
def _sums_at_six(x: np.ndarray, k: int) -> np.ndarray:  # pragma: no cover - compiled
    """``_oadev_at``'s sums of squared second differences for six columns (a node's
    accelerometer and gyro), each in a scalar: 1.8x faster than the loop over a column array (the
    sums stay in registers), the same additions in the same order (equal bit for bit)."""
    t0 = t1 = t2 = t3 = t4 = t5 = 0.0
    for i in range(x.shape[0] - 2 * k):
        p, q = i + k, i + 2 * k
        d0 = x[q, 0] - 2.0 * x[p, 0] + x[i, 0]
        d1 = x[q, 1] - 2.0 * x[p, 1] + x[i, 1]
        d2 = x[q, 2] - 2.0 * x[p, 2] + x[i, 2]
        d3 = x[q, 3] - 2.0 * x[p, 3] + x[i, 3]
        d4 = x[q, 4] - 2.0 * x[p, 4] + x[i, 4]
        d5 = x[q, 5] - 2.0 * x[p, 5] + x[i, 5]
        t0 += d0 * d0
        t1 += d1 * d1
        t2 += d2 * d2
        t3 += d3 * d3
        t4 += d4 * d4
        t5 += d5 * d5
    return np.array([t0, t1, t2, t3, t4, t5])


@numba.njit(cache=True, nogil=True)
def oadev_serial(x: np.ndarray, m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """sqrt(sum d^2 / (2 m^2 (n+1-2m))) per column of the phase x (n+1, a), d its second
    difference at lag m; (len(m), a). Phase in units of samples: the caller's units cancel."""
    out = np.empty((len(m), x.shape[1]))
    for t in range(len(m)):
        _oadev_at(x, m[t], out[t])
    return out


@numba.njit(cache=True, nogil=True)
def running_sum_into(x: np.ndarray, first: int, block: np.ndarray, mean: np.ndarray) -> None:  # pragma: no cover
    """x[i + 1, first + j] = x[i, first + j] + (block[i, j] - mean[j]) for the columns of block
    (n, k) (any float dtype, summed in float64), x[0] left as it is: ``pendsim_mj.allan.deviation.phase``
    in one pass over the data (numpy needed a float64 copy of the data and a strided cumsum,
    0.32 s for a 6 h node against 0.02 s here), the same additions in the same order."""
    n, k = block.shape
    total = np.empty(k)
    for j in range(k):
        total[j] = x[0, first + j]
    for i in range(n):
        for j in range(k):
            total[j] += np.float64(block[i, j]) - mean[j]
            x[i + 1, first + j] = total[j]


def warm_up() -> None:
    """Call every kernel once on a few samples, in the forms the Allan report uses (float32 and
    float64 data, C-ordered): numba's first call in a process loads its compiled code. A caller
    that must not lose Ctrl-C meanwhile holds interrupts back around this call
    (the bridge's ``signals.interrupts_deferred``: numba's callbacks would swallow them)."""
    x = np.zeros((9, 6))
    running_sum_into(x, 0, np.zeros((8, 3), np.float32), np.zeros(3))
    running_sum_into(x, 3, np.zeros((8, 3)), np.zeros(3))
    oadev_serial(x, np.ones(1, np.int64))
