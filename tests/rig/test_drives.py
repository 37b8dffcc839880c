"""Drives: torques at the hinges, support motion and parametric (vertical pivot) excitation, in
the MuJoCo model and the planar reference, checked against each other and against independent
physics (the equivalence of a uniformly accelerated support and gravity, Galilean invariance,
the static deflection under a torque, the energy balance with the input's work)."""

import math

import mujoco
import numpy as np
import pytest
from mujoco import rollout

from pendsim_bridge.io.trajectory_file import save_trajectory
from pendsim_mj.engines import reference
from pendsim_mj.engines.linearised import linear_modes
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.errors import ModelError, ParameterError
from pendsim_mj.nonlinear.flow import RigFlow
from pendsim_mj.rig.drives import (
    CHANNEL_LABELS,
    Chirp,
    Drive,
    Sampling,
    Sine,
    SteppedSine,
    Target,
    TimeSeries,
    frequency_hz,
    held_inputs,
    phase_rad,
    read_time_series_csv,
    signal_values,
)
from pendsim_mj.rig.model import Clamp, build_model, exact_mjcf
from pendsim_mj.rig.params import DEFAULT_PARAMS

DEG = math.pi / 180


def _csv_drive(tmp_path) -> TimeSeries:
    t = np.arange(0.0, 120.01, 0.05)
    torque = 0.002 * np.sin(2 * math.pi * 1.47 * t) * np.exp(-(((t - 40) / 30) ** 2))
    path = tmp_path / "torque.csv"
    np.savetxt(path, np.column_stack([t, torque]), delimiter=",", header="t_s,torque_n_m", comments="")
    return read_time_series_csv(path)


def _cases(tmp_path) -> dict[str, Drive]:
    return {
        "torque_m1 sine near mode 1": Drive(torque_m1=Sine(0.004, 0.86)),
        "torque_m2 linear chirp": Drive(torque_m2=Chirp(0.004, 0.6, 2.0, 100.0)),
        "support_x sine": Drive(support_x=Sine(0.6, 0.9, phase_rad=0.3)),
        "pivot_z sine in the principal tongue": Drive(pivot_z=Sine(3.0, 1.755)),
        "pivot_z log chirp": Drive(pivot_z=Chirp(2.0, 0.5, 3.0, 120.0, "log")),
        "torque_m1 stepped sine": Drive(torque_m1=SteppedSine.linear(0.003, 0.75, 0.95, 6, 20.0)),
        "torque_m2 from a CSV file": Drive(torque_m2=_csv_drive(tmp_path)),
        "all four at once": Drive(
            torque_m1=Sine(0.002, 0.8), torque_m2=Sine(0.002, 1.3), support_x=Sine(0.3, 1.1), pivot_z=Sine(1.0, 1.7)
        ),
    }


def test_every_drive_agrees_between_mujoco_and_the_reference_to_1e_9_rad_over_120_s(tmp_path):
    cases = _cases(tmp_path)
    phi0 = (30 * DEG, 0.0)
    # one reference batch: every case and, last, the undriven run
    drives = [*cases.values(), None]
    # the reference with MuJoCo's rule (each step's midpoint value held over it: Sampling.HELD)
    ref = reference.solve_batch(
        DEFAULT_PARAMS, [phi0] * len(drives), (0.0, 0.0), 120.0, drive=drives, sampling=Sampling.HELD
    )
    free = ref.member(len(cases))
    for i, (name, drive) in enumerate(cases.items()):
        mj = simulate(DEFAULT_PARAMS, phi0, (0.0, 0.0), 120.0, drive=drive)
        r = ref.member(i)
        assert np.max(np.abs(mj.phi_rad - r.phi_rad)) < 1e-9, name
        assert np.max(np.abs(mj.omega_rad_s - r.omega_rad_s)) < 1e-8, name
        # the drive did something: the swing differs from the undriven run's
        assert np.max(np.abs(r.phi_rad - free.phi_rad)) > 0.02, name
        # derived quantities: IMU specific force (the support's acceleration included), moments, energies
        np.testing.assert_allclose(mj.imu_accel_m_s2, r.imu_accel_m_s2, atol=1e-8, err_msg=name)
        np.testing.assert_allclose(mj.spring_moment_n_m, r.spring_moment_n_m, atol=1e-9, err_msg=name)
        np.testing.assert_allclose(mj.kinetic_j, r.kinetic_j, atol=1e-9, err_msg=name)
        np.testing.assert_allclose(mj.potential_j, r.potential_j, atol=1e-9, err_msg=name)
        np.testing.assert_array_equal(mj.drive_input, r.drive_input)
        # the support's displacement: MuJoCo's heavy carriage against exact integration of the
        # held accelerations (the carriage sags by (m1 + m2) g / 1e12 m/s^2: 3e-8 m in 120 s)
        np.testing.assert_allclose(mj.support_m, r.support_m, atol=1e-7, err_msg=name)


