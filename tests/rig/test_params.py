"""RigParams against the paper's table (spec RIG.md section 1) and the mass derivation."""

import dataclasses
import math

import mujoco
import numpy as np
import pytest

from pendsim_mj.engines.simulation import simulate
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.analysis import peak_amplitudes
from pendsim_mj.rig.model import Clamp
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams, far_from_paper


def test_printed_values_are_the_papers():
    # paper, table of parameters (RIG.md section 1), SI units
    expected = {
        "oc1_m": 0.3274, "oc2_m": 0.326, "j1_kg_m2": 0.02592, "j2_kg_m2": 0.02188,
        "l01_m": 0.0525, "l04_m": 0.187, "l24_m": 0.150, "l34_m": 0.150, "l05_m": 0.322,
        "l08_m": 0.266, "l68_m": 0.150, "l78_m": 0.150, "om1_m": 0.417, "om2_m": 0.384,
        "c1_n_m": 6.173, "c2_n_m": 6.562, "g_m_s2": 9.81, "rod_length_m": 0.510,
        "rod_diameter_m": 0.0051, "disk_diameter_m": 0.0605, "disk_thickness_m": 0.0118,
        "transverse_rod_length_m": 0.300, "transverse_rod_diameter_m": 0.003,
    }  # fmt: skip
    for name, value in expected.items():
        assert getattr(DEFAULT_PARAMS, name) == value, name


def test_rest_inclinations_of_the_springs_match_the_papers_alpha_and_beta():
    p = DEFAULT_PARAMS
    # paper: alpha = 41.88 deg = atan(l14 / l24), l14 = l04 - l01; beta = 20.47 deg = atan(l58 / l68)
    assert math.degrees(math.atan((p.l04_m - p.l01_m) / p.l24_m)) == pytest.approx(41.88, abs=0.01)
    assert math.degrees(math.atan((p.l05_m - p.l08_m) / p.l68_m)) == pytest.approx(20.47, abs=0.01)


def _components_compiled_by_mujoco(*, transverse_rod: bool) -> mujoco.MjModel:
    """The pendulum's parts as solid steel geoms whose mass, centre of mass and inertia MuJoCo's
    compiler computes from their shapes (an independent derivation of our arithmetic): the main
    rod 510 mm x 5.1 mm from the pivot down, the 100 g disk (60.5 mm x 11.8 mm, its axis along the
    pivot axis) at 384 mm (OM2), and on M1 the transverse rod 300 mm x 3 mm at l04."""
    spec = mujoco.MjSpec()
    body = spec.worldbody.add_body(name="pendulum")
    body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_CYLINDER, fromto=[0, 0, 0, 0, 0, -0.510], size=[0.00255, 0, 0], density=7850
    )
    body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_CYLINDER, pos=[0, 0, -0.384], quat=[0.7071067811865476, 0.7071067811865476, 0, 0],
        size=[0.03025, 0.0059, 0], mass=0.100,
    )  # fmt: skip
    if transverse_rod:
        body.add_geom(
            type=mujoco.mjtGeom.mjGEOM_CYLINDER, fromto=[-0.15, 0, -0.187, 0.15, 0, -0.187], size=[0.0015, 0, 0],
            density=7850,
        )  # fmt: skip
    body.add_joint(type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0])
    return spec.compile()


def test_masses_equal_the_steel_components_as_mujoco_computes_them_plus_the_node():
    # spec: main rod about 81.8 g, transverse rod about 16.6 g, disk 100 g, node 12.8 g
    m2 = _components_compiled_by_mujoco(transverse_rod=False).body_mass[1]
    m1 = _components_compiled_by_mujoco(transverse_rod=True).body_mass[1]
    assert m2 - 0.100 == pytest.approx(0.0818, abs=1e-4)
    assert m1 - m2 == pytest.approx(0.0166, abs=1e-4)
    assert DEFAULT_PARAMS.m1_kg == pytest.approx(m1 + 0.0128, rel=1e-6)
    assert DEFAULT_PARAMS.m2_kg == pytest.approx(m2 + 0.0128, rel=1e-6)


def test_m2_rod_and_disk_alone_reproduce_the_printed_oc2_and_j2():
    # The check that confirms the mass derivation (spec section 1): MuJoCo's own centre of mass and
    # inertia of the rod + disk about the pivot equal the paper's printed OC2 and J2.
    model = _components_compiled_by_mujoco(transverse_rod=False)
    mass, com = model.body_mass[1], -model.body_ipos[1][2]
    assert com == pytest.approx(DEFAULT_PARAMS.oc2_m, rel=1e-3)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    full = np.zeros((1, 1))
    mujoco.mj_fullM(model, data, full)
    j_pivot = full[0, 0]  # the joint-space inertia of the hinge: about the pivot axis
    assert j_pivot == pytest.approx(DEFAULT_PARAMS.j2_kg_m2, rel=1e-3)
    assert mass * com**2 < j_pivot


