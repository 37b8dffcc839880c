"""The unscented filter's compiled arithmetic (``twin.unscented``) against what it must give: the
sigma points carry the estimate's mean and covariance, a linear measurement's moments are the
linear filter's, and the correction is the Kalman update."""

from __future__ import annotations

import numpy as np
import pytest

from pendsim_mj.twin.estimator import _sigma_weights
from pendsim_mj.twin.unscented import accelerations_at, corrected, moments, sigma_points, swing_moments


@pytest.fixture
def estimate():
    rng = np.random.default_rng(7)
    n = 16
    scale = np.concatenate([np.full(4, 0.05), np.logspace(-7, -1, n - 4)])  # the twin's spread of units
    a = rng.normal(size=(n, n))
    p = (a @ a.T / n + 0.1 * np.eye(n)) * np.outer(scale, scale)
    return rng.normal(size=n) * scale, p


@pytest.mark.parametrize("alpha", [1e-3, 0.5])
def test_the_sigma_points_carry_the_estimates_mean_and_covariance(estimate, alpha):
    x, p = estimate
    n = len(x)
    lam, wm, wc = _sigma_weights(n, alpha, 2.0, 0.0)
    points = np.empty((2 * n + 1, n))
    sigma_points(x, p, lam, points)
    np.testing.assert_allclose(wm @ points, x, rtol=0, atol=1e-9 * np.abs(x).max())
    d = points - x
    covariance = (d.T * wc) @ d
    np.testing.assert_allclose(covariance, p, rtol=1e-6, atol=1e-9 * np.abs(p).max())


def test_a_linear_measurements_moments_and_correction_are_the_kalman_filters(estimate):
    x, p = estimate
    n = len(x)
    rng = np.random.default_rng(8)
    h = rng.normal(size=(2, n))
    r = np.diag([1e-3, 2e-3]) ** 2
    lam, wm, wc = _sigma_weights(n, 1e-3, 2.0, 0.0)
    points = np.empty((2 * n + 1, n))
    sigma_points(x, p, lam, points)
    mean, s, pxz = moments(points, x, points @ h.T, wm, wc, r)
    np.testing.assert_allclose(mean, h @ x, rtol=1e-8)
    np.testing.assert_allclose(s, h @ p @ h.T + r, rtol=1e-6)
    np.testing.assert_allclose(pxz, p @ h.T, rtol=1e-6, atol=1e-12)
    z = h @ x + np.array([2e-3, -1e-3])
    gain = p @ h.T @ np.linalg.inv(h @ p @ h.T + r)
    x_new, p_new = corrected(x, p, s, pxz, z - mean)
    np.testing.assert_allclose(x_new, x + gain @ (z - h @ x), rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(p_new, p - gain @ h @ p, rtol=1e-5, atol=1e-9 * np.abs(p).max())
    assert np.array_equal(p_new, p_new.T)


WARM_CHECK = """
import json
from numba.core.registry import CPUDispatcher
from pendsim_mj.engines.fast_planar import step
from pendsim_mj.twin import measurement, unscented
from pendsim_mj.twin.estimator import warm_up
kernels = {f"{m.__name__}.{name}": k for m in (step, unscented, measurement) for name, k in vars(m).items()
           if isinstance(k, CPUDispatcher) and k.py_func.__module__ == m.__name__ and not name.startswith("_")}
warm_up()
warm = {name: sorted(map(str, k.signatures)) for name, k in kernels.items()}
from pendsim_bridge.acquire.emulator import plan
from pendsim_bridge.acquire.packets import GROUP_SLICES
from pendsim_bridge.cli import build_parser
from pendsim_bridge.commands.nodes import spec_from
from pendsim_mj.twin.session import TwinSession
p = plan(spec_from(build_parser().parse_args(["nodes", "--duration-s", "6", "--seed", "1", "--loss", "0.02"])))
session = TwinSession()
q, g, a = GROUP_SLICES["quat"], GROUP_SLICES["gyro"], GROUP_SLICES["accel"]
for t, k, i in p.sent_in_time_order():
    row = p.streams[k].rows[i]
    session.take(k, t, row[q], row[g], row[a])
after = {name: sorted(map(str, k.signatures)) for name, k in kernels.items()}
print(json.dumps([warm, after, session.estimator.count]))
"""


def test_the_warm_up_loads_every_kernel_in_every_form_a_twin_then_uses():
    """``estimator.warm_up`` (a live twin calls it before it listens): a fresh process that warms
    up and then runs a twin on 6 s of emulated nodes meets no kernel signature the warm-up did not
    load (each new one would be loaded, or compiled, behind the first samples: a 279 ms latency
    tail on a 16 s live run before)."""
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", WARM_CHECK], capture_output=True, text=True, timeout=240, check=True)
    warm, after, count = json.loads(out.stdout.strip().splitlines()[-1])
    assert count > 300  # the twin ran
    used = {name.rsplit(".", 1)[1] for name, signatures in after.items() if signatures}
    assert {"predict", "update_moments", "corrected", "swing_moments", "accelerations_at", "add_roughness"} <= used, (
        used
    )
    assert after == warm


@pytest.mark.parametrize(("node", "offset_col"), [(0, -1), (1, -1), (0, 5), (1, 9)])
def test_a_swing_readings_moments_are_the_linear_filters(estimate, node, offset_col):
    """``swing_moments``: the angle x[node] (+ the offset's state), the rate x[2 + node]: H x,
    H P H' + R and P H' with H written out."""
    x, p = estimate
    h = np.zeros((2, len(x)))
    h[0, node] = h[1, 2 + node] = 1.0
    if offset_col >= 0:
        h[0, offset_col] = 1.0
    r = np.diag([3e-4, 2e-3]) ** 2
    mean, s, pxz = swing_moments(x, p, node, offset_col, r[0, 0], r[1, 1])
    np.testing.assert_allclose(mean, h @ x, rtol=1e-12)
    np.testing.assert_allclose(s, h @ p @ h.T + r, rtol=1e-12)
    np.testing.assert_allclose(pxz, p @ h.T, rtol=1e-12, atol=1e-300)


def test_one_states_accelerations_are_the_closed_forms():
    """``accelerations_at`` (the compiled force law from Python) against the numpy closed form, on
    a rig with dry friction and hinge torques."""
    import dataclasses

    from pendsim_mj.engines.fast_planar.closed_form import accelerations, coefficients
    from pendsim_mj.rig.params import DEFAULT_PARAMS

    params = dataclasses.replace(DEFAULT_PARAMS, friction1_n_m=2e-4, friction2_n_m=1e-4)
    c = coefficients([params])
    rng = np.random.default_rng(3)
    for _ in range(50):
        x = rng.normal(size=4) * [1.5, 1.5, 3.0, 3.0]
        tau = rng.normal(size=2) * 0.01
        a1, a2 = accelerations(x[:1], x[1:2], x[2:3], x[3:4], c, np.array([[tau[0]], [tau[1]], [0.0], [0.0]]))
        b1, b2 = accelerations_at(x, c[:, 0].copy(), tau[0], tau[1])
        assert b1 == pytest.approx(a1[0], rel=1e-12, abs=1e-12)
        assert b2 == pytest.approx(a2[0], rel=1e-12, abs=1e-12)
