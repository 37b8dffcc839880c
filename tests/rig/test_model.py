"""models/pendulums.xml: agreement with RigParams, naming, warnings, frames (Menagerie habits)."""

import math
import subprocess
import sys

import mujoco
import numpy as np
import pytest

from pendsim_mj.rig.model import (
    HINGES,
    PENDULUMS_XML,
    SCENE_XML,
    SPRING_ENDS,
    SPRINGS,
    Clamp,
    build_model,
    exact_mjcf,
    paper_to_world,
)
from pendsim_mj.rig.params import DEFAULT_PARAMS

XML_DIGITS = 1e-8  # the XML prints 9 significant digits


@pytest.fixture(scope="module")
def xml_model():
    return mujoco.MjModel.from_xml_path(str(PENDULUMS_XML))


def test_xml_agrees_with_params_field_by_field(xml_model):
    m, p = xml_model, DEFAULT_PARAMS
    assert m.opt.timestep == 0.01
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    np.testing.assert_allclose(m.opt.gravity, [0, 0, -p.g_m_s2])
    for n in (1, 2):
        body = m.body(f"m{n}")
        assert body.mass[0] == pytest.approx(getattr(p, f"m{n}_kg"), rel=XML_DIGITS)
        np.testing.assert_allclose(body.ipos, [0, 0, -getattr(p, f"oc{n}_m")], rtol=XML_DIGITS)
        np.testing.assert_allclose(body.inertia, p.inertia_about_com_kg_m2(n), rtol=XML_DIGITS)
        assert m.dof_damping[m.joint(HINGES[n - 1]).dofadr[0]] == pytest.approx(
            getattr(p, f"b{n}_n_m_s"), rel=XML_DIGITS
        )
        np.testing.assert_allclose(m.site(f"imu_m{n}").pos, [0, 0, -getattr(p, f"om{n}_m")])
        np.testing.assert_allclose(m.geom(f"m{n}_rod").size[:2], [p.rod_diameter_m / 2, p.rod_length_m / 2])
        np.testing.assert_allclose(m.geom(f"m{n}_disk").size[:2], [p.disk_diameter_m / 2, p.disk_thickness_m / 2])
    np.testing.assert_allclose(
        m.geom("m1_transverse_rod").size[:2], [p.transverse_rod_diameter_m / 2, p.transverse_rod_length_m / 2]
    )
    # Sites at the paper's coordinates (paper (x, y) -> world (y, 0, -x)), on their bodies at rest.
    expected_sites = {
        "point_1": (p.l01_m, 0.0),
        "point_2": (p.l04_m, p.l24_m),
        "point_3": (p.l04_m, -p.l34_m),
        "point_4": (p.l04_m, 0.0),
        "point_5": (p.l05_m, 0.0),
        "point_6": (p.l08_m, p.l68_m),
        "point_7": (p.l08_m, -p.l78_m),
        "point_8": (p.l08_m, 0.0),
    }
    for name, (x, y) in expected_sites.items():
        np.testing.assert_allclose(m.site(name).pos, [y, 0.0, -x], atol=1e-15, err_msg=name)
    for name in SPRINGS:
        tid = m.tendon(name).id
        c = p.c1_n_m if name in ("spring_12", "spring_13") else p.c2_n_m
        assert m.tendon_stiffness[tid] == c
        np.testing.assert_array_equal(m.tendon_lengthspring[tid], [0.0, 0.0])  # zero free length
        assert m.tendon_damping[tid] == 0.0


def test_build_model_without_overrides_equals_the_xml(xml_model):
    built = build_model(DEFAULT_PARAMS)
    for field in ("body_mass", "body_ipos", "body_inertia", "dof_damping", "site_pos", "tendon_stiffness"):
        np.testing.assert_allclose(getattr(built, field), getattr(xml_model, field), rtol=XML_DIGITS, err_msg=field)


def test_overrides_reach_the_compiled_model_through_mjspec():
    p = DEFAULT_PARAMS.with_overrides(
        c1_n_m=7.0, c2_n_m=8.0, b1_n_m_s=0.003, m2_kg=0.25, oc2_m=0.3, j2_kg_m2=0.03, l24_m=0.12, g_m_s2=9.8
    )
    m = build_model(p, timestep_s=0.005)
    assert m.opt.timestep == 0.005
    assert m.tendon_stiffness[m.tendon("spring_12").id] == 7.0
    assert m.tendon_stiffness[m.tendon("spring_57").id] == 8.0
    assert m.dof_damping[0] == 0.003
    assert m.body("m2").mass[0] == 0.25
    np.testing.assert_allclose(m.body("m2").ipos, [0, 0, -0.3])
    # inertia about the pivot axis is J exactly: I_com + m OC^2
    assert m.body("m2").inertia[1] + 0.25 * 0.3**2 == pytest.approx(0.03, rel=1e-14)
    np.testing.assert_allclose(m.site("point_2").pos, [0.12, 0, -p.l04_m])
    assert m.opt.gravity[2] == -9.8


