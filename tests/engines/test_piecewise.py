"""A run in pieces (pendsim_mj.engines.piecewise): cut with unchanged parameters it is the whole
run, row for row, on every engine; a schedule's ramp is constant pieces at its midpoint values."""

import numpy as np
import pytest

from pendsim_mj.engines import dispatch
from pendsim_mj.engines.piecewise import ParameterChange, run_pieces, schedule_pieces
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import DEFAULT_PARAMS


@pytest.mark.parametrize("engine", ["mujoco", "reference", "fast"])
def test_pieces_with_the_same_parameters_are_the_whole_run(engine):
    whole = dispatch.run(engine, DEFAULT_PARAMS, (0.5, -0.1), (0.2, 0.0), 2.0, 0.01)
    cut = run_pieces(
        engine, [(0, DEFAULT_PARAMS), (37, DEFAULT_PARAMS), (150, DEFAULT_PARAMS)], (0.5, -0.1), (0.2, 0.0), 2.0, 0.01
    )
    np.testing.assert_array_equal(cut.t_s, whole.t_s)
    for name in ("phi_rad", "omega_rad_s", "alpha_rad_s2", "imu_gyro_rad_s", "imu_quat_wxyz"):
        np.testing.assert_allclose(getattr(cut, name), getattr(whole, name), rtol=0, atol=1e-12, err_msg=name)
    np.testing.assert_allclose(cut.dissipated_j, whole.dissipated_j, rtol=0, atol=1e-15)


def test_a_ramp_is_held_at_its_midpoint_values_and_a_later_step_starts_from_its_end():
    ramp = ParameterChange("c1_n_m", 5.0, first_step=100, last_step=125)
    step = ParameterChange("c1_n_m", 4.0, first_step=200, last_step=200)
    other = ParameterChange("b1_n_m_s", 1e-3, first_step=110, last_step=110)
    pieces = schedule_pieces(DEFAULT_PARAMS, [step, ramp, other], ramp_every=10)
    firsts = [a for a, _ in pieces]
    assert firsts == [0, 100, 110, 120, 125, 200]
    c1 = DEFAULT_PARAMS.c1_n_m
    expected = [c1, c1 + (5 / 25) * (5.0 - c1), c1 + (15 / 25) * (5.0 - c1), c1 + (22.5 / 25) * (5.0 - c1), 5.0, 4.0]
    np.testing.assert_allclose([p.c1_n_m for _, p in pieces], expected, rtol=1e-15)
    assert [p.b1_n_m_s for _, p in pieces][1:3] == [DEFAULT_PARAMS.b1_n_m_s, 1e-3]


def test_overlapping_changes_of_one_parameter_and_pieces_past_the_end_are_refused():
    with pytest.raises(ParameterError, match="two changes of c1_n_m overlap"):
        schedule_pieces(
            DEFAULT_PARAMS,
            [ParameterChange("c1_n_m", 5.0, 100, 200), ParameterChange("c1_n_m", 4.0, 150, 150)],
            ramp_every=10,
        )
    with pytest.raises(ParameterError, match="increasing steps below 100"):
        run_pieces("fast", [(0, DEFAULT_PARAMS), (100, DEFAULT_PARAMS)], (0.1, 0.0), (0.0, 0.0), 1.0, 0.01)