def _rollout_with_gravity(gravity_world, phi0, nstep, dt_s=0.01):
    model = build_model(DEFAULT_PARAMS, timestep_s=dt_s)
    model.opt.gravity[:] = gravity_world
    data = mujoco.MjData(model)
    state = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    data.qpos[:] = phi0
    mujoco.mj_getState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    states, _ = rollout.rollout(model, [data], state[None], nstep=nstep)
    return np.concatenate([[phi0], states[0, :, 1:3]])


def _constant(value: float, duration_s: float) -> TimeSeries:
    return TimeSeries((0.0, duration_s), (value, value), source="constant")


def test_a_constant_vertical_support_acceleration_is_stronger_gravity():
    # Einstein's equivalence: in the frame of a support accelerating upward by a, everything
    # feels g + a. MuJoCo's carriage against the plain model with gravity g + a.
    a = 2.5
    phi0 = (40 * DEG, -10 * DEG)
    driven = simulate(DEFAULT_PARAMS, phi0, (0.0, 0.0), 20.0, drive=Drive(pivot_z=_constant(a, 20.0)))
    heavier = _rollout_with_gravity([0.0, 0.0, -(DEFAULT_PARAMS.g_m_s2 + a)], phi0, 2000)
    assert np.max(np.abs(driven.phi_rad - heavier)) < 1e-9
    # and the support rose as a t^2 / 2 (zero mean velocity: it starts moving down at a t_end / 2)
    z = driven.support_m[:, 1]
    t = driven.t_s
    np.testing.assert_allclose(z, 0.5 * a * t**2 - 0.5 * a * t[-1] * t, atol=1e-7)


def test_a_constant_horizontal_support_acceleration_is_tilted_gravity():
    # A support accelerating toward +y (world +x) by a: everything feels gravity plus -a along
    # world x, so the rest pose leans toward negative phi.
    a = 1.5
    phi0 = (20 * DEG, 5 * DEG)
    driven = simulate(DEFAULT_PARAMS, phi0, (0.0, 0.0), 20.0, drive=Drive(support_x=_constant(a, 20.0)))
    tilted = _rollout_with_gravity([-a, 0.0, -DEFAULT_PARAMS.g_m_s2], phi0, 2000)
    assert np.max(np.abs(driven.phi_rad - tilted)) < 1e-9
    # the mean swing of M1 is shifted toward negative angles
    free = simulate(DEFAULT_PARAMS, phi0, (0.0, 0.0), 20.0)
    assert np.mean(driven.phi_rad[:, 0]) < np.mean(free.phi_rad[:, 0]) - 0.05


def test_the_support_velocity_does_not_matter_galilean_invariance():
    # simulate() starts the support with the drift-free velocity; RigFlow starts it at rest
    drive = Drive(support_x=Sine(0.8, 1.1), pivot_z=Sine(1.2, 1.6))
    tr = simulate(DEFAULT_PARAMS, (25 * DEG, 0.0), (0.0, 0.0), 20.0, drive=drive)
    assert abs(np.mean(np.gradient(tr.support_m[:, 0], tr.t_s))) < 1e-3  # drift-free
    with RigFlow(DEFAULT_PARAMS, drive.targets) as flow:
        x = flow.run([[25 * DEG, 0.0, 0.0, 0.0]], 0.01, 2000, held_inputs(drive, 2000, 0.01)[None])[0]
    assert np.max(np.abs(x[:, :2] - tr.phi_rad)) < 1e-10


