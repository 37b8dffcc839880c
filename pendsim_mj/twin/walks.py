"""Adaptive random walks of the rig's tracked parameters: slow while the rig looks healthy, as fast as
``estimator.TRACKABLE``'s from a suspicion of a change on.

The estimator tracks the rig's parameters (damping, dry friction, the coupling springs) as random
walks. Their rates (``TRACKABLE``) are what follows a change within seconds and tells a hinge's two
loss laws apart in the health monitor's bank; on a healthy rig the same walks follow the swing's
noise a little (each walk is a low-pass path from the innovations into the model), which colours the
angle's innovations (docs/twin.md, Whiteness on the whole twin: scaled by 0.01 the angles were white,
but at 0.1 the monitor named the hinge's other law on 4 of 24 faults). So the walks switch:

- **calm** (the rate ``calm_scale`` times ``TRACKABLE``'s), from the monitor's start on: while no
  check has found a watched rig parameter's statistic g (``HealthMonitor.statistics``) at
  ``SUSPECT_LEVEL`` and no node's recent NIS has exceeded ``SUSPECT_NIS`` for ``CALM_AFTER_S``, no
  attribution runs and nothing is alarmed;
- **alert** (``TRACKABLE``'s rates, the estimator's as it was given): from such a check or such
  innovations on (a step of damping throws the swing's angle off by hundreds of its sigmas within a
  second, when the checks are held for the misfit: the slow walks' narrow interval then led the
  estimate astray, to dry friction and a restart), while the monitor's bank runs, and while an alarm
  stands (until it is reset).

Going alert, each adapted parameter's variance also gets the difference of the two walks over the
calm time behind it (at most ``LOOKBACK_S``): the covariance the fast walk would have had, as if the
change had been followed at its rate from a little before it showed (a fixed-lag reset), so that the
estimate moves to the change at once rather than over the fast walk's own tens of seconds. Going
calm changes nothing in the covariance: it shrinks at the slow rate from there on.

The monitor's own walks (its bank's hypotheses, ``HealthMonitor.walk_for``, a reset parameter's)
are the fast ones it found in the estimator when it was made: make ``AdaptiveWalks`` after it.
"""

from __future__ import annotations

import math

import numpy as np

from pendsim_mj.errors import ParameterError
from pendsim_mj.twin.estimator import NSTATE, RigEstimator
from pendsim_mj.twin.health import SINCE_LEVEL, HealthMonitor

DEFAULT_CALM_SCALE = 0.03  # the calm walks over TRACKABLE's. On bench_twin_whiteness's 8 seeds (all imperfections)
# the angle's median Ljung-Box p went from 0.14 (M1) and 0.03 (M2) at 1 to 0.39-0.48 and 0.03-0.05 at 0.1-0.03,
# 0.53 and 0.06 at 0.01; bench_twin_faults named the right parameter on every step and ramp at 0.03 and 0.01, at
# 0.1 it left one damping ramp's law open (docs/twin.md, Whiteness on the whole twin)
SUSPECT_LEVEL = SINCE_LEVEL  # sigmas: a rig parameter's g at this level is a suspicion (the level below which
# the monitor calls a check calm, ``health.SINCE_LEVEL``; its detection is at 5 for 3 s)
SUSPECT_NIS = 5.0  # a node's recent NIS (2 on a healthy rig) above this is a suspicion: never crossed in 20
# node-hours of simulated chi^2 values (4: 0.45 times an hour); a step of M1's damping crossed it within 0.2 s
NIS_SAMPLES = 20.0  # ... recent: an exponential mean over about this many of its updates (0.25 s at 80 Hz)
CALM_AFTER_S = 10.0  # no suspicion for this long before the walks slow again, s (a detection needs 3 s of
# |g| over 5, and a bank runs for up to 45 s; the monitor's checks are 1 s apart)
LOOKBACK_S = 20.0  # going alert, the fast walk's variance over at most this much calm time behind, s: as the
# estimator's start spread (20 s of TRACKABLE's walk). Without it steps of the springs, damping and dry friction
# were alarmed up to 2 s later and a damping ramp's law was left open; 10 s and 30 s named the same parameters,
# within 1 s of 20 s's times (bench_twin_faults, 14 steps and 10 ramps)


