"""pendsim record / inspect / recover: outputs, summaries, one-line errors, data never lost."""

import re

import numpy as np
import pytest

from pendsim_bridge.cli import main
from pendsim_bridge.io.recording import read_recording


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("pendsim: error: ")
    return err[0]


def test_record_writes_a_complete_recording_with_the_requested_run(tmp_path, capsys):
    out = tmp_path / "run.mcap"
    args = ["record", "-o", str(out), "--duration-s", "10", "--phi1-deg", "20", "--seed", "3", "--b1", "0.001"]
    assert main(args) == 0
    assert f"wrote {out}: 10 s, 801 IMU samples per node" in capsys.readouterr().out
    rec = read_recording(out)
    assert rec.complete and len(rec.imu["m1"].t_ns) == 801 and len(rec.joint_states.t_ns) == 1001
    assert rec.params().b1_n_m_s == 0.001
    assert rec.run_info().phi0_rad[0] == pytest.approx(np.radians(20))
    assert rec.metadata["pendsim/run"]["seed"] == "3"
    assert [p.name for p in tmp_path.iterdir()] == ["run.mcap"]  # no partial file left


def test_record_without_noise_is_ideal_and_reference_engine_is_recorded(tmp_path):
    out = tmp_path / "ideal.mcap"
    assert main(["record", "-o", str(out), "--duration-s", "2", "--no-noise", "--engine", "reference"]) == 0
    rec = read_recording(out)
    assert rec.metadata["pendsim/run"]["engine"] == "reference"
    assert rec.metadata["pendsim/run"]["noise"] == "false"
    accel = rec.imu["m1"].accel_m_s2
    assert not np.allclose(accel / 0.01, np.rint(accel / 0.01))  # not quantised


@pytest.mark.parametrize("engine", ["mujoco", "reference", "fast"])
def test_a_recording_of_every_engine_record_runs_is_read_back_and_replayed(tmp_path, capsys, engine):
    """Each engine ``record --engine`` offers writes a recording the readers take (the fast engine's
    was refused: ``engine = 'fast'; allowed: mujoco, reference, static``), and the twin replays it."""
    out = tmp_path / f"{engine}.mcap"
    assert main(["record", "-o", str(out), "--duration-s", "8", "--engine", engine]) == 0
    assert read_recording(out).run_info().engine == engine
    capsys.readouterr()
    assert main(["twin", "--replay", str(out), "--speed", "0", "-o", str(tmp_path / "twin.mcap")]) == 0
    assert "innovations: mean NIS" in capsys.readouterr().out


def test_inspect_prints_topics_counts_rates_and_metadata(tmp_path, capsys):
    out = tmp_path / "run.mcap"
    main(["record", "-o", str(out), "--duration-s", "5"])
    capsys.readouterr()
    assert main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in text.splitlines() if line.startswith("/")}
    assert rows["/imu/m1"][1:] == ["sensor_msgs/msg/Imu", "401", "80.00"]
    assert rows["/joint_states"][1:] == ["sensor_msgs/msg/JointState", "501", "100.00"]
    assert rows["/tf"][2:] == ["501", "100.00"]
    assert "duration 5.000 s" in text and "metadata pendsim/rig_parameters:" in text and "c1_n_m = 6.173" in text
    assert "attachment pendulums.xml (application/xml" in text


def test_record_refuses_to_overwrite_an_existing_file_unless_forced(tmp_path, capsys):
    out = tmp_path / "keep.mcap"
    out.write_bytes(b"precious data")
    assert main(["record", "-o", str(out), "--duration-s", "1"]) == 2
    assert "exists; choose another name or pass --force" in _one_error_line(capsys)
    assert out.read_bytes() == b"precious data"
    assert main(["record", "-o", str(out), "--duration-s", "1", "--force"]) == 0
    assert read_recording(out).complete


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--compression", "bzip2"], "unknown compression 'bzip2'; allowed: zstd, lz4, none"),
        (["--duration-s", "-5"], "--duration-s must be a finite number > 0 s"),
        (["--set", "c1_n_m=1e6"], "simulation diverged"),
        (["--seed", "x"], "argument --seed: must be an integer in [0, 9223372036854775807], got 'x'"),
    ],
)
def test_record_bad_input_is_one_line_exit_2_and_leaves_no_file(tmp_path, capsys, args, message):
    out = tmp_path / "x.mcap"
    assert main(["record", "-o", str(out), "--duration-s", "3", *args]) == 2
    assert message in _one_error_line(capsys)
    assert list(tmp_path.iterdir()) == []


