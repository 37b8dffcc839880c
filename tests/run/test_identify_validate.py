"""Damping identification and validation, end to end on synthetic recordings made with known
damping and the spec's noise: record -> identify -> validate -> thresholds; a wrong model fails."""

import json
import math

import numpy as np
import pytest

from pendsim_bridge.cli import main
from pendsim_bridge.io.measured import align_recording, recorded_params
from pendsim_bridge.io.recording import RunInfo, read_recording, write_recording
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.estimation.identification import fit_damping, log_decrement
from pendsim_mj.rig.model import exact_mjcf
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, sample_imu

RELEASE_DEG = 34.0  # the paper's experiment was released from about 34 deg
HOLD_S = 2.0


def _record(path, b1, b2, seed):
    params = DEFAULT_PARAMS.with_overrides(b1_n_m_s=b1, b2_n_m_s=b2)
    phi0 = (math.radians(RELEASE_DEG), 0.0)
    traj = simulate(params, phi0, (0.0, 0.0), 120.0)
    imu = sample_imu(traj, Bno055(seed=seed), hold_s=HOLD_S)
    run = RunInfo("mujoco", phi0, (0.0, 0.0), 120.0, 0.01, release_time_s=HOLD_S)
    return write_recording(path, imu, run, exact_mjcf(params), params, traj=traj)


@pytest.fixture(scope="module")
def proportional(tmp_path_factory):
    # b1/J1 = b2/J2: both modes decay alike (the paper's per-pendulum log decrement holds)
    b1 = 8e-4
    return _record(
        tmp_path_factory.mktemp("p") / "prop.mcap", b1, b1 * DEFAULT_PARAMS.j2_kg_m2 / DEFAULT_PARAMS.j1_kg_m2, 3
    )


@pytest.fixture(scope="module")
def unequal(tmp_path_factory):
    return _record(tmp_path_factory.mktemp("u") / "unequal.mcap", 9e-4, 3e-4, 4)


@pytest.fixture(scope="module")
def proportional_aligned(proportional):
    """The proportional recording's rig and its aligned run (deterministic; read only by the tests)."""
    rec = read_recording(proportional)
    params = recorded_params(rec)
    return params, align_recording(rec, params)


def test_the_release_instant_and_angle_are_found_from_the_imus_alone(proportional_aligned):
    _, run = proportional_aligned
    assert run.start.kind == "release"
    assert run.release_time_s == pytest.approx(HOLD_S, abs=0.004)  # sample period 12.5 ms
    assert math.degrees(run.release_angle_rad[0]) == pytest.approx(RELEASE_DEG, abs=0.1)
    assert math.degrees(run.release_angle_rad[1]) == pytest.approx(0.0, abs=0.1)
    for node in run.nodes:
        assert node.t_s[0] >= 0 and node.t_s[0] < 0.0125


def test_log_decrement_recovers_proportional_damping(proportional_aligned):
    params, run = proportional_aligned
    t = np.stack([run.nodes[0].t_s, run.nodes[1].t_s], axis=1)
    phi = np.stack([run.nodes[0].phi_rad, run.nodes[1].phi_rad], axis=1)
    b = [d.b_n_m_s for d in log_decrement(t, phi, params)]
    assert b[0] == pytest.approx(params.b1_n_m_s, rel=0.02)
    # M2 swings only ~3 deg and beats against M1, so its amplitudes carry more error
    assert b[1] == pytest.approx(params.b2_n_m_s, rel=0.12)


def test_least_squares_recovers_unequal_damping_within_2_percent(unequal):
    rec = read_recording(unequal)
    params = recorded_params(rec)
    run = align_recording(rec, params)
    at = np.stack([run.nodes[0].value_t_s, run.nodes[1].value_t_s], axis=1)  # where the fused values belong
    omega = np.stack([run.nodes[0].omega_rad_s, run.nodes[1].omega_rad_s], axis=1)
    start = DEFAULT_PARAMS.with_overrides(b1_n_m_s=1e-3, b2_n_m_s=1e-3)  # the fit must not start at the truth
    fit = fit_damping(
        start, run.release_angle_rad, np.clip(at, 0, None), omega, gyro_sigma_rad_s=run.gyro_sigma_rad_s,
        fusion_rate_hz=None,
    )  # fmt: skip
    np.testing.assert_allclose(fit.b_n_m_s, [9e-4, 3e-4], rtol=0.02)
    assert np.all(fit.ci95_n_m_s > 0) and np.all(fit.ci95_n_m_s < 0.02 * fit.b_n_m_s)
    assert 0.9 < fit.residual_rms_sigma < 1.5  # explained to about the noise level


