"""The pendsim command line: summaries, outputs, and one-line errors with exit code 2."""

import json
import math
import shutil
import subprocess
import sys

import numpy as np
import pytest

from pendsim_bridge.cli import main
from pendsim_mj.engines.reference import solve
from pendsim_mj.rig.params import RigParams


def test_simulate_on_defaults_prints_frequencies_amplitudes_and_energy(capsys):
    assert main(["simulate", "--duration-s", "30"]) == 0
    out = capsys.readouterr().out
    assert "engine mujoco, 30 s at dt = 0.01 s (3001 samples)" in out
    phi1 = next(line for line in out.splitlines() if line.startswith("phi1")).split()
    freq, start_deg = float(phi1[1]), float(phi1[2])
    # the linearised in-phase mode of the rig is near 0.87 Hz; the first peak of a 30 deg release
    # lies just below 30 deg (energy already lost to damping)
    assert 0.8 < freq < 0.95
    assert 28.5 < start_deg < 30.0
    assert "energy lost" in out and "dissipated by the hinges (damping, friction)" in out
    assert "(integration error; large means reduce --dt-s)" in out  # no dry friction: the step's error alone
    assert "dry friction:" not in out


def test_a_mujoco_run_with_dry_friction_names_its_soft_constraint_in_the_balance(capsys):
    # MuJoCo's frictionloss is a soft constraint: its dissipation is the ideal law's only nearly
    # (7e-5 J of the 0.107 J lost here; the fast engine's smooth law closes it to 2e-7 J)
    for engine in ("mujoco", "fast"):
        assert main(["simulate", "--duration-s", "20", "--set", "friction1_n_m=0.01", "--engine", engine]) == 0
        out = capsys.readouterr().out
        balance = next(line for line in out.splitlines() if line.startswith("energy balance"))
        assert ("MuJoCo's soft dry friction" in balance) == (engine == "mujoco"), balance
        assert (
            "dry friction: MuJoCo's soft constraint holds a pendulum off-centre" in out
            and f"(this run: {engine};" in out
        )
        residual = abs(float(balance.split()[3]))
        assert residual < (1e-3 if engine == "mujoco" else 1e-5) * 0.107, balance


def test_simulate_writes_npz_that_matches_the_reference_engine(tmp_path, capsys):
    out = tmp_path / "ref.npz"
    args = ["simulate", "--engine", "reference", "--phi1-deg", "10", "--phi2-deg", "-5", "--duration-s", "2"]
    assert main([*args, "--b1", "0", "-o", str(out)]) == 0
    saved = np.load(out)
    params = RigParams().with_overrides(b1_n_m_s=0.0)
    expected = solve(params, (math.radians(10), math.radians(-5)), (0.0, 0.0), 2.0)
    np.testing.assert_array_equal(saved["phi_rad"], expected.phi_rad)
    assert f"wrote {out}" in capsys.readouterr().out


def test_simulate_writes_csv_with_a_header(tmp_path):
    out = tmp_path / "run.csv"
    assert main(["simulate", "--duration-s", "1", "--set", "c2_n_m=5", "-o", str(out)]) == 0
    header = out.read_text().splitlines()[0].split(",")
    assert header[:3] == ["t_s", "phi1_rad", "omega1_rad_s"]
    assert len(np.loadtxt(out, delimiter=",", skiprows=1)) == 101


