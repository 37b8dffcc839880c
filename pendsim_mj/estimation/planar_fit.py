"""Damping identification on the fast planar kernel: the hinge losses fitted together with the
start state, by scipy's least squares, with intervals that carry the start's uncertainty.

Model: the planar equations of ``fast_planar`` (viscous b_n and/or dry friction F_n at each hinge),
integrated by its compiled RK4 at ``FIT_DT_S``. Unknowns, fitted together:

- the hinge losses of the chosen law: "viscous" (b1, b2), "coulomb" (F1, F2) or "both";
- the start angles phi1_0, phi2_0; for a start in motion also omega1_0, omega2_0;
- for a release from rest, a small offset tau of the release instant (the model rests at phi_0
  until tau, then swings);
- where the alignment leaves the nodes' relative fusion timing open (``MeasuredRun``'s
  ``relative_timing_range_s``), the shift of M2's value instants against M1's, within that
  range: a 0.2 ms error of it biases b2 by a few per cent and reads as dry friction, and only
  the whole run pins it (to microseconds), the damping fitted with it.

Residuals: each node's gyro about its hinge minus the model's rate, in units of that node's noise
sigma, at the instants the chip's fused values belong to (``MeasuredRun``'s ``value_t_s``: a
node reports the latest 100 Hz fused value, 0-10 ms old; taking the sample instants instead put
b1 1.1 % off), lost samples (NaN) left out. The model's rate between steps is cubic Hermite
through omega and its exact derivative (the closed-form accelerations).

Jacobian: exact, from the compiled kernel (``fast_planar.normal_equations_at``): RK4 applied to
the variational equations alongside the state, i.e. the derivative of the discrete solution the
residuals use (central differences of it agree to O(step^2); the previous central-difference
Jacobian was off by up to 2e-4 relative in the friction columns); the release offset's column is
-alpha at the instants. One pass of one member per iteration, which sums each instant's row into
J^T J (P x P), J^T r and r.r as it goes: nothing n x P is kept (before: the whole Jacobian, about
250 MB at 6 h), so the fit's memory is that of the data and one residual vector (n) at the
optimum (BIC, Ljung-Box, rms: the rates alone, ``fast_planar.rates_at``). The sums run in the
instants' order, not BLAS's: equal to the explicit J^T J to rounding (tests: 1e-12 relative).

Drives: a driven run's inputs (``pendsim_mj.rig.drives``, its time 0 at the release: a shifted release
shifts the drive with it) enter each RK4 stage of the kernel at the stage's own time
(``drives.stage_inputs``: fourth order, as the fit's undriven model); the Jacobian stays exact
(the kernel with ``inputs``).

Intervals: covariance s^2 (J^T J)^-1 of the normalised residuals with s^2 = RSS/(n - P) (the
residual variance, so a misjudged noise sigma does not narrow them), 95 % half-widths
1.96 sqrt(diag). Their coverage is tested over seeded synthetic records (tests/estimation/test_planar_fit.py).

Law selection: BIC = n ln(RSS/n) + P ln n for each law; the smallest wins. Residual whiteness:
the Ljung-Box statistic of each node's residuals over ``LJUNG_BOX_LAGS`` lags and its p-value
(a small p: structure the model leaves unexplained).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy import optimize, stats

from pendsim_mj.engines import fast_planar
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.drives import Drive, stage_inputs
from pendsim_mj.rig.params import RigParams

Floats = NDArray[np.float64]

LAWS = ("viscous", "coulomb", "both")
LAW_CHOICES = ("auto", *LAWS)
FIT_DT_S = 0.01  # the recordings' MuJoCo step; the planar kernel equals MuJoCo at it to ~1e-14 rad
LJUNG_BOX_LAGS = 20
MAX_RELEASE_OFFSET_S = 0.05
BIC_RESOLUTION = 0.05  # the fits stop when an iteration moves the BIC by less (``fit_law``)
_DAMPING = {
    "viscous": ("b1_n_m_s", "b2_n_m_s"),
    "coulomb": ("friction1_n_m", "friction2_n_m"),
    "both": ("b1_n_m_s", "b2_n_m_s", "friction1_n_m", "friction2_n_m"),
}
_ROW = {name: fast_planar.COEFFICIENTS.index(name) for name in _DAMPING["both"]}
# the optimiser's scale of each kind of unknown
_SCALE = {"damping": 1e-3, "phi": 1e-2, "omega": 1e-2, "tau": 1e-3, "timing": 1e-4}


@dataclasses.dataclass(frozen=True)
class LawFit:
    """The least-squares fit of one damping law.

    Attributes:
      law: "viscous", "coulomb" or "both".
      names: the P unknowns: damping fields of RigParams, then "phi1_0", "phi2_0", ("omega1_0",
        "omega2_0"), ("release_offset_s"), ("timing2_s": the shift of M2's value instants).
      values: (P,) estimates (SI units: N m s/rad, N m, rad, rad/s, s).
      ci95: (P,) half-widths of the 95 % intervals.
      covariance: (P, P).
      residual_rms_sigma: rms residual in gyro noise sigmas (1: explained to the noise level).
      bic: n ln(RSS/n) + P ln n.
      ljung_box_p: (2,) whiteness p-value of each node's residuals.
      n_residuals: samples used (both nodes).
      iterations: Jacobian evaluations; seconds: wall time.
    """

    law: str
    names: tuple[str, ...]
    values: Floats
    ci95: Floats
    covariance: Floats
    residual_rms_sigma: float
    bic: float
    ljung_box_p: tuple[float, float]
    n_residuals: int
    iterations: int
    seconds: float

    def value(self, name: str) -> float:
        """An estimate by name, 0 for a damping term this law does not have."""
        return float(self.values[self.names.index(name)]) if name in self.names else 0.0

    def half_width(self, name: str) -> float:
        return float(self.ci95[self.names.index(name)]) if name in self.names else 0.0


@dataclasses.dataclass(frozen=True)
class _Data:
    at: tuple[Floats, Floats]  # each node's value instants since the start, s (finite only)
    gyro: tuple[Floats, Floats]  # its measured rate, rad/s
    sigma: Floats  # (2,)
    inputs: Floats | None = None  # (H, NSTAGE, NINPUT) at each step's stages from the release on, or None
    timing_range_s: tuple[float, float] | None = None  # M2's instants may shift within it, s (None: fixed)


class _Model:
    """The planar model of one law with its unknowns' layout."""

    def __init__(self, params: RigParams, law: str, moving: bool, data: _Data) -> None:
        self.data = data
        self.damping = _DAMPING[law]
        self.moving = moving
        names = [*self.damping, "phi1_0", "phi2_0"]
        kinds = ["damping"] * len(self.damping) + ["phi", "phi"]
        if moving:
            names += ["omega1_0", "omega2_0"]
            kinds += ["omega", "omega"]
        else:
            names.append("release_offset_s")
            kinds.append("tau")
        self.timed = data.timing_range_s is not None
        if self.timed:
            names.append("timing2_s")
            kinds.append("timing")
        self.names, self.kinds = tuple(names), tuple(kinds)
        base = fast_planar.coefficients([params])
        for name in _DAMPING["both"]:  # a law's absent terms are zero
            base[_ROW[name]] = 0.0
        self.coef = base

    def _start(self, x: Floats) -> tuple[Floats, Floats | tuple[float, float], float, tuple[Floats, Floats]]:
        """The kernel's arguments at x: coefficients, start rates, release instant, instants."""
        p = len(self.damping)
        coef = self.coef.copy()
        for j, name in enumerate(self.damping):
            coef[_ROW[name]] = x[j]
        omega0 = x[p + 2 : p + 4] if self.moving else (0.0, 0.0)
        release = 0.0 if self.moving else float(x[p + 2])
        at = (self.data.at[0], self.data.at[1] + x[-1]) if self.timed else self.data.at
        return coef, omega0, release, at

    def residuals(self, x: Floats) -> tuple[Floats, Floats]:
        """Each node's normalised residuals (rate - gyro) / sigma at x, (m1,), (m2,): the rates
        alone (no sensitivities), turned into residuals in place."""
        coef, omega0, release, at = self._start(x)
        p = len(self.damping)
        d = self.data
        rates, _, _ = fast_planar.rates_at(
            coef, x[p : p + 2], omega0, at, FIT_DT_S, release_s=release, inputs=d.inputs, slopes=False
        )
        for rate, gyro, sigma in zip(rates, d.gyro, d.sigma, strict=True):
            np.subtract(rate, gyro, out=rate)
            np.divide(rate, sigma, out=rate)
        return rates

    def normal_equations(self, x: Floats) -> tuple[Floats, Floats, float]:
        """J^T J (P, P), J^T r (P,) and r.r of the normalised residuals at x, summed in one kernel
        pass (``fast_planar.normal_equations_at``: no n x P Jacobian). J's columns: the unknowns
        the kernel rolls (damping, phi_0, omega_0), then the release offset (d rate / d tau), then
        M2's timing (0 for M1, alpha = -d rate / d tau for M2)."""
        rolled = tuple(name for name in self.names if name not in ("release_offset_s", "timing2_s"))
        coef, omega0, release, at = self._start(x)
        p = len(self.damping)
        d = self.data
        return fast_planar.normal_equations_at(
            coef, x[p : p + 2], omega0, at, d.gyro, d.sigma, FIT_DT_S, release_s=release, wrt=rolled,
            release_column=not self.moving, timing_column=self.timed, inputs=d.inputs,
        )  # fmt: skip

    def reduced(self, x: Floats) -> Floats:
        """The problem as scipy sees it, P + 1 residuals with the same cost, gradient and
        Gauss-Newton matrix as the n residuals: R with R^T R = J^T J (from the eigenvectors of
        J^T J, columns scaled to unit norm first), f~ = (R^-T J^T r, sqrt(r.r - |R^-T J^T r|^2)),
        J~ = (R; 0). J^T J, J^T r and r.r come summed from the kernel (``normal_equations``):
        neither the optimiser nor the model holds an n x P matrix (a 6 h record: n = 3.5 M).
        J~ is kept for ``reduced_jacobian`` at the same x."""
        jtj, jtr, rr = self.normal_equations(x)
        if not (np.all(np.isfinite(jtj)) and np.all(np.isfinite(jtr)) and math.isfinite(rr)):
            raise ParameterError("the planar model diverged during the damping fit (non-finite rates)")
        norm = np.sqrt(np.diag(jtj).copy())
        norm[norm == 0] = 1.0
        w, v = np.linalg.eigh(jtj / np.outer(norm, norm))
        root = np.sqrt(np.clip(w, 0.0, None))
        upper = (root[:, None] * v.T) * norm[None, :]  # upper^T upper = J^T J
        inverse = np.divide(1.0, root, out=np.zeros_like(root), where=root > 1e-12 * root.max())
        projected = inverse * (v.T @ (jtr / norm))
        rest = math.sqrt(max(rr - float(projected @ projected), 0.0))
        self._cached = (x.copy(), np.vstack([upper, np.zeros((1, len(x)))]))
        return np.append(projected, rest)

    def reduced_jacobian(self, x: Floats) -> Floats:
        cached = getattr(self, "_cached", None)
        if cached is None or not np.array_equal(cached[0], x):
            self.reduced(x)
        jac: Floats = self._cached[1]
        return jac


def ljung_box_p(residuals: Floats, lags: int = LJUNG_BOX_LAGS) -> float:
    """p-value of the Ljung-Box test that a series (n,) is white (over ``lags`` lags): the
    autocorrelations at lags 1..lags as direct sums (one centred copy of the series, no FFT:
    lags * n operations, memory n)."""
    r = np.asarray(residuals, dtype=float) - float(np.mean(residuals))
    n = len(r)
    if n <= lags + 1:
        return math.nan
    acov = np.array([float(r[: n - k] @ r[k:]) for k in range(lags + 1)])
    rho = acov[1:] / acov[0]
    q = n * (n + 2) * float(np.sum(rho * rho / (n - np.arange(1, lags + 1))))
    return float(stats.chi2.sf(q, lags))


def fit_law(
    params: RigParams,
    law: str,
    data: _Data,
    phi0_rad: Sequence[float] | Floats,
    omega0_rad_s: Sequence[float] | Floats,
    moving: bool,
    guess: dict[str, float] | None = None,
) -> LawFit:
    """One law's fit from the alignment's start state (see the module docstring); ``guess``:
    first values of any unknowns by name (default: the rig's b, friction 2e-4 N m, the start
    state given, no release offset).

    Stopping: the step is below 1e-8 of the scaled unknowns (in scaled units about 1-2 % of the
    smallest 95 % half-width, measured on 120 s and 1 h records), or an iteration lowered the
    cost by less than ``BIC_RESOLUTION / n`` of it: the BIC n ln(RSS/n) then moved by less
    than BIC_RESOLUTION, and the iterations left (converging at least linearly) would move it by
    about as much: far below the differences that choose a law (tens to millions)."""
    start = time.perf_counter()
    model = _Model(params, law, moving, data)
    guess = guess or {"b1_n_m_s": params.b1_n_m_s, "b2_n_m_s": params.b2_n_m_s}
    x0 = [max(guess.get(name, 2e-4), 1e-12) for name in model.damping]
    x0 += [guess.get(name, float(v)) for name, v in zip(("phi1_0", "phi2_0"), phi0_rad, strict=True)]
    if moving:
        x0 += [guess.get(name, float(v)) for name, v in zip(("omega1_0", "omega2_0"), omega0_rad_s, strict=True)]
    else:
        x0.append(guess.get("release_offset_s", 0.0))
    low = [0.0] * len(model.damping) + [-math.inf] * 2 + ([-math.inf] * 2 if moving else [-MAX_RELEASE_OFFSET_S])
    high = [math.inf] * (len(x0) - (0 if moving else 1)) + ([] if moving else [MAX_RELEASE_OFFSET_S])
    if data.timing_range_s is not None:
        x0.append(guess.get("timing2_s", 0.0))
        low.append(data.timing_range_s[0])
        high.append(data.timing_range_s[1])
    scale = np.array([_SCALE[k] for k in model.kinds])
    n_res = len(data.at[0]) + len(data.at[1])
    result = optimize.least_squares(
        model.reduced,
        np.array(x0, dtype=float),
        jac=model.reduced_jacobian,
        bounds=(low, high),
        x_scale=scale,
        method="trf",
        xtol=1e-8,
        ftol=max(BIC_RESOLUTION / n_res, 1e-10),
        gtol=1e-10,
        max_nfev=50,
    )
    r = model.residuals(np.asarray(result.x, dtype=float))  # the n residuals at the optimum
    n, p = len(r[0]) + len(r[1]), len(x0)
    rss = float(r[0] @ r[0]) + float(r[1] @ r[1])
    jac = result.jac
    try:
        covariance = (rss / max(1, n - p)) * np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        covariance = np.full((p, p), math.nan)
    ci = 1.959964 * np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    return LawFit(
        law=law,
        names=model.names,
        values=np.asarray(result.x, dtype=float),
        ci95=ci,
        covariance=covariance,
        residual_rms_sigma=math.sqrt(rss / n),
        bic=n * math.log(rss / n) + p * math.log(n),
        ljung_box_p=(ljung_box_p(r[0]), ljung_box_p(r[1])),
        n_residuals=n,
        iterations=int(result.njev or 0),
        seconds=time.perf_counter() - start,
    )


def _per_node(values: Floats | Sequence[NDArray[np.floating]]) -> list[NDArray[np.floating]]:
    """Each node's (m_k,) column of an (m, 2) array, or the pair of per-node arrays given."""
    if isinstance(values, np.ndarray) and values.ndim == 2 and values.shape[1] == 2:
        return [values[:, 0], values[:, 1]]
    columns = [np.asarray(v) for v in values] if isinstance(values, (tuple, list)) else []
    if len(columns) != 2 or any(c.ndim != 1 for c in columns):
        shape = np.shape(values) if isinstance(values, np.ndarray) else type(values).__name__
        raise ParameterError(f"expected an (m, 2) array or two per-node (m_k,) arrays, got {shape}")
    return columns


def fit_planar(
    params: RigParams,
    value_t_s: Floats | Sequence[NDArray[np.floating]],
    gyro_z_rad_s: Floats | Sequence[NDArray[np.floating]],
    *,
    gyro_sigma_rad_s: Sequence[float],
    phi0_rad: Sequence[float],
    omega0_rad_s: Sequence[float] = (0.0, 0.0),
    moving: bool | None = None,
    law: str = "auto",
    drive: Drive | None = None,
    timing_range_s: tuple[float, float] | None = None,
) -> list[LawFit]:
    """Fit the hinge losses and the start state of a free decay (or of a driven run) on the
    planar model.

    Args:
      params: the rig (its damping fields are only the first guess).
      value_t_s: (m, 2) each node's value instants since the start, s (NaN: no sample), or the
        pair of each node's (m_k,) instants (used without a copy when float64, contiguous,
        finite and ascending: what a long record's fit needs).
      gyro_z_rad_s: (m, 2) the measured rates about the hinges, rad/s (NaN: lost), or the pair
        of each node's (m_k,).
      gyro_sigma_rad_s: each node's gyro noise sigma, rad/s.
      phi0_rad, omega0_rad_s: the start state estimated by the alignment (first guess).
      moving: the run starts in motion (fit omega_0, no release offset); default: any |omega_0|
        above 0.
      law: "viscous", "coulomb", "both", or "auto" (all three).
      drive: the run's drive, its time 0 at the start (for a release: at the fitted release
        instant, the drive starting with the swing), or None for a free decay.
      timing_range_s: (lo_s <= 0, hi_s >= 0): fit the shift of M2's value instants against M1's
        within it, s (``MeasuredRun.relative_timing_range_s``); None: the instants as given.

    Returns:
      The fit of each law tried, the one with the smallest BIC first.
    """
    if law not in LAW_CHOICES:
        raise ParameterError(f"law must be one of {', '.join(LAW_CHOICES)}, got {law!r}")
    t, y = _per_node(value_t_s), _per_node(gyro_z_rad_s)
    if any(a.shape != b.shape for a, b in zip(t, y, strict=True)):
        raise ParameterError(
            f"expected value_t_s and gyro_z_rad_s of the same shape per node, got {[a.shape for a in t]}, "
            f"{[b.shape for b in y]}"
        )
    at, gyro = [], []
    for k in range(2):  # finite and ascending, each node's own contiguous arrays (no copy if they are)
        ok = np.isfinite(t[k]) & np.isfinite(y[k])
        tk, yk = (t[k], y[k]) if ok.all() else (t[k][ok], y[k][ok])
        del ok
        if np.any(tk[1:] < tk[:-1]):
            order = np.argsort(tk, kind="stable")
            tk, yk = tk[order], yk[order]
        at.append(np.ascontiguousarray(tk, dtype=np.float64))
        gyro.append(np.ascontiguousarray(yk, dtype=np.float64))
        if len(at[-1]) < 10:
            raise ParameterError(f"node {k + 1} has {len(at[-1])} usable gyro samples; the fit needs at least 10")
    inputs = None
    if drive:  # the steps the latest release offset needs (``fast_planar.rates_at``), and one more
        end_s = max(float(at[0][-1]), float(at[1][-1])) + MAX_RELEASE_OFFSET_S + max((0.0, *(timing_range_s or ())))
        inputs = stage_inputs(drive, math.ceil(end_s / FIT_DT_S) + 2, FIT_DT_S)
    if timing_range_s is not None and not timing_range_s[0] <= 0.0 <= timing_range_s[1]:
        raise ParameterError(f"timing_range_s must hold 0 (the instants as given), got {timing_range_s!r}")
    sigma = np.asarray(gyro_sigma_rad_s, dtype=float)
    data = _Data((at[0], at[1]), (gyro[0], gyro[1]), sigma, inputs, timing_range_s)
    if moving is None:
        moving = bool(np.any(np.abs(np.asarray(omega0_rad_s, dtype=float)) > 0))
    if law != "auto":
        return [fit_law(params, law, data, phi0_rad, omega0_rad_s, moving)]
    # viscous first; Coulomb starts from it: the same start state, and the dry friction that
    # dissipates the same mean power, F_n = b_n <omega_n^2> / <|omega_n|> (fewer iterations)
    viscous = fit_law(params, "viscous", data, phi0_rad, omega0_rad_s, moving)
    b = [viscous.value("b1_n_m_s"), viscous.value("b2_n_m_s")]
    n_start = len(_DAMPING["viscous"])
    phi_v = viscous.values[n_start : n_start + 2]
    omega_v = viscous.values[n_start + 2 : n_start + 4] if moving else omega0_rad_s
    equivalent = {
        f"friction{k + 1}_n_m": b[k] * float(np.mean(gyro[k] ** 2)) / max(float(np.mean(np.abs(gyro[k]))), 1e-12)
        for k in range(2)
    }
    equivalent["timing2_s"] = viscous.value("timing2_s")
    dry = fit_law(params, "coulomb", data, phi_v, omega_v, moving, guess=equivalent)
    # "both" nests the two: it starts from the better of them, the other law's terms at ~0 (its
    # cost can then only fall below both: RSS_both <= min(RSS_viscous, RSS_coulomb))
    better = min(viscous, dry, key=lambda f: f.bic)
    both = fit_law(
        params,
        "both",
        data,
        phi0_rad,
        omega0_rad_s,
        moving,
        guess={**dict.fromkeys(_DAMPING["both"], 0.0), **dict(zip(better.names, better.values, strict=True))},
    )
    return sorted([viscous, dry, both], key=lambda f: f.bic)
