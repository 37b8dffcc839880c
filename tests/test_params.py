"""RigParams against the paper's table (spec RIG.md section 1) and the mass derivation."""

import dataclasses
import math

import pytest

from pendsim_mj.errors import ParameterError
from pendsim_mj.params import DEFAULT_PARAMS, RigParams


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


def test_masses_are_the_component_sum_from_steel_density():
    steel = 7850.0
    rod = steel * math.pi * 0.00255**2 * 0.510  # spec: about 81.8 g
    trod = steel * math.pi * 0.0015**2 * 0.300  # spec: about 16.6 g
    assert rod == pytest.approx(0.0818, abs=1e-4)
    assert trod == pytest.approx(0.0166, abs=1e-4)
    assert DEFAULT_PARAMS.m1_kg == pytest.approx(rod + 0.100 + trod + 0.0128, rel=1e-12)
    assert DEFAULT_PARAMS.m2_kg == pytest.approx(rod + 0.100 + 0.0128, rel=1e-12)


def test_m2_rod_and_disk_alone_reproduce_the_printed_oc2_and_j2():
    # The check that confirms the mass derivation (spec section 1).
    rod = 7850.0 * math.pi * 0.00255**2 * 0.510
    disk = 0.100
    oc2 = (rod * 0.255 + disk * 0.384) / (rod + disk)
    j2 = rod * 0.510**2 / 3 + disk * 0.384**2 + disk * 0.03025**2 / 2
    assert oc2 == pytest.approx(DEFAULT_PARAMS.oc2_m, rel=1e-3)
    assert j2 == pytest.approx(DEFAULT_PARAMS.j2_kg_m2, rel=1e-3)


def test_default_damping_is_the_documented_log_decrement():
    # assumed: amplitude to 20 % in 120 s, b = 2 J ln(5) / 120
    assert DEFAULT_PARAMS.b1_n_m_s == pytest.approx(2 * 0.02592 * math.log(5) / 120, rel=1e-12)
    assert DEFAULT_PARAMS.b2_n_m_s == pytest.approx(2 * 0.02188 * math.log(5) / 120, rel=1e-12)


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


def test_params_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        DEFAULT_PARAMS.c1_n_m = 1.0  # type: ignore[misc]


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
