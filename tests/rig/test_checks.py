"""rig.checks: which run of a batch a diverged run's message speaks of."""

import numpy as np
import pytest

from pendsim_mj.rig.checks import first_nonfinite_run


@pytest.mark.parametrize("run_axis", [0, 1, 2])
def test_the_first_run_with_a_non_finite_value_is_found_along_any_axis(run_axis):
    values = np.zeros((4, 5, 6))
    assert first_nonfinite_run(values, run_axis) is None
    runs = values.shape[run_axis]
    for bad_runs, expected in (([runs - 1], runs - 1), ([2, 1], 1)):
        v = np.moveaxis(values.copy(), run_axis, 0)
        for k, run in enumerate(bad_runs):
            v[run, -1, k] = (np.nan, np.inf)[k % 2]  # one value of the run, deep inside it
        assert first_nonfinite_run(np.moveaxis(v, 0, run_axis), run_axis) == expected


def test_a_single_run_of_states_is_run_zero():
    y = np.ones((5, 1))
    y[3, 0] = -np.inf
    assert first_nonfinite_run(y, run_axis=1) == 0
