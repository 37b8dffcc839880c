"""The spatial variant (issue 7): plane offset and tilt freedoms, each against something
independent: the planar model and reference, an exact geometric argument, energy, linear modes."""

import math

import mujoco
import numpy as np
import pytest

from pendsim_mj.engines import reference
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.estimation.analysis import zero_crossing_hz
from pendsim_mj.rig.model import SPATIAL, TILTS, Variant, build_model, exact_mjcf
from pendsim_mj.rig.params import DEFAULT_PARAMS, PLANE_OFFSET_PRESETS_M

PHI0 = (math.radians(30), 0.0)
UNDAMPED = DEFAULT_PARAMS.with_overrides(b1_n_m_s=0.0, b2_n_m_s=0.0, tilt_damping_n_m_s_rad=0.0)


def test_offset_zero_with_the_tilt_freedoms_reproduces_the_planar_model():
    planar = simulate(DEFAULT_PARAMS, PHI0, (0.0, 0.0), 120.0)
    spatial = simulate(DEFAULT_PARAMS, PHI0, (0.0, 0.0), 120.0, variant=SPATIAL)
    assert np.max(np.abs(spatial.phi_rad - planar.phi_rad)) < 1e-9
    assert np.max(np.abs(spatial.tilt_rad)) < 1e-12  # in-plane forces only: nothing tilts


@pytest.fixture(scope="module")
def planar_reference():
    """The planar reference's 120 s from PHI0 (no offset, no MuJoCo): the truth of every offset below,
    solved once (the numpy RK4 loop takes seconds)."""
    return reference.solve(DEFAULT_PARAMS, PHI0, (0.0, 0.0), 120.0)


@pytest.mark.parametrize("offset_m", PLANE_OFFSET_PRESETS_M)
def test_a_plane_offset_with_rigid_hinges_leaves_the_in_plane_motion_unchanged(offset_m, planar_reference):
    # The moment about the pivot axis a is a . (r x F), F = c (p_j - p_i). A triple product with a
    # uses only the components perpendicular to a; the offset changes only components along a.
    # So the moments, and phi(t), are exactly the planar ones; the tensions grow to c sqrt(L^2 + d^2).
    params = DEFAULT_PARAMS.with_overrides(plane_offset_m=offset_m)
    offset = simulate(params, PHI0, (0.0, 0.0), 120.0)
    planar = planar_reference  # no offset, no MuJoCo
    assert np.max(np.abs(offset.phi_rad - planar.phi_rad)) < 1e-9
    expected = params.c1_n_m * np.sqrt(planar.spring_length_m[:, :2] ** 2 + offset_m**2)
    np.testing.assert_allclose(offset.spring_force_n[:, :2], expected, rtol=1e-12)
    # points 6, 7 in M2's plane: springs 5-6 and 5-7 do not cross planes
    np.testing.assert_allclose(offset.spring_force_n[:, 2:], planar.spring_force_n[:, 2:], rtol=1e-12)
    np.testing.assert_allclose(offset.spring_moment_n_m, planar.spring_moment_n_m, atol=1e-12)


def test_fixed_points_in_m1s_plane_make_springs_5_6_and_5_7_cross_too():
    params = DEFAULT_PARAMS.with_overrides(plane_offset_m=0.05)
    variant = Variant(fixed_points_plane="m1")
    run = simulate(params, PHI0, (0.0, 0.0), 5.0, variant=variant)
    planar = reference.solve(DEFAULT_PARAMS, PHI0, (0.0, 0.0), 5.0)
    assert np.max(np.abs(run.phi_rad - planar.phi_rad)) < 1e-9  # still no in-plane change
    expected = params.c2_n_m * np.sqrt(planar.spring_length_m[:, 2:] ** 2 + 0.05**2)
    np.testing.assert_allclose(run.spring_force_n[:, 2:], expected, rtol=1e-12)


def test_energy_is_conserved_with_the_tilt_freedoms_on_and_the_step_it_needs():
    params = UNDAMPED.with_overrides(plane_offset_m=0.05)
    drift = {}
    for dt in (0.01, 0.005, 0.0025):
        run = simulate(params, PHI0, (0.0, 0.0), 120.0, dt, variant=SPATIAL)
        e = run.total_energy_j
        drift[dt] = np.max(np.abs(e - e[0])) / e[0]
        assert np.max(np.abs(run.tilt_rad)) > math.radians(1)  # the tilts do move: energy flows there
    assert drift[0.0025] < 1e-6  # 1e-6 over 120 s needs 2.5 ms; at 10 ms it is stable, ~4e-5
    assert drift[0.01] < 1e-3
    assert 25 < drift[0.005] / drift[0.0025] < 40  # RK4: fifth order in dt, not a constraint loss


