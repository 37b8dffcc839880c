"""Driven recordings (a /drive topic) through validate, identify and the drive they hold: the start
where the drive starts, every model run driven by the recorded inputs, the damping fitted with
them. The yardstick is a free run of the same length: a driven record must validate about as
well as it, and its recorded drive must reproduce the recorded ground truth (/joint_states)."""

import json

import numpy as np
import pytest

from pendsim_bridge.cli import main
from pendsim_bridge.io.recording import read_recording
from pendsim_bridge.run.validate import identify
from pendsim_mj.engines import dispatch as engines
from pendsim_mj.engines import fast_planar
from pendsim_mj.rig import drives
from pendsim_mj.rig.params import DEFAULT_PARAMS

DRIVE = ("--torque1-n-m", "sine:0.3,1.2")
ONE_SAMPLE_S = 1 / 80  # the nodes' sample spacing


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    """Three 12 s records of the same rig: driven from the start, driven after a 2 s hold, free."""
    folder = tmp_path_factory.mktemp("driven")
    out = {}
    for name, options in (("driven", DRIVE), ("held", (*DRIVE, "--hold-s", "2")), ("free", ())):
        path = folder / f"{name}.mcap"
        assert main(["record", "--duration-s", "12", "-o", str(path), *options]) == 0
        out[name] = path
    return out


@pytest.fixture(scope="module")
def reports(records):
    """validate's report.json and printed text for each record (damping identified: the default)."""
    out = {}
    for name, path in records.items():
        folder = path.with_name(path.stem + "_report")
        assert main(["validate", str(path), "--no-plots", "-o", str(folder)]) == 0
        out[name] = json.loads((folder / "report.json").read_text())
    return out


def _phi1_max_abs(report, engine="mujoco"):
    cases = {(c["engine"], c["release"], c["window"]): c["metrics"] for c in report["cases"]}
    return cases[(engine, "estimated", "whole")]["phi1"]["max_abs"]


def test_a_driven_record_starts_in_motion_at_0_s_and_after_a_hold_at_the_release(reports):
    driven, held = reports["driven"]["release"], reports["held"]["release"]
    assert driven["kind"] == "in motion" and driven["time_s"] == pytest.approx(0.0, abs=1e-9)
    assert held["kind"] == "release" and held["time_s"] == pytest.approx(2.0, abs=ONE_SAMPLE_S)
    for start in (driven, held):
        assert start["estimated_angle_rad"][0] == pytest.approx(np.pi / 6, abs=0.002)  # the recorded 30 deg
        assert start["start_fit_unexplained"] < 0.03  # no "poor start fit"


def test_the_driven_models_match_the_measurement_about_as_well_as_on_a_free_run(reports):
    free = _phi1_max_abs(reports["free"])
    for name in ("driven", "held"):
        for engine in ("mujoco", "reference"):
            assert _phi1_max_abs(reports[name], engine) < 3 * free, (name, engine, free)
        nominal = next(c for c in reports[name]["cases"] if c["release"] == "nominal" and c["window"] == "whole")
        assert nominal["metrics"]["phi1"]["max_abs"] < 0.05  # from 30 deg at rest with the drive too


def test_the_recorded_drive_reproduces_the_recorded_joint_states(records):
    rec = read_recording(records["held"])
    info = rec.run_info()
    drive = rec.drive_from(info.release_time_s, until_s=10.0)
    assert drive is not None and drive.targets == (drives.Target.TORQUE_M1,)
    model = engines.run("mujoco", rec.params(), info.phi0_rad, info.omega0_rad_s, 10.0, info.dt_s, drive=drive)
    js = rec.joint_states
    assert js is not None
    after = (js.t_s >= info.release_time_s) & (js.t_s <= info.release_time_s + 10.0)
    phi = np.interp(js.t_s[after] - info.release_time_s, model.t_s, model.phi_rad[:, 0])
    assert np.max(np.abs(phi - js.position_rad[after, 0])) < 1e-9


def test_identify_fits_the_recorded_damping_with_the_drive_and_skips_the_decrements(records, capsys):
    truth = read_recording(records["driven"]).params()
    result = identify(records["driven"])
    assert result.driven and result.log_decrement == [] and result.modal_decrement is None
    fit = result.fit
    assert fit.residual_rms_sigma < 1.2  # explained to the noise level
    for b, half, true in zip(fit.b_n_m_s, fit.ci95_n_m_s, (truth.b1_n_m_s, truth.b2_n_m_s), strict=True):
        assert abs(b - true) <= max(half, 1e-3 * true), (b, half, true)
    assert main(["identify", str(records["driven"])]) == 0
    text = capsys.readouterr().out
    assert "decrement skipped" in text and "log decrement b =" not in text


@pytest.mark.parametrize("command", ["validate", "identify"])
def test_the_spatial_model_on_a_driven_record_is_one_line_exit_2(records, capsys, command):
    assert main([command, str(records["driven"]), "--model", "spatial"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pendsim: error:") and "driven" in err and "\n" not in err


def test_plain_validate_of_a_driven_record_exits_0(records, monkeypatch):
    monkeypatch.chdir(records["driven"].parent)
    assert main(["validate", records["driven"].name]) == 0


def test_driven_rates_and_sensitivities_equal_solve_and_central_differences():
    """fast_planar.rates_at with stage inputs (a hinge torque and a sideways support acceleration
    at each RK4 stage's time): its rates at the steps are solve's, its sensitivities the central
    differences of its rates (the variational step stays the exact derivative of the step)."""
    t = np.arange(0.0, 4.0, 0.01)
    held = np.zeros((len(t), 4))
    held[:, 0] = 0.3 * np.sin(2 * np.pi * 1.2 * (t + 0.005))
    held[:, 2] = 0.5 * np.cos(3.0 * t)
    drive = drives.recorded_drive(t, held, 0.0)
    inputs = drives.stage_inputs(drive, 400, 0.01)
    coef = fast_planar.coefficients([DEFAULT_PARAMS])
    phi0, omega0 = np.array([0.5, 0.1]), np.array([0.2, -0.3])
    steps = np.arange(0.0, 3.9, 0.01)
    (r1, r2), _, _ = fast_planar.rates_at(coef, phi0, omega0, (steps, steps), 0.01, inputs=inputs)
    ref = fast_planar.solve(DEFAULT_PARAMS, phi0, omega0, 3.9, 0.01, drive=drive)
    assert np.max(np.abs(np.stack([r1, r2], 1) - ref.omega_rad_s[: len(steps)])) < 1e-12
    at = (np.linspace(0.013, 3.8, 200), np.linspace(0.007, 3.75, 180))
    wrt = ("phi1_0", "phi2_0", "omega1_0", "omega2_0", "b1_n_m_s", "b2_n_m_s")
    _, sens, _ = fast_planar.rates_at(coef, phi0, omega0, at, 0.01, wrt=wrt, inputs=inputs)
    exact = np.concatenate(sens)

    def rates(j, e):
        x = np.concatenate([phi0, omega0, [0.0, 0.0]])
        x[j] += e
        k = coef.copy()
        k[fast_planar.COEFFICIENTS.index("b1_n_m_s")] += x[4]
        k[fast_planar.COEFFICIENTS.index("b2_n_m_s")] += x[5]
        return np.concatenate(fast_planar.rates_at(k, x[:2], x[2:4], at, 0.01, inputs=inputs)[0])

    for j in range(len(wrt)):
        central = (rates(j, 1e-6) - rates(j, -1e-6)) / 2e-6
        assert np.max(np.abs(exact[:, j] - central)) < 1e-6 * np.max(np.abs(central)), wrt[j]
