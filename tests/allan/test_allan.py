"""Allan deviation: the kernel against allantools, analytic limits, noise-term extraction, gaps,
and the pendsim allan command."""

import dataclasses
import json
import math
import re

import allantools
import numpy as np
import pytest
from mcap_ros2.writer import Writer as Ros2Writer

from pendsim_bridge.cli import main
from pendsim_bridge.io import ros2
from pendsim_bridge.io.recording import RunInfo, read_recording, write_recording
from pendsim_bridge.report.allan_report import cv_percent, duration_text
from pendsim_mj.allan.deviation import (
    MIN_MOTION_RAD_S,
    MOTION_MARGIN_S,
    allan_curves,
    check_sampling,
    confidence_interval,
    edf_overlapping,
    gyro_motion,
    longest_uniform_segment,
    motion_intervals_s,
    noise_terms,
    overlapping_adev,
    phase,
    still_samples,
    tau_grid,
)
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.model import exact_mjcf
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, ImuNoise, flicker_noise, static_imu

FS = 80.0


def test_kernel_equals_allantools_oadev_on_one_and_two_threads():
    rng = np.random.default_rng(0)
    y = rng.normal(size=(800_000, 3)) + np.cumsum(rng.normal(size=(800_000, 3)) * 1e-3, axis=0)
    m = tau_grid(len(y))
    parallel = overlapping_adev(y, m, threads=2)  # 2.4 M values: two threads
    serial = overlapping_adev(y, m, threads=1)
    np.testing.assert_allclose(parallel, serial, rtol=1e-14)  # summation order differs per column set
    for j in range(3):
        _, reference, _, _ = allantools.oadev(y[:, j], rate=FS, data_type="freq", taus=m / FS)
        np.testing.assert_allclose(serial[:, j], reference, rtol=1e-11)


def test_six_columns_together_give_each_columns_deviations_bit_for_bit():
    """A node's six columns take the kernel's scalar-sum path; one column alone the general loop."""
    rng = np.random.default_rng(3)
    y = (rng.normal(size=(60_000, 6)) * [1, 2, 3, 1e-3, 2e-3, 3e-3] + 9.81).astype(np.float32)
    m = tau_grid(len(y))
    together = overlapping_adev(y, m, threads=1)
    alone = np.column_stack([overlapping_adev(y[:, j], m, threads=1) for j in range(6)])
    np.testing.assert_array_equal(together, alone)
    _, reference, _, _ = allantools.oadev(y[:, 4].astype(float), rate=FS, data_type="freq", taus=m / FS)
    np.testing.assert_allclose(together[:, 4], reference, rtol=1e-9)


def test_phase_is_the_running_sum_of_each_column_less_its_mean():
    rng = np.random.default_rng(4)
    accel = (rng.normal(size=(5000, 3)) + np.array([0.1, 9.8, -0.2])).astype(np.float32)
    gyro = rng.normal(size=(5000, 3)) * 1e-3
    x = phase(accel, gyro)
    assert x.shape == (5001, 6) and np.all(x[0] == 0)
    for j, column in enumerate([*accel.T, *gyro.T]):
        values = column.astype(float)
        mean = math.fsum(values) / len(values)
        exact = np.array([0.0, *np.cumsum(values - mean)])
        np.testing.assert_allclose(x[:, j], exact, rtol=0, atol=1e-9 * np.abs(values).max() * len(values))


