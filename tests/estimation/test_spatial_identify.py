"""The spatial model against recordings: identify --model spatial finds the tilt stiffness and
damping a spatial record was made with, with intervals that cover them (the start state fitted
too), from the support's tilt at the start as the recording was made; validate --model spatial
says which model fits better."""

import json
import math

import mujoco
import numpy as np
import pytest

from pendsim_bridge.cli import main
from pendsim_bridge.io.recording import read_recording
from pendsim_bridge.run.record import RecordSpec, simulate_for
from pendsim_bridge.run.spatial_validate import gyro_in_swing_frames, tilt_start_of
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.errors import RecordingError
from pendsim_mj.estimation.alignment import NodeSamples, align
from pendsim_mj.estimation.spatial_identification import NAMES, fit_tilt, static_tilt_rad
from pendsim_mj.rig.model import HINGES, SPATIAL, TILTS, build_spec
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, sample_imu

TRUE = {"tilt_stiffness_n_m_rad": 3.0, "tilt_damping_n_m_s_rad": 0.0015}  # defaults: 2.0 and 0.0007


@pytest.fixture(scope="module")
def spatial_record(tmp_path_factory):
    """20 s from the spatial model (50 mm, tilt values off the defaults), held 1 s, with noise."""
    path = tmp_path_factory.mktemp("spatial") / "spatial.mcap"
    sets = [a for name, value in TRUE.items() for a in ("--set", f"{name}={value}")]
    assert main(["record", "--model", "spatial", "--duration-s", "20", "--hold-s", "1", *sets, "-o", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def planar_record(tmp_path_factory):
    path = tmp_path_factory.mktemp("planar") / "planar.mcap"
    assert main(["record", "--duration-s", "20", "--hold-s", "1", "-o", str(path)]) == 0
    return path


def test_identify_spatial_finds_the_tilt_stiffness_and_damping_of_a_spatial_record(spatial_record, tmp_path, capsys):
    written = tmp_path / "tilt.json"
    assert main(["identify", str(spatial_record), "--model", "spatial", "--write", str(written)]) == 0
    text = capsys.readouterr().out
    values = json.loads(written.read_text())
    assert set(values) == {"tilt_stiffness_n_m_rad", "tilt_damping_n_m_s_rad", "b1_n_m_s", "b2_n_m_s"}
    # started from the assumed defaults (2.0, 0.0007), 50 % and 114 % away
    assert values["tilt_stiffness_n_m_rad"] == pytest.approx(TRUE["tilt_stiffness_n_m_rad"], rel=0.01)
    assert values["tilt_damping_n_m_s_rad"] == pytest.approx(TRUE["tilt_damping_n_m_s_rad"], rel=0.03)
    assert values["b1_n_m_s"] == pytest.approx(DEFAULT_PARAMS.b1_n_m_s, rel=0.03)
    assert values["b2_n_m_s"] == pytest.approx(DEFAULT_PARAMS.b2_n_m_s, rel=0.03)
    assert "tilt_stiffness_n_m_rad" in text and "+-" in text and "95 % intervals" in text
    # the written values drive record --model spatial
    again = tmp_path / "again.mcap"
    assert (
        main(["record", "--model", "spatial", "--duration-s", "1", "--params-file", str(written), "-o", str(again)])
        == 0
    )


def test_validate_spatial_prefers_the_spatial_model_for_a_spatial_record(spatial_record, tmp_path, capsys):
    out = tmp_path / "v"
    assert main(["validate", str(spatial_record), "--model", "spatial", "--no-plots", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    choice = json.loads((out / "report.json").read_text())["model_choice"]
    assert choice["better"] == "spatial" and "the spatial model fits better" in text
    assert choice["overall"]["spatial"] < 0.2 * choice["overall"]["planar"]
    assert choice["quantities"]["phi1"]["better"] == "spatial"
    assert set(choice["quantities"]["phi1"]["rms"]) == {"planar", "spatial"}


def test_validate_spatial_prefers_the_planar_model_for_a_planar_record(planar_record, tmp_path, capsys):
    out = tmp_path / "v"
    assert main(["validate", str(planar_record), "--model", "spatial", "--no-plots", "-o", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["model_choice"]["better"] == "planar"
    assert report["model_choice"]["plane_offset_m"] == 0.05  # a planar rig's offset is unknown: the paper's
    # without --model spatial the report is the planar one, unchanged
    capsys.readouterr()
    assert main(["validate", str(planar_record), "--no-plots", "-o", str(tmp_path / "p")]) == 0
    assert "model_choice" not in json.loads((tmp_path / "p" / "report.json").read_text())
    assert "planar vs spatial" not in capsys.readouterr().out


@pytest.mark.parametrize("command", ["identify", "validate"])
@pytest.mark.parametrize("value", ["spacial", "", "SPATIAL"])
def test_a_bad_model_is_one_error_line_exit_2(planar_record, capsys, command, value):
    assert main([command, str(planar_record), "--model", value]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("pendsim: error: ") and "--model" in err[0]


SPATIAL_RIG = DEFAULT_PARAMS.with_overrides(plane_offset_m=0.05)


def _spatial_run(truth, seed, phi0_rad, *, tilt0_rad=(0.0, 0.0), duration_s=10.0, hold_s=1.0):
    """A synthetic spatial record through the BNO055 model (held, then released), aligned."""
    traj = simulate(truth, phi0_rad, (0.0, 0.0), duration_s, 0.01, variant=SPATIAL, tilt0_rad=tilt0_rad)
    config = Bno055(seed=seed)
    imu = sample_imu(traj, config, hold_s=hold_s)
    nodes = []
    for k in range(2):
        stamp, log, received = imu.node_times(k)
        values = (imu.quat_wxyz[received, k], imu.gyro_rad_s[received, k], imu.accel_m_s2[received, k])
        nodes.append(NodeSamples(log[received], *values, stamp_s=stamp[received]))
    return align(nodes, truth, fusion_rate_hz=config.fusion_rate_hz)


def _tilt_fit(truth, run, tilt_start="zero"):
    """The tilt fit from the assumed defaults, as identify --model spatial starts it."""
    base = truth.with_mapping({n: getattr(DEFAULT_PARAMS, n) for n in NAMES})
    t, gyro, sigma = gyro_in_swing_frames(run, [None, None])
    return fit_tilt(
        base, run.start.phi_rad, t, gyro, sigma, omega0_rad_s=run.start.omega_rad_s, tilt_start=tilt_start,
        timing_range_s=run.relative_timing_range_s,
    )  # fmt: skip


def test_tilt_intervals_cover_the_true_tilt_values_over_seeded_spatial_records():
    """8 records (16 intervals) at the defaults and at stiffness 5, damping 0.0015. At a true 95 %
    three or more misses in 16 have probability 4 %; four or more 0.7 %: the test asks at most
    three. The start taken as exact (the fit before) missed 11 of these 16: the stiffness 8 of 8
    (median error 7.7 half-widths), the damping 3 of 8; bench/bench_spatial_coverage.py measures
    30 records per setting (93-100 %)."""
    rng = np.random.default_rng(5)
    misses, ratios = 0, []
    for i in range(8):
        stiffness, damping = (2.0, 0.0007) if i % 2 == 0 else (5.0, 0.0015)
        truth = SPATIAL_RIG.with_overrides(
            tilt_stiffness_n_m_rad=stiffness,
            tilt_damping_n_m_s_rad=damping,
            b1_n_m_s=float(rng.uniform(4e-4, 1.2e-3)),
            b2_n_m_s=float(rng.uniform(2e-4, 1e-3)),
        )
        run = _spatial_run(truth, 500 + i, (math.radians(float(rng.uniform(20, 40))), 0.0))
        fit = _tilt_fit(truth, run)
        for name in NAMES[:2]:
            error = abs(fit.value(name) - getattr(truth, name))
            misses += error > fit.half_width(name)
            ratios.append(error / fit.half_width(name))
        assert "phi1_0" in fit.names and "release_offset_s" in fit.names
    assert misses <= 3, (misses, ratios)
    assert np.median(ratios) > 0.1, ratios  # and not far too wide (0.34 expected for honest ones)


def test_static_tilt_is_where_the_held_support_settles():
    """Newton on the tilts' generalized force against MuJoCo settling the support with both
    hinges held (heavily damped tilts, stepped until still)."""
    phi = (math.radians(34), math.radians(-5))
    rig = SPATIAL_RIG.with_overrides(tilt_damping_n_m_s_rad=0.05)
    model = build_spec(rig, variant=SPATIAL, timestep_s=0.001).compile()  # the held hinges drift 1e-5 rad per step
    data = mujoco.MjData(model)
    hinge_q = [model.joint(h).qposadr[0] for h in HINGES]
    hinge_v = [model.joint(h).dofadr[0] for h in HINGES]
    tilt_q = [model.joint(n).qposadr[0] for n in TILTS]
    for _ in range(30_000):
        data.qpos[hinge_q], data.qvel[hinge_v] = phi, 0.0
        mujoco.mj_step(model, data)
    np.testing.assert_allclose(static_tilt_rad(rig, phi), data.qpos[tilt_q], atol=1e-6)
    # at rest the offset coupling springs tilt M1's support by about 2.3 deg
    assert math.degrees(static_tilt_rad(SPATIAL_RIG, (0.0, 0.0))[0]) == pytest.approx(2.34, abs=0.02)


def test_the_fit_starts_the_support_tilted_as_the_record_was_made():
    """A support that rests at its static tilt before the release (a real rig) is fitted with
    the static start; the untilted start, pendsim's, leaves residuals far above the noise."""
    truth = SPATIAL_RIG.with_overrides(tilt_stiffness_n_m_rad=3.0, tilt_damping_n_m_s_rad=0.0015)
    phi0 = (math.radians(30), 0.0)
    run = _spatial_run(truth, 77, phi0, tilt0_rad=static_tilt_rad(truth, phi0))
    static = _tilt_fit(truth, run, "static")
    assert static.residual_rms_sigma < 1.1 and static.tilt_start == "static"
    for name in NAMES[:2]:
        assert abs(static.value(name) - getattr(truth, name)) <= static.half_width(name)
    assert _tilt_fit(truth, run, "zero").residual_rms_sigma > 3


def test_record_model_spatial_holds_the_support_untilted_and_identify_starts_it_so(spatial_record):
    traj = simulate_for(RecordSpec(params=SPATIAL_RIG, model="spatial", duration_s=0.5, hold_s=2.0))
    assert np.all(traj.tilt_rad[0] == 0.0) and np.all(traj.tilt_rate_rad_s[0] == 0.0)
    assert abs(static_tilt_rad(SPATIAL_RIG, RecordSpec().phi0_rad)[0]) > math.radians(1)  # so not at rest
    assert tilt_start_of(read_recording(spatial_record)) == "zero"

    class Elsewhere:  # a recording without pendsim's run metadata (a real rig)
        def run_info(self):
            raise RecordingError("no pendsim/run metadata")

    assert tilt_start_of(Elsewhere()) == "static"


def test_a_spatial_record_that_starts_at_the_release_is_fitted_as_a_release(tmp_path, capsys):
    """No hold: the alignment starts "in motion" at the first sample, all but at rest; the fit
    takes it as a release at the recording's start (its instant fitted: the first fused values
    are 0-10 ms old), so that the support's tilt there is known (untilted, as record made it)."""
    path = tmp_path / "nohold.mcap"
    assert main(["record", "--model", "spatial", "--duration-s", "10", "-o", str(path)]) == 0
    capsys.readouterr()
    written = tmp_path / "tilt.json"
    assert main(["identify", str(path), "--model", "spatial", "--write", str(written)]) == 0
    text = capsys.readouterr().out
    assert "in motion at 0.000 s" in text and "release_offset_s" in text and "omega1_0" not in text
    rows = {line.split()[0]: line.split() for line in text.splitlines() if "+-" in line}
    for name in NAMES:
        value, half = float(rows[name][1]), float(rows[name][3])
        assert abs(value - getattr(DEFAULT_PARAMS, name)) <= 2 * half, (name, value, half)
    residual = float(text.split("residual ")[1].split()[0])
    assert residual < 1.1