def test_a_small_constant_torque_deflects_the_rig_by_the_inverse_stiffness():
    # static equilibrium K phi = tau, K from the reference's linearisation; heavy damping settles it
    params = DEFAULT_PARAMS.with_overrides(b1_n_m_s=0.05, b2_n_m_s=0.05)
    tau = np.array([1e-3, -5e-4])
    drive = Drive(torque_m1=_constant(tau[0], 60.0), torque_m2=_constant(tau[1], 60.0))
    tr = simulate(params, (0.0, 0.0), (0.0, 0.0), 60.0, drive=drive)
    expected = np.linalg.solve(linear_modes(params).stiffness_n_m, tau)
    np.testing.assert_allclose(tr.phi_rad[-1], expected, rtol=2e-4)
    # the first instant: alpha = tau / J exactly (a positive torque raises phi)
    np.testing.assert_allclose(tr.alpha_rad_s2[0], tau / [params.j1_kg_m2, params.j2_kg_m2], rtol=1e-12)


def _energy_balance(run, params, drive, dt_s: float) -> tuple[float, float]:
    """(largest |E - E0 + D - W|, largest |W|) over 15 s, W the drive's work on the pendulums."""
    p = params
    tr = run(p, (20 * DEG, -5 * DEG), (0.0, 0.0), 15.0, dt_s, drive=drive)
    phi, w = tr.phi_rad, tr.omega_rad_s
    # the input at either end of each step: the signal there (stages) or the value held over it
    u0 = tr.drive_input[:-1]
    u1 = tr.drive_input[1:] if tr.drive_sampling == "stages" else u0
    moc = np.array([p.m1_kg * p.oc1_m, p.m2_kg * p.oc2_m])

    def power(w, phi, u):
        return np.sum(u[:, :2] * w, axis=1) - np.sum(moc * w * (u[:, 3:4] * np.sin(phi) + u[:, 2:3] * np.cos(phi)), 1)

    step = 0.5 * dt_s * (power(w[:-1], phi[:-1], u0) + power(w[1:], phi[1:], u1))
    work = np.concatenate([[0.0], np.cumsum(step)])
    balance = tr.total_energy_j - tr.total_energy_j[0] + tr.dissipated_j - work
    return float(np.max(np.abs(balance))), float(np.max(np.abs(work)))


@pytest.mark.parametrize("engine", ["mujoco", "reference"])
def test_energy_gained_equals_the_work_of_the_drive_minus_the_damping(engine):
    # Power into the pendulums (support frame): tau . omega and the inertial force -m a_s at each
    # centre of mass, -m OC omega (a_v sin phi + a_h cos phi); the work by the trapezoid rule,
    # whose O(dt^2) error is the only residual: it shrinks 4x per halving of the step.
    drive = Drive(torque_m1=Sine(0.003, 0.85), support_x=Sine(0.4, 1.3), pivot_z=Sine(1.5, 1.74))
    run = simulate if engine == "mujoco" else reference.solve
    coarse, work = _energy_balance(run, DEFAULT_PARAMS, drive, 0.01)
    fine, _ = _energy_balance(run, DEFAULT_PARAMS, drive, 0.005)
    assert work > 0.2  # the drive did real work (J)
    assert fine < 3e-4 * work, fine / work
    assert 3.5 < coarse / fine < 4.5, coarse / fine


@pytest.mark.parametrize("engine", ["reference", "fast", "mujoco"])
def test_a_drive_faster_than_the_step_can_follow_is_refused_on_every_engine(engine):
    # a new user's 1000 Hz torque at dt 0.01 s fell on its zeros (1.4e-14 J of work), without a word
    from pendsim_mj.engines.dispatch import run

    phi0 = (0.5, 0.0)
    fast = Drive(torque_m1=Sine(0.01, 1000.0))
    with pytest.raises(ParameterError, match=r"torque_m1 drive reaches 1000 Hz: a step of 0.01 s gives it 0.1 steps"):
        run(engine, DEFAULT_PARAMS, phi0, duration_s=1.0, dt_s=0.01, drive=fast)
    # 49 Hz at 10 ms (2 steps a period) ran with its work 50 % off; 20 Hz 7 %
    for signal in (Sine(0.01, 49.0), SteppedSine(0.01, (5.0, 20.0), 1.0), Chirp(0.01, 1.0, 11.0, 1.0)):
        with pytest.raises(ParameterError, match=r"reaches (49|20|11) Hz"):
            run(engine, DEFAULT_PARAMS, phi0, duration_s=1.0, dt_s=0.01, drive=Drive(support_x=signal))
    # at the limit (10 steps a period), and with a step that follows it, the same drives run
    run(engine, DEFAULT_PARAMS, phi0, duration_s=0.2, dt_s=0.01, drive=Drive(torque_m1=Sine(0.01, 10.0)))
    assert np.all(np.isfinite(run(engine, DEFAULT_PARAMS, phi0, duration_s=0.01, dt_s=5e-5, drive=fast).phi_rad))


