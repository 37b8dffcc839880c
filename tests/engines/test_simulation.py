"""The simulation API: instants paired correctly, shapes, batches, errors, saving."""

import math

import mujoco
import numpy as np
import pytest

from pendsim_bridge.io.trajectory_file import save_trajectory
from pendsim_mj.engines import fast_planar
from pendsim_mj.engines.reference import solve, solve_batch
from pendsim_mj.engines.simulation import simulate, simulate_batch, simulate_batch_sampled
from pendsim_mj.errors import ParameterError, SimulationDiverged
from pendsim_mj.rig.drives import Drive, Sine
from pendsim_mj.rig.model import SPATIAL, build_model
from pendsim_mj.rig.params import DEFAULT_PARAMS

ENGINES = {
    "mujoco": (simulate, simulate_batch),
    "reference": (solve, solve_batch),
    "fast": (fast_planar.solve, fast_planar.solve_batch),
}


@pytest.fixture(scope="module")
def run_30deg():
    return simulate(DEFAULT_PARAMS, (math.pi / 6, 0.0), (0.0, 0.0), 20.0)


def test_gyro_reads_omega_at_the_same_timestamp(run_30deg):
    # MuJoCo's sensors after a step describe the state before it; a one-row shift would leave
    # errors of about alpha * dt = 0.15 rad/s here.
    tr = run_30deg
    np.testing.assert_allclose(tr.imu_gyro_rad_s[..., 2], tr.omega_rad_s, atol=1e-12)
    np.testing.assert_allclose(tr.imu_gyro_rad_s[..., :2], 0.0, atol=1e-12)  # planar: only z


def test_accelerometer_pairs_with_phi_omega_alpha_of_its_own_instant(run_30deg):
    # spec section 6: tangential r alpha + g sin phi, normal r omega^2 + g cos phi
    tr, p = run_30deg, DEFAULT_PARAMS
    r = np.array([p.om1_m, p.om2_m])
    phi, omega, alpha = tr.phi_rad, tr.omega_rad_s, tr.alpha_rad_s2
    np.testing.assert_allclose(tr.imu_accel_m_s2[..., 0], r * alpha + p.g_m_s2 * np.sin(phi), atol=1e-9)
    np.testing.assert_allclose(tr.imu_accel_m_s2[..., 1], r * omega**2 + p.g_m_s2 * np.cos(phi), atol=1e-9)
    np.testing.assert_allclose(tr.imu_accel_m_s2[..., 2], 0.0, atol=1e-9)


def test_angular_acceleration_vector_in_sensor_axes_is_alpha_about_z(run_30deg):
    tr = run_30deg
    np.testing.assert_allclose(tr.imu_angacc_rad_s2[..., 2], tr.alpha_rad_s2, atol=1e-12)
    np.testing.assert_allclose(tr.imu_angacc_rad_s2[..., :2], 0.0, atol=1e-12)


def test_alpha_is_the_time_derivative_of_omega(run_30deg):
    tr = run_30deg
    w = tr.omega_rad_s
    # fourth-order central difference (plus the RK4 solution's own O(dt^4) error): ~1e-5 rad/s^2 here;
    # pairing alpha with the neighbouring row instead would be off by ~alpha' dt ~ 0.1 rad/s^2
    central = (-w[4:] + 8 * w[3:-1] - 8 * w[1:-3] + w[:-4]) / (12 * tr.dt_s)
    np.testing.assert_allclose(tr.alpha_rad_s2[2:-2], central, atol=1e-4)


def test_orientation_quaternion_is_the_rotation_by_phi(run_30deg):
    tr = run_30deg
    # the IMU's y axis (toward the pivot) in the world: rotate (0, 0, 1) by phi about world -y
    q = tr.imu_quat_wxyz
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    y_axis_world = np.stack([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)], axis=-1)
    phi = tr.phi_rad
    np.testing.assert_allclose(y_axis_world, np.stack([-np.sin(phi), 0 * phi, np.cos(phi)], axis=-1), atol=1e-12)


