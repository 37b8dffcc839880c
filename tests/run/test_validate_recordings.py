"""Validation holds on recordings as real ones come, through the CLI a newcomer uses: no hold, an
arbitrary heading with a hand-glued remapped node, a hold with hand wobble and a replay cut of it,
lost packets with drifting clocks, a start mid-swing. Each must validate with max |Delta phi1|
over 5 s below 0.01 rad and a phi1 frequency delta below 0.5 % (issue 11)."""

import json

import pytest

from pendsim_bridge.cli import main

MAX_DELTA_PHI1_RAD = 0.01
MAX_FREQUENCY_DELTA = 0.005


def _record(path, *options):
    assert main(["record", "-o", str(path), *options]) == 0
    return path


def _validate(path, capsys, *options):
    out = path.with_name(path.stem + "_report")
    assert main(["validate", str(path), "-o", str(out), *options]) == 0
    text = capsys.readouterr().out
    return json.loads((out / "report.json").read_text()), text


def _assert_validates(report):
    cases = {(c["engine"], c["release"], c["window"]): c["metrics"] for c in report["cases"]}
    short, whole = cases[("mujoco", "estimated", "5 s")]["phi1"], cases[("mujoco", "estimated", "whole")]["phi1"]
    assert short["max_abs"] < MAX_DELTA_PHI1_RAD, short
    assert short["delta_f"] < MAX_FREQUENCY_DELTA and whole["delta_f"] < MAX_FREQUENCY_DELTA, (short, whole)


def test_an_arbitrary_heading_and_a_misaligned_remapped_node_validate(tmp_path, capsys):
    path = _record(
        tmp_path / "heading.mcap", "--duration-s", "12", "--heading-deg", "137", "--mount-misalignment-deg", "10",
        "--axis-remap", "0x21,0x00", "--seed", "3",
    )  # fmt: skip
    report, _ = _validate(path, capsys, "--no-plots")
    _assert_validates(report)
    assert report["nodes"]["m1"]["mirrored_axes"] is True  # 0x21,0x00 swaps x and y: a mirror image


def test_a_hold_with_hand_wobble_and_a_replay_cut_6_s_after_the_release_validate(tmp_path, capsys):
    path = _record(
        tmp_path / "held.mcap", "--duration-s", "14", "--hold-s", "2", "--hold-wobble-deg", "0.2", "--seed", "4"
    )
    report, text = _validate(path, capsys, "--no-plots")
    assert report["release"]["kind"] == "release" and report["release"]["time_s"] == pytest.approx(2.0, abs=0.005)
    assert "release from rest found, at" in text
    _assert_validates(report)
    cut = tmp_path / "cut.mcap"
    assert main(["replay", str(path), "--start", "8", "-o", str(cut)]) == 0
    report, text = _validate(cut, capsys, "--no-plots")
    assert report["release"]["kind"] == "in motion" and report["release"]["time_s"] == pytest.approx(8.0, abs=1e-6)
    assert report["release"]["nominal_angle_rad"] is None  # mid-swing: no comparison from 30 deg at rest
    _assert_validates(report)


def test_lost_packets_and_a_drifting_clock_validate_and_say_what_was_covered(tmp_path, capsys):
    path = _record(
        tmp_path / "lossy.mcap", "--duration-s", "12", "--packet-loss", "0.05", "--clock-drift-ppm", "50",
        "--latency-s", "0.002", "--seed", "5",
    )  # fmt: skip
    report, text = _validate(path, capsys, "--no-plots")
    _assert_validates(report)
    m2 = report["nodes"]["m2"]
    assert m2["clock_drift_ppm"] == pytest.approx(50, abs=10)
    assert 0.03 < m2["coverage"]["lost_fraction"] < 0.08 and m2["coverage"]["covered_fraction"] < 1.0
    assert "% lost" in text and "clock +" in text


def test_a_start_mid_swing_validates_from_the_state_at_the_first_samples(tmp_path, capsys):
    path = _record(tmp_path / "swinging.mcap", "--duration-s", "12", "--phi1-deg", "10", "--omega1-deg-s", "90")
    report, _ = _validate(path, capsys, "--no-plots")
    assert report["release"]["estimated_rate_rad_s"][0] == pytest.approx(1.571, abs=0.05)  # 90 deg/s
    _assert_validates(report)


def test_identify_and_view_take_a_recording_without_a_hold_and_a_given_release(tmp_path, capsys):
    path = _record(tmp_path / "short.mcap", "--duration-s", "10", "--hold-s", "1")
    assert main(["identify", str(path), "--release-s", "1.0"]) == 0
    assert "start given, at 1.000 s" in capsys.readouterr().out
    assert main(["view", str(path), "--save", str(tmp_path / "short.rrd"), "--max-gap-s", "0.05"]) == 0
    assert (tmp_path / "short.rrd").stat().st_size > 0


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--release-s", "99"], "release_s = 99.0 s is outside the samples of both nodes"),
        (["--max-gap-s", "0"], "argument --max-gap-s: must be in (0, 10] s"),
    ],
)
def test_bad_alignment_options_are_one_line_exit_2(tmp_path, capsys, options, message):
    path = _record(tmp_path / "r.mcap", "--duration-s", "5")
    capsys.readouterr()
    assert main(["validate", str(path), *options]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "r_validation").exists()


def test_a_recording_without_motion_is_one_line_exit_2(tmp_path, capsys):
    path = _record(tmp_path / "still.mcap", "--static", "--duration-s", "5")
    capsys.readouterr()
    for command in ("validate", "identify", "view"):
        assert main([command, str(path)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "no motion found: both gyros stay below 0.05 rad/s" in err[0], err