def _linear_modes(params):
    """Eigenvalues of the continuous dynamics linearised at the static equilibrium: central
    differences of MuJoCo's accelerations in qpos and qvel (hinges: qpos are plain angles)."""
    model = build_model(params, variant=SPATIAL)
    data = mujoco.MjData(model)
    for _ in range(200):  # settle into the equilibrium (the crossing springs tilt M1 toward M2)
        data.qvel[:] = 0.0
        mujoco.mj_step(model, data, nstep=50)
    rest = data.qpos.copy()
    nv, eps = model.nv, 1e-6

    def acceleration(qpos, qvel):
        data.qpos[:], data.qvel[:] = qpos, qvel
        mujoco.mj_forward(model, data)
        return data.qacc.copy()

    zero = np.zeros(nv)

    def stiffness(q):
        return np.stack(
            [(acceleration(q + e, zero) - acceleration(q - e, zero)) / (2 * eps) for e in np.eye(nv) * eps], axis=1
        )

    for _ in range(8):  # Newton on qacc(q) = 0: the exact equilibrium
        rest = rest - np.linalg.solve(stiffness(rest), acceleration(rest, zero))
    jacobian = np.zeros((2 * nv, 2 * nv))
    jacobian[:nv, nv:] = np.eye(nv)
    for j in range(nv):
        step = np.zeros(nv)
        step[j] = eps
        jacobian[nv:, j] = (acceleration(rest + step, zero) - acceleration(rest - step, zero)) / (2 * eps)
        jacobian[nv:, nv + j] = (acceleration(rest, step) - acceleration(rest, -step)) / (2 * eps)
    assert np.max(np.abs(acceleration(rest, zero))) < 1e-9  # it is an equilibrium
    return model, rest, np.linalg.eigvals(jacobian)


def test_a_tiny_out_of_plane_perturbation_follows_the_linearised_four_dof_modes():
    params = UNDAMPED.with_overrides(plane_offset_m=0.05)
    model, rest, eigenvalues = _linear_modes(params)
    assert np.all(eigenvalues.real < 1e-6)  # no growing mode: perturbations stay bounded
    predicted_hz = np.sort(eigenvalues.imag[eigenvalues.imag > 1e-9]) / (2 * math.pi)
    assert len(predicted_hz) == 4
    # perturb the tilt of M1 by 1e-4 rad from the equilibrium and follow it for 60 s
    tilt_index = [model.jnt_qposadr[model.joint(t).id] for t in TILTS]
    phi_index = [model.jnt_qposadr[model.joint(h).id] for h in ("hinge_phi1", "hinge_phi2")]
    tilt0 = rest[tilt_index] + np.array([1e-4, 0.0])
    run = simulate(params, rest[phi_index], (0.0, 0.0), 60.0, variant=SPATIAL, tilt0_rad=tilt0)
    deviation = run.tilt_rad[:, 0] - rest[tilt_index[0]]
    assert np.max(np.abs(deviation)) < 5e-4  # bounded, as the modes predict
    measured = zero_crossing_hz(run.t_s, deviation)
    # the response is a sum of modes; its mean crossing rate lies between the extreme mode frequencies
    assert predicted_hz.min() * 0.99 <= measured <= predicted_hz.max() * 1.01
    spectrum = np.abs(np.fft.rfft(deviation * np.hanning(len(deviation))))
    f = np.fft.rfftfreq(len(deviation), run.dt_s)
    peak = f[np.argmax(spectrum[1:]) + 1]
    assert np.min(np.abs(predicted_hz - peak)) < 0.02  # the strongest line is one of the modes


def test_the_spatial_mjcf_attachment_compiles_to_the_simulated_model():
    params = DEFAULT_PARAMS.with_overrides(plane_offset_m=0.023, tilt_stiffness_n_m_rad=1.234567)
    built = build_model(params, variant=SPATIAL)
    text = mujoco.MjModel.from_xml_string(exact_mjcf(params, variant=SPATIAL))
    assert [built.joint(i).name for i in range(built.njnt)] == ["tilt_m1", "hinge_phi1", "tilt_m2", "hinge_phi2"]
    for name in ("qpos0", "jnt_axis", "dof_damping", "jnt_stiffness", "body_pos", "site_pos", "key_qpos"):
        np.testing.assert_array_equal(getattr(text, name), getattr(built, name), err_msg=name)
