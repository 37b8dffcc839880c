"""Both nodes' samples into one time order: what waits for what, for how long, and what comes
too late."""

from __future__ import annotations

import pytest

from pendsim_mj.errors import ParameterError
from pendsim_mj.twin.merge import SampleMerger


def _times(held) -> list[tuple[int, float]]:
    return [(h.node, h.t_s) for h in held]


def test_a_sample_waits_until_the_other_node_has_reached_its_instant():
    m = SampleMerger(hold_s=0.02)
    m.push(0, 1.000, "a", arrived_s=1.001)
    assert m.pop(1.002) == []  # M2 has sent nothing as new yet
    m.push(1, 1.004, "b", arrived_s=1.005)
    assert _times(m.pop(1.005)) == [(0, 1.000)]  # M2 at 1.004 >= 1.000: M1's goes; M2's waits for M1
    m.push(0, 1.0125, "c", arrived_s=1.013)
    assert _times(m.pop(1.013)) == [(1, 1.004)]


def test_the_two_streams_come_out_in_time_order_whatever_the_arrival_order():
    m = SampleMerger(hold_s=0.02)
    arrivals = [(1, 0.004), (0, 0.0), (0, 0.0125), (1, 0.0165), (1, 0.029), (0, 0.025), (0, 0.0375), (1, 0.0415)]
    out = []
    for k, (node, t) in enumerate(arrivals):
        m.push(node, t, k, arrived_s=0.05 + 0.001 * k)
        out += m.pop(0.05 + 0.001 * k)
    out += m.pop(1.0, final=True)
    assert [h.t_s for h in out] == sorted(t for _, t in arrivals)
    assert m.late == []


def test_a_sample_waits_at_most_the_hold_when_the_other_node_is_silent():
    m = SampleMerger(hold_s=0.02)
    m.push(0, 1.0, "a", arrived_s=1.0)
    assert m.pop(1.019) == []
    assert _times(m.pop(1.020)) == [(0, 1.0)]


def test_a_sample_older_than_one_released_is_late_and_counted():
    m = SampleMerger(hold_s=0.02)
    m.push(0, 1.0, "a", arrived_s=1.0)
    m.pop(1.03)  # released on the hold
    assert not m.push(1, 0.996, "b", arrived_s=1.031)
    assert m.late == [(1, 0.996)]
    assert m.pop(2.0, final=True) == []


@pytest.mark.parametrize("hold_s", [-0.1, float("nan"), 11.0])
def test_a_hold_out_of_range_is_refused(hold_s):
    with pytest.raises(ParameterError, match="hold_s"):
        SampleMerger(hold_s=hold_s)


def test_with_the_period_known_a_sample_older_than_the_other_nodes_next_goes_at_once():
    """Both nodes at 80 Hz, M2 4 ms after M1: each sample goes as soon as it comes (the other
    node's next sample is newer), where without the period each waits for that sample."""
    m = SampleMerger(hold_s=0.02, period_s=0.0125)
    m.push(0, 1.000, "a", arrived_s=1.001)
    m.push(1, 1.004, "b", arrived_s=1.005)
    assert _times(m.pop(1.005)) == [(0, 1.000), (1, 1.004)]  # M1's next, 1.0125, is newer than 1.004
    m.push(0, 1.0125, "c", arrived_s=1.013)
    assert _times(m.pop(1.013)) == [(0, 1.0125)]  # M2's next, 1.0165, is newer
    plain = SampleMerger(hold_s=0.02)
    plain.push(0, 1.000, "a", arrived_s=1.001)
    plain.push(1, 1.004, "b", arrived_s=1.005)
    assert _times(plain.pop(1.005)) == [(0, 1.000)]
    plain.push(0, 1.0125, "c", arrived_s=1.013)
    assert _times(plain.pop(1.013)) == [(1, 1.004)]


def test_with_the_period_known_a_sample_waits_for_the_other_nodes_due_sample_until_it_is_given_up():
    """M1's sample at 1.020 is newer than M2's next (1.0165, due): it waits for it; when that sample
    is lost, until nothing has come from M2 for the hold since its last arrival (1.005 + 0.02), not
    the hold after its own arrival (1.021 + 0.02); a sample that then comes is late."""
    m = SampleMerger(hold_s=0.02, period_s=0.0125)
    m.push(0, 1.000, "a", arrived_s=1.001)
    m.push(1, 1.004, "b", arrived_s=1.005)
    assert _times(m.pop(1.005)) == [(0, 1.000), (1, 1.004)]
    m.push(0, 1.020, "c", arrived_s=1.021)
    assert m.pop(1.021) == []  # 1.020 waits for M2's 1.0165
    assert m.due_s() == pytest.approx(1.025)
    assert m.pop(1.0249) == []
    assert _times(m.pop(1.025)) == [(0, 1.020)]
    assert not m.push(1, 1.0165, "d", arrived_s=1.026)  # it came after all: late
    assert m.late == [(1, 1.0165)]


def test_with_the_period_known_the_first_sample_still_waits_for_the_other_node_to_be_heard():
    m = SampleMerger(hold_s=0.02, period_s=0.0125)
    m.push(0, 1.0, "a", arrived_s=1.0)
    assert m.pop(1.019) == []
    assert _times(m.pop(1.020)) == [(0, 1.0)]


@pytest.mark.parametrize("period_s", [0.0, -0.0125, float("nan"), 11.0])
def test_a_period_out_of_range_is_refused(period_s):
    with pytest.raises(ParameterError, match="period_s"):
        SampleMerger(period_s=period_s)