def test_record_needs_an_mcap_name_in_an_existing_directory(tmp_path, capsys):
    assert main(["record", "-o", str(tmp_path / "run.npz")]) == 2
    assert "must end in .mcap" in _one_error_line(capsys)
    assert main(["record", "-o", str(tmp_path / "missing" / "run.mcap")]) == 2
    assert "does not exist" in _one_error_line(capsys)


def test_inspect_and_recover_handle_a_truncated_recording(tmp_path, capsys):
    out = tmp_path / "run.mcap"
    main(["record", "-o", str(out), "--duration-s", "60"])
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(out.read_bytes()[: out.stat().st_size * 2 // 3])
    capsys.readouterr()
    assert main(["inspect", str(cut)]) == 2
    line = _one_error_line(capsys)
    assert "cut.mcap:" in line and re.search(r"chunks? intact", line) and "pendsim recover" in line
    fixed = tmp_path / "fixed.mcap"
    assert main(["recover", str(cut), str(fixed)]) == 0
    assert "wrote" in capsys.readouterr().out
    rec = read_recording(fixed)
    full = read_recording(out)
    n = len(rec.imu["m1"].t_ns)
    assert rec.complete and 0 < n < len(full.imu["m1"].t_ns)
    np.testing.assert_array_equal(rec.imu["m1"].accel_m_s2, full.imu["m1"].accel_m_s2[:n])
    assert rec.mjcf_xml == full.mjcf_xml and rec.params() == full.params()
    assert main(["recover", str(cut), str(fixed)]) == 2  # never overwrites without --force
    assert "exists; choose another name or pass --force" in _one_error_line(capsys)


@pytest.mark.parametrize("content", [b"", b"garbage" * 100])
def test_inspect_of_garbage_is_one_line_exit_2(tmp_path, capsys, content):
    path = tmp_path / "junk.mcap"
    path.write_bytes(content)
    assert main(["inspect", str(path)]) == 2
    assert "junk.mcap: not an MCAP file" in _one_error_line(capsys)
    assert main(["inspect", str(tmp_path / "absent.mcap")]) == 2
    assert "absent.mcap: no such file" in _one_error_line(capsys)


def test_record_summary_counts_what_each_node_wrote_and_the_hold(tmp_path, capsys):
    out = tmp_path / "lossy.mcap"
    assert main(["record", "-o", str(out), "--duration-s", "4", "--hold-s", "1", "--packet-loss", "0.1"]) == 0
    rec = read_recording(out)
    m1, m2 = (len(rec.imu[n].t_ns) for n in ("m1", "m2"))
    assert m1 < 401 and m2 < 401 and m1 != m2  # 5 s at 80 Hz: 401 instants, some lost per node
    lost = 100 * (1 - (m1 + m2) / 802)
    assert f"wrote {out}: 5 s, {m1} (M1) and {m2} (M2) IMU samples of 401, {lost:.1f} % lost" in capsys.readouterr().out


def test_a_recording_without_both_nodes_is_refused_naming_the_file_once(tmp_path, capsys):
    csv = tmp_path / "lab.csv"
    csv.write_text("t_ms,gx,gy,gz\n" + "".join(f"{12.5 * i},0.1,0,0\n" for i in range(5)))
    lab = tmp_path / "lab.mcap"
    assert main(["import", str(csv), "-o", str(lab), "--node", "m1", "--columns", "t_ms,gx,gy,gz"]) == 0
    assert ", 0.050 s, m1: 5 samples" in capsys.readouterr().out  # first to last stamp, as inspect says
    for command in ("validate", "identify"):
        assert main([command, str(lab)]) == 2
        line = _one_error_line(capsys)
        assert line == (
            f"pendsim: error: {lab}: needs both /imu/m1 and /imu/m2 (M1's and M2's IMU); /imu/m2 missing; "
            "a one-node recording is for 'pendsim inspect' and 'pendsim allan' (docs/acquisition.md)"
        )
