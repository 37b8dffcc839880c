"""Health monitoring: noticing when the rig stops behaving like its twin, and saying what changed.

The estimator (``estimator.RigEstimator``) tracks the parameters that can drift (damping, dry
friction, the coupling springs, each node's mount) as random walks, with their joint covariance.
The monitor works in two stages.

**Detection** (once per ``period_s``, cheap). With delta = theta - theta_ref the tracked
parameters' departure from their references (the rig as calibrated, or its first ``baseline_s``
of healthy swinging) and P their covariance block, the generalised likelihood ratio of "only
parameter i changed" against "nothing changed", for a Gaussian estimate, is

    g_i = (P^-1 delta)_i / sqrt((P^-1)_ii),

the change of theta_i that best explains delta with the others held at their references, in units
of its standard deviation under that hypothesis. On a healthy rig each g_i is a standard normal
variable. Unlike the marginal z_i = delta_i / sqrt(P_ii), g_i does not lose its power where two
parameters are correlated: dry friction and viscous damping at one hinge trade off in the
estimate, so each alone is poorly determined (small z), but their combination is not (large g).
Parameters that have already alarmed are left free (their rows marginalised out of P). A
detection is raised when max_i |g_i| stays above ``threshold`` for ``persist_s``.

**Attribution** (after a detection, costly, for up to ``decide_s``). At one steady amplitude,
viscous damping and dry friction take out the same energy per cycle; they differ in how the loss
scales with the amplitude (b: as A^2 per cycle, F: as A), which only the data over a changing
amplitude shows. So from the detection on (the change has happened by then, and a transient such
as a knock is over), the monitor feeds the samples (the estimator keeps the latest, ``keep_s``)
to a bank of copies of the filter started from the estimator's state, one per hypothesis: H0
"nothing changed" (every parameter held at its reference) and, for each of the ``candidates``
parameters with the largest |g|, H_i "parameter i has stepped, the others held" (theta_i constant
with a wide prior, ``PRIOR_SIGMA``). Each copy sums the log-likelihood of its innovations (its
evidence, ``-0.5 (nu' S^-1 nu + ln det S)`` per sample). The alarm is raised on H_i once its
evidence exceeds every other hypothesis's, H0's included, by ``margin`` (a likelihood ratio of
e^margin), or, after ``decide_s``, once it exceeds H0's by ``margin`` (the alarm names the
runner-up and the evidence between them). Otherwise the detection is dismissed: a false detection
costs the bank's CPU, not an alarm.

**A change still under way** (a spring weakening over a minute, a bearing starting to rub). A
hinge's damping and dry friction are weighed twice: as a step (above) and as a change still going
on (theta_i walking as fast as the change so far: its size over the square root of how long it
took). A hinge's two laws, in either kind, are one explanation ("the loss at this hinge changed"),
named once it beats the rest by ``margin``; its law is the steps' better one by ``margin``, unless
a change under way fits better than every step (by ``margin``) and leans to the other law: then its
law if it leads by ``margin``, else the law is left open (``Alarm.law_open``). Where the steps do
not tell the law, a change under way that fits better and tells it does; where nothing tells it by
``decide_s``, it is left open. The reason: a damping that keeps rising while the swing decays takes
out energy as a step of dry friction does (b A^2 per cycle with b growing as A falls, against F A),
and the step hypotheses then name dry friction confidently (seen: by e^26).

After an alarm the parameter walks in the estimator as fast as its change came, so that the
estimate follows a change that goes on (a slow walk left it to the hinge's other law, alarmed
later as a second change); once the estimate has moved on from the alarm's value by more than
``threshold`` sigmas for ``persist_s`` (where the law was left open, either law's), a second
alarm says so (``Alarm.follows_s``) with where it has got to. A step of dry friction fits a walk
better than a step by e^13-15 (the estimator's smooth friction law against the simulator's), so
a change under way is said only from the estimate moving on, not at the first alarm.

**The references' spread** (``reference_sigma``): a reference known only within an interval (a
calibration's; the mount offsets within the nodes' slowly varying fusion error, by default) adds
its variance to P in g, and leaves the parameter free within it in H0.

The alarm says which parameter (and so which node or hinge), since when (the last check with
|g_i| below 2 before the detection), and by how much (the step's estimate under H_i, with its
standard deviation), and how much better it explains the data than the runner-up. Each parameter
alarms once until it is reset, and once more if its change goes on.

False alarms: the checks are strongly correlated (the estimate's memory is tens of seconds) and
the attribution stage screens detections again, so the rate is what a benchmark over healthy
emulated hours measures (``bench/bench_twin.py``; docs/twin.md), not a formula. As a design
bound, with k parameters and checks that decorrelate over tau_c, the detection stage alone gives
about k (3600 s / tau_c) P(|N(0,1)| > threshold) detections per hour: 7 x 180 x 5.7e-7 = 7e-4 per
hour at threshold 5 and tau_c = 20 s, if the filter's covariance were exact; the model's error
makes the tails heavier, which is what the measurement is for.
"""

