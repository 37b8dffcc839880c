"""The drive options of simulate/record/view/compare and the `pendsim analyze` verbs, on the real
command line: outputs a person and a program can read, recordings that carry their drive, and
one-line errors with exit code 2."""

import json
import math

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from pendsim_bridge.cli import main
from pendsim_bridge.io.recording import read_recording
from pendsim_mj.engines.reference import solve
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.rig.drives import Drive, Sine, drive_from_held_inputs, held_inputs
from pendsim_mj.rig.params import DEFAULT_PARAMS


def test_simulate_with_a_drive_matches_the_library_and_reports_the_drive_work(tmp_path, capsys):
    out = tmp_path / "run.npz"
    args = ["simulate", "--duration-s", "10", "--torque1-n-m", "sine:0.003,0.87,90", "--pivot-z-m-s2", "sine:1,1.7"]
    assert main([*args, "--engine", "reference", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "work done by the drive" in text
    drive = Drive(torque_m1=Sine(0.003, 0.87, math.pi / 2), pivot_z=Sine(1.0, 1.7))
    expected = solve(DEFAULT_PARAMS, (math.radians(30), 0.0), (0.0, 0.0), 10.0, drive=drive)
    saved = np.load(out)
    np.testing.assert_array_equal(saved["phi_rad"], expected.phi_rad)
    np.testing.assert_array_equal(saved["drive_input"], expected.drive_input)
    # the balance closes with the drive's work (second-order error of its trapezoid integral)
    residual = float(next(line for line in text.splitlines() if "residual" in line).split()[3])
    work = float(next(line for line in text.splitlines() if "work done" in line).split()[-2])
    assert abs(residual) < 2e-3 * abs(work)


def test_simulate_reads_a_drive_from_a_csv_file(tmp_path, capsys):
    path = tmp_path / "shaker.csv"
    t = np.arange(0, 10.01, 0.01)
    np.savetxt(path, np.column_stack([t, 0.5 * np.sin(2 * math.pi * t)]), delimiter=",", header="t_s,a", comments="")
    out = tmp_path / "run.csv"
    assert main(["simulate", "--duration-s", "10", "--support-x-m-s2", f"csv:{path}:a", "-o", str(out)]) == 0
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    header = out.read_text().splitlines()[0].split(",")
    support_x = data[:-1, header.index("support_x_m_s2")]
    # the series, linearly interpolated at each step's midpoint
    expected = np.interp((np.arange(1000) + 0.5) * 0.01, t, 0.5 * np.sin(2 * math.pi * t))
    np.testing.assert_allclose(support_x, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--torque1-n-m", "sine:1"], "sine takes sine:AMP,FREQ_HZ[,PHASE_DEG], got 'sine:1'"),
        (["--torque2-n-m", "square:1,2"], "expected a signal sine:AMP,FREQ_HZ[,PHASE_DEG]; stepped:"),
        (["--pivot-z-m-s2", "chirp:1,0.5,2,-3"], "duration_s must be > 0"),
        (["--support-x-m-s2", "sine:1,nan"], "must be finite"),
        (["--torque1-n-m", "csv:missing.csv"], "csv drive file missing.csv: no such file"),
        (["--torque1-n-m", "sine:0.001,1", "--duration-s", "5", "--dt-s", "0.3"], "--dt-s must be at most 0.1 s"),
    ],
)
def test_bad_drive_options_are_one_line_exit_2(capsys, args, message):
    assert main(["simulate", "--duration-s", "1", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pendsim: error: ") and message in err and err.count("\n") == 1


def test_a_csv_drive_shorter_than_the_run_is_refused(tmp_path, capsys):
    path = tmp_path / "short.csv"
    path.write_text("t_s,tau\n0,0\n5,0.001\n")
    assert main(["simulate", "--torque2-n-m", f"csv:{path}"]) == 2
    assert "covers 0 to 5 s; the run needs 0 to 120 s" in capsys.readouterr().err


def test_a_driven_recording_carries_its_drive_and_view_reproduces_the_run(tmp_path, capsys):
    rec = tmp_path / "driven.mcap"
    args = ["record", "-o", str(rec), "--duration-s", "10", "--hold-s", "1", "--no-noise"]
    assert main([*args, "--support-x-m-s2", "sine:0.5,0.9", "--torque1-n-m", "chirp:0.002,0.5,1.5,10"]) == 0
    recording = read_recording(rec)
    drive = Drive(support_x=Sine(0.5, 0.9))
    assert recording.drive_input is not None
    t_ns, held = recording.drive_input
    assert len(t_ns) == 1001 and t_ns[0] == 1_000_000_000  # every step, from the release
    np.testing.assert_allclose(held[:-1, 2], held_inputs(drive, 1000, 0.01)[:, 2], rtol=0, atol=1e-15)
    meta = recording.metadata["pendsim/drive"]
    assert json.loads(meta["support_x"]) == {
        "kind": "Sine", "unit": "m/s^2", "amplitude": 0.5, "frequency_hz": 0.9, "phase_rad": 0.0
    }  # fmt: skip
    assert json.loads(meta["torque_m1"])["kind"] == "Chirp"
    # other tools decode the /drive topic with its own schema
    with open(rec, "rb") as f:
        messages = list(make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(topics=["/drive"]))
    first = messages[0][3]
    assert first.layout.dim[0].label == "torque_m1_n_m,torque_m2_n_m,support_x_m_s2,pivot_z_m_s2"
    assert list(first.data) == pytest.approx(held[0].tolist(), abs=0)
    # /tf carries the support's displacement
    assert recording.tf_rotation_wxyz is not None
    # the recorded inputs rebuild the drive exactly: the re-simulation is the run itself
    original = simulate(DEFAULT_PARAMS, (math.radians(30), 0.0), (0.0, 0.0), 10.0, drive=_recorded_drive(t_ns, held))
    direct = simulate(
        DEFAULT_PARAMS, (math.radians(30), 0.0), (0.0, 0.0), 10.0,
        drive=Drive(support_x=Sine(0.5, 0.9), torque_m1=_chirp()),
    )  # fmt: skip
    assert np.max(np.abs(original.phi_rad - direct.phi_rad)) < 1e-12
    assert main(["view", str(rec), "--save", str(tmp_path / "driven.rrd")]) == 0
    assert (tmp_path / "driven.rrd").stat().st_size > 10_000


def _recorded_drive(t_ns, held):
    return drive_from_held_inputs((t_ns - t_ns[0]) * 1e-9, held)


def _chirp():
    from pendsim_mj.rig.drives import Chirp

    return Chirp(0.002, 0.5, 1.5, 10.0)


def test_compare_takes_the_drive_options(tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["compare", "--duration-s", "5", "--support-x-m-s2", "sine:0.3,0.9", "-o", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["pendulums"]["m1"]["out_of_plane_amplitude_rad"] > 0


def test_analyze_backbone_writes_json_csv_and_png_whose_numbers_agree(tmp_path, capsys):
    out = tmp_path / "bb"
    assert main(["analyze", "backbone", "--mode", "1", "--max-amplitude-deg", "20", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "mode 1:" in text and "free-simulation frequency within" in text
    data = json.loads((out / "backbone.json").read_text())
    (b,) = data["backbones"]
    rows = np.genfromtxt(out / "backbone.csv", delimiter=",", names=True)
    np.testing.assert_allclose(rows["frequency_hz"], b["frequency_hz"])
    np.testing.assert_allclose(rows["amplitude_phi1_deg"], np.degrees(np.array(b["amplitude_rad"])[:, 0]))
    assert np.all(rows["relative_difference"] < 1e-4) and rows["amplitude_phi1_deg"][-1] >= 20
    assert (out / "backbone.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_analyze_response_reports_the_folds_and_the_agreement(tmp_path, capsys):
    out = tmp_path / "resp"
    args = ["analyze", "response", "--torque1-n-m", "sine:0.05,0.8", "--set", "b1_n_m_s=0.00695",
            "--set", "b2_n_m_s=0.00587", "--f-min-hz", "0.74", "--f-max-hz", "0.86", "--frequencies", "3"]  # fmt: skip
    assert main([*args, "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert text.count("  fold at") == 2
    data = json.loads((out / "response.json").read_text())
    assert [b["kind"] for b in data["continuation"]["bifurcations"]] == ["fold", "fold"]
    assert all(a["max_relative_difference"] < 0.01 for a in data["agreement"])
    for name in ("response_continuation.csv", "response_stepped.csv", "response.png"):
        assert (out / name).stat().st_size > 100


def test_analyze_tongues_lyapunov_bifurcation_and_sync_on_small_settings(tmp_path, capsys):
    t = tmp_path
    assert main(["analyze", "tongues", "--f-min-hz", "1.7", "--f-max-hz", "1.8", "--frequencies", "5",
                 "--level-max-m-s2", "0.6", "--levels", "4", "-o", str(t / "tg")]) == 0  # fmt: skip
    rows = np.genfromtxt(t / "tg" / "tongues.csv", delimiter=",", names=True)
    inside = np.isfinite(rows["boundary_m_s2"])
    assert inside.any()
    np.testing.assert_allclose(rows["boundary_m_s2"][inside], rows["mathieu_mode1_m_s2"][inside], rtol=0.02)
    free = ["analyze", "lyapunov", "--free", "--phi1-deg", "20", "--set", "b1_n_m_s=0", "--set", "b2_n_m_s=0",
            "--duration-s", "200", "--transient-s", "0", "--members", "3", "--dt-s", "0.02"]  # fmt: skip
    assert main([*free, "-o", str(t / "ly")]) == 0
    ly = json.loads((t / "ly" / "lyapunov.json").read_text())["result"]
    assert ly["converged"] and abs(ly["exponent_per_s"]) + ly["uncertainty_per_s"] < 0.04  # regular: about 0
    assert len(ly["member_exponents_per_s"]) == 3 and len(ly["half_step_exponents_per_s"]) == 1
    assert main(["analyze", "bifurcation", "--values", "3", "--transient-periods", "5", "--sample-periods", "4",
                 "-o", str(t / "bf")]) == 0  # fmt: skip
    rows = np.genfromtxt(t / "bf" / "bifurcation.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert len(rows) == 2 * 3 * 4 and np.all(np.abs(rows["phi1_rad"]) <= math.pi)
    assert main(["analyze", "sync", "--frequencies", "3", "--measure-periods", "10", "-o", str(t / "sy")]) == 0
    rows = np.genfromtxt(t / "sy" / "sync.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert np.all(rows["locking_index"] > 0.9)  # small drive, damped: M2 follows M1 at the drive frequency
    for folder, stem in (("tg", "tongues"), ("ly", "lyapunov"), ("bf", "bifurcation"), ("sy", "sync")):
        assert (t / folder / f"{stem}.png").stat().st_size > 10_000


def test_an_unconverged_lyapunov_exponent_is_one_line_and_exit_1_with_the_files_written(tmp_path, capsys):
    out = tmp_path / "ly"
    args = ["analyze", "lyapunov", "--duration-s", "60", "--transient-s", "20", "--members", "3", "-o", str(out)]
    assert main(args) == 1
    captured = capsys.readouterr()
    (line,) = captured.err.strip().splitlines()
    assert line.startswith("pendsim: unconverged: the Lyapunov exponent is ") and "--duration-s" in line
    assert "NOT converged" in captured.out
    ly = json.loads((out / "lyapunov.json").read_text())["result"]
    assert not ly["converged"] and ly["uncertainty_per_s"] > ly["tolerance_per_s"]


def test_an_unconverged_tongue_tip_is_one_line_and_exit_1(tmp_path, capsys):
    out = tmp_path / "tg"
    args = ["analyze", "tongues", "--f-min-hz", "1.74", "--f-max-hz", "1.77", "--frequencies", "3",
            "--level-max-m-s2", "0.3", "--levels", "2", "--steps-per-period", "32", "-o", str(out)]  # fmt: skip
    assert main(args) == 1
    captured = capsys.readouterr()
    (line,) = captured.err.strip().splitlines()
    assert line.startswith("pendsim: unconverged: the tongue tip at 1.754") and "raise --steps-per-period" in line
    assert "tongue tip near 2 f1: 0.1107" in captured.out  # 64 steps per period: within 1e-4 of the tip
    (tip,) = json.loads((out / "tongues.json").read_text())["tongues"]["tips"]
    assert not tip["converged"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["analyze"], "analyze needs a verb: backbone, response, bifurcation, lyapunov, tongues, sync"),
        (["analyze", "response", "--torque1-n-m", "chirp:0.01,0.5,1,10"], "sweeps a sine drive"),
        (["analyze", "response", "--f-min-hz", "1", "--f-max-hz", "0.9"], "--f-max-hz (0.9) must exceed --f-min-hz"),
        (["analyze", "backbone", "--mode", "3"], "--mode must be 1, 2 or both, got '3'"),
        (["analyze", "tongues", "--level-max-m-s2", "-1"], "must be in [0.01, 100] m/s^2"),
    ],
)
def test_analyze_bad_input_is_one_line_exit_2(tmp_path, capsys, args, message):
    assert main([*args, "-o", str(tmp_path / "x")] if len(args) > 1 else args) == 2
    err = capsys.readouterr().err
    assert err.startswith("pendsim: error: ") and message in err, err
    assert not (tmp_path / "x").exists()
