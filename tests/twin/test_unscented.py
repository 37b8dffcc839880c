"""The unscented filter's compiled arithmetic (``twin.unscented``) against what it must give: the
sigma points carry the estimate's mean and covariance, a linear measurement's moments are the
linear filter's, and the correction is the Kalman update."""

from __future__ import annotations

import numpy as np
import pytest

from pendsim_mj.twin.estimator import _sigma_weights
from pendsim_mj.twin.unscented import correct, moments, sigma_points


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
    x_new, p_new = x.copy(), p.copy()
    correct(x_new, p_new, s, pxz, z - mean)
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
    assert {"predict", "update_moments", "correct", "add_roughness"} <= used, used
    assert after == warm
