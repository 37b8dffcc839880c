"""The rig's parameters' adaptive walks (``twin.walks``): slow while the rig looks healthy, as fast as
``TRACKABLE``'s from a suspicion of a change on (a rig parameter's g at the suspicion level, a burst
of large innovations, a bank of hypotheses, an alarm), with the fast walk's variance over the calm
time behind added at the switch; slow again after a quiet spell; the monitor's own walks stay fast."""

from __future__ import annotations

import math

import numpy as np
import pytest
from emulated_twin import twin_on_nodes

from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.twin.estimator import NSTATE, TRACKABLE, RigEstimator
from pendsim_mj.twin.health import Alarm, HealthMonitor
from pendsim_mj.twin.session import RIG_PARAMETERS
from pendsim_mj.twin.walks import CALM_AFTER_S, LOOKBACK_S, SUSPECT_LEVEL, SUSPECT_NIS, AdaptiveWalks

TRACKED = (*RIG_PARAMETERS, "offset_m1_rad", "offset_m2_rad")
SCALE = 0.03


def _walks(t0_s: float = 0.0) -> tuple[RigEstimator, HealthMonitor, AdaptiveWalks]:
    estimator = RigEstimator(DEFAULT_PARAMS, track=TRACKED)
    estimator.start(t0_s, [0.3, 0.1, 0.0, 0.0])
    monitor = HealthMonitor(estimator)
    return estimator, monitor, AdaptiveWalks(monitor, RIG_PARAMETERS, SCALE)


def _fast(name: str) -> float:
    return TRACKABLE[name][2]


def test_the_rigs_parameters_walk_slowly_while_calm_and_the_node_states_as_they_were():
    estimator, monitor, walks = _walks()
    assert walks.calm
    for i, name in enumerate(TRACKED):
        expected = _fast(name) * (SCALE if name in RIG_PARAMETERS else 1.0)
        assert estimator.drift_per_s[i] == pytest.approx(expected)
    # the monitor's own walks (its bank's hypotheses, ``walk_for``'s floor, a reset) stay the fast ones
    assert monitor.walk_for("b1_n_m_s", 0.0, 1.0) == pytest.approx(_fast("b1_n_m_s"))


def test_a_burst_of_large_innovations_makes_the_walks_fast_and_widens_their_interval():
    """A step of damping throws the angle off by hundreds of sigmas within a second, before any
    check: the node's recent NIS above ``SUSPECT_NIS`` switches at once, and each parameter's
    variance gets the fast walk's over the calm time behind (at most ``LOOKBACK_S``)."""
    estimator, _, walks = _walks()
    before = estimator.p.diagonal().copy()
    walks.take(30.0, 0, 2.0 * SUSPECT_NIS)  # one sample: the recent mean barely moves
    assert walks.calm
    for k in range(20):
        walks.take(30.0 + 0.0125 * (k + 1), 0, 50.0)
    assert not walks.calm and walks.switches == 1
    span = min(30.0, LOOKBACK_S)
    for i, name in enumerate(TRACKED):
        fast = name in RIG_PARAMETERS
        assert estimator.drift_per_s[i] == pytest.approx(_fast(name))
        added = (1 - SCALE**2) * _fast(name) ** 2 * span if fast else 0.0
        assert estimator.p[NSTATE + i, NSTATE + i] == pytest.approx(before[NSTATE + i] + added)


def test_the_walks_slow_again_after_a_quiet_spell():
    estimator, monitor, walks = _walks()
    g = dict.fromkeys(monitor.estimator.track, 0.0)
    monitor.history.append((5.0, g | {"friction2_n_m": SUSPECT_LEVEL + 0.1}))
    walks.at_check(5.0)
    assert not walks.calm
    for t in (6.0, 10.0, 5.0 + CALM_AFTER_S - 0.5):
        monitor.history.append((t, g))
        walks.at_check(t)
        assert not walks.calm
    monitor.history.append((5.0 + CALM_AFTER_S, g))
    walks.at_check(5.0 + CALM_AFTER_S)
    assert walks.calm and walks.alert_s == pytest.approx(CALM_AFTER_S)
    i = TRACKED.index("friction2_n_m")
    assert estimator.drift_per_s[i] == pytest.approx(SCALE * _fast("friction2_n_m"))