def test_exact_mjcf_compiles_to_the_model_build_model_makes():
    # MjSpec.to_xml() keeps 6 digits; the recording's attachment must reproduce the run exactly
    p = DEFAULT_PARAMS.with_overrides(c1_n_m=7.123456789, b2_n_m_s=0.000412345678, m1_kg=0.2034567891)
    built = build_model(p, timestep_s=0.005)
    from_text = mujoco.MjModel.from_xml_string(exact_mjcf(p, timestep_s=0.005))
    compared = 0
    for name in dir(built):
        value = getattr(built, name)
        if not name.startswith("_") and isinstance(value, np.ndarray) and value.dtype.kind in "fiu":
            np.testing.assert_array_equal(getattr(from_text, name), value, err_msg=name)
            compared += 1
    assert compared > 100


def _named(m, objtype, count):
    return [mujoco.mj_id2name(m, objtype, i) for i in range(count)]


@pytest.mark.parametrize("path", [PENDULUMS_XML, SCENE_XML], ids=["pendulums", "scene"])
def test_model_loads_steps_and_raises_no_warning(path):
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("release_30deg").id)
    mujoco.mj_step(m, d, nstep=2000)
    warnings = {mujoco.mjtWarning(i).name: d.warning[i].number for i in range(len(d.warning)) if d.warning[i].number}
    assert not warnings, f"MuJoCo warnings: {warnings}"


def test_every_element_is_named(xml_model):
    m = xml_model
    obj = mujoco.mjtObj
    for objtype, count, label in [
        (obj.mjOBJ_BODY, m.nbody, "body"),
        (obj.mjOBJ_JOINT, m.njnt, "joint"),
        (obj.mjOBJ_SITE, m.nsite, "site"),
        (obj.mjOBJ_TENDON, m.ntendon, "tendon"),
        (obj.mjOBJ_SENSOR, m.nsensor, "sensor"),
        (obj.mjOBJ_GEOM, m.ngeom, "geom"),
    ]:
        names = _named(m, objtype, count)
        start = 1 if objtype == obj.mjOBJ_BODY else 0  # the world body
        assert all(names[start:]), f"unnamed {label}: {names}"


def test_geoms_are_visual_only(xml_model):
    m = xml_model
    assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
    # mass comes from the explicit inertials alone: total = m1 + m2
    assert m.body_mass.sum() == pytest.approx(DEFAULT_PARAMS.m1_kg + DEFAULT_PARAMS.m2_kg, rel=1e-8)


def test_spring_ends_follow_the_paper():
    # springs 1-2, 1-3 (c1) couple M1 and M2; 5-6, 5-7 (c2) tie M2 to the frame; M1 has none to the frame
    m = mujoco.MjModel.from_xml_path(str(PENDULUMS_XML))
    for name, (a, b) in zip(SPRINGS, SPRING_ENDS, strict=True):
        tid = m.tendon(name).id
        adr = m.tendon_adr[tid]
        sites = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_SITE, m.wrap_objid[adr + k]) for k in range(2)]
        assert sites == [a, b]


def test_positive_phi_swings_the_lower_end_toward_world_x_like_paper_y():
    m = build_model()
    d = mujoco.MjData(m)
    d.qpos[:] = [0.3, -0.2]
    mujoco.mj_kinematics(m, d)
    p = DEFAULT_PARAMS
    # paper: point 2 at (l04 cos phi1 - l24 sin phi1, l04 sin phi1 + l24 cos phi1)
    x2 = p.l04_m * math.cos(0.3) - p.l24_m * math.sin(0.3)
    y2 = p.l04_m * math.sin(0.3) + p.l24_m * math.cos(0.3)
    np.testing.assert_allclose(d.site("point_2").xpos, paper_to_world(x2, y2), atol=1e-15)
    x5, y5 = p.l05_m * math.cos(-0.2), p.l05_m * math.sin(-0.2)
    np.testing.assert_allclose(d.site("point_5").xpos, paper_to_world(x5, y5), atol=1e-15)


def test_clamping_removes_exactly_one_hinge():
    for clamp, kept in ((Clamp.M1, "hinge_phi2"), (Clamp.M2, "hinge_phi1")):
        m = build_model(clamp=clamp)
        assert m.njnt == 1 and m.joint(0).name == kept


def test_reference_solver_does_not_import_mujoco():
    code = "import sys, pendsim_mj.engines.reference, pendsim_mj.estimation.analysis; print('mujoco' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
