"""The planar damping fit (pendsim_mj.estimation.planar_fit): honest intervals (coverage over seeded
synthetic records made with MuJoCo and the BNO055 model), accuracy with the nodes'
imperfections, and the choice between viscous and dry-friction damping."""

import math

import numpy as np
import pytest

from pendsim_mj.engines import fast_planar
from pendsim_mj.engines.simulation import simulate, simulate_batch
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation import planar_fit
from pendsim_mj.estimation.alignment import NodeSamples, align
from pendsim_mj.estimation.planar_fit import fit_planar
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, sample_imu
from pendsim_mj.sensors.imperfections import Imperfections

RECORDS = 60  # 120 intervals; at a true 95 % the count of misses has sd 1.7 per 60


def _fit(traj, config, law="viscous", hold_s=1.0):
    args, keywords = _record(traj, config, hold_s)
    return fit_planar(*args, **keywords, law=law)


def _record(traj, config, hold_s=1.0):
    """fit_planar's arguments for a record sampled from a trajectory: (params, at, omega) and the
    alignment's keywords (noise, start state, relative timing range)."""
    imu = sample_imu(traj, config, hold_s=hold_s)
    nodes = []
    for k in range(2):
        stamp, log, received = imu.node_times(k)
        values = (imu.quat_wxyz[received, k], imu.gyro_rad_s[received, k], imu.accel_m_s2[received, k])
        nodes.append(NodeSamples(log[received], *values, stamp_s=stamp[received]))
    run = align(nodes, DEFAULT_PARAMS, fusion_rate_hz=config.fusion_rate_hz)
    at, omega = run.both_nodes("value_t_s"), run.both_nodes("omega_rad_s")
    return (
        (DEFAULT_PARAMS, at, omega),
        dict(
            gyro_sigma_rad_s=run.gyro_sigma_rad_s, phi0_rad=run.start.phi_rad, omega0_rad_s=run.start.omega_rad_s,
            moving=run.start.kind != "release", timing_range_s=run.relative_timing_range_s,
        ),
    )  # fmt: skip


def test_95_percent_intervals_cover_the_true_damping_90_to_99_percent_of_the_time():
    rng = np.random.default_rng(11)
    b = np.stack([rng.uniform(4e-4, 1.2e-3, RECORDS), rng.uniform(2e-4, 1e-3, RECORDS)], axis=1)
    params = [DEFAULT_PARAMS.with_overrides(b1_n_m_s=x, b2_n_m_s=y) for x, y in b]
    phi0 = np.stack([np.radians(rng.uniform(20, 40, RECORDS)), np.zeros(RECORDS)], axis=1)
    runs = simulate_batch(params, phi0, np.zeros_like(phi0), 20.0)
    covered = np.zeros(2)
    for i in range(RECORDS):
        fit = _fit(runs.member(i), Bno055(seed=100 + i))[0]
        covered += np.abs(fit.values[:2] - b[i]) <= fit.ci95[:2]
    coverage = covered / RECORDS
    assert np.all((coverage >= 0.90) & (coverage <= 0.99)), coverage


@pytest.fixture(scope="module")
def imperfect_fit():
    truth = DEFAULT_PARAMS.with_overrides(b1_n_m_s=9e-4, b2_n_m_s=3e-4)
    traj = simulate(truth, (math.radians(34), 0.0), (0.0, 0.0), 30.0)
    imperfect = Imperfections(
        heading_rad=1.0,
        axis_map_config=(0x21, 0x24),
        axis_map_sign=(0x01, 0x04),
        fusion_error_rad=0.003,
        packet_loss=0.05,
        loss_burst_samples=3,
        clock_drift_ppm=(0.0, 50.0),
        clock_offset_s=(0.0, 12.0),
        latency_s=0.002,
        fusion_phase_s=(0.0031, 0.0074),
    )
    return _fit(traj, Bno055(seed=5, imperfections=imperfect), law="auto")


