"""Planar against spatial: beat analysis on an analytic case, the zero-offset limit, the compare
command, and spatial recordings validated against the planar model."""

import collections
import json
import math

import numpy as np
import pytest
import rerun as rr
from scipy.signal import hilbert

from pendsim_bridge.cli import main
from pendsim_bridge.io.recording import read_recording
from pendsim_mj.estimation.analysis import beat
from pendsim_mj.estimation.comparison import compare_planar_spatial
from pendsim_mj.rig.params import DEFAULT_PARAMS


def test_beat_period_and_depth_of_an_amplitude_modulated_decay():
    t = np.arange(0, 120, 0.01)
    period, depth = 12.0, 0.2
    x = (1 + depth * np.cos(2 * math.pi * t / period)) * np.exp(-t / 80) * np.sin(2 * math.pi * 0.87 * t)
    b = beat(t, x)
    assert b.period_s == pytest.approx(period, rel=0.03)
    assert b.depth == pytest.approx(depth, rel=0.1)
    assert math.isinf(beat(t, np.exp(-t / 80) * np.sin(2 * math.pi * 0.87 * t)).period_s)  # no beat


@pytest.mark.parametrize(("a", "b"), [(1.0, 0.3), (1.0, 0.03), (0.5, 1.0), (1.0, 0.9)])
def test_two_close_modes_beat_with_period_one_over_their_difference_and_depth_min_over_max(a, b):
    # a sin(2 pi f1 t) + b sin(2 pi f2 t): envelope sqrt(a^2 + b^2 + 2 a b cos(2 pi (f2 - f1) t)),
    # between |a - b| and a + b, so (high - low) / (high + low) = min(a, b) / max(a, b)
    t = np.arange(0, 120, 0.01)
    f1, f2 = 0.87, 0.95
    x = np.exp(-t / 80) * (a * np.sin(2 * math.pi * f1 * t) + b * np.sin(2 * math.pi * f2 * t))
    result = beat(t, x)
    assert result.period_s == pytest.approx(1 / (f2 - f1), rel=0.005)
    assert result.depth == pytest.approx(min(a, b) / max(a, b), rel=0.01)
    assert result.carrier_hz == pytest.approx(f1 if a > b else f2, abs=0.002)


def test_a_distant_mode_mixing_in_is_a_ripple_not_a_beat():
    # two modes 0.6 Hz apart (M2 of the spatial rig: 0.878 and 1.474 Hz, nearly equal): the whole
    # signal's envelope swings by 60 %, but the carrier band holds one line: no beat
    t = np.arange(0, 120, 0.01)
    decay = np.exp(-t / 80)
    ripple = decay * (np.sin(2 * math.pi * 0.874 * t) + 0.6 * np.sin(2 * math.pi * 1.47 * t))
    whole = np.abs(hilbert(ripple))[500:-500] / decay[500:-500]
    assert (whole.max() - whole.min()) / (whole.max() + whole.min()) > 0.5  # what the ripple looks like
    result = beat(t, ripple)
    assert math.isinf(result.period_s) and result.depth < 0.01
    # a shallow true beat under the same ripple is still found, with its own depth
    beating = ripple + decay * 0.03 * np.sin(2 * math.pi * (0.874 + 1 / 12.6) * t)
    result = beat(t, beating)
    assert result.period_s == pytest.approx(12.6, rel=0.005)
    assert result.depth == pytest.approx(0.03, rel=0.03)


def test_with_zero_offset_the_spatial_variant_shows_no_difference():
    result = compare_planar_spatial(DEFAULT_PARAMS, (math.radians(30), 0.0), 60.0)
    for p in result.pendulums.values():
        assert p.in_plane_difference_max_rad < 1e-9
        assert p.out_of_plane_amplitude_rad < 1e-12
        assert p.beats["planar"].depth == pytest.approx(p.beats["spatial"].depth, abs=1e-9)


def test_compare_reports_the_out_of_plane_motion_and_the_beat_and_draws_both_rigs(tmp_path, capsys):
    out = tmp_path / "cmp"
    rrd = tmp_path / "cmp.rrd"
    assert main(["compare", "-o", str(out), "--rerun", str(rrd)]) == 0
    text = capsys.readouterr().out
    assert "planar vs spatial (50 mm between the planes" in text
    summary = json.loads((out / "summary.json").read_text())
    m1 = summary["pendulums"]["m1"]
    assert summary["plane_offset_m"] == 0.05 and summary["main_frequency_hz"] == pytest.approx(0.87, abs=0.02)
    assert m1["in_plane_difference_max_rad"] > math.radians(1) and m1["out_of_plane_amplitude_rad"] > math.radians(1)
    assert m1["beat_period_s"]["planar"] is None  # the planar M1 swing does not beat (< 1 % ripple)
    assert 5 < m1["beat_period_s"]["spatial"] < 30  # the spatial one does, slowly (12.6 s measured)
    assert m1["beat_depth"]["spatial"] > 2 * m1["beat_depth"]["planar"]
    assert len(m1["spectrum_peaks_hz"]["spatial"]) >= 1
    assert sorted(p.name for p in out.glob("*.png")) == [
        "compare_angles.png",
        "compare_difference_and_tilt.png",
        "compare_envelope_and_spectrum.png",
    ]
    rows, static = collections.Counter(), collections.Counter()
    for chunk in rr.chunk.RrdReader(str(rrd)).stream():
        (static if chunk.is_static else rows)[str(chunk.entity_path)] += chunk.num_rows
    for rig in ("planar", "spatial"):
        assert rows[f"/rig/{rig}/m1"] == rows[f"/rig/{rig}/springs"] == 12001
        assert static[f"/rig/{rig}/m1/geoms"] == 1
        assert rows[f"/plots/phi1/{rig}"] == 12001
    assert rows["/plots/tilt1/spatial"] == 12001


def test_a_spatial_recording_shows_the_tilt_in_imu_and_tf_and_fails_planar_validation(tmp_path, capsys):
    path = tmp_path / "spatial.mcap"
    assert main(["record", "--model", "spatial", "-o", str(path), "--duration-s", "40", "--hold-s", "1"]) == 0
    rec = read_recording(path)
    assert rec.run_info().model == "spatial" and rec.params().plane_offset_m == 0.05
    assert np.max(np.abs(rec.imu["m1"].gyro_rad_s[:, 0])) > 0.05  # rotation about sensor x: out of plane
    _, quat = rec.tf_rotation_wxyz
    y_axis = 2 * (quat[..., 2] * quat[..., 3] + quat[..., 0] * quat[..., 1])  # z of the body's y axis
    assert np.max(np.abs(y_axis[:, 0])) > 0.02  # the pivot axis of M1 rocks
    gates = ["--damping", "recorded", "--no-plots", "-o", str(tmp_path / "v"), "--max-error-phi1", "0.01"]
    assert main(["validate", str(path), *gates]) == 1
    assert "validation failed: max |Delta phi1|" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["compare", "--fixed-points-plane", "m3"], "--fixed-points-plane must be m1 or m2"),
        (["compare", "--engine", "reference"], "the spatial model runs in MuJoCo only"),
        (["record", "-o", "x.mcap", "--model", "cubic"], "unknown model 'cubic'; allowed: planar, spatial"),
        (["record", "-o", "x.mcap", "--model", "spatial", "--static"], "--model spatial needs the mujoco engine"),
    ],
)
def test_spatial_bad_input_is_one_line_exit_2(tmp_path, monkeypatch, capsys, args, message):
    monkeypatch.chdir(tmp_path)
    assert main([*args, "--duration-s", "10"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