class AdaptiveWalks:
    """Switches the estimator's walks of ``names`` between calm and alert (module docstring).

    Args:
      monitor: the health monitor (its estimator's walks for ``names`` are the alert ones).
      names: the tracked parameters whose walks adapt (the rig's own: not a node's states).
      calm_scale: the calm walks over the alert ones (1: no adaptation).

    Attributes:
      calm: whether the walks are calm now. switches: how many times they went alert.
      alert_s: how long they have been alert in all, s (counted at the checks, 1 s apart).
    """

    def __init__(self, monitor: HealthMonitor, names: tuple[str, ...], calm_scale: float = DEFAULT_CALM_SCALE) -> None:
        if not (math.isfinite(calm_scale) and 0 < calm_scale <= 1):
            raise ParameterError(f"calm_scale must be in (0, 1], got {calm_scale!r}")
        est: RigEstimator = monitor.estimator
        unknown = [name for name in names if name not in est.track]
        if unknown:
            raise ParameterError(f"cannot adapt {', '.join(unknown)}: the estimator does not track it")
        self.monitor, self.names, self.calm_scale = monitor, tuple(names), float(calm_scale)
        self._index = np.array([est.track.index(name) for name in self.names], dtype=np.intp)
        self._fast = est.drift_per_s[self._index].copy()  # unit per sqrt(s): the alert walks
        self.calm = False
        self.switches = 0
        self.alert_s = 0.0
        self._calm_since_s = est.t_s  # the walks calm since, s
        self._quiet_since_s = est.t_s  # the last suspicion (a check's or the innovations'), s
        self._checked_s = est.t_s
        self._nis = [2.0, 2.0]  # each node's recent mean NIS
        self._slow()

    def _slow(self) -> None:
        """The calm walks into the estimator."""
        self.monitor.estimator.drift_per_s[self._index] = self._fast * self.calm_scale
        self.calm = True
        self._calm_since_s = self.monitor.estimator.t_s

    def _alert(self, t_s: float) -> None:
        """The fast walks into the estimator, their variance over the calm time behind added (an
        alarmed parameter keeps the walk its alarm gave it: ``HealthMonitor.walk_for``)."""
        est = self.monitor.estimator
        own = np.array([name not in self.monitor.alarmed for name in self.names])
        index, fast = self._index[own], self._fast[own]
        est.drift_per_s[index] = fast
        span = min(max(t_s - self._calm_since_s, 0.0), LOOKBACK_S)
        added = (1.0 - self.calm_scale**2) * np.square(fast) * span
        j = NSTATE + index
        p = est.p.copy()  # a new array, as the estimator's own steps make: those handed out before stay
        p[j, j] += added
        est.p = p
        self.calm = False
        self.switches += 1

    def suspicious(self) -> bool:
        """Whether the monitor's last check found a watched rig parameter at ``SUSPECT_LEVEL`` or beyond,
        or its bank runs, or an alarm stands."""
        monitor = self.monitor
        if monitor.attributing or monitor.alarmed:
            return True
        if not monitor.history:
            return False
        g = monitor.history[-1][1]
        return any(abs(g.get(name, 0.0)) >= SUSPECT_LEVEL for name in self.names)

    def take(self, t_s: float, node: int, nis: float) -> None:
        """After each of a node's samples taken in (at ``t_s``, s; its NIS): a misfit that shows in
        the innovations within a fraction of a second, before any check can (a step of damping
        throws the swing's angle off by hundreds of its sigmas in a second, and the slow walks'
        narrow interval then leads the estimate astray), is a suspicion too."""
        recent = self._nis[node] + (nis - self._nis[node]) / NIS_SAMPLES
        self._nis[node] = recent
        if recent > SUSPECT_NIS:
            self._quiet_since_s = t_s
            if self.calm:
                self._alert(t_s)

    def at_check(self, t_s: float) -> None:
        """After each of the monitor's checks (at ``t_s``, s): calm or alert from it on."""
        if not self.calm:
            self.alert_s += t_s - self._checked_s
        self._checked_s = t_s
        if self.suspicious():
            self._quiet_since_s = t_s
            if self.calm:
                self._alert(t_s)
        elif not self.calm and t_s - self._quiet_since_s >= CALM_AFTER_S:
            self._slow()