def test_damping_is_within_2_percent_with_the_nodes_imperfections(imperfect_fit):
    best = imperfect_fit[0]
    assert best.law == "viscous"
    np.testing.assert_allclose([best.value("b1_n_m_s"), best.value("b2_n_m_s")], [9e-4, 3e-4], rtol=0.02)


def test_a_record_with_dry_friction_is_identified_as_coulomb_and_a_viscous_one_as_viscous(imperfect_fit):
    dry = DEFAULT_PARAMS.with_overrides(b1_n_m_s=0.0, b2_n_m_s=0.0, friction1_n_m=1e-3, friction2_n_m=4e-4)
    fits = _fit(simulate(dry, (math.radians(34), 0.0), (0.0, 0.0), 20.0), Bno055(seed=8), law="auto")
    assert fits[0].law == "coulomb"
    best = fits[0]
    # MuJoCo's soft frictionloss against the planar law: a few per cent (docs/identification.md)
    np.testing.assert_allclose([best.value("friction1_n_m"), best.value("friction2_n_m")], [1e-3, 4e-4], rtol=0.05)
    by_law = {f.law: f for f in fits}
    assert by_law["viscous"].bic > by_law["coulomb"].bic + 100
    viscous = {f.law: f for f in imperfect_fit}
    assert viscous["coulomb"].bic > viscous["viscous"].bic + 100
    assert viscous["both"].bic > viscous["viscous"].bic  # two idle parameters cost 2 ln n


def test_a_run_that_starts_mid_swing_fits_its_start_rates_too():
    truth = DEFAULT_PARAMS.with_overrides(b1_n_m_s=7e-4, b2_n_m_s=5e-4)
    traj = simulate(truth, (0.2, -0.05), (1.1, 0.3), 20.0)
    best = _fit(traj, Bno055(seed=9), hold_s=0.0)[0]
    assert "omega1_0" in best.names
    np.testing.assert_allclose([best.value("b1_n_m_s"), best.value("b2_n_m_s")], [7e-4, 5e-4], rtol=0.02)


def _explicit_normal_equations(model, x):
    """The reference for ``_Model.normal_equations``: the whole n x P Jacobian assembled from
    rates_at's sensitivities (the kernel's rolled unknowns, then the release offset's column
    d rate / d tau, then M2's timing column -d rate / d tau, 0 for M1), and BLAS's products."""
    rolled = tuple(name for name in model.names if name not in ("release_offset_s", "timing2_s"))
    coef, omega0, release, at = model._start(x)
    p, d = len(model.damping), model.data
    rates, sens, slopes = fast_planar.rates_at(
        coef, x[p : p + 2], omega0, at, planar_fit.FIT_DT_S, release_s=release, wrt=rolled, inputs=d.inputs
    )
    blocks, residuals = [], []
    for node in range(2):
        cols = [sens[node]]
        if not model.moving:
            cols.append(slopes[node][:, None])
        if model.timed:
            cols.append((-slopes[node] if node else np.zeros_like(slopes[node]))[:, None])
        blocks.append(np.hstack(cols) / d.sigma[node])
        residuals.append((rates[node] - d.gyro[node]) / d.sigma[node])
    jac, r = np.vstack(blocks), np.concatenate(residuals)
    return jac.T @ jac, jac.T @ r, float(r @ r)