@pytest.mark.parametrize("engine", ENGINES)
def test_trajectory_shapes_are_as_documented(engine):
    single, _ = ENGINES[engine]
    tr = single(DEFAULT_PARAMS, (0.3, 0.1), (0.0, 0.2), 1.0, 0.01)
    n = 101
    assert tr.t_s.shape == (n,) and tr.t_s[-1] == pytest.approx(1.0)
    shapes = {
        "phi_rad": (n, 2), "omega_rad_s": (n, 2), "alpha_rad_s2": (n, 2), "imu_accel_m_s2": (n, 2, 3),
        "imu_gyro_rad_s": (n, 2, 3), "imu_quat_wxyz": (n, 2, 4), "imu_angacc_rad_s2": (n, 2, 3),
        "spring_length_m": (n, 4), "spring_force_n": (n, 4), "spring_moment_n_m": (n, 2), "kinetic_j": (n,),
        "potential_j": (n,),
        "dissipated_j": (n,),
    }  # fmt: skip
    for name, shape in shapes.items():
        assert getattr(tr, name).shape == shape, name
    assert tr.engine == engine
    np.testing.assert_array_equal(tr.phi_rad[0], [0.3, 0.1])
    np.testing.assert_array_equal(tr.omega_rad_s[0], [0.0, 0.2])


def test_spring_moments_equal_mujocos_own_passive_spring_force(run_30deg):
    # pendsim computes the moments from the anchor points' positions and the stiffness; MuJoCo's
    # passive-force stage computes the generalised tendon spring force itself (qfrc_spring).
    model = build_model()
    data = mujoco.MjData(model)
    for k in range(0, len(run_30deg.t_s), 997):
        data.qpos[:] = run_30deg.phi_rad[k]
        data.qvel[:] = run_30deg.omega_rad_s[k]
        mujoco.mj_forward(model, data)
        np.testing.assert_allclose(run_30deg.spring_moment_n_m[k], data.qfrc_spring, rtol=1e-12, atol=1e-15)


def test_batch_members_equal_single_runs_with_their_own_parameters():
    params = [DEFAULT_PARAMS, DEFAULT_PARAMS.with_overrides(c1_n_m=8.0), DEFAULT_PARAMS.with_overrides(b2_n_m_s=0.0)]
    phi0 = np.array([[0.5, 0.0], [0.2, -0.3], [-1.0, 1.0]])
    batch = simulate_batch(params, phi0, (0.0, 0.0), 5.0, nthread=2)
    assert batch.phi_rad.shape == (3, 501, 2) and len(batch) == 3
    for i in range(3):
        single = simulate(params[i], phi0[i], (0.0, 0.0), 5.0)
        np.testing.assert_array_equal(batch.member(i).phi_rad, single.phi_rad)
        np.testing.assert_array_equal(batch.member(i).imu_accel_m_s2, single.imu_accel_m_s2)
        np.testing.assert_array_equal(batch.member(i).dissipated_j, single.dissipated_j)


@pytest.mark.parametrize("engine", ENGINES)
def test_diverging_run_raises_instead_of_returning_garbage(engine):
    single, _ = ENGINES[engine]
    stiff = DEFAULT_PARAMS.with_overrides(c1_n_m=1e6)  # RK4 at 10 ms is unstable for this spring
    with pytest.raises(SimulationDiverged, match=r"diverged.*reduce dt_s"):
        single(stiff, (0.5, 0.0), (0.0, 0.0), 10.0, 0.01)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"duration_s": 0.0}, "duration_s must be a finite number > 0 s, got 0.0"),
        ({"duration_s": -1.0}, "duration_s must be a finite number > 0 s"),
        ({"dt_s": 0.0}, "dt_s must be a finite number > 0 s, got 0.0"),
        ({"dt_s": float("nan")}, "dt_s must be a finite number > 0 s, got nan"),
        ({"duration_s": 1.005, "dt_s": 0.01}, "must be a whole number of steps"),
        ({"phi0_rad": (float("nan"), 0.0)}, r"phi0_rad must be finite"),
        ({"phi0_rad": (0.1, 0.2, 0.3)}, r"phi0_rad must have shape \(2,\) or \(nbatch, 2\), got \(3,\)"),
    ],
)
def test_bad_arguments_name_the_argument_and_the_allowed_range(engine, kwargs, message):
    single, _ = ENGINES[engine]
    args = {"params": DEFAULT_PARAMS, "phi0_rad": (0.1, 0.0), "omega0_rad_s": (0.0, 0.0), "duration_s": 1.0}
    args.update(kwargs)
    with pytest.raises(ParameterError, match=message):
        single(**args)