def test_info_lists_every_parameter_with_unit_and_source(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    for name, unit, source in RigParams.describe():
        line = next(line for line in out.splitlines() if line.split()[:1] == [name])
        assert unit in line and source in line


def test_info_of_a_recording_lists_the_rig_it_states_and_its_json_is_a_parameter_file(tmp_path, capsys):
    rec = tmp_path / "rig.mcap"
    assert main(["record", "-o", str(rec), "--set", "c1_n_m=6.5", "--set", "m1_kg=0.22", "--duration-s", "2"]) == 0
    capsys.readouterr()
    assert main(["info", str(rec)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0].startswith(f"Rig parameters stated by {rec}: 2 not the paper's")
    rows = {line.split()[0]: line for line in out.splitlines()[1:]}
    assert set(rows) == {name for name, _, _ in RigParams.describe()}
    assert "6.5" in rows["c1_n_m"] and f"(the paper's: {RigParams().c1_n_m:.6g})" in rows["c1_n_m"]
    assert "(the paper's" not in rows["c2_n_m"]  # as the paper's: its own source
    assert main(["info", str(rec), "--json"]) == 0
    stated = json.loads(capsys.readouterr().out)
    assert stated == RigParams().with_mapping({"c1_n_m": 6.5, "m1_kg": 0.22}).as_dict()
    rig = tmp_path / "rig.json"
    rig.write_text(json.dumps(stated))
    assert main(["info", str(rig)]) == 0  # a parameter file, read as --params-file reads it
    assert "2 not the paper's" in capsys.readouterr().out.splitlines()[0]


def test_info_refuses_a_file_that_states_no_rig_in_one_line(tmp_path, capsys):
    from mcap.writer import Writer

    other = tmp_path / "other.mcap"  # another tool's recording: no pendsim metadata
    with open(other, "wb") as f:
        w = Writer(f)
        w.start()
        w.finish()
    rec = tmp_path / "rig.mcap"
    assert main(["record", "-o", str(rec), "--duration-s", "2"]) == 0
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(rec.read_bytes()[:1000])
    bad = tmp_path / "bad.json"
    bad.write_text('{"c1_nm": 6.5}')
    capsys.readouterr()
    later = tmp_path / "later.mcap"  # cut after its metadata: the rig is read, and the damage said
    later.write_bytes(rec.read_bytes()[: rec.stat().st_size * 4 // 5])
    assert main(["info", str(later)]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith(f"Rig parameters stated by {later}: 0 not the paper's")
    warning = captured.err.strip().splitlines()
    assert len(warning) == 1 and warning[0].startswith(f"warning: {later}: ") and "pendsim recover" in warning[0]
    for path, message in ((other, "states no rig"), (cut, "truncated"), (bad, "did you mean 'c1_n_m'"),
                          (tmp_path / "none.mcap", "no such file")):  # fmt: skip
        assert main(["info", str(path)]) == 2
        captured = capsys.readouterr()
        err = captured.err.strip().splitlines()
        assert not captured.out and len(err) == 1 and err[0].startswith("pendsim: error: ") and message in err[0], err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--phi1-deg", "nan"], "--phi1-deg must be a finite number, got 'nan'"),
        (["--phi2-deg", "abc"], "--phi2-deg must be a finite number, got 'abc'"),
        (["--set", "c1_n_m=-1"], "c1_n_m must be >= 0 N/m, got -1.0"),
        (["--set", "m2_kg=-0.1"], "m2_kg must be > 0 kg, got -0.1"),
        (["--set", "spring=1"], "unknown parameter(s) spring; allowed:"),
        (["--set", "c2_nm=1"], "unknown parameter(s) c2_nm (did you mean 'c2_n_m'?); allowed:"),
        (["--set", "c1_n_m"], "expected NAME=VALUE"),
        (["--b1", "-0.001"], "--b1 must be a finite number >= 0 N m s/rad, got -0.001"),
        (["--duration-s", "0"], "--duration-s must be a finite number > 0 s, got 0.0"),
        (["--dt-s", "-0.01"], "--dt-s must be a finite number > 0 s, got -0.01"),
        (["--engine", "simulink"], "unknown engine 'simulink'; allowed: mujoco, reference, fast"),
        (["-o", "/nonexistent-dir/run.npz"], "output directory '/nonexistent-dir' does not exist"),
        (["-o", "run.txt"], "output 'run.txt' must end in .npz or .csv"),
        (["--set", "c1_n_m=1e7"], "c1_n_m must be 0 or between 1e-09 and 1e+06 N/m, got 1e+07"),
        (["--set", "c1_n_m=1e6"], "simulation diverged"),
        (["--set", "c1_n_m=1e6", "--engine", "reference"], "simulation diverged"),
        (["--bogus"], "unrecognized arguments: --bogus"),
    ],
)
def test_bad_input_gives_one_line_and_exit_code_2(capsys, tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "--duration-s", "10", *args]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("pendsim: error: ") and message in lines[0]
    assert list(tmp_path.iterdir()) == []  # no output file, partial or otherwise


def test_unwritable_output_directory_is_refused(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        code = main(["simulate", "--duration-s", "1", "-o", str(locked / "x.npz")])
        err = capsys.readouterr().err
        if code == 0:  # running as root: the directory is writable after all, and the file must be whole
            assert np.load(locked / "x.npz")["phi_rad"].shape == (101, 2)
        else:
            assert code == 2 and "is not writable" in err
    finally:
        locked.chmod(0o700)


def test_a_diverging_run_leaves_an_existing_output_file_untouched(tmp_path):
    out = tmp_path / "keep.npz"
    assert main(["simulate", "--duration-s", "1", "-o", str(out)]) == 0
    before = out.read_bytes()
    assert main(["simulate", "--duration-s", "10", "--set", "c1_n_m=1e6", "-o", str(out)]) == 2
    assert out.read_bytes() == before


def test_installed_console_script_runs_without_a_traceback():
    exe = shutil.which("pendsim") or str(__import__("pathlib").Path(sys.executable).parent / "pendsim")
    ok = subprocess.run([exe, "simulate", "--duration-s", "5"], capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0 and "phi1" in ok.stdout
    bad = subprocess.run([exe, "simulate", "--engine", "x"], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    helped = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=120)
    assert helped.returncode == 0 and "simulate" in helped.stdout and "info" in helped.stdout
