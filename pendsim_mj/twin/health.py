"""Health monitoring: noticing when the rig stops behaving like its twin, and saying what changed.

The estimator (``estimator.RigEstimator``) tracks the parameters that can drift (damping, dry
friction, the coupling springs, each node's mount) with their standard deviations. After a
baseline (the rig as calibrated, or its first ``baseline_s`` of healthy swinging), the monitor
watches each tracked parameter's deviation from its reference in units of its current standard
deviation,

    z_i(t) = (theta_i(t) - theta_i,ref) / sigma_i(t),

once per ``period_s`` (a second: the estimate's correlation time is tens of seconds, so the
checks are not independent, and the false-alarm rate is what a benchmark over healthy emulated
hours measures, not a formula). An alarm is raised for parameter i when |z_i| stays above
``threshold`` for ``persist_s``; it says which parameter (and so which node or hinge), since
when (the last time |z_i| was below 2 before the alarm), and by how much (the estimate minus the
reference, with its standard deviation). Each parameter alarms once until it is reset.

A drift is a step spread over time: the same test finds it once its size passes the threshold.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from pendsim_mj.errors import ParameterError
from pendsim_mj.twin.estimator import TRACKABLE, RigEstimator

DEFAULT_THRESHOLD = 5.0  # sigmas
DEFAULT_PERSIST_S = 3.0
SINCE_LEVEL = 2.0  # sigmas: "since when" is the last check below this before the alarm

WHAT = {
    "b1_n_m_s": "damping at M1's hinge",
    "b2_n_m_s": "damping at M2's hinge",
    "friction1_n_m": "dry friction at M1's hinge",
    "friction2_n_m": "dry friction at M2's hinge",
    "coupling_sin_n_m": "the coupling springs' stiffness",
    "offset_m1_rad": "M1's node turned on its mount",
    "offset_m2_rad": "M2's node turned on its mount",
    "offset_rate_m1_rad_s": "M1's node turning on its mount (or its fused orientation drifting)",
    "offset_rate_m2_rad_s": "M2's node turning on its mount (or its fused orientation drifting)",
    "delay_m2_s": "M2's node's values later than M1's against their instants (fusion timing or clock)",
}
"""What each tracked parameter's change means on the rig."""


@dataclasses.dataclass(frozen=True)
class Alarm:
    """A parameter that changed.

    Attributes:
      parameter: its name (``estimator.TRACKABLE``). what: what that means on the rig.
      t_s: when the alarm was raised, s. since_s: since when it has been changing, s.
      reference: its reference value; value: its estimate at the alarm; sigma: the estimate's
        standard deviation (the parameter's unit: ``TRACKABLE``).
    """

    parameter: str
    what: str
    t_s: float
    since_s: float
    reference: float
    value: float
    sigma: float

    @property
    def change(self) -> float:
        """The estimate minus the reference."""
        return self.value - self.reference

    def describe(self) -> str:
        unit = TRACKABLE[self.parameter][1]
        relative = f" ({100 * self.change / self.reference:+.0f} %)" if self.reference else ""
        return (
            f"{self.what} changed since {self.since_s:.1f} s (alarm at {self.t_s:.1f} s): {self.parameter} "
            f"{self.reference:.4g} -> {self.value:.4g} +- {2 * self.sigma:.2g} {unit}{relative}"
        )


class HealthMonitor:
    """Checks a ``RigEstimator``'s tracked parameters (module docstring).

    Args:
      estimator: the estimator (its ``track`` names the parameters watched).
      baseline_s: the references are the estimates at this time (0: the estimator's rig).
      threshold: |z| in sigmas above which a parameter counts as changed.
      persist_s: how long |z| must stay above the threshold, s.
      period_s: how often the parameters are checked, s.
    """

    def __init__(
        self,
        estimator: RigEstimator,
        *,
        baseline_s: float = 0.0,
        threshold: float = DEFAULT_THRESHOLD,
        persist_s: float = DEFAULT_PERSIST_S,
        period_s: float = 1.0,
    ) -> None:
        for name, value in (("baseline_s", baseline_s), ("persist_s", persist_s)):
            if not (math.isfinite(value) and value >= 0):
                raise ParameterError(f"{name} must be a finite number >= 0 s, got {value!r}")
        if not (math.isfinite(threshold) and threshold > SINCE_LEVEL):
            raise ParameterError(f"threshold must be a number > {SINCE_LEVEL} sigmas, got {threshold!r}")
        if not (math.isfinite(period_s) and period_s > 0):
            raise ParameterError(f"period_s must be > 0 s, got {period_s!r}")
        if not estimator.track:
            raise ParameterError("the estimator tracks no parameter: give it track=(...) to monitor")
        self.estimator = estimator
        self.baseline_s, self.threshold, self.persist_s, self.period_s = baseline_s, threshold, persist_s, period_s
        self.reference: dict[str, float] | None = None
        if baseline_s == 0:
            self.reference = {name: estimator.stated(name) for name in estimator.track}
        self._next_s = estimator.t_s + period_s
        self._above_since: dict[str, float | None] = dict.fromkeys(estimator.track)
        self._calm_s: dict[str, float] = dict.fromkeys(estimator.track, estimator.t_s)
        self.alarmed: dict[str, Alarm] = {}
        self.history: list[tuple[float, dict[str, float]]] = []  # (t_s, z per parameter)

    def check(self) -> list[Alarm]:
        """Check at the estimator's current time (call after each update: it checks once per
        period); the new alarms."""
        t = self.estimator.t_s
        if t < self._next_s:
            return []
        self._next_s = t + self.period_s
        found = self.estimator.parameters()
        if self.reference is None:
            if t >= self.baseline_s:
                self.reference = {name: value for name, (value, _) in found.items()}
                self._calm_s = dict.fromkeys(found, t)
            return []
        z = {name: (value - self.reference[name]) / sigma for name, (value, sigma) in found.items()}
        self.history.append((t, z))
        new = []
        for name, zi in z.items():
            if abs(zi) < SINCE_LEVEL:
                self._calm_s[name] = t
            if abs(zi) <= self.threshold:
                self._above_since[name] = None
                continue
            since = self._above_since[name]
            if since is None:
                self._above_since[name] = since = t
            if t - since >= self.persist_s and name not in self.alarmed:
                value, sigma = found[name]
                alarm = Alarm(name, WHAT[name], t, self._calm_s[name], self.reference[name], value, sigma)
                self.alarmed[name] = alarm
                new.append(alarm)
        return new

    def reset(self, parameter: str) -> None:
        """Take a parameter's current estimate as its new reference (the change was acknowledged)."""
        value, _ = self.estimator.parameters()[parameter]
        if self.reference is not None:
            self.reference[parameter] = value
        self.alarmed.pop(parameter, None)
        self._above_since[parameter] = None

    def largest_z(self) -> dict[str, float]:
        """Each parameter's largest |z| so far (0 before the baseline)."""
        out = dict.fromkeys(self.estimator.track, 0.0)
        for _, z in self.history:
            for name, zi in z.items():
                out[name] = max(out[name], abs(zi))
        return out


def zscores(history: list[tuple[float, dict[str, float]]]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A monitor's history as arrays: (t_s (k,), z per parameter (k,))."""
    t = np.array([h[0] for h in history])
    names = history[0][1].keys() if history else ()
    return t, {name: np.array([h[1][name] for h in history]) for name in names}