def test_midpoint_sampling_keeps_a_sine_in_phase():
    # The held staircase of A sin(2 pi f t + p) sampled at step midpoints has the fundamental
    # A sinc(pi f dt) sin(2 pi f t + p): no phase lag (sampling at the step start would lag pi f dt).
    f, dt, n_per = 0.8, 0.01, 125  # 1.25 s period = 125 steps
    sine = Sine(1.0, f, phase_rad=0.4)
    held = held_inputs(Drive(torque_m1=sine), 4 * n_per, dt)[:, 0]
    fine = np.repeat(held, 100)  # the staircase on a 100x finer grid
    t = (np.arange(len(fine)) + 0.5) * dt / 100
    c = 2 / len(fine) * np.sum(fine * np.exp(-2j * math.pi * f * t))
    x = math.pi * f * dt
    assert abs(c) == pytest.approx(math.sin(x) / x, rel=1e-6)
    assert np.angle(c) == pytest.approx(0.4 - math.pi / 2, abs=1e-6)


def test_chirps_sweep_from_f0_to_f1_with_a_continuous_phase():
    for law in ("linear", "log"):
        chirp = Chirp(1.0, 0.5, 3.0, 40.0, law)
        t = np.linspace(0, 60, 600_001)
        theta = phase_rad(chirp, t)
        numeric = np.gradient(theta, t) / (2 * math.pi)
        np.testing.assert_allclose(numeric[1:-1], frequency_hz(chirp, t)[1:-1], rtol=1e-6, atol=1e-6)
        assert frequency_hz(chirp, 0.0) == pytest.approx(0.5) and frequency_hz(chirp, 40.0) == pytest.approx(3.0)
        assert frequency_hz(chirp, 50.0) == pytest.approx(3.0)  # holds f1 afterwards
    # logarithmic: the frequency doubles in equal times
    log = Chirp(1.0, 0.5, 4.0, 30.0, "log")
    assert frequency_hz(log, 10.0) == pytest.approx(1.0) and frequency_hz(log, 20.0) == pytest.approx(2.0)


def test_a_stepped_sine_holds_each_frequency_for_its_dwell_with_a_continuous_phase():
    stepped = SteppedSine(1.0, (0.7, 0.9, 1.3), 10.0)
    t = np.linspace(0, 35, 350_001)
    theta = phase_rad(stepped, t)
    assert np.max(np.abs(np.diff(theta))) < 2 * math.pi * 1.3 * 1e-4 * 1.01  # no jump at the steps
    np.testing.assert_allclose(frequency_hz(stepped, [5.0, 15.0, 25.0, 34.0]), [0.7, 0.9, 1.3, 1.3])
    assert theta[-1] == pytest.approx(2 * math.pi * (7 + 9 + 13 + 1.3 * 5), rel=1e-12)
    down = SteppedSine.linear(1.0, 1.0, 0.8, 3, 5.0)
    assert down.frequencies_hz == pytest.approx((1.0, 0.9, 0.8)) and down.duration_s == 15.0


def test_a_time_series_is_read_from_csv_and_interpolated(tmp_path):
    path = tmp_path / "shaker.csv"
    path.write_text("time,x_m_s2,z_m_s2\n0,0,1\n1,2,1\n2,0,1\n")
    ts = read_time_series_csv(path, "x_m_s2", scale=0.5)
    np.testing.assert_allclose(signal_values(ts, [0.25, 1.0, 1.5]), [0.25, 1.0, 0.5])
    assert ts.source == "shaker.csv:x_m_s2"
    assert read_time_series_csv(path).values == (0.0, 2.0, 0.0)  # first value column by default
    held = held_inputs(Drive(support_x=ts), 4, 0.5)  # midpoints 0.25, 0.75, 1.25, 1.75
    np.testing.assert_allclose(held[:, Target.SUPPORT_X.index], [0.25, 0.75, 0.75, 0.25])
    np.testing.assert_array_equal(held[:, [0, 1, 3]], 0.0)