@pytest.mark.parametrize("start", ["release", "moving"])
def test_the_fit_from_summed_normal_equations_equals_the_fit_from_the_explicit_jacobian(start, monkeypatch):
    """The fit sums J^T J, J^T r and r.r in the kernel (no n x P Jacobian); on a record with
    imperfections (release from rest or a start in motion, M2's timing fitted) its estimates and
    95 % intervals equal those of the same fit on the explicit Jacobian's products to 1e-9
    relative (of the interval, for a value pinned at its bound 0): the sums' order differs from
    BLAS's, rounding only."""
    truth = DEFAULT_PARAMS.with_overrides(b1_n_m_s=9e-4, b2_n_m_s=3e-4, friction1_n_m=2e-4)
    imperfect = Imperfections(fusion_error_rad=0.003, packet_loss=0.05, fusion_phase_s=(0.0031, 0.0074))
    if start == "release":
        traj, hold_s = simulate(truth, (math.radians(30), 0.0), (0.0, 0.0), 12.0), 1.0
    else:
        traj, hold_s = simulate(truth, (0.2, -0.05), (1.1, 0.3), 12.0), 0.0
    args, keywords = _record(traj, Bno055(seed=4, imperfections=imperfect), hold_s)
    summed = fit_planar(*args, **keywords, law="both")[0]
    monkeypatch.setattr(planar_fit._Model, "normal_equations", _explicit_normal_equations)
    explicit = fit_planar(*args, **keywords, law="both")[0]
    assert summed.names == explicit.names
    assert "timing2_s" in summed.names  # the fusion phases leave M2's timing open
    assert ("omega1_0" in summed.names) == (start == "moving")
    # relative to the value, or to its interval for a value at its bound (a dry friction at ~0)
    size = np.maximum(np.abs(explicit.values), explicit.ci95)
    assert np.all(np.abs(summed.values - explicit.values) <= 1e-9 * size), (summed.values - explicit.values) / size
    np.testing.assert_allclose(summed.ci95, explicit.ci95, rtol=1e-9, atol=0)
    assert summed.bic == pytest.approx(explicit.bic, rel=1e-9)


def test_ljung_box_p_equals_the_fft_autocorrelations_and_tells_white_from_correlated_noise():
    """The direct lag sums give the statistic of the zero-padded FFT autocorrelation (the previous
    computation) to 1e-12; white noise passes, AR(1) noise with coefficient 0.1 fails."""
    from scipy import fft, stats

    rng = np.random.default_rng(5)
    white = rng.normal(size=20_000)
    ar = white.copy()
    for i in range(1, len(ar)):
        ar[i] += 0.1 * ar[i - 1]
    for series in (white, ar):
        r = series - series.mean()
        n, lags = len(r), planar_fit.LJUNG_BOX_LAGS
        spectrum = fft.rfft(r, 2 * n)
        acov = fft.irfft(spectrum * np.conj(spectrum), 2 * n)[: lags + 1]
        rho = acov[1:] / acov[0]
        q = n * (n + 2) * np.sum(rho * rho / (n - np.arange(1, lags + 1)))
        assert planar_fit.ljung_box_p(series) == pytest.approx(stats.chi2.sf(q, lags), rel=1e-9, abs=1e-12)
    assert planar_fit.ljung_box_p(white) > 0.01
    assert planar_fit.ljung_box_p(ar) < 1e-10


def test_the_fit_takes_each_nodes_own_arrays_as_it_takes_the_m_by_2_columns():
    """fit_planar on the pair of per-node arrays (what validate passes, no (m, 2) copies) gives the
    fit of the (m, 2) arrays with NaN padding, bit for bit; a wrong shape is a ParameterError."""
    truth = DEFAULT_PARAMS.with_overrides(b1_n_m_s=8e-4, b2_n_m_s=4e-4)
    imperfect = Imperfections(packet_loss=0.05, fusion_phase_s=(0.002, 0.006))
    (params, at, omega), keywords = _record(
        simulate(truth, (math.radians(30), 0.0), (0.0, 0.0), 8.0), Bno055(seed=3, imperfections=imperfect)
    )
    ok = [np.isfinite(at[:, k]) & np.isfinite(omega[:, k]) for k in range(2)]
    at_pair = tuple(np.ascontiguousarray(at[ok[k], k]) for k in range(2))
    omega_pair = tuple(omega[ok[k], k] for k in range(2))
    assert len(at_pair[0]) != len(at_pair[1])  # the losses differ: the (m, 2) arrays hold NaN
    by_columns = fit_planar(params, at, omega, **keywords, law="viscous")[0]
    by_node = fit_planar(params, at_pair, omega_pair, **keywords, law="viscous")[0]
    np.testing.assert_array_equal(by_node.values, by_columns.values)
    np.testing.assert_array_equal(by_node.ci95, by_columns.ci95)
    with pytest.raises(ParameterError, match="per-node"):
        fit_planar(params, at[:, 0], omega[:, 0], **keywords)
