"""The features of a sweep, computed for a whole batch of runs at once from their sampled motion.

Imports no physics engine: every engine hands over a ``Motion`` (the fast kernel's states, or a
MuJoCo Trajectory) and gets the same features. Feature groups and the columns they give:

- ``frequency``: ``freq1_hz``, ``freq2_hz``: dominant frequency of phi1, phi2, the same estimate
  ``pendsim simulate`` prints (``analysis.spectral_peak_hz``: Hann window, 8x zero padding,
  log-parabola refinement). With them, two quality columns per pendulum (``QUALITY_COLUMNS``, not
  features: no maps, no elasticities): ``freq1_peak_ratio``, ``freq2_peak_ratio``, the height of
  the second-highest spectral peak over the highest (``analysis.second_peak_ratio_batch``, the same way; 0.03
  for a pure sine: the window's side lobes), and ``freq1_ambiguous``, ``freq2_ambiguous`` (bool):
  that ratio is at least ``AMBIGUOUS_PEAK_RATIO``, so that which peak the frequency is can flip
  with a small change (M2 released at 0 swings in both modes about equally: 0.97 to 1). A peak
  below one cycle in the run (f < 1 / duration: an overdamped hinge, a pendulum that creeps), and
  the peak of a pendulum that went over the top (``amp > pi``: its angle's spectrum is its turns'
  ramp, whose peak sits just above one cycle), are no swing's frequency
  (``analysis.swing_frequency_hz``): NaN, with a NaN ratio and not ambiguous.
- ``amplitude``: ``amp1_rad``, ``amp2_rad``: largest |phi| over the run; ``amp1_end_rad``,
  ``amp2_end_rad``: largest |phi| over its last fifth (what is left at the end).
- ``decay``: ``decay1_per_s``, ``decay2_per_s``: ln(A_head / A_tail) / (t_tail - t_head), where
  A_head is the largest |phi| in the first fifth of the run at time t_head and A_tail the largest
  in the last fifth at t_tail. For a free decay with envelope exp(-sigma t) this is sigma (the
  paper's log decrement gives b = 2 J sigma for one pendulum swinging alone).
- ``energy``: ``energy_j``, ``energy_end_j``: total (kinetic + potential above rest) energy at the
  start and the end; ``dissipated_j``: energy taken by the hinge damping over the run.
- ``poincare``: list columns ``poincare_t_s``, ``poincare_phi2_rad``, ``poincare_omega2_rad_s``:
  the section phi1 = 0 crossed upward (omega1 > 0), one entry per crossing; the crossing instant
  is the root of the cubic Hermite interpolant of phi1 (slopes omega1) between samples, phi2 and
  omega2 are interpolated the same way (slopes omega2, alpha2): fourth order in the step.
- ``lyapunov``: ``lyapunov_per_s``: largest Lyapunov exponent (fast engine only; computed by
  ``fast_planar.lyapunov`` and passed in).
- always: ``diverged`` (bool): the run became non-finite or its energy grew without input; its
  other features are NaN. And the quality columns ``energy_residual_j``, ``unresolved``: the energy
  balance and whether the step resolves the run (``with_balance``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.checks import unresolved_balance

FloatArray = NDArray[np.float64]

FEATURE_GROUPS: dict[str, tuple[str, ...]] = {
    "frequency": ("freq1_hz", "freq2_hz"),
    "amplitude": ("amp1_rad", "amp2_rad", "amp1_end_rad", "amp2_end_rad"),
    "decay": ("decay1_per_s", "decay2_per_s"),
    "energy": ("energy_j", "energy_end_j", "dissipated_j"),
    "poincare": ("poincare_t_s", "poincare_phi2_rad", "poincare_omega2_rad_s"),
    "lyapunov": ("lyapunov_per_s",),
}
QUALITY_COLUMNS: dict[str, tuple[str, ...]] = {
    "frequency": ("freq1_peak_ratio", "freq2_peak_ratio", "freq1_ambiguous", "freq2_ambiguous"),
}
"""Per feature group, the columns that say how far its values can be trusted (after the features)."""
AMBIGUOUS_PEAK_RATIO = 0.8  # a second spectral peak within 20 % of the first: the frequency is ambiguous
BALANCE_COLUMNS = ("energy_residual_j", "unresolved")
"""Quality columns of every sweep (after the features): ``with_balance``."""
DEFAULT_GROUPS = ("frequency", "amplitude", "energy")
LIST_GROUPS = frozenset({"poincare"})  # groups whose columns hold one list per case
WINDOW_SHARE = 0.2  # head and tail windows of amplitude and decay: a fifth of the run


def check_groups(groups: Sequence[str]) -> tuple[str, ...]:
    """Feature group names, checked and de-duplicated in the canonical order; a single column name
    (``freq1_hz``) selects its group."""
    by_column = {col: group for group, cols in FEATURE_GROUPS.items() for col in cols}
    chosen = set()
    for name in groups:
        group = name if name in FEATURE_GROUPS else by_column.get(name)
        if group is None:
            allowed = ", ".join(FEATURE_GROUPS)
            raise ParameterError(f"unknown feature {name!r}; allowed: {allowed} (or one of their columns)")
        chosen.add(group)
    if not chosen:
        raise ParameterError(f"no features asked for; allowed: {', '.join(FEATURE_GROUPS)}")
    return tuple(g for g in FEATURE_GROUPS if g in chosen)


def scalar_columns(groups: Sequence[str]) -> tuple[str, ...]:
    """The one-number-per-case columns of these groups, in order."""
    return tuple(col for g in groups if g not in LIST_GROUPS for col in FEATURE_GROUPS[g])


@dataclasses.dataclass(frozen=True)
class Motion:
    """A batch of m runs sampled at n instants t_s (s), what every feature is computed from.

    Attributes:
      t_s: (n,) sample times, uniformly spaced.
      phi_rad, omega_rad_s, alpha_rad_s2: (m, n, 2) angles, rates, angular accelerations.
      total_energy_j: (m, n) kinetic + potential energy above rest, J.
      dissipated_j: (m, n) energy taken by the hinge damping since t = 0, J.
      diverged: (m,) runs that became non-finite or gained energy without input.
    """

    t_s: FloatArray
    phi_rad: FloatArray
    omega_rad_s: FloatArray
    alpha_rad_s2: FloatArray
    total_energy_j: FloatArray
    dissipated_j: FloatArray
    diverged: NDArray[np.bool_]


@dataclasses.dataclass(frozen=True)
class PoincareSamples:
    """Section crossings per case: three tuples of m arrays (one array per case, k_i entries)."""

    t_s: tuple[FloatArray, ...]
    phi2_rad: tuple[FloatArray, ...]
    omega2_rad_s: tuple[FloatArray, ...]


@dataclasses.dataclass(frozen=True)
class Features:
    """Features of m runs: ``values[:, j]`` is column ``names[j]`` (NaN where a run diverged);
    ``quality`` the columns of ``QUALITY_COLUMNS`` for the groups computed, each (m,) (float
    ratios, NaN where a run diverged; bool flags, False there)."""

    names: tuple[str, ...]
    values: FloatArray
    diverged: NDArray[np.bool_]
    poincare: PoincareSamples | None
    quality: dict[str, NDArray[np.float64] | NDArray[np.bool_]] = dataclasses.field(default_factory=dict)

    def column(self, name: str) -> FloatArray:
        """One scalar column, (m,)."""
        if name not in self.names:
            raise ParameterError(f"feature {name!r} was not computed; computed: {', '.join(self.names)}")
        return self.values[:, self.names.index(name)]


@dataclasses.dataclass(frozen=True)
class MotionSummary:
    """A batch of m runs reduced to what the scalar features need (a ``Motion`` reduced by
    ``summarise``, or the fast engine's pass that never stores the motion).

    Attributes:
      t_s: (n,) sample times, uniformly spaced.
      phi_rad: (m, 2, n) the sampled angles (the frequency's input), or None when not needed.
      amp_rad: (m, 2) largest |phi_n| over the samples.
      head_amp_rad, head_index: (m, 2) largest |phi_n| over samples 0..head (``head_samples``)
        and its first sample.
      tail_amp_rad, tail_index: (m, 2) the same over samples n - 1 - head .. n - 1.
      energy_start_j, energy_end_j: (m,) total energy at the first and last sample, J.
      dissipated_j: (m,) energy taken by the hinge damping over the run, J.
      diverged: (m,) as ``Motion.diverged``.
    """

    t_s: FloatArray
    phi_rad: FloatArray | None
    amp_rad: FloatArray
    head_amp_rad: FloatArray
    head_index: NDArray[np.int64]
    tail_amp_rad: FloatArray
    tail_index: NDArray[np.int64]
    energy_start_j: FloatArray
    energy_end_j: FloatArray
    dissipated_j: FloatArray
    diverged: NDArray[np.bool_]


def head_samples(n: int) -> int:
    """The head window of n samples is samples 0..head_samples(n) (a fifth of the run, at least
    one step); the tail window the last head_samples(n) + 1."""
    return max(1, round(WINDOW_SHARE * (n - 1)))


def summarise(motion: Motion, *, keep_phi: bool = True) -> MotionSummary:
    """The reductions of ``MotionSummary`` from a stored motion (first of equal maxima)."""
    phi = motion.phi_rad
    n = phi.shape[1]
    head = head_samples(n)
    mag = np.abs(phi)
    head_i = np.argmax(mag[:, : head + 1], axis=1)  # (m, 2)
    tail_i = n - 1 - head + np.argmax(mag[:, n - 1 - head :], axis=1)
    return MotionSummary(
        t_s=motion.t_s,
        phi_rad=np.moveaxis(phi, 2, 1) if keep_phi else None,
        amp_rad=mag.max(axis=1),
        head_amp_rad=np.take_along_axis(mag, head_i[:, None, :], axis=1)[:, 0],
        head_index=head_i,
        tail_amp_rad=np.take_along_axis(mag, tail_i[:, None, :], axis=1)[:, 0],
        tail_index=tail_i,
        energy_start_j=motion.total_energy_j[:, 0],
        energy_end_j=motion.total_energy_j[:, -1],
        dissipated_j=motion.dissipated_j[:, -1],
        diverged=motion.diverged,
    )


def compute(motion: Motion, groups: Sequence[str], *, lyapunov_per_s: FloatArray | None = None) -> Features:
    """The features of ``groups`` (checked by ``check_groups``) for every run of ``motion``.

    Args:
      motion: the sampled runs.
      groups: feature groups.
      lyapunov_per_s: (m,) exponents, required when "lyapunov" is asked for.
    """
    groups = check_groups(groups)
    features = compute_summary(summarise(motion, keep_phi="frequency" in groups), groups, lyapunov_per_s=lyapunov_per_s)
    if "poincare" in groups:
        features = dataclasses.replace(features, poincare=_poincare(motion))
    return features


def compute_summary(
    summary: MotionSummary,
    groups: Sequence[str],
    *,
    lyapunov_per_s: FloatArray | None = None,
    nthread: int | None = None,
) -> Features:
    """The scalar features of ``groups`` from reduced runs (Poincare samples need the motion:
    ``compute``).

    Args:
      summary: the reduced runs (``phi_rad`` needed for "frequency").
      groups: feature groups.
      lyapunov_per_s: (m,) exponents, required when "lyapunov" is asked for.
      nthread: threads for the frequency's transforms (default: every core).
    """
    groups = check_groups(groups)
    t = summary.t_s
    m = len(summary.diverged)
    columns: dict[str, FloatArray] = {}
    quality: dict[str, NDArray[np.float64] | NDArray[np.bool_]] = {}
    if "frequency" in groups:
        if summary.phi_rad is None:
            raise ParameterError("the frequency feature needs the sampled angles (phi_rad)")
        from pendsim_mj.estimation.analysis import swing_frequency_hz
        from pendsim_mj.estimation.spectral_peaks import peaks_and_ratios  # start-up: numba and scipy.fft

        freq, ratio = (
            v.reshape(m, 2) for v in peaks_and_ratios(t, summary.phi_rad.reshape(2 * m, -1), nthread=nthread)
        )
        # a decay's or a drift's peak (below one cycle in the run), or the ramp of a pendulum that
        # went over the top: no swing frequency (``analysis.swing_frequency_hz``)
        duration_s = float(t[-1] - t[0]) if len(t) > 1 else 0.0
        freq = swing_frequency_hz(freq, duration_s, summary.amp_rad)
        ratio[np.isnan(freq)] = np.nan
        columns["freq1_hz"], columns["freq2_hz"] = freq[:, 0], freq[:, 1]
        ratio[summary.diverged] = np.nan
        for k in (0, 1):
            quality[f"freq{k + 1}_peak_ratio"] = ratio[:, k]
            quality[f"freq{k + 1}_ambiguous"] = np.nan_to_num(ratio[:, k]) >= AMBIGUOUS_PEAK_RATIO
    if "amplitude" in groups:
        columns["amp1_rad"], columns["amp2_rad"] = summary.amp_rad[:, 0], summary.amp_rad[:, 1]
        columns["amp1_end_rad"], columns["amp2_end_rad"] = summary.tail_amp_rad[:, 0], summary.tail_amp_rad[:, 1]
    if "decay" in groups:
        with np.errstate(divide="ignore", invalid="ignore"):
            decay = np.log(summary.head_amp_rad / summary.tail_amp_rad) / (
                t[summary.tail_index] - t[summary.head_index]
            )
        decay[~np.isfinite(decay)] = np.nan  # a pendulum at rest has no decay
        decay += 0.0  # no -0.0 (ln 1 over a negative span rounds to it): 0.0
        columns["decay1_per_s"], columns["decay2_per_s"] = decay[:, 0], decay[:, 1]
    if "energy" in groups:
        columns["energy_j"] = summary.energy_start_j
        columns["energy_end_j"] = summary.energy_end_j
        columns["dissipated_j"] = summary.dissipated_j
    if "lyapunov" in groups:
        if lyapunov_per_s is None or np.shape(lyapunov_per_s) != (m,):
            raise ParameterError("the lyapunov feature needs the exponents of every run (the fast engine)")
        columns["lyapunov_per_s"] = np.asarray(lyapunov_per_s, dtype=float)
    names = scalar_columns(groups)
    values = np.stack([columns[c] for c in names], axis=1) if names else np.zeros((m, 0))
    values[summary.diverged] = np.nan
    return Features(names=names, values=values, diverged=summary.diverged.copy(), poincare=None, quality=quality)


def with_balance(
    features: Features,
    energy_start_j: FloatArray,
    energy_end_j: FloatArray,
    dissipated_j: FloatArray,
    energy_scale_j: FloatArray,
    checked: NDArray[np.bool_],
) -> Features:
    """``features`` with the energy balance of each run as quality columns: ``energy_residual_j``,
    the energy lost less the energy the losses took (start - end - dissipated, J: the integration
    error; NaN where not ``checked`` or diverged) and ``unresolved`` (bool): that error is more than
    ``checks.UNRESOLVED_SHARE`` of the run's energy scale (m1 g OC1): the step does not resolve this run
    (a stiff spring, a violent swing) and its features are not to be trusted (rerun it with a
    smaller dt_s). ``checked``: (m,) runs whose every loss is in ``dissipated_j`` and that take no
    input (a drive's work is not counted here)."""
    residual = np.where(checked & ~features.diverged, energy_start_j - energy_end_j - dissipated_j, np.nan)
    unresolved = unresolved_balance(np.nan_to_num(residual), energy_scale_j)
    quality = {**features.quality, "energy_residual_j": residual, "unresolved": unresolved}
    return dataclasses.replace(features, quality=quality)


def _hermite(y0: FloatArray, y1: FloatArray, d0: FloatArray, d1: FloatArray, h: float, s: FloatArray) -> FloatArray:
    """Cubic Hermite interpolant through (0, y0), (h, y1) with slopes d0, d1, at s in [0, 1]."""
    s2, s3 = s * s, s * s * s
    return (2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * h * d0 + (-2 * s3 + 3 * s2) * y1 + (s3 - s2) * h * d1


def _poincare(motion: Motion) -> PoincareSamples:
    """Upward crossings of phi1 = 0 (see the module docstring), every case at once."""
    t = motion.t_s
    h = float(t[1] - t[0])
    p1 = motion.phi_rad[..., 0]
    case, i = np.nonzero((p1[:, :-1] < 0) & (p1[:, 1:] >= 0))
    y0, y1 = p1[case, i], p1[case, i + 1]
    d0, d1 = motion.omega_rad_s[case, i, 0], motion.omega_rad_s[case, i + 1, 0]
    s = y0 / (y0 - y1)  # the linear estimate, then Newton on the Hermite cubic (kept in [0, 1])
    for _ in range(6):
        s2 = s * s
        value = _hermite(y0, y1, d0, d1, h, s)
        slope = (
            (6 * s2 - 6 * s) * y0 + (3 * s2 - 4 * s + 1) * h * d0 + (-6 * s2 + 6 * s) * y1 + (3 * s2 - 2 * s) * h * d1
        )
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(slope != 0, value / slope, 0.0)
        s = np.clip(s - step, 0.0, 1.0)
    ts = t[i] + s * h
    phi2 = _hermite(
        motion.phi_rad[case, i, 1], motion.phi_rad[case, i + 1, 1], motion.omega_rad_s[case, i, 1],
        motion.omega_rad_s[case, i + 1, 1], h, s,
    )  # fmt: skip
    omega2 = _hermite(
        motion.omega_rad_s[case, i, 1], motion.omega_rad_s[case, i + 1, 1], motion.alpha_rad_s2[case, i, 1],
        motion.alpha_rad_s2[case, i + 1, 1], h, s,
    )  # fmt: skip
    m = motion.phi_rad.shape[0]
    bounds = np.searchsorted(case, np.arange(m + 1))
    empty = np.zeros(0)

    def split(values: FloatArray) -> tuple[FloatArray, ...]:
        return tuple(empty if motion.diverged[c] else values[bounds[c] : bounds[c + 1]].copy() for c in range(m))

    return PoincareSamples(t_s=split(ts), phi2_rad=split(phi2), omega2_rad_s=split(omega2))