def test_default_damping_makes_the_amplitude_fall_to_20_percent_in_120_s():
    # assumed: amplitude to 20 % in 120 s. Checked on the simulated rig: each pendulum swinging
    # alone (the other clamped) at a small amplitude, where the decay is that of a linear oscillator.
    for clamp, k in ((Clamp.M2, 0), (Clamp.M1, 1)):
        phi0 = [0.0, 0.0]
        phi0[k] = math.radians(3.0)
        run = simulate(DEFAULT_PARAMS, phi0, (0.0, 0.0), 125.0, clamp=clamp)
        times, amps = peak_amplitudes(run.t_s, run.phi_rad[:, k])
        ratio_per_120_s = math.exp(np.polyfit(times, np.log(amps), 1)[0] * 120.0)
        assert ratio_per_120_s == pytest.approx(0.2, rel=0.01)


def test_inertia_about_com_keeps_the_papers_pivot_inertia():
    for n in (1, 2):
        p = DEFAULT_PARAMS
        m, oc, j = getattr(p, f"m{n}_kg"), getattr(p, f"oc{n}_m"), getattr(p, f"j{n}_kg_m2")
        i_inplane, i_pivot, i_rod = p.inertia_about_com_kg_m2(n)
        assert i_pivot + m * oc**2 == pytest.approx(j, rel=1e-14)
        # a physical inertia: positive and obeying the triangle inequality
        assert min(i_inplane, i_pivot, i_rod) > 0
        assert i_inplane + i_pivot >= i_rod and i_pivot + i_rod >= i_inplane and i_rod + i_inplane >= i_pivot


def test_every_field_has_a_unit_and_a_source():
    for f in dataclasses.fields(RigParams):
        assert f.metadata["unit"], f.name
        assert f.metadata["source"].split(":")[0] in {"paper", "derived", "assumed"}, f.name


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ({"c1_n_m": -1.0}, "c1_n_m must be >= 0 N/m, got -1.0"),
        ({"m1_kg": -0.2}, "m1_kg must be > 0 kg, got -0.2"),
        ({"m2_kg": 0.0}, "m2_kg must be > 0 kg, got 0.0"),
        ({"j1_kg_m2": float("nan")}, "j1_kg_m2 must be finite, got nan"),
        ({"b2_n_m_s": float("inf")}, "b2_n_m_s must be finite, got inf"),
        ({"j1_kg_m2": 0.01}, "j1_kg_m2 = 0.01 must exceed m1_kg * oc1_m^2"),
    ],
)
def test_bad_values_are_rejected_with_the_field_named(override, message):
    with pytest.raises(ParameterError, match=message.replace("^", r"\^").replace("*", r"\*")):
        DEFAULT_PARAMS.with_overrides(**override)


def test_unknown_override_names_the_allowed_fields():
    with pytest.raises(ParameterError, match=r"unknown parameter.*stiffness.*allowed: b1_n_m_s"):
        DEFAULT_PARAMS.with_overrides(stiffness=3.0)


def test_override_changes_only_the_named_field():
    p = DEFAULT_PARAMS.with_overrides(c1_n_m=7.5)
    assert p.c1_n_m == 7.5
    assert {k: v for k, v in p.as_dict().items() if k != "c1_n_m"} == {
        k: v for k, v in DEFAULT_PARAMS.as_dict().items() if k != "c1_n_m"
    }


def test_values_far_from_the_papers_rig_are_named_with_how_far():
    # a spring in N/mm, a mass in grams: 10x and more from the paper's rig; losses may differ
    # by orders of magnitude between real rigs, and a value 2x off is just another rig
    lines = far_from_paper(
        {"c1_n_m": 0.0064, "m2_kg": 194.6, "b1_n_m_s": 1e-7, "friction2_n_m": 0.5, "c2_n_m": 2 * DEFAULT_PARAMS.c2_n_m,
         "b2_n_m_s": 0.0, "l24_m": 0.0}
    )  # fmt: skip
    assert lines == [
        "c1_n_m = 0.0064 N/m is 1/964.5 of the paper's rig's (6.173 N/m)",
        "m2_kg = 194.6 kg is 1000 times the paper's rig's (0.194584 kg)",
    ]
