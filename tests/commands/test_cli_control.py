"""pendsim control: the plain invocations a newcomer types, the recording they write (read with the
mcap library, replayed on the independent reference solver, validated and viewed by pendsim's own
commands), and bad input refused before any run."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from pendsim_bridge.cli import main
from pendsim_mj.control.plant import replay_drive
from pendsim_mj.engines import reference
from pendsim_mj.rig.drives import Sampling
from pendsim_mj.rig.params import DEFAULT_PARAMS


def test_control_lqr_without_options_prints_the_decay_against_the_open_loop(capsys):
    assert main(["control", "lqr"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.strip().startswith(("1 ", "2 "))]
    assert len(rows) == 2
    for row in rows:
        assert row[-1].endswith("x") and float(row[-1][:-1]) >= 10.0  # both modes at least 10x shorter


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp("control") / "run.mcap"
    assert main(["control", "lqr", "-o", str(path)]) == 0
    return path


def _messages(path, topic):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(m.log_time, d) for _, _, m, d in reader.iter_decoded_messages(topics=[topic])]


def test_the_recording_holds_the_loop_on_drive_and_control_and_replays_on_the_reference(recorded):
    with open(recorded, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    control = meta["pendsim/control"]
    assert control["controller"] == "lqr" and json.loads(control["motors"]) == ["m1", "m2"]
    assert json.loads(control["metrics"])["peak_torque_m1_n_m"] <= 0.05
    steps = _messages(recorded, "/control")
    names = steps[0][1].layout.dim[0].label.split(",")
    assert len(steps) == 3000 and "tau1_n_m" in names and "seen_phi1_rad" in names
    drive = np.array([d.data for _, d in _messages(recorded, "/drive")])
    logged = np.array([d.data for _, d in steps])
    applied = logged[:, [names.index("tau1_n_m"), names.index("tau2_n_m")]]
    np.testing.assert_allclose(drive[:3000, :2], applied, rtol=0, atol=1e-15)  # the replayed drive, to rounding
    assert np.max(np.abs(drive[:, :2])) <= 0.05
    # the recorded joint states are the recorded torques replayed on the independent planar solver
    joints = np.array([d.position for _, d in _messages(recorded, "/joint_states")])
    ref = reference.solve(
        DEFAULT_PARAMS, (math.radians(30), 0.0), (0.0, 0.0), 30.0, 0.01,
        drive=replay_drive(drive[:3000], 0.01), sampling=Sampling.HELD,
    )  # fmt: skip
    assert np.max(np.abs(joints - ref.phi_rad)) < 1e-9
    assert np.max(np.abs(joints[-100:])) < math.radians(0.05)  # damped to rest within 30 s


def test_validate_and_view_open_a_control_recording(recorded, tmp_path):
    assert main(["validate", str(recorded), "-o", str(tmp_path / "validation")]) == 0
    report = json.loads((tmp_path / "validation" / "report.json").read_text())
    assert report
    assert main(["view", str(recorded), "-o", str(tmp_path / "run.rrd")]) == 0
    assert (tmp_path / "run.rrd").stat().st_size > 0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["control", "pid"], "unknown controller 'pid'"),
        (["control", "lqr", "--engine", "reference"], "unknown engine 'reference' for a closed loop"),
        (["control", "lqr", "--motors", "m3"], "unknown motors 'm3'"),
        (["control", "energy", "--torque-limit-n-m", "0"], "--torque-limit-n-m"),
        (["control", "lqr", "--dt-s", "0.1"], "the control period (--dt-s) must be in (0, 0.02] s"),
        (["control", "lqr", "--packet-loss", "0.05"], "add --observe nodes"),
        (["control", "energy", "--input-weight", "3"], "an input weight is for the lqr design"),
        (["control", "lqr", "--target-amplitude-deg", "10"], "for the energy controller"),
        (["control", "energy", "--target-amplitude-deg", "20", "--phi1-deg", "0"], "mode 1 starts still"),
    ],
)
def test_bad_options_get_one_line_and_exit_2(args, message, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main([*args, "-o", "run.mcap"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pendsim: error:") and message in err[0]
    assert list(tmp_path.iterdir()) == []


def test_gains_that_destabilise_the_rig_are_refused_before_anything_runs_or_is_written(tmp_path, capsys):
    gains = tmp_path / "gains.json"
    gains.write_text(json.dumps([[0.0, 0.0, -0.05, 0.0], [0.0, 0.0, 0.0, 0.0]]))  # negative damping on M1
    out = tmp_path / "run.mcap"
    assert main(["control", "lqr", "--gain-file", str(gains), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "destabilise the linearised rig" in err[0]
    assert not out.exists()
    gains.write_text(json.dumps([[0.0, 0.0, 0.02, 0.0], [0.0, 0.0, 0.0, 0.02]]))  # plain added damping: stable
    assert main(["control", "lqr", "--gain-file", str(gains), "--duration-s", "2", "--no-open-loop"]) == 0