def test_batch_with_mismatched_parameter_count_is_rejected():
    with pytest.raises(ParameterError, match="got 2 parameter sets for 3 initial conditions"):
        solve_batch([DEFAULT_PARAMS] * 2, np.zeros((3, 2)), (0.0, 0.0), 1.0)


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_saved_trajectory_reads_back(tmp_path, run_30deg, suffix):
    path = save_trajectory(run_30deg, tmp_path / f"run{suffix}")
    if suffix == ".npz":
        data = np.load(path)
        np.testing.assert_array_equal(data["phi_rad"], run_30deg.phi_rad)
        np.testing.assert_array_equal(data["imu_quat_wxyz"], run_30deg.imu_quat_wxyz)
    else:
        data = np.genfromtxt(path, delimiter=",", names=True)
        np.testing.assert_allclose(data["phi1_rad"], run_30deg.phi_rad[:, 0], rtol=1e-15)
        np.testing.assert_allclose(data["imu_m2_accel_y_m_s2"], run_30deg.imu_accel_m_s2[:, 1, 1], rtol=1e-15)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"run{suffix}"]  # no temporary left


SAMPLED_CASES = {
    "planar, a parameter set per run": ({}, None),
    "spatial": ({"variant": SPATIAL}, None),
    "support shaken and M1 driven": ({}, Drive(torque_m1=Sine(0.2, 1.3, 0.4), pivot_z=Sine(2.0, 0.7))),
}


@pytest.mark.parametrize("case", SAMPLED_CASES)
@pytest.mark.parametrize("every", [1, 3])
def test_sampled_batch_is_the_trajectory_at_every_saved_step(case, every):
    """What a MuJoCo sweep keeps without building Trajectory objects: the same values at the saved
    rows (the dissipated energy integrated over every step, not over the saved ones)."""
    kwargs, drive = SAMPLED_CASES[case]
    params = [DEFAULT_PARAMS, DEFAULT_PARAMS.with_overrides(c1_n_m=8.0, b2_n_m_s=0.003)]
    phi0 = np.array([[0.5, 0.0], [0.2, -1.9]])
    full = simulate_batch(params, phi0, (0.0, 0.0), 3.0, drive=drive, **kwargs)
    sampled = simulate_batch_sampled(params, phi0, (0.0, 0.0), 3.0, every=every, drive=drive, **kwargs)
    rows = slice(None, None, every)
    assert sampled.phi_rad.shape == (2, 300 // every + 1, 2)
    np.testing.assert_array_equal(sampled.phi_rad, full.phi_rad[:, rows])
    np.testing.assert_array_equal(sampled.omega_rad_s, full.omega_rad_s[:, rows])
    np.testing.assert_array_equal(sampled.alpha_rad_s2, full.alpha_rad_s2[:, rows])
    np.testing.assert_array_equal(sampled.total_energy_j, full.total_energy_j[:, rows])
    np.testing.assert_array_equal(sampled.dissipated_j, full.dissipated_j[:, rows])


def test_sampled_batch_conserves_energy_with_what_the_damping_took():
    # an independent check of the sampled energies: undriven, energy + dissipated stays constant
    # to RK4's error (measured 6e-6 of the energy for the larger swing), sampled every 7th step
    phi0 = np.array([[0.5, 0.0], [1.2, -0.8]])
    run = simulate_batch_sampled(DEFAULT_PARAMS, phi0, (0.0, 0.0), 20.0, every=7)
    budget = run.total_energy_j + run.dissipated_j
    assert np.all(run.dissipated_j[:, -1] > 0.05 * run.total_energy_j[:, 0])  # the damping took a share
    np.testing.assert_allclose(budget, np.broadcast_to(budget[:, :1], budget.shape), rtol=2e-5)


@pytest.mark.parametrize("every", [0, 1.5, True])
def test_sampled_batch_refuses_a_bad_sampling_step(every):
    with pytest.raises(ParameterError, match=r"every must be a whole number >= 1"):
        simulate_batch_sampled(DEFAULT_PARAMS, (0.5, 0.0), (0.0, 0.0), 1.0, every=every)