from __future__ import annotations

import dataclasses
import datetime
import math

import numpy as np

from pendsim_mj.errors import ParameterError
from pendsim_mj.twin.estimator import DIVERGED_RAD, NSTATE, TRACKABLE, RigEstimator
from pendsim_mj.units import NS_PER_S, nanoseconds

DEFAULT_THRESHOLD = 5.0  # sigmas
DEFAULT_PERSIST_S = 3.0
DEFAULT_MARGIN = 5.0  # natural log of the likelihood ratio: 150 to 1
DEFAULT_DECIDE_S = 45.0
DEFAULT_CANDIDATES = 4
SINCE_LEVEL = 2.0  # sigmas: "since when" is the last check below this before the alarm
FROM_START_SIGMAS = SINCE_LEVEL + 1.0  # a change under this many of the sharpest calm check's sigma
# may have been there at that check (``Alarm.from_start``)
KEEP_S = 5.0  # samples the estimator keeps for the attribution's bank between two checks, s
BANK_LATE_S = 0.0125  # the kept samples' instants interleave out of order as the estimator took them
PIN_FRACTION = 1e-6  # a parameter held at its reference in a hypothesis: sigma = PRIOR_SIGMA * this
CHANGING_OVER_S = 60.0  # a change still under way: the walking hypothesis's random walk covers
# PRIOR_SIGMA in this long (WALK_PER_SQRT_S), as a ramp over a minute or two would need
OTHER_LAW = {
    "b1_n_m_s": "friction1_n_m",
    "friction1_n_m": "b1_n_m_s",
    "b2_n_m_s": "friction2_n_m",
    "friction2_n_m": "b2_n_m_s",
}
"""The other loss law at the same hinge. At one hinge the two take out energy alike at a steady
amplitude; a step is told from the other law by how the loss scales with the decaying amplitude
(b A^2 per cycle against F A), but a damping that keeps rising while the swing decays scales like
dry friction: while a change goes on the two laws may not be told apart."""

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
    "offset_accel_m1_rad_s2": "M1's fused orientation drifting",
    "offset_accel_m2_rad_s2": "M2's fused orientation drifting",
    "offset_jerk_m1_rad_s3": "M1's fused orientation drifting",
    "offset_jerk_m2_rad_s3": "M2's fused orientation drifting",
    "delay_m2_s": "M2's node's values later than M1's against their instants (fusion timing or clock)",
    "accel_turn_m1_rad": "M1's accelerometer axes turned from its learned frame",
    "accel_turn_m2_rad": "M2's accelerometer axes turned from its learned frame",
}
"""What each tracked parameter's change means on the rig."""

PRIOR_SIGMA = {
    "b1_n_m_s": 1e-3,  # N m s/rad: 1.4 times the stated b1 (the fault doubles it)
    "b2_n_m_s": 1e-3,
    "friction1_n_m": 5e-4,  # N m: 2.5 times the 2e-4
    "friction2_n_m": 5e-4,
    "coupling_sin_n_m": 0.02,  # N m: 17 % of K_s (the fault: 5 %)
    "offset_m1_rad": 0.1,  # rad: 5.7 deg (the slip: 3 deg)
    "offset_m2_rad": 0.1,
}
"""Each parameter's prior spread under the hypothesis that it stepped (the attribution's bank). A
tracked parameter without one is a nuisance of the measurement (a node's offset rate, M2's delay):
never alarmed, left free in g and in every hypothesis, as the estimator has it."""
RELATIVE = ("b1_n_m_s", "b2_n_m_s", "friction1_n_m", "friction2_n_m", "coupling_sin_n_m")  # said in % too
WALK_PER_SQRT_S = {name: PRIOR_SIGMA[name] / math.sqrt(CHANGING_OVER_S) for name in RELATIVE}
"""A change still under way: a random walk as fast as the change so far (its size over the square
root of how long it took: ``walk_for``), at most this fast (unit per sqrt(s)); a hinge's laws are
weighed so in the bank beside their steps, and each of the rig's parameters (not a node's turn, a
step by nature) walks so in the estimator after its alarm."""
NON_NEGATIVE = RELATIVE  # a rig cannot have these below zero: a change found there is no change of the rig

UNCHANGED = "unchanged"  # the name of H0 in ``Alarm.runner_up``