def test_white_noise_follows_sigma_over_sqrt_tau_fs_inside_its_confidence_band():
    sigma = 0.0117
    y = np.random.default_rng(1).normal(size=int(2 * 3600 * FS)) * sigma
    curve = allan_curves(y, FS, confidence=0.95)[0]
    theory = sigma / np.sqrt(curve.tau_s * FS)
    inside = (curve.low <= theory) & (theory <= curve.high)
    # neighbouring taus are strongly correlated, so one record's coverage scatters (0.8-1.0 seen)
    assert inside.mean() >= 0.8, curve.tau_s[~inside]
    assert curve.tau_s[0] == pytest.approx(1 / FS)
    assert curve.adev[0] == pytest.approx(sigma, rel=0.03)
    assert np.all(curve.alpha[: len(curve.alpha) // 2] == 0)  # identified as white noise


@pytest.mark.parametrize("confidence", [0.683, 0.95])
def test_confidence_bands_are_calibrated_over_many_records(confidence):
    sigma = 0.002
    coverage = []
    for seed in range(10):
        y = np.random.default_rng(100 + seed).normal(size=int(3600 * FS)) * sigma
        curve = allan_curves(y, FS, confidence=confidence)[0]
        theory = sigma / np.sqrt(curve.tau_s * FS)
        coverage.append(np.mean((curve.low <= theory) & (theory <= curve.high)))
    assert np.mean(coverage) == pytest.approx(confidence, abs=0.08), coverage


def test_a_pure_random_walk_has_log_log_slope_plus_one_half():
    y = np.cumsum(np.random.default_rng(2).normal(size=int(2 * 3600 * FS))) * 1e-4
    curve = allan_curves(y, FS)[0]
    slope = np.polyfit(np.log(curve.tau_s), np.log(curve.adev), 1)[0]
    assert slope == pytest.approx(0.5, abs=0.05)


def test_noise_terms_recover_white_noise_and_bias_instability_within_10_percent():
    # 6 h at 80 Hz (the paper's static test); white N = 5e-4 units*sqrt(s), flicker B = 4e-4 units
    rng = np.random.default_rng(3)
    n_white, b = 5e-4, 4e-4
    n = int(6 * 3600 * FS)
    y = rng.normal(size=n) * n_white * math.sqrt(FS) + flicker_noise(rng, (n,), FS, b)
    terms = noise_terms(allan_curves(y, FS)[0])
    assert terms.white == pytest.approx(n_white, rel=0.10)
    assert terms.bias_instability == pytest.approx(b, rel=0.10)
    assert terms.rate_random_walk is None


def test_noise_terms_recover_the_rate_random_walk_and_report_no_bias_instability():
    rng = np.random.default_rng(4)
    n_white, k = 1e-3, 1e-3
    n = int(2 * 3600 * FS)
    y = rng.normal(size=n) * n_white * math.sqrt(FS) + np.cumsum(rng.normal(size=n)) * k / math.sqrt(FS)
    terms = noise_terms(allan_curves(y, FS)[0])
    assert terms.white == pytest.approx(n_white, rel=0.10)
    assert terms.rate_random_walk == pytest.approx(k, rel=0.10)
    assert terms.bias_instability is None  # the -1/2 to +1/2 crossover is not a flat region


def _record(seed: int, hours: float, n_white: float, b: float = 0.0, k: float = 0.0) -> np.ndarray:
    """White noise N, flicker of bias instability B and a rate random walk K at FS, in one unit."""
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 * FS)
    y = rng.normal(size=n) * n_white * math.sqrt(FS)
    if b:
        y += flicker_noise(rng, (n,), FS, b)
    if k:
        y += np.cumsum(rng.normal(size=n)) * k / math.sqrt(FS)
    return y


def test_a_weak_rate_random_walk_is_never_taken_for_bias_instability():
    # A new user's record (2026-11-28): a gyro's white noise with K = 5e-6 rad/s/sqrt(s), no B, 1 h.
    # Read off the slope lines, the crossover from -1/2 to +1/2 (the random walk dominates only
    # past 45 s, where the estimate has few degrees of freedom) passed for bias instability on 10
    # of 12 axes and K was found on 2. Fitted: never B; K within 20 % where the record resolves it.
    found = 0
    for seed in range(6):
        terms = noise_terms(allan_curves(_record(seed, 1.0, 1.3e-4, k=5e-6), FS)[0])
        assert terms.white == pytest.approx(1.3e-4, rel=0.03)
        assert terms.bias_instability is None
        if terms.rate_random_walk is not None:
            found += 1
            assert terms.rate_random_walk == pytest.approx(5e-6, rel=0.20)
        else:
            assert terms.unresolved  # the rise is there: said, not dropped
    assert found >= 4


def test_white_noise_alone_gives_no_other_term():
    # a gyro's and an accelerometer's level; 1 h, whose last tau (360 s) has about 5 degrees of
    # freedom: a flat part "dominating" there alone gave B on a new user's white recording
    for n_white in (1.3e-4, 1.2e-3):
        for seed in range(6):
            terms = noise_terms(allan_curves(_record(10 + seed, 1.0, n_white), FS)[0])
            assert terms.white == pytest.approx(n_white, rel=0.03)
            assert (terms.bias_instability, terms.rate_random_walk, terms.unresolved) == (None, None, False), seed


def test_gaps_and_irregular_timestamps_are_found():
    t = np.arange(10_000, dtype=np.int64) * 12_500_000
    t[5000:] += 3 * 12_500_000  # three samples missing
    t[200] += 3_000_000  # 3 ms late: irregular
    report = check_sampling(t, FS)
    assert not report.uniform
    assert [(g[0], round(g[2], 4)) for g in report.gaps] == [(4999, 0.0375)]
    assert report.irregular == 2  # the late sample shortens one interval and lengthens the next
    assert "1 gap(s), the largest 0.038 s missing after t = 62.488 s" in report.describe()
    segment = longest_uniform_segment(t, FS)
    assert (segment.start, segment.stop) == (5000, 10_000)


@pytest.fixture(scope="module")
def static_recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("allan") / "static.mcap"
    assert (
        main(["record", "--static", "--duration-s", "1800", "-o", str(path), "--gyro-bias-instability-rad-s", "2e-4"])
        == 0
    )
    return path


def test_allan_command_prints_the_papers_table_and_the_noise_terms(static_recording, capsys):
    capsys.readouterr()
    assert main(["allan", str(static_recording), "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "sampled by its header stamps" not in out  # a recording's log times are its samples' instants
    first_table = out.split("\n\n")[1]  # header line, blank, the paper's table, blank, noise terms
    rows = {tuple(line.split()[:3]): line.split() for line in first_table.splitlines() if line.startswith(("m1", "m2"))}
    assert len(rows) == 12
    noise = ImuNoise()
    for node in ("m1", "m2"):
        for k, axis in enumerate("xyz"):
            sigma = float(rows[(node, "accelerometer", axis)][3])
            assert sigma == pytest.approx(noise.accel_sigma_m_s2[k], rel=0.05)
            assert float(rows[(node, "gyroscope", axis)][3]) == pytest.approx(noise.gyro_sigma_rad_s[k], rel=0.05)
        # at rest the y accelerometer reads g: mean and CV = sigma / mean
        y_row = rows[(node, "accelerometer", "y")]
        assert float(y_row[4]) == pytest.approx(DEFAULT_PARAMS.g_m_s2, abs=0.01)
        assert float(y_row[5]) == pytest.approx(100 * noise.accel_sigma_m_s2[1] / DEFAULT_PARAMS.g_m_s2, rel=0.05)
        # a gyro at rest reads its small bias, below its noise: no CV (it would be thousands of %)
        for axis in "xyz":
            gyro_row = rows[(node, "gyroscope", axis)]
            assert abs(float(gyro_row[4])) < float(gyro_row[3])
            assert gyro_row[5] == "-"
    assert "CV '-': the axis' mean is below its one-sample noise" in out
    assert "N (white)" in out and "B (bias inst.)" in out


def test_allan_command_writes_a_plot_per_node_and_sensor_and_json(static_recording, tmp_path, capsys):
    capsys.readouterr()
    plot_dir = tmp_path / "plots"
    assert main(["allan", str(static_recording), "--json", "--plot-dir", str(plot_dir)]) == 0
    result = json.loads(capsys.readouterr().out)
    names = sorted(p.name for p in plot_dir.iterdir())
    assert names == ["allan_m1_accel.png", "allan_m1_gyro.png", "allan_m2_accel.png", "allan_m2_gyro.png"]
    for p in plot_dir.iterdir():
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000
    assert len(result["axes"]) == 12 and result["rate_hz"] == 80.0
    gyro_x = next(a for a in result["axes"] if a["node"] == "m1" and a["sensor"] == "gyro" and a["axis"] == "x")
    assert gyro_x["bias_instability_B"] == pytest.approx(2e-4, rel=0.25)  # 30 min: the flat part has few dof
    curve = gyro_x["curve"]
    assert len(curve["tau_s"]) == len(curve["adev"]) == len(curve["low"]) > 40
    assert all(lo <= a <= hi for lo, a, hi in zip(curve["low"], curve["adev"], curve["high"], strict=True))
    assert gyro_x["cv_percent"] is None  # its mean below its noise: no ratio to it
    accel_y = next(a for a in result["axes"] if a["node"] == "m1" and a["sensor"] == "accel" and a["axis"] == "y")
    assert accel_y["cv_percent"] == pytest.approx(100 * accel_y["sigma"] / accel_y["mean"])


def test_cv_is_given_only_where_the_mean_stands_above_the_noise():
    assert cv_percent(0.01, 9.81) == pytest.approx(0.01 / 9.81 * 100)
    assert cv_percent(0.01, -0.02) == pytest.approx(50.0)  # |mean|: a negative mean as well
    assert cv_percent(0.01, 0.0101) == pytest.approx(0.01 / 0.0101 * 100)  # just below 100 %
    for mean in (0.0099, 0.0, -0.001, math.nan):
        assert math.isnan(cv_percent(0.01, mean))


def test_a_recording_with_a_gap_is_reported_not_silently_analysed(tmp_path, capsys):
    imu = static_imu(DEFAULT_PARAMS, 600.0, Bno055(seed=1))
    keep = np.ones(len(imu.t_s), bool)
    keep[20_000:20_400] = False  # 5 s lost
    gappy = dataclasses.replace(
        imu,
        **{
            f: getattr(imu, f)[keep]
            for f in (
                "t_s",
                "fused_t_s",
                "gyro_rad_s",
                "accel_m_s2",
                "linear_accel_m_s2",
                "gravity_m_s2",
                "quat_wxyz",
                "calibration",
            )
        },
    )
    path = write_recording(
        tmp_path / "gap.mcap",
        gappy,
        RunInfo("static", (0, 0), (0, 0), 600.0, 0.0125, "static"),
        exact_mjcf(),
        DEFAULT_PARAMS,
    )
    assert len(read_recording(path).imu["m1"].t_ns) == len(imu.t_s) - 400
    capsys.readouterr()
    assert main(["allan", str(path), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        len(err) == 1 and "gap.mcap: /imu/m1 is not uniformly sampled (1 gap(s), the largest 5.000 s missing" in err[0]
    )
    assert main(["allan", str(path), "--no-plots", "--longest-segment"]) == 0
    out = capsys.readouterr().out
    assert (
        "analysed the longest uniform stretch 0.000-249.988 s" in out
        or "analysed the longest uniform stretch 255.000-600.000 s" in out
    )
    # nodes whose stretches differ (a gap on one node only): the header gives each its own span
    # (it gave the longest node's span beside both counts)
    from pendsim_bridge.report.allan_report import analyse, table

    report = analyse(path, longest_segment=True)
    start, end = report.segment["m2"]
    shorter = dataclasses.replace(report, segment={**report.segment, "m2": (start, start + 100.0)})
    head = table(shorter).splitlines()[0]
    n1, n2 = report.n_samples["m1"], report.n_samples["m2"]
    assert f"m1: {n1} samples, {(end - start) / 60:.1f} min; m2: {n2} samples, 100.0 s" in head, head


def test_allan_on_a_missing_or_broken_file_is_one_line_exit_2(tmp_path, capsys):
    assert main(["allan", str(tmp_path / "absent.mcap")]) == 2
    assert "absent.mcap: no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not mcap")
    assert main(["allan", str(bad)]) == 2
    assert "bad.mcap: not an MCAP file" in capsys.readouterr().err


def test_a_node_at_rest_is_static_with_a_gyro_bias_and_a_1_deg_swing_is_motion():
    rng = np.random.default_rng(3)
    t = np.arange(0, 60, 1 / FS)
    noise = rng.normal(size=(len(t), 3)) * ImuNoise().gyro_sigma_rad_s
    at_rest = gyro_motion(noise + np.array([0.02, -0.03, 0.01]), FS)  # a bias of 0.04 rad/s: not motion
    assert at_rest.static and at_rest.largest_rad_s < 0.01
    w = 2 * math.pi * 0.86
    swing = noise.copy()
    swing[:, 2] += math.radians(1.0) * w * np.cos(w * t)  # 1 deg at the rig's 0.86 Hz
    moving = gyro_motion(swing, FS)
    assert not moving.static and moving.largest_rad_s > MIN_MOTION_RAD_S


@pytest.fixture(scope="module")
def held_then_swinging(tmp_path_factory):
    path = tmp_path_factory.mktemp("allan_moving") / "held.mcap"
    assert main(["record", "--hold-s", "20", "--duration-s", "5", "-o", str(path)]) == 0
    return path


def test_allan_on_a_swinging_recording_is_refused_naming_the_motion(held_then_swinging, capsys):
    capsys.readouterr()
    assert main(["allan", str(held_then_swinging), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert re.fullmatch(
        r"pendsim: error: .*held\.mcap: /imu/m1 is not static: it turns at up to 2\.\d+ rad/s \(20\.\d s into the "
        r"recording; .*'pendsim record --static'\), or '--longest-segment' analyses the longest static, .*",
        err[0],
    )


def test_allan_longest_segment_analyses_only_the_static_hold_of_a_swinging_recording(held_then_swinging, capsys):
    capsys.readouterr()
    assert main(["allan", str(held_then_swinging), "--no-plots", "--longest-segment"]) == 0
    out = capsys.readouterr().out
    stretch = re.search(
        r"m1: uniform, turns at up to [\d.]+ rad/s; analysed the longest static, uniform stretch ([\d.]+)-([\d.]+) s",
        out,
    )
    # the hold, not the swing: it ends MOTION_MARGIN_S before the release at 20 s
    assert stretch and float(stretch[1]) == 0.0 and 19.0 < float(stretch[2]) <= 20.0 - MOTION_MARGIN_S
    rows = {
        tuple(line.split()[:3]): line.split() for line in out.split("\n\n")[1].splitlines() if line.startswith("m1")
    }
    for k, axis in enumerate("xyz"):  # the noise table of the hold: the gyro's own noise
        assert float(rows[("m1", "gyroscope", axis)][3]) == pytest.approx(ImuNoise().gyro_sigma_rad_s[k], rel=0.15)


def test_confidence_intervals_equal_allantools_per_value():
    dev, edf = np.array([0.1, 0.02, 3.0, 1e-4]), np.array([1.5, 200.0, 7e6, 12.0])
    for confidence in (0.6827, 0.95):
        low, high = confidence_interval(dev, edf, confidence)
        for k in range(len(dev)):  # scipy.special's quantile as scipy.stats computes it: bit for bit
            assert (low[k], high[k]) == allantools.confidence_interval(dev[k], edf[k], ci=confidence)


@pytest.mark.parametrize("alpha", [1, 0, -1, -2])
def test_edf_equals_allantools_edf_greenhall_in_every_case(alpha):
    # Greenhall's cases for d = 2, F = S = m on the taus of short and long records: J <= 100 (2.1a,
    # 3.1) and r > d + 1 (the tables: 2.2, 3.2); beyond the grid (m > n / 10), J <= 100 with
    # m (d + 1) > 100 (2.1b: m = 40 of 150) and J > 100 with r <= d + 1 (2.3, 3.3: m = 80 of 400)
    cases = [(int(m), n) for n in (25, 200, 4001, 1_728_002) for m in tau_grid(n - 1)]
    for m, n_phase in [*cases, (40, 150), (50, 300), (80, 400)]:
        expected = allantools.edf_greenhall(alpha=alpha, d=2, m=m, N=n_phase, overlapping=True)
        assert edf_overlapping(alpha, m, n_phase) == expected, (alpha, m, n_phase)


def test_edf_refuses_a_noise_type_the_slopes_never_give():
    with pytest.raises(ParameterError, match="alpha must be 1, 0, -1 or -2, got 2"):
        edf_overlapping(2, 10, 1000)


def test_no_stretch_is_static_within_the_margin_of_any_nodes_motion():
    t = np.arange(0.0, 10.0, 0.5)
    moving = (t >= 4.0) & (t <= 5.0)  # one node moves from 4 to 5 s
    intervals = motion_intervals_s(t, moving)
    assert intervals.tolist() == [[4.0, 5.0]]
    other = np.arange(0.25, 10.0, 0.5)  # another node's instants
    still = still_samples(other, intervals, margin_s=1.0)
    assert other[~still].tolist() == [3.25, 3.75, 4.25, 4.75, 5.25, 5.75]  # within 1 s of [4, 5]
    assert still_samples(other, np.zeros((0, 2))).all()


@pytest.fixture(scope="module")
def held_then_released(tmp_path_factory):
    """2 s held at 30 deg, then released (M1 released; M2 follows through the springs)."""
    path = tmp_path_factory.mktemp("allan_release") / "release.mcap"
    assert main(["record", "--hold-s", "2", "--duration-s", "10", "-o", str(path)]) == 0
    return path


def test_longest_segment_of_a_release_ends_before_the_earliest_motion_of_any_node(held_then_released, capsys):
    # the release is at 2 s (the hold's end); M2 only starts turning later, through the springs
    rec = read_recording(held_then_released)
    onsets = {n: float(rec.imu[n].t_s[gyro_motion(rec.imu[n].gyro_rad_s, FS).moving][0]) for n in ("m1", "m2")}
    assert onsets["m1"] < 2.05 and onsets["m2"] > onsets["m1"]
    capsys.readouterr()
    assert main(["allan", str(held_then_released), "--no-plots", "--longest-segment", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    for node in ("m1", "m2"):  # both stretches end a margin before the earliest onset (M1's), M2's too
        start, end = result["sampling"][node]["analysed_s"]
        assert start == 0.0 and 2.0 - MOTION_MARGIN_S - 0.1 < end <= onsets["m1"] - MOTION_MARGIN_S + 1e-9


@pytest.mark.parametrize(
    ("duration_s", "text"), [(1.475, "1.5 s"), (119.0, "119.0 s"), (1800.0, "30.0 min"), (21600.0, "6.00 h")]
)
def test_durations_print_in_a_readable_unit(duration_s, text):
    assert duration_text(duration_s) == text


def test_a_short_stretch_prints_its_duration_in_seconds_not_zero_hours(held_then_released, capsys):
    capsys.readouterr()
    assert main(["allan", str(held_then_released), "--no-plots", "--longest-segment"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert re.search(r": 1\.\d s at 80 Hz", first) and " h at" not in first


def test_a_ros_bag_whose_log_times_jitter_is_analysed_on_its_header_stamps(tmp_path, capsys):
    """A bag as rosbag2 writes it: each message logged when it arrived (0.5 ms rms of transport
    delay: hundreds of intervals more than 10 % off), its header stamp the sensor's own regular
    80 Hz. The sampling is checked on the stamps, and the deviations are allantools' on the data."""
    path = tmp_path / "bag.mcap"
    rng = np.random.default_rng(5)
    n = 9600  # 2 min
    gyro = rng.normal(0.0, 1e-3, size=(2, n, 3))
    accel = rng.normal(0.0, 1e-2, size=(2, n, 3)) + np.array([0.0, 0.0, 9.81])
    with open(path, "wb") as f:
        w = Ros2Writer(f, chunk_size=200_000)
        schema = w.register_msgdef("sensor_msgs/msg/Imu", ros2.SCHEMAS["sensor_msgs/msg/Imu"].decode())
        for i in range(n):
            stamp = 1_700_000_000 * 10**9 + i * 12_500_000
            for k, node in enumerate(("m1", "m2")):
                arrival = stamp + int(abs(rng.normal(0.0, 0.5e6)))
                msg = {
                    "header": {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9}, "frame_id": node},
                    "angular_velocity": dict(zip("xyz", map(float, gyro[k, i]), strict=True)),
                    "linear_acceleration": dict(zip("xyz", map(float, accel[k, i]), strict=True)),
                }
                w.write_message(f"/imu/{node}", schema, msg, log_time=arrival, publish_time=arrival)
        w.finish()
    assert main(["allan", str(path), "--no-plots"]) == 0
    text = capsys.readouterr().out
    assert "m1: sampled by its header stamps (by its log times: " in text and "irregular interval(s)" in text
    assert main(["allan", str(path), "--no-plots", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["sampling"]["m2"]["clock"] == "header stamps" and result["n_samples"]["m1"] == n
    sigma = {(a["node"], a["sensor"], a["axis"]): a["sigma"] for a in result["axes"]}
    for k, node in enumerate(("m1", "m2")):
        _, reference, _, _ = allantools.oadev(gyro[k, :, 2], rate=FS, data_type="freq", taus=[1 / FS])
        assert sigma[(node, "gyro", "z")] == pytest.approx(reference[0], rel=1e-9)


def _bag_without_accelerometers(path, n: int = 4800) -> np.ndarray:
    """A ROS bag (mcap_ros2's writer) of two nodes at rest whose messages carry no accelerometer:
    zeros with covariance element 0 = -1, REP-145's "not provided"."""
    rng = np.random.default_rng(8)
    gyro = rng.normal(0.0, 1e-3, size=(2, n, 3))
    with open(path, "wb") as f:
        w = Ros2Writer(f, chunk_size=200_000)
        schema = w.register_msgdef("sensor_msgs/msg/Imu", ros2.SCHEMAS["sensor_msgs/msg/Imu"].decode())
        for i in range(n):
            stamp = 1_700_000_000 * 10**9 + i * 12_500_000
            for k, node in enumerate(("m1", "m2")):
                msg = {
                    "header": {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9}, "frame_id": node},
                    "angular_velocity": dict(zip("xyz", map(float, gyro[k, i]), strict=True)),
                    "linear_acceleration_covariance": [-1.0] + [0.0] * 8,
                }
                w.write_message(f"/imu/{node}", schema, msg, log_time=stamp, publish_time=stamp)
        w.finish()
    return gyro


def test_sensors_a_recording_does_not_provide_say_not_provided_never_a_number(tmp_path, capsys):
    path = tmp_path / "gyro_only.mcap"
    gyro = _bag_without_accelerometers(path)
    capsys.readouterr()
    assert main(["allan", str(path), "--plot-dir", str(tmp_path / "plots")]) == 0
    text = capsys.readouterr().out
    rows = [line for line in text.splitlines() if line.startswith(("m1 ", "m2 "))]
    accel_rows = [line for line in rows if " accelerometer " in line]
    assert len(accel_rows) == 12 and all("not provided" in line for line in accel_rows)  # both tables
    assert not any(re.search(r"\binf\b|\bnan\b", line) for line in rows)
    assert "m1: no accelerometer in the recording (its messages say not provided)" in text
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == ["allan_m1_gyro.png", "allan_m2_gyro.png"]
    assert main(["allan", str(path), "--no-plots", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["sampling"]["m1"]["not_provided"] == ["accel"]
    for a in result["axes"]:
        if a["sensor"] == "accel":
            assert a["provided"] is False and a["sigma"] is None and a["cv_percent"] is None and a["curve"] is None
        else:
            assert a["provided"] is True and a["sigma"] > 0
    _, reference, _, _ = allantools.oadev(gyro[1, :, 0], rate=FS, data_type="freq", taus=[1 / FS])
    m2_gx = next(a for a in result["axes"] if (a["node"], a["sensor"], a["axis"]) == ("m2", "gyro", "x"))
    assert m2_gx["sigma"] == pytest.approx(reference[0], rel=1e-9)


def test_a_lab_log_without_an_accelerometer_column_gets_not_provided_rows(tmp_path, capsys):
    rng = np.random.default_rng(9)
    lines = ["t_ms,gx,gy,gz"] + [f"{12.5 * k},{g[0]:.4f},{g[1]:.4f},{g[2]:.4f}" for k, g in enumerate(
        rng.normal(0.0, 0.06, size=(4800, 3)))]  # fmt: skip
    (tmp_path / "front.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "front.mcap"
    assert main(["import", str(tmp_path / "front.csv"), "-o", str(out), "--node", "m1"]) == 0
    capsys.readouterr()
    assert main(["allan", str(out), "--no-plots"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("m1 ")]
    accel = [r for r in rows if r[1] == "accelerometer"]
    assert len(accel) == 6 and all(r[3:5] == ["not", "provided"] for r in accel)
    gyro_x = next(r for r in rows if r[1:3] == ["gyroscope", "x"])
    assert float(gyro_x[3]) == pytest.approx(math.radians(0.06), rel=0.05)  # the file's 0.06 dps, in rad/s