def test_identify_prints_both_estimates_and_writes_values_simulate_can_use(unequal, tmp_path, capsys):
    out = tmp_path / "damping.json"
    assert main(["identify", str(unequal), "--write", str(out)]) == 0
    text = capsys.readouterr().out
    assert "log decrement" in text and "least squares" in text and "95 %" in text
    values = json.loads(out.read_text())
    assert values["b1_n_m_s"] == pytest.approx(9e-4, rel=0.02) and values["b2_n_m_s"] == pytest.approx(3e-4, rel=0.02)
    assert main(["simulate", "--duration-s", "2", "--params-file", str(out), "-o", str(tmp_path / "x.npz")]) == 0


def test_validate_end_to_end_meets_its_thresholds_and_writes_the_report_and_figures(proportional, tmp_path, capsys):
    out = tmp_path / "report"
    gates = ["--max-delta", "0.005", "--max-iae", "0.01", "--max-error-phi1", "0.005"]
    assert main(["validate", str(proportional), "-o", str(out), *gates]) == 0
    text = capsys.readouterr().out
    assert "mujoco model, from the estimated start, 5 s:" in text and "reference model" in text
    report = json.loads((out / "report.json").read_text())
    assert report["release"]["time_s"] == pytest.approx(HOLD_S, abs=0.004)
    fitted = report["identification"]["least_squares"]["b_n_m_s"]
    assert fitted[0] == pytest.approx(8e-4, rel=0.02)
    cases = {(c["engine"], c["release"], c["window"]): c["metrics"] for c in report["cases"]}
    runs = (("mujoco", "estimated"), ("reference", "estimated"), ("reference", "nominal"))  # nominal: the paper's
    assert set(cases) == {(e, r, w) for e, r in runs for w in ("5 s", "whole")}
    best = cases[("mujoco", "estimated", "whole")]
    assert set(best) == {"phi1", "omega1", "omega2", "tangential_m1", "normal_m1"}
    assert best["phi1"]["delta_f"] < 1e-3 and best["omega1"]["max_abs"] < 0.02
    # the nominal 30 deg start (the paper's simulation) is far worse than the estimated release
    assert cases[("reference", "nominal", "whole")]["phi1"]["iae"] > 50 * best["phi1"]["iae"]
    # the two engines agree on the same comparison
    assert cases[("reference", "estimated", "whole")]["phi1"]["iae"] == pytest.approx(best["phi1"]["iae"], rel=1e-6)
    figures = sorted(p.name for p in out.glob("*.png"))
    assert [f[:5] for f in figures] == ["fig09", "fig10", "fig11", "fig12", "fig13", "fig14", "fig15"]


def test_a_model_with_10_percent_stiffer_coupling_springs_fails_validation(proportional, tmp_path, capsys):
    gates = ["--max-delta", "0.005", "--max-iae", "0.01", "--max-error-phi1", "0.005"]
    c1 = DEFAULT_PARAMS.c1_n_m * 1.1
    args = ["validate", str(proportional), "-o", str(tmp_path / "r"), "--no-plots", "--damping", "recorded"]
    assert main([*args, "--set", f"c1_n_m={c1}", *gates]) == 1
    err = capsys.readouterr().err
    assert "validation failed" in err and "max |Delta phi1|" in err
    # and the same command with the true model passes (--force: its report replaces the first one)
    assert main([*args, *gates, "--force"]) == 0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--damping", "fast"], "--damping must be 'identified', 'recorded' or B1,B2"),
        (["--damping", "1e-3,-1"], "--damping values must be finite, >= 0 and at most 1000"),
        (["--max-delta", "-1"], "argument --max-delta: must be in [0, 100]"),
    ],
)
def test_validate_bad_options_are_one_line_exit_2(proportional, capsys, extra, message):
    assert main(["validate", str(proportional), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_validate_and_identify_refuse_missing_and_broken_files(tmp_path, capsys):
    for command in ("validate", "identify"):
        assert main([command, str(tmp_path / "none.mcap")]) == 2
        assert "none.mcap: no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)
    assert main(["validate", str(bad)]) == 2
    assert "bad.mcap:" in capsys.readouterr().err
