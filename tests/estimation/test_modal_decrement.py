"""The per-mode decrement (pendsim_mj.estimation.identification.modal_decrement) against the damping that
made coupled runs of the planar equations (fast kernel, no noise): proportional and
non-proportional damping, small swings and 30 deg; the paper's per-pendulum decrement on the same
runs is biased."""

import math

import numpy as np
import pytest

from pendsim_mj.engines import fast_planar
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.identification import log_decrement, modal_decrement
from pendsim_mj.rig.params import DEFAULT_PARAMS

P = DEFAULT_PARAMS
CASES = {
    "non-proportional": (9e-4, 3e-4),
    "proportional": (9e-4, 9e-4 * P.j2_kg_m2 / P.j1_kg_m2),
    "reversed": (3e-4, 9e-4),
}


def _run(b, deg):
    truth = P.with_overrides(b1_n_m_s=b[0], b2_n_m_s=b[1])
    return truth, fast_planar.solve(truth, (math.radians(deg), 0.0), (0.0, 0.0), 121.0, 0.01)


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize(("deg", "rtol"), [(3, 1e-3), (30, 1e-2)])
def test_per_mode_decrement_recovers_b1_b2_on_coupled_runs(case, deg, rtol):
    truth, run = _run(CASES[case], deg)
    found = modal_decrement(run.t_s, run.phi_rad, truth, 120.0)
    np.testing.assert_allclose(found.b_n_m_s, CASES[case], rtol=rtol)
    np.testing.assert_allclose(found.frequency_hz[0], 0.877, atol=0.01)  # the linearised M1 mode


def test_the_papers_per_pendulum_decrement_is_biased_where_the_modal_one_is_not():
    truth, run = _run(CASES["non-proportional"], 3)
    paper = np.array([d.b_n_m_s for d in log_decrement(run.t_s, run.phi_rad, truth, 120.0)])
    modal = modal_decrement(run.t_s, run.phi_rad, truth, 120.0).b_n_m_s
    assert abs(paper[1] / 3e-4 - 1) > 0.1
    assert abs(modal[1] / 3e-4 - 1) < 1e-3


def test_a_record_without_swing_is_refused():
    t = np.arange(1000) * 0.01
    with pytest.raises(ParameterError, match="amplitude peaks"):
        modal_decrement(t, np.zeros((1000, 2)), P, 120.0)