@pytest.mark.parametrize(
    ("text", "column", "message"),
    [
        ("t_s,a\n0,1\n1,x\n", None, "line 3"),
        ("t_s,a\n0,1\n0,2\n", None, "increase strictly"),
        ("t_s,a\n0,1\n1,2\n", "b", "no column 'b'; value columns: a"),
        ("t_s,a\n0,1\n", None, "at least 2 rows"),
        ("t_s\n0\n1\n", None, "need a time column and a value column"),
    ],
)
def test_a_bad_csv_time_series_is_refused_naming_the_problem(tmp_path, text, column, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ParameterError, match=message):
        read_time_series_csv(path, column)


def test_a_time_series_must_cover_the_run():
    ts = TimeSeries((0.0, 10.0), (0.0, 1.0), source="short.csv:a")
    with pytest.raises(ParameterError, match=r"covers 0 to 10 s; the run needs 0 to 20 s"):
        simulate(DEFAULT_PARAMS, duration_s=20.0, drive=Drive(torque_m1=ts))


def test_bad_drives_are_refused():
    with pytest.raises(ParameterError, match="frequency_hz must be > 0"):
        Sine(1.0, 0.0)
    with pytest.raises(ParameterError, match="chirp law must be one of linear, log"):
        Chirp(1.0, 0.5, 1.0, 10.0, "cubic")
    with pytest.raises(ParameterError, match="torque_m1 must be a Sine"):
        Drive(torque_m1=1.0)
    with pytest.raises(ParameterError, match="clamped"):
        simulate(DEFAULT_PARAMS, (0.0, 0.0), duration_s=1.0, clamp=Clamp.M1, drive=Drive(torque_m1=Sine(0.1, 1)))
    with pytest.raises(ModelError, match="clamped"):
        build_model(clamp=Clamp.M2, drive_targets=[Target.TORQUE_M2])


def test_the_driven_model_has_named_actuators_and_slides_and_its_exact_mjcf_compiles_to_it():
    targets = list(Target)
    built = build_model(DEFAULT_PARAMS, drive_targets=targets)
    names = [built.actuator(i).name for i in range(built.nu)]
    assert names == ["drive_torque_m1", "drive_torque_m2", "drive_support_x", "drive_support_z"]
    assert [built.joint(i).name for i in range(built.njnt)] == ["support_x", "support_z", "hinge_phi1", "hinge_phi2"]
    text = mujoco.MjModel.from_xml_string(exact_mjcf(DEFAULT_PARAMS, drive_targets=targets))
    for field in ("body_mass", "dof_armature", "actuator_gear", "site_pos", "key_qpos"):
        np.testing.assert_array_equal(getattr(built, field), getattr(text, field), err_msg=field)
    # undriven: the model is the plain one (no support body, no actuators)
    plain = build_model(DEFAULT_PARAMS)
    assert plain.nu == 0 and plain.nq == 2 and mujoco.mj_name2id(plain, mujoco.mjtObj.mjOBJ_BODY, "support") < 0


def test_a_driven_trajectory_saves_its_inputs_and_support_motion_to_csv(tmp_path):
    drive = Drive(torque_m1=Sine(0.01, 1.0), pivot_z=Sine(1.0, 1.7))
    tr = simulate(DEFAULT_PARAMS, duration_s=2.0, drive=drive)
    path = save_trajectory(tr, tmp_path / "run.csv")
    header = path.read_text().splitlines()[0].split(",")
    assert header[-6:] == [*CHANNEL_LABELS, "support_x_m", "support_z_m"]
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    np.testing.assert_allclose(data[:-1, header.index("torque_m1_n_m")], held_inputs(drive, 200, 0.01)[:, 0])
    plain = save_trajectory(simulate(DEFAULT_PARAMS, duration_s=2.0), tmp_path / "plain.csv")
    assert "torque_m1_n_m" not in plain.read_text().splitlines()[0]
