"""The unscented filter's arithmetic, compiled: Merwe's scaled sigma points of an estimate, the
predicted measurement's moments over them, and the gain's correction. The filter (``estimator``)
draws sigma points two or three times per node sample and updates once or twice; numpy's
per-call overhead on a 16-state estimate (a Cholesky factor and its scaling, weighted sums, small
solves) was 90 us of each draw and about as much per update, most of the twin's cost.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from pendsim_mj import compile_notice

Floats = NDArray[np.float64]
JITTER = 1e-12  # relative to each variance (an absolute one would add a random walk to every parameter)

compile_notice.watch()  # the cache folder; one line on a cold compile (the CLI prints it)


@numba.njit(cache=True)
def sigma_points(x: Floats, p: Floats, scale: float, out: Floats) -> None:
    """The 2n + 1 points of the estimate x (n,) with covariance p (n, n) into out (2n + 1, n): x,
    then x + and x - each column of the lower Cholesky factor of scale p. The factor is taken of
    the correlation matrix with ``JITTER`` on its diagonal and scaled back by the standard
    deviations (a variance near 0, a parameter held, stays near 0 instead of being floored)."""
    n = x.shape[0]
    d = np.empty(n)
    for i in range(n):
        d[i] = math.sqrt(max(scale * p[i, i], 1e-300))
    c = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            c[i, j] = scale * p[i, j] / (d[i] * d[j])
        c[i, i] += JITTER
    root = np.linalg.cholesky(c)
    for j in range(n):
        out[0, j] = x[j]
    for i in range(n):  # the i-th column of the scaled factor
        for j in range(n):
            v = root[j, i] * d[j]
            out[1 + i, j] = x[j] + v
            out[1 + n + i, j] = x[j] - v


@numba.njit(cache=True)
def moments(points: Floats, x: Floats, zs: Floats, wm: Floats, wc: Floats, r: Floats) -> tuple[Floats, Floats, Floats]:
    """The predicted measurement over the sigma points (m, n) with their measurements zs (m, k):
    its mean (k,), its covariance with the noise r (k, k) added, and its cross covariance with the
    state (n, k) about the estimate x (n,); weights wm, wc (m,)."""
    m, n = points.shape
    k = zs.shape[1]
    mean = np.zeros(k)
    for i in range(m):
        for a in range(k):
            mean[a] += wm[i] * zs[i, a]
    s = r.copy()
    pxz = np.zeros((n, k))
    for i in range(m):
        w = wc[i]
        for a in range(k):
            da = zs[i, a] - mean[a]
            for b in range(k):
                s[a, b] += w * da * (zs[i, b] - mean[b])
            for j in range(n):
                pxz[j, a] += w * (points[i, j] - x[j]) * da
    return mean, s, pxz


@numba.njit(cache=True)
def correct(x: Floats, p: Floats, s: Floats, pxz: Floats, nu: Floats) -> None:
    """The update in place: gain K = pxz s^-1, x += K nu, p -= K s K' (kept symmetric)."""
    n = x.shape[0]
    gain = pxz @ np.linalg.inv(s)
    x += gain @ nu
    p -= gain @ s @ gain.T
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (p[i, j] + p[j, i])
            p[i, j] = v
            p[j, i] = v