def time_of_day_utc(start_utc_ns: int, t_s: float) -> str:
    """An instant ``t_s`` (s on the twin's clock, which starts at ``start_utc_ns``, UTC ns) as the
    time of day in UTC ("14:03:27 UTC"), to match the rig's own log."""
    when = datetime.datetime.fromtimestamp((start_utc_ns + nanoseconds(t_s)) // NS_PER_S, datetime.UTC)
    return f"{when:%H:%M:%S} UTC"


@dataclasses.dataclass(frozen=True)
class Alarm:
    """A parameter that changed.

    Attributes:
      parameter: its name (``estimator.TRACKABLE``). what: what that means on the rig.
      t_s: when the alarm was raised, s. since_s: since when it has been changing, s.
      reference: its reference value; value: its estimate at the alarm; sigma: the estimate's
        standard deviation (the parameter's unit: ``TRACKABLE``).
      runner_up: the next-best explanation of the data (a parameter's name, ``UNCHANGED``, or ""
        where no attribution was run).
      evidence: how much better this change explains the data than the runner-up: the natural
        log of their likelihood ratio (inf where no attribution was run).
      law_open: a change at a hinge whose law the data do not pin down: the other law there
        (damping for dry friction, and the reverse). Set where the hypotheses of a step and of a
        change still under way disagree on the law and neither settles it (a damping that keeps
        rising while the swing decays looks like a step of dry friction), or where nothing
        decides by ``decide_s``.
      open_value: with ``law_open`` on a first alarm, that law's value (its unit) under its own
        hypothesis at the alarm (None on a second alarm).
      from_start: the change may have been there since the checks began: every check found it
        at its reference only while the estimate was too uncertain to see it (its size under
        ``FROM_START_SIGMAS`` of their sharpest sigma), so a rig that differs from its stated
        parameters would look the same (set only where the references are the stated rig).
      follows_s, followed_value: a second alarm, raised when the change alarmed at ``follows_s``
        went on (``still_changing``): on the alarmed parameter, or, where that alarm left the law
        open, on whichever of the hinge's two moved on; ``followed_value`` its value at that alarm,
        ``value`` where it has got to now (None on a first alarm).
      per_spring_m2: for the coupling springs' moment constant K_s = 2 c1 l01 l04 (what the model
        tracks), K_s per unit of c1 at the rig's anchors (2 l01 l04, m^2), so that the alarm also
        gives the springs' stiffness c1_n_m, as the rig's parameters and the emulator's faults say it.
    """

    parameter: str
    what: str
    t_s: float
    since_s: float
    reference: float
    value: float
    sigma: float
    runner_up: str = ""
    evidence: float = math.inf
    law_open: str = ""
    follows_s: float | None = None
    followed_value: float | None = None
    open_value: float | None = None
    from_start: bool = False
    per_spring_m2: float | None = None

    @property
    def still_changing(self) -> bool:
        """Whether this alarm says that an alarmed change went on (``follows_s``)."""
        return self.follows_s is not None

    @property
    def change(self) -> float:
        """The estimate minus the reference."""
        return self.value - self.reference

    def describe(self, start_utc_ns: int | None = None) -> str:
        """One line: what changed, by how much (2-sigma interval at the alarm, from the hypothesis
        that this parameter alone stepped: narrower than the estimate's later, with every
        parameter free), since when and when it was alarmed (s on the twin's clock; with the
        twin's start ``start_utc_ns``, UTC ns, also the time of day in UTC: the twin's clock
        starts with the twin, not with the rig or the nodes, so its seconds match no one's log)."""

        def utc(t_s: float) -> str:
            return "" if start_utc_ns is None else time_of_day_utc(start_utc_ns, t_s)

        def at(t_s: float) -> str:
            return f"{t_s:.1f} s ({utc(t_s)})" if start_utc_ns is not None else f"{t_s:.1f} s"

        since = f"{utc(self.since_s)}; " if start_utc_ns is not None else ""
        unit = TRACKABLE[self.parameter][1]
        relative = (
            f" ({100 * self.change / self.reference:+.0f} %)" if self.reference and self.parameter in RELATIVE else ""
        )
        if unit == "rad":  # a node's turn, in degrees too
            relative = f" (turned {math.degrees(self.change):+.2f} deg)"
        if self.per_spring_m2:  # the coupling springs: their stiffness c1 too
            k = self.per_spring_m2
            relative += f"; the springs' c1_n_m {self.reference / k:.4g} -> {self.value / k:.4g} N/m"
        line = (
            f"{self.what}: {self.parameter} {self.reference:.4g} -> {self.value:.4g} {unit} "
            f"(+- {2 * self.sigma:.2g}, 2 sigma, at the alarm under this hypothesis){relative}; changing since "
            f"{self.since_s:.1f} s ({since}its last check within 2 sigma of the reference), "
            f"alarm at {at(self.t_s)}"
        )
        if self.from_start:
            line += (
                "; it may have been so from the start (no check before could have seen it): a rig whose "
                "parameters differ from those stated looks the same (if nothing changed, calibrate the rig: "
                "'pendsim calibrate' on its recordings, then --params-file)"
            )
        if self.follows_s is not None:
            line += (
                f"; still changing: it moved on from {self.followed_value:.4g} {unit} at its alarm at "
                f"{at(self.follows_s)}"
            )
        other = f" ({self.law_open})"
        if self.law_open and self.open_value is not None:
            other = f" ({self.law_open} {self.open_value:.4g} {TRACKABLE[self.law_open][1]} as that law)"
        if self.law_open and self.follows_s is not None:
            line += (
                f"; while it changes, {WHAT[self.parameter]} and {WHAT[self.law_open]}{other} are not "
                "told apart (a loss that keeps rising over a decaying swing looks like the other law)"
            )
        elif self.law_open:
            line += f"; {WHAT[self.parameter]} or {WHAT[self.law_open]}{other}: the data do not tell the two laws apart"
        elif self.runner_up:
            line += f"; likelier than {self.runner_up} by e^{self.evidence:.0f}"
        return line


class _Bank:
    """The attribution stage: one filter per hypothesis, fed the same samples from ``t0_s`` on.
    Hypothesis k: parameter ``names[k]`` (``UNCHANGED`` for none) stepped, or, where
    ``walking[k]``, still changing."""

    def __init__(
        self, names: list[str], walking: list[bool], filters: list[RigEstimator], t0_s: float, since_s: float
    ) -> None:
        self.names, self.walking, self.filters, self.t0_s, self.since_s = names, walking, filters, t0_s, since_s
        self.loglik = np.zeros(len(filters))

    def take(self, sample) -> None:
        for k, f in enumerate(self.filters):
            updates = [
                f.update(
                    sample.t_s, sample.node, sample.phi_rad, sample.omega_rad_s, sample.torques_n_m, late_s=BANK_LATE_S
                )
            ]
            if sample.accel_m_s2 is not None:
                tangential, normal = sample.accel_m_s2
                updates.append(
                    f.update_accel(sample.t_s, sample.node, tangential, normal, sample.torques_n_m, late_s=BANK_LATE_S)
                )
            self.loglik[k] -= 0.5 * sum(u.nis + math.log(np.linalg.det(u.covariance)) for u in updates)


class HealthMonitor:
    """Checks a ``RigEstimator``'s tracked parameters (module docstring).

    Args:
      estimator: the estimator (its ``track`` names the parameters watched; the monitor makes it
        keep the last ``KEEP_S`` of samples).
      baseline_s: the references are the estimates at this time (0: the estimator's rig).
      threshold: |g| in sigmas above which a parameter counts as changed.
      persist_s: how long |g| must stay above the threshold, s.
      period_s: how often the parameters are checked, s.
      margin: the natural log of the likelihood ratio by which the attributed change must beat
        the other explanations.
      decide_s: the longest an attribution runs before it decides on the evidence it has, s.
      candidates: how many parameters (largest |g| first) the attribution weighs (0: all).
      attribute: False skips the attribution stage: the alarm goes to the largest |g| at the
        detection (cheap, but damping and dry friction are then often confused).
      reference_sigma: the references' own spread, each parameter's unit (a calibration's interval;
        default: the nodes' fusion error, ``estimator.fusion_error_rad``, for the mount offsets,
        whose slowly varying error looks like a turned mount; 0 for the others). A departure
        within it is no change: it adds to P in g and leaves the parameter that free in H0.

    Attributes:
      alarmed: the alarms raised, by parameter. history: (t_s, g per parameter) at each check
        (for a parameter that has alarmed, its marginal z). dismissed: detections that the
        attribution found no change behind (t_s of each).
    """

    def __init__(
        self,
        estimator: RigEstimator,
        *,
        baseline_s: float = 0.0,
        threshold: float = DEFAULT_THRESHOLD,
        persist_s: float = DEFAULT_PERSIST_S,
        period_s: float = 1.0,
        margin: float = DEFAULT_MARGIN,
        decide_s: float = DEFAULT_DECIDE_S,
        candidates: int = DEFAULT_CANDIDATES,
        attribute: bool = True,
        reference_sigma: dict[str, float] | None = None,
    ) -> None:
        for name, value in (("baseline_s", baseline_s), ("persist_s", persist_s), ("decide_s", decide_s)):
            if not (math.isfinite(value) and value >= 0):
                raise ParameterError(f"{name} must be a finite number >= 0 s, got {value!r}")
        if not (math.isfinite(threshold) and threshold > SINCE_LEVEL):
            raise ParameterError(f"threshold must be a number > {SINCE_LEVEL} sigmas, got {threshold!r}")
        if not (math.isfinite(period_s) and period_s > 0):
            raise ParameterError(f"period_s must be > 0 s, got {period_s!r}")
        if not (math.isfinite(margin) and margin >= 0):
            raise ParameterError(f"margin must be a finite number >= 0, got {margin!r}")
        if isinstance(candidates, bool) or not isinstance(candidates, int) or candidates < 0:
            raise ParameterError(f"candidates must be an integer >= 0, got {candidates!r}")
        if not estimator.track:
            raise ParameterError("the estimator tracks no parameter: give it track=(...) to monitor")
        spread = {name: estimator.fusion_error_rad for name in estimator.track if name.startswith("offset")}
        for name, value in (reference_sigma or {}).items():
            if name not in estimator.track:
                raise ParameterError(f"reference_sigma names {name!r}, which the estimator does not track")
            if not (math.isfinite(value) and value >= 0):
                raise ParameterError(f"reference_sigma[{name!r}] must be a finite number >= 0, got {value!r}")
            spread[name] = float(value)
        self.reference_sigma = np.array([spread.get(name, 0.0) for name in estimator.track])
        self.estimator = estimator
        self.baseline_s, self.threshold, self.persist_s, self.period_s = baseline_s, threshold, persist_s, period_s
        self.margin, self.decide_s, self.candidates, self.attribute = margin, decide_s, candidates, attribute
        self.reference: dict[str, float] | None = None
        if baseline_s == 0:
            self.reference = {name: estimator.stated(name) for name in estimator.track}
        if attribute:
            estimator.keep_s = max(estimator.keep_s, KEEP_S)
        self._next_s = estimator.t_s + period_s
        self._above_since: float | None = None
        self._calm_s: dict[str, float] = dict.fromkeys(estimator.track, estimator.t_s)
        self._calm_sigma: dict[str, float] = {}  # the sharpest sigma of a check at the reference, per parameter
        self._bank: _Bank | None = None
        self._taken = estimator.count  # samples the bank has seen (the estimator's count)
        self._quiet_until_s = -math.inf
        self.alarmed: dict[str, Alarm] = {}
        self.impossible: list[Alarm] = []  # changes found to values the rig cannot have: not alarmed
        self._aside: set[str] = set()  # left free, as an alarmed one: found at an impossible value, or
        # the law an alarm at its hinge left open
        self.dismissed: list[float] = []
        self._drift_per_s = estimator.drift_per_s.copy()  # the estimator's walks before any alarm
        self._moving_since: dict[str, float] = {}  # an alarmed change moving on from its value since, s
        self._followed: set[str] = set()  # alarms whose change has been said to go on
        self.history: list[tuple[float, dict[str, float]]] = []  # (t_s, g per parameter)

    @property
    def attributing(self) -> bool:
        """Whether a bank of hypotheses runs now (a detection being attributed)."""
        return self._bank is not None

    def statistics(self) -> dict[str, float]:
        """Each tracked parameter's g (module docstring) now; a parameter that has alarmed gets
        its marginal z and is left free in the others' g."""
        return self._statistics()[0]

    def _statistics(self) -> tuple[dict[str, float], dict[str, float]]:
        """``statistics`` and each one's sigma: the change in the parameter alone that gives g = 1
        (its unit)."""
        assert self.reference is not None
        est = self.estimator
        track = est.track
        delta = np.array([est.x[NSTATE + i] - self.reference[name] for i, name in enumerate(track)])
        p = est.p[NSTATE:, NSTATE:] + np.diag(self.reference_sigma**2)  # the references' spread: no change
        sigma = np.sqrt(np.diag(p))
        out = {name: float(delta[i] / sigma[i]) for i, name in enumerate(track) if name in PRIOR_SIGMA}
        spread = {name: float(sigma[i]) for i, name in enumerate(track) if name in PRIOR_SIGMA}
        watched = [i for i, name in enumerate(track) if not self._is_free(name) and name in PRIOR_SIGMA]
        if watched:
            info = np.linalg.inv(p[np.ix_(watched, watched)])
            g = info @ delta[watched] / np.sqrt(np.diag(info))
            out.update({track[i]: float(gi) for i, gi in zip(watched, g, strict=True)})
            spread.update({track[i]: float(1 / math.sqrt(v)) for i, v in zip(watched, np.diag(info), strict=True)})
        return out, spread

    def check(self) -> list[Alarm]:
        """Check at the estimator's current time (call after each update: it checks once per
        period, and feeds a running attribution every sample); the new alarms."""
        est = self.estimator
        if self._bank is not None:
            self._feed()
        t = est.t_s
        if t < self._next_s:
            return []
        self._next_s = t + self.period_s
        if self.reference is None:
            if t >= self.baseline_s:
                self.reference = {name: float(est.x[NSTATE + i]) for i, name in enumerate(est.track)}
                self._calm_s = dict.fromkeys(est.track, t)
            return []
        follow_ups = self._follow_ups(t)
        return follow_ups + self._detect(t)

    def _detect(self, t: float) -> list[Alarm]:
        """The detection and attribution stages at a check (module docstring)."""
        est = self.estimator
        assert self.reference is not None
        g, spread = self._statistics()
        self.history.append((t, g))
        for name, gi in g.items():
            if abs(gi) < SINCE_LEVEL:
                self._calm_s[name] = t
                self._calm_sigma[name] = min(self._calm_sigma.get(name, math.inf), spread[name])
        watched = {name: abs(gi) for name, gi in g.items() if not self._is_free(name)}
        top = max(watched, key=watched.__getitem__) if watched else None
        if top is None or watched[top] <= self.threshold:
            self._above_since = None
        elif self._above_since is None:
            self._above_since = t
        if self._bank is not None:
            return self._decide(t)
        if self._above_since is None or t - self._above_since < self.persist_s or t < self._quiet_until_s:
            return []
        assert top is not None
        if not self.attribute:
            value, sigma = est.parameters()[top]
            return self._raise(Alarm(top, WHAT[top], t, self._calm_s[top], self.reference[top], value, sigma))
        self._start_bank(sorted(watched, key=watched.__getitem__, reverse=True), self._calm_s[top])
        return self._decide(t)

    def _raise(self, alarm: Alarm) -> list[Alarm]:
        self._above_since = None
        if alarm.parameter in NON_NEGATIVE and alarm.value + 2 * alarm.sigma < 0:
            self.impossible.append(alarm)  # a negative damping or friction: the model does not fit, no alarm
            self._aside.add(alarm.parameter)
            return []
        stated = TRACKABLE[alarm.parameter][0] is not None and alarm.reference == self.estimator.stated(alarm.parameter)
        if stated and alarm.follows_s is None:  # against the rig as stated (not the run's own, a node's)
            seen = self._calm_sigma.get(alarm.parameter, math.inf)
            alarm = dataclasses.replace(alarm, from_start=abs(alarm.change) < FROM_START_SIGMAS * seen)
        if alarm.parameter == "coupling_sin_n_m":
            p = self.estimator.params
            alarm = dataclasses.replace(alarm, per_spring_m2=2.0 * p.l01_m * p.l04_m)
        self.alarmed[alarm.parameter] = alarm
        i = self.estimator.track.index(alarm.parameter)
        if alarm.parameter in WALK_PER_SQRT_S:  # followed as closely as a change under way needs: a
            # ramp goes on after its alarm, and a slow walk would leave it to the hinge's other law
            self.estimator.drift_per_s[i] = self.walk_for(alarm.parameter, alarm.change, alarm.t_s - alarm.since_s)
        self._moving_since.pop(alarm.parameter, None)
        return [alarm]

    def walk_for(self, name: str, change: float, span_s: float) -> float:
        """The random walk (unit per sqrt(s)) of a change of ``change`` that took ``span_s``:
        |change| / sqrt(span), within the estimator's own walk and ``WALK_PER_SQRT_S``."""
        i = self.estimator.track.index(name)
        walk = abs(change) / math.sqrt(max(span_s, self.period_s))
        return min(max(walk, float(self._drift_per_s[i])), WALK_PER_SQRT_S[name])

    def _follow_ups(self, t: float) -> list[Alarm]:
        """An alarmed change that went on: the parameter's estimate has moved on from the alarm's
        value by more than ``threshold`` sigmas (the alarm's and the estimate's together) for
        ``persist_s`` (where the alarm left the law open, the other law's from its reference too:
        what goes on may go there); alarmed once more, on the one that moved, as still changing."""
        out: list[Alarm] = []
        assert self.reference is not None
        found = self.estimator.parameters() if self.alarmed else {}
        for name, alarm in list(self.alarmed.items()):
            if alarm.follows_s is not None or name not in WALK_PER_SQRT_S or name in self._followed:
                self._moving_since.pop(name, None)
                continue
            watched = [(name, alarm.value, alarm.sigma)]
            if alarm.law_open:
                watched.append((alarm.law_open, self.reference[alarm.law_open], 0.0))
            moved, before, z = max(
                ((n, v, abs(found[n][0] - v) / math.hypot(found[n][1], s)) for n, v, s in watched),
                key=lambda row: row[2],
            )
            if z <= self.threshold:
                self._moving_since.pop(name, None)
                continue
            since = self._moving_since.setdefault(name, t)
            if t - since < self.persist_s:
                continue
            other = OTHER_LAW.get(moved, "")  # a hinge's loss still changing: its law was told from a
            # step's hypotheses, which a change under way fools (a rising damping looks like dry friction)
            value, sigma = found[moved]
            follow = dataclasses.replace(
                alarm, parameter=moved, what=WHAT[moved], reference=self.reference[moved], t_s=t, value=value,
                sigma=sigma, runner_up="", evidence=math.inf, follows_s=alarm.t_s, followed_value=before,
                law_open=other, open_value=None,  # (the other law's estimate stayed where the alarm put it)
            )  # fmt: skip
            if other:
                self._aside.add(other)
            self._followed.add(name)
            self.alarmed[moved] = follow
            self._moving_since.pop(name, None)
            out.append(follow)
        return out

    def _start_bank(self, ranked: list[str], since_s: float) -> None:
        """The bank of hypotheses (module docstring) from the estimator's state now."""
        assert self.reference is not None
        est = self.estimator
        t0, x0, p0 = est.t_s, est.x, est.p
        chosen = list(ranked if self.candidates == 0 else ranked[: self.candidates])
        chosen += [  # a hinge's other law weighed beside it (``OTHER_LAW``)
            other for name in chosen if (other := OTHER_LAW.get(name)) in ranked and other not in chosen
        ]
        names = [UNCHANGED, *chosen, *(name for name in chosen if name in OTHER_LAW)]  # a hinge's laws also
        # as changes under way (what tells their law; the springs' or a node's would name nothing new)
        walking = [k > len(chosen) for k in range(len(names))]
        filters = []
        for hypothesis, walks in zip(names, walking, strict=True):
            x = x0.copy()
            p = np.zeros_like(p0)
            p[:NSTATE, :NSTATE] = p0[:NSTATE, :NSTATE]
            drift = np.zeros(len(est.track))
            for i, name in enumerate(est.track):
                j = NSTATE + i
                if self._is_free(name) or name not in PRIOR_SIGMA:  # free, as in the estimator
                    p[j, j], drift[i] = p0[j, j], est.drift_per_s[i]
                    continue
                x[j] = self.reference[name]
                p[j, j] = (PRIOR_SIGMA[name] * (1.0 if name == hypothesis else PIN_FRACTION)) ** 2
                if self.reference_sigma[i] > 0:  # free within the reference's spread, and wandering
                    if name != hypothesis:
                        p[j, j] = self.reference_sigma[i] ** 2
                    drift[i] = est.drift_per_s[i]
                if walks and name == hypothesis:
                    drift[i] = self.walk_for(name, x0[j] - self.reference[name], t0 - self._calm_s[name])
            f = est.copy(drift_per_s=drift)
            f.t_s, f.x, f.p = t0, x, p
            filters.append(f)
        self._bank = _Bank(names, walking, filters, t0, since_s)
        self._taken = est.count

    def _feed(self) -> None:
        assert self._bank is not None
        est = self.estimator
        new = est.count - self._taken
        if new > 0:
            recent = est.recent
            for k in range(max(0, len(recent) - new), len(recent)):
                self._bank.take(recent[k])
        self._taken = est.count

    def _decide(self, t: float) -> list[Alarm]:
        """Weigh the bank's evidence: a change is named once its explanation beats every other
        by ``margin`` (H0's included), where a hinge's two laws, stepped or still changing, are one
        explanation ("the loss at this hinge changed"); then its law: the steps' better law by
        ``margin`` (waiting for it up to ``decide_s``), unless a change under way fits better
        than every step by ``margin`` and leans to the other law: then its law if it leads by
        ``margin``, else left open (``Alarm.law_open``); left open too where neither kind decides
        by ``decide_s``. The value said is the step's, unless the law came from the changes under
        way (then where the change had got to, with its wider interval): a step of damping fitted a
        walk better too (the model's misfit), and the walk's value was 12 % short of it."""
        bank = self._bank
        assert bank is not None and self.reference is not None
        loglik = bank.loglik
        groups: dict[str, list[int]] = {}
        for k, name in enumerate(bank.names):
            groups.setdefault(min(name, OTHER_LAW.get(name, name)), []).append(k)  # a hinge's laws: one
        best_of = {group: max(members, key=lambda k: loglik[k]) for group, members in groups.items()}
        ranked = sorted(best_of, key=lambda group: loglik[best_of[group]], reverse=True)
        top, second = best_of[ranked[0]], best_of[ranked[1]]
        lead = float(loglik[top] - loglik[second])
        over_null = float(loglik[top] - loglik[0])
        timed_out = t - bank.t0_s >= self.decide_s
        if top == 0:
            if lead >= self.margin or timed_out:  # nothing changed after all: dismissed
                self._dismiss(t)
            return []
        if lead < self.margin and not (timed_out and over_null >= self.margin):
            if timed_out:
                self._dismiss(t)
            return []
        members = groups[ranked[0]]
        steps = [k for k in members if not bank.walking[k]]
        walks = [k for k in members if bank.walking[k]]
        name, law_lead = self._law(steps)
        walk_name, walk_lead = self._law(walks)
        under_way = bool(walks) and max(loglik[k] for k in walks) - max(loglik[k] for k in steps) >= self.margin
        # (a change under way explains the data better than any step, by the margin)
        law_open, from_walks = "", False
        if law_lead < self.margin:  # the steps do not tell the law
            if walk_lead >= self.margin and (under_way or timed_out):
                name, law_lead, from_walks = walk_name, walk_lead, True
            elif not timed_out:
                return []  # decided on more data, up to decide_s
            else:
                law_open = OTHER_LAW.get(name, "")
        elif under_way and walk_name == OTHER_LAW.get(name):  # the kinds disagree, and a change under
            # way fits best: a rising damping read as a step of dry friction
            if walk_lead >= self.margin:
                name, law_lead, from_walks = walk_name, walk_lead, True
            else:
                law_open = walk_name
        # (where the steps fit as well, a lean of the changes under way is no evidence against them:
        # seen, e^1.2-2.8 against a step of damping that the steps named by e^6-8)
        rival = OTHER_LAW.get(name, "")
        best = max((k for k in members if bank.names[k] == name and bank.walking[k] == from_walks),
                   key=lambda k: loglik[k])  # fmt: skip
        i = self.estimator.track.index(name)
        winner = bank.filters[best]
        if not np.max(np.abs(winner.x[:2] - self.estimator.x[:2])) <= DIVERGED_RAD:
            # the winning explanation's own estimate diverged (its likelihood is no evidence): dismissed
            self._dismiss(t)
            return []
        value, sigma = float(winner.x[NSTATE + i]), float(math.sqrt(winner.p[NSTATE + i, NSTATE + i]))
        since = min(self._calm_s[name], bank.since_s)
        self._bank = None
        est = self.estimator
        if winner.t_s == est.t_s:  # the estimate goes on from the winning explanation: the others at
            est.x, est.p = winner.x.copy(), winner.p.copy()  # their references (the change is named
            # once, not again on a parameter it traded off against, as dry friction against damping)
        runner_up, evidence = (bank.names[second], lead) if law_lead >= lead or not rival else (rival, law_lead)
        open_value = None
        if law_open:  # the other law's own estimate, so that the alarm gives the change either way
            k = max(
                (k for k in members if bank.names[k] == law_open and bank.walking[k] == from_walks),
                key=lambda k: loglik[k],
            )
            open_value = float(bank.filters[k].x[NSTATE + self.estimator.track.index(law_open)])
        alarm = Alarm(
            name, WHAT[name], t, since, self.reference[name], value, sigma, runner_up, evidence, law_open=law_open,
            open_value=open_value,
        )  # fmt: skip
        if law_open:
            self._aside.add(law_open)  # the hinge's change is named once, whichever law it is
        return self._raise(alarm)

    def _law(self, members: list[int]) -> tuple[str, float]:
        """Among hypotheses of one explanation (a hinge's two laws, of one kind of change): the
        best one's parameter and its lead over the other law's (inf where alone; "" where none)."""
        bank = self._bank
        assert bank is not None
        if not members:
            return "", -math.inf
        loglik = bank.loglik
        best = max(members, key=lambda k: loglik[k])
        others = [loglik[k] for k in members if bank.names[k] != bank.names[best]]
        return bank.names[best], float(loglik[best] - max(others)) if others else math.inf

    def _dismiss(self, t: float) -> None:
        """The bank ends with nothing alarmed; the checks stay quiet for ``decide_s``."""
        self._bank = None
        self.dismissed.append(t)
        self._quiet_until_s = t + self.decide_s

    def _is_free(self, name: str) -> bool:
        """Left free in the checks: alarmed already, or set aside at an impossible value."""
        return name in self.alarmed or name in self._aside

    def reset(self, parameter: str) -> None:
        """Take a parameter's current estimate as its new reference (the change was acknowledged)."""
        value, _ = self.estimator.parameters()[parameter]
        if self.reference is not None:
            self.reference[parameter] = value
        alarm = self.alarmed.pop(parameter, None)
        self._calm_sigma.pop(parameter, None)  # a new reference: its checks begin again
        self._aside.discard(parameter)
        self._followed.discard(parameter)
        if alarm is not None and alarm.law_open:
            self._aside.discard(alarm.law_open)
        i = self.estimator.track.index(parameter)
        self.estimator.drift_per_s[i] = self._drift_per_s[i]

    def largest_z(self) -> dict[str, float]:
        """Each parameter's largest |g| so far (0 before the baseline)."""
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