def test_a_node_states_statistic_is_no_suspicion_of_the_rig():
    _, monitor, walks = _walks()
    monitor.history.append((5.0, dict.fromkeys(monitor.estimator.track, 0.0) | {"offset_m1_rad": 4.0}))
    walks.at_check(5.0)
    assert walks.calm


def test_the_walks_stay_fast_while_an_alarm_stands_and_keep_the_alarmed_ones_walk():
    estimator, monitor, walks = _walks()
    alarm = Alarm("b1_n_m_s", "damping at M1's hinge", 17.0, 10.0, 7e-4, 8.4e-4, 1e-6)
    monitor._raise(alarm)
    i = TRACKED.index("b1_n_m_s")
    alarmed_walk = float(estimator.drift_per_s[i])
    assert alarmed_walk > 10 * _fast("b1_n_m_s")  # as fast as its change came (``walk_for``)
    quiet = dict.fromkeys(monitor.estimator.track, 0.0)
    for t in np.arange(18.0, 18.0 + 3 * CALM_AFTER_S):
        monitor.history.append((float(t), quiet))
        walks.at_check(float(t))
        assert not walks.calm
    assert estimator.drift_per_s[i] == alarmed_walk
    monitor.reset("b1_n_m_s")  # acknowledged: calm again after a quiet spell, every walk slow
    t_s = 18.0 + 3 * CALM_AFTER_S
    for t in (t_s, t_s + CALM_AFTER_S):
        monitor.history.append((t, quiet))
        walks.at_check(t)
    assert walks.calm and estimator.drift_per_s[i] == pytest.approx(SCALE * _fast("b1_n_m_s"))


@pytest.mark.parametrize("scale", [0.0, -0.1, 1.5, math.nan])
def test_a_calm_scale_out_of_range_is_refused(scale):
    _, monitor, _ = _walks()
    with pytest.raises(ParameterError, match="calm_scale"):
        AdaptiveWalks(monitor, RIG_PARAMETERS, scale)


def test_only_tracked_parameters_adapt():
    estimator = RigEstimator(DEFAULT_PARAMS, track=("b1_n_m_s",))
    with pytest.raises(ParameterError, match="friction1_n_m"):
        AdaptiveWalks(HealthMonitor(estimator), ("b1_n_m_s", "friction1_n_m"))


def test_the_twin_on_a_healthy_run_stays_calm_and_a_step_of_damping_is_alarmed_on_it():
    """The whole twin on the emulator's imperfect nodes: a healthy run keeps its walks calm once the
    start has settled; a step of M1's damping switches them within a second, and is alarmed on its
    own parameter."""
    nodes = ["--hold-s", "2", "--seed", "1", "--phi1-deg", "30", "--heading-deg", "40", "--mount-misalignment-deg",
             "2", "--fusion-error-deg", "0.2", "--hold-wobble-deg", "1", "--loss", "0.02"]  # fmt: skip
    healthy = twin_on_nodes(["--duration-s", "40", *nodes])
    assert healthy._walks is not None and healthy._walks.calm
    assert healthy._walks.alert_s <= CALM_AFTER_S + 5.0
    assert not healthy.summary().alarms
    stepped = twin_on_nodes(["--duration-s", "40", *nodes, "--fault", "damping:m1*2@15"])
    alarms = stepped.summary().alarms
    assert stepped._walks is not None and stepped._walks.switches >= 1
    assert alarms and alarms[0].parameter == "b1_n_m_s" and alarms[0].t_s < 17.0 + 15.0
