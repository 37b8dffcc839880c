"""The Ljung-Box whiteness test of a series that never ends: the live twin's normalised innovations
over a run of any length, in constant memory.

``Whiteness.add(value)`` keeps the running sums the test needs: the count, the sum, the sum of
products at each lag 1..L, and the first and last L values. From them the centred
autocorrelations are exact (the same numbers, to rounding, as the whole series through
``estimation.planar_fit.ljung_box_p``), so a ten-hour live run costs a few hundred bytes, not its
millions of values.

The autocovariance at lag k of n values x with mean m, as ``ljung_box_p`` computes it:
  sum_{t=k}^{n-1} (x_t - m)(x_{t-k} - m) = S_k - m (A_k + B_k) + (n - k) m^2,
with S_k the sum of x_t x_{t-k}, A_k the sum of all but the first k values and B_k the sum of all
but the last k (the total minus the kept first and last values).
"""

from __future__ import annotations

import collections
import math

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from pendsim_mj.estimation.planar_fit import LJUNG_BOX_LAGS

Floats = NDArray[np.float64]
MIN_VALUES = 200  # fewer: no p-value (NaN)
BLOCK = 64  # values taken into the sums at once


class Whiteness:
    """Running Ljung-Box sums of one series (``lags`` lags, the same as identify's residuals').

    Values are taken in blocks of ``BLOCK``: ``add`` keeps a value in a short list, and each full
    block goes into the sums in a few vectorised products (a value at a time, numpy's calls cost
    about 4 us each; the twin adds four per sample)."""

    def __init__(self, lags: int = LJUNG_BOX_LAGS) -> None:
        self.lags = int(lags)
        self._taken = 0  # values in the sums
        self._sum = 0.0
        self._products = np.zeros(self.lags + 1)  # lag 0 .. lags
        self._first: list[float] = []
        self._last: collections.deque[float] = collections.deque(maxlen=self.lags)
        self._block: list[float] = []  # values not yet in the sums (fewer than BLOCK)

    @property
    def count(self) -> int:
        """How many values were taken (finite ones)."""
        return self._taken + len(self._block)

    def add(self, value: float) -> None:
        """The next value of the series (a finite number; others are ignored)."""
        v = float(value)
        if not math.isfinite(v):
            return
        block = self._block
        block.append(v)
        if len(block) == BLOCK:
            self._take()

    def _take(self) -> None:
        """The kept block into the sums: each lag's products over the block, with the last
        ``lags`` values before it."""
        block = self._block
        if not block:
            return
        before = list(self._last)
        values = np.array(before + block)
        new = values[len(before) :]
        for k in range(min(self.lags, len(values) - 1) + 1):
            lo = max(len(before) - k, 0)  # the first lagged value that exists
            self._products[k] += float(new[lo - len(before) + k :] @ values[lo : len(values) - k])
        self._sum += float(new.sum())
        need = self.lags - len(self._first)
        if need > 0:
            self._first += block[:need]
        self._last.extend(block[-self.lags :])
        self._taken += len(block)
        self._block = []

    def autocorrelation(self) -> Floats:
        """(lags,) the centred autocorrelations at lags 1..lags (NaN where too few values)."""
        self._take()
        n = self.count
        out = np.full(self.lags, math.nan)
        if n < 2:
            return out
        m = self._sum / n
        first, last = np.array(self._first), np.array(self._last)
        acov = np.empty(self.lags + 1)
        for k in range(self.lags + 1):
            if k >= n:
                acov[k] = math.nan
                continue
            a = self._sum - float(first[:k].sum())  # x_k .. x_{n-1}
            b = self._sum - float(last[len(last) - k :].sum()) if k else self._sum  # x_0 .. x_{n-1-k}
            acov[k] = self._products[k] - m * (a + b) + (n - k) * m * m
        if not acov[0] > 0:
            return out
        return acov[1:] / acov[0]

    def p_value(self) -> float:
        """The Ljung-Box p-value (NaN: fewer than ``MIN_VALUES`` values)."""
        n = self.count
        if n < max(MIN_VALUES, self.lags + 2):
            return math.nan
        rho = self.autocorrelation()
        q = n * (n + 2) * float(np.sum(rho * rho / (n - np.arange(1, self.lags + 1))))
        return float(stats.chi2.sf(q, self.lags))
