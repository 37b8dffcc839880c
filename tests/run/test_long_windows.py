"""Long recordings (issue 16): what a run mostly at rest must not spoil (the swing frames, the
whole-run frequencies), and computations done in windows or blocks that equal the whole-run
ones. The truths are the recording's own mounts, the reference solver and closed forms."""

import math

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from pendsim_bridge.io.measured import align_recording
from pendsim_bridge.io.recording import NODES, imu_topic, read_recording
from pendsim_bridge.report import figure_lines
from pendsim_bridge.run.record import RecordSpec, record
from pendsim_bridge.run.validate import model_series, validate
from pendsim_mj.engines.linearised import linear_modes
from pendsim_mj.estimation import analysis
from pendsim_mj.estimation.analysis import hann_magnitude, padded_length, spectral_peak_hz
from pendsim_mj.estimation.swing_frame import ANGLE_BLOCK, SwingFrame, relative_axis, twist_angle
from pendsim_mj.estimation.validation import SERIES, WINDOW_SAMPLES, compare, resample
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import Bno055
from pendsim_mj.sensors.imperfections import random_mount

DAMPING_FACTOR = 10.0  # the paper's hinge damping x10: the swing is lost in the noise within 2 minutes
PARAMS = DEFAULT_PARAMS.with_overrides(
    b1_n_m_s=DAMPING_FACTOR * DEFAULT_PARAMS.b1_n_m_s, b2_n_m_s=DAMPING_FACTOR * DEFAULT_PARAMS.b2_n_m_s
)
MOUNTS = tuple(random_mount(math.radians(10), np.random.default_rng(5)) for _ in range(2))


@pytest.fixture(scope="module")
def mostly_at_rest(tmp_path_factory):
    """20 minutes of a heavily damped free decay from 30 deg, both nodes mounted 10 deg off:
    about 95 % of it at rest, as a 6 h recording of the paper's rig is."""
    path = tmp_path_factory.mktemp("long") / "rest.mcap"
    imu = Bno055(seed=3, mount_quat_wxyz=MOUNTS)
    record(RecordSpec(params=PARAMS, duration_s=1200.0, hold_s=1.0, imu=imu), path)
    return path


# What several tests below take of the one recording, made once (each is deterministic, and none
# of the tests changes what it is given): its validation, its IMU topics read as float64 and as
# float32, and the float64 ones aligned.
TOPICS = [imu_topic(n) for n in NODES]


@pytest.fixture(scope="module")
def validated(mostly_at_rest):
    return validate(mostly_at_rest, damping="recorded")


@pytest.fixture(scope="module")
def read64(mostly_at_rest):
    return read_recording(mostly_at_rest, topics=TOPICS)


@pytest.fixture(scope="module")
def read32(mostly_at_rest):
    return read_recording(mostly_at_rest, topics=TOPICS, sensor_float32=True)


@pytest.fixture(scope="module")
def aligned64(read64):
    return align_recording(read64, PARAMS)


def _degrees_between(a, b) -> float:
    return math.degrees(math.acos(min(1.0, float(np.dot(a, b)))))


def test_a_run_mostly_at_rest_finds_the_mounts_it_was_recorded_with(aligned64):
    # Truth: the mount rotation R turns body vectors into sensor axes as R^T v; in the body the
    # hinge is +z and the pivot is +y (sensors.sample_imu). Fitted over the whole 20 minutes, the
    # hours-long rest's noise flipped M2's frame (mirrored, 89 mm from its hinge).
    run = aligned64
    radii = (PARAMS.om1_m, PARAMS.om2_m)
    for k, node in enumerate(run.nodes):
        r = rotations.to_matrix(np.asarray(MOUNTS[k]))
        frame = node.frame
        assert _degrees_between(frame.toward_pivot, r.T @ [0.0, 1.0, 0.0]) < 0.2
        hinge = r.T @ [0.0, 0.0, 1.0]
        assert math.degrees(math.acos(min(1.0, abs(float(frame.hinge_axis @ hinge))))) < 0.2  # its sign: M1's swing
        assert not frame.mirrored
        # the accelerometer fit's radius errs low by a few % on a small, heavily damped swing
        assert frame.radius_m == pytest.approx(radii[k], rel=0.1)
    assert run.start.kind == "release" and run.start.unexplained < 0.01


def test_whole_run_frequencies_of_a_decay_lost_in_noise_are_the_swing_s(validated):
    # After the swing has decayed, sparse noise excursions beyond the hysteresis band used to
    # count as crossings minutes apart (omega1 measured near 0.1 Hz on a 1 h recording). Truths:
    # the noiseless reference solver from the same start over the same run, and, as most of the
    # counted cycles are small, the rig's small-angle normal modes (linearised reference).
    report = validated
    whole = report.case("reference", "estimated", "whole").comparisons
    for name in ("phi1", "omega1", "tangential_m1"):
        assert whole[name].f_measured_hz == pytest.approx(whole[name].f_computed_hz, rel=0.01), name
    in_phase, anti_phase = linear_modes(PARAMS).frequency_hz
    assert whole["omega1"].f_measured_hz == pytest.approx(in_phase, rel=0.01)
    assert whole["omega1"].f_measured_fft_hz == pytest.approx(in_phase, rel=0.003)
    assert whole["omega2"].f_measured_fft_hz == pytest.approx(anti_phase, rel=0.003)
    # omega2 mixes both modes: its crossings come between their frequencies
    assert in_phase < whole["omega2"].f_measured_hz < anti_phase


def test_zero_crossing_frequency_of_a_decay_into_quantised_noise_is_the_oscillation_s():
    # Closed form: the upward zero crossings of exp(-t / tau) sin(2 pi f t) are exactly 1/f
    # apart. One hour at 80 Hz, the swing below the noise after about 6 minutes, the gyro's
    # quantisation (1/900 rad/s) and noise (1.3e-3 rad/s) on top.
    f_hz, tau_s, fs = 0.8765, 40.0, 80.0
    t = np.arange(0.0, 3600.0, 1.0 / fs)
    clean = 2.0 * np.exp(-t / tau_s) * np.sin(2 * math.pi * f_hz * t)
    noisy = np.round((clean + np.random.default_rng(1).normal(0.0, 1.3e-3, len(t))) * 900.0) / 900.0
    result = compare(t, noisy, clean)
    assert result.f_measured_hz == pytest.approx(f_hz, rel=1e-3)
    assert result.f_computed_hz == pytest.approx(f_hz, rel=1e-3)


def _series(n, *, gaps=False):
    rng = np.random.default_rng(4)
    t = np.arange(n) / 80.0
    if gaps:  # lost samples: single ones and a burst, and a lone sample between two gaps
        keep = rng.random(n) > 0.02
        keep[1000:1040] = False
        keep[70_000:70_020] = False
        keep[70_030:70_050] = False
        t = t[keep] + rng.normal(0.0, 1e-4, keep.sum())  # jittered instants: not uniform
    measured = np.sin(2 * math.pi * 0.87 * t) * np.exp(-t / 900.0) + rng.normal(0.0, 0.01, len(t))
    computed = np.sin(2 * math.pi * 0.871 * t + 0.01) * np.exp(-t / 880.0)
    return t, measured, computed


@pytest.mark.parametrize("gaps", [False, True])
def test_metrics_computed_window_by_window_equal_the_whole_run_s(gaps):
    # three windows and a remainder (validation.WINDOW_SAMPLES each): the errors without their
    # curves, window by window, against the whole-run computation with the curves
    t, measured, computed = _series(3 * WINDOW_SAMPLES + 1001, gaps=gaps)
    whole = compare(t, measured, computed)
    windowed = compare(t, measured, computed, series=())
    for name, value in whole.summary().items():
        assert windowed.summary()[name] == pytest.approx(value, rel=1e-12, abs=1e-15), name
    assert windowed.measured_std == pytest.approx(whole.measured_std, rel=1e-12)
    assert all(len(getattr(windowed, name)) == 0 for name in SERIES)
    assert whole.iae == pytest.approx(whole.iae_curve[-1], rel=1e-12)  # the curves' total: the same rule


def test_resampling_window_by_window_equals_one_spline_through_the_whole_series():
    # a model series at 100 Hz to the measured instants (80 Hz, jittered) of 3 windows and more
    t_model = np.arange(0.0, 2900.0, 0.01)
    values = np.sin(2 * math.pi * 0.87 * t_model) * np.exp(-t_model / 900.0) + 0.1 * np.cos(9.0 * t_model)
    t = np.clip(_series(3 * WINDOW_SAMPLES + 1001, gaps=True)[0], 0.0, None)
    whole = CubicSpline(t_model, values)(t)
    np.testing.assert_allclose(resample(t_model, values, t), whole, rtol=0, atol=1e-13)


def test_the_spectral_peak_of_a_long_series_in_parts_is_the_whole_spectrum_s():
    # 4 h at 80 Hz: too long for one zero-padded spectrum (analysis.SPECTRUM_PARTS parts); the
    # truth is the peak of the whole spectrum, refined by the same parabola
    fs, n = 80.0, 1_152_000
    t = np.arange(n) / fs
    rng = np.random.default_rng(2)
    x = np.sin(2 * math.pi * 0.8771 * t) * np.exp(-t / 3000.0) + 0.3 * np.sin(2 * math.pi * 1.4745 * t)
    x += rng.normal(0.0, 0.05, n)
    nfft = padded_length(n)
    spectrum = hann_magnitude(x, nfft)
    k = int(np.argmax(spectrum[1:])) + 1
    a, b, c = np.log(spectrum[k - 1 : k + 2])
    truth = (k + 0.5 * (a - c) / (a - 2 * b + c)) * fs / nfft
    del spectrum
    assert spectral_peak_hz(t, x) == pytest.approx(truth, rel=1e-9)
    assert spectral_peak_hz(t, x, min_hz=1.0) == pytest.approx(1.4745, rel=1e-4)  # the band still applies


@pytest.mark.parametrize("n", [40_000, 65_536, 100_003, 131_072])
def test_spectrum_parts_folded_onto_their_length_find_the_whole_spectrum_s_peak(n):
    # each part's transform is of nfft / SPECTRUM_PARTS points, shorter than the series from n >
    # 65 536 on (its samples folded onto that length); the truth is the argmax of the whole
    # zero-padded spectrum and its parabola, over all bins and over a band
    rng = np.random.default_rng(n)
    t = np.arange(n) / 80.0
    x = np.sin(2 * math.pi * 0.8771 * t) * np.exp(-t / 900.0) + 0.5 * np.sin(2 * math.pi * 7.31 * t)
    x += rng.normal(0.0, 0.3, n)
    nfft = 1 << 20  # at least 8 n: one part is 65 536 points (analysis._TURN_BLOCK)
    spectrum = hann_magnitude(x, nfft)
    for bottom, top in ((1, nfft // 2 + 1), (nfft // 20, nfft // 4)):  # all bins; about 4-20 Hz
        k = bottom + int(np.argmax(spectrum[bottom:top]))
        a, b, c = np.log(spectrum[k - 1 : k + 2])
        truth = k + 0.5 * (a - c) / (a - 2 * b + c)
        assert analysis._peak_in_parts(x, nfft, bottom, top) == pytest.approx(truth, rel=1e-12, abs=1e-9)


def test_a_long_whole_run_line_is_drawn_as_its_envelope_broken_at_gaps():
    # 1 h at 80 Hz with a 5 s gap: every drawn point is a sample, each run of samples keeps its
    # lowest and highest, and no drawn segment bridges the gap
    t = np.arange(288_000) / 80.0
    t = t[(t < 1000.0) | (t > 1005.0)]
    y = np.sin(2 * math.pi * 0.87 * t) * np.exp(-t / 900.0)
    drawn_t, drawn_y = figure_lines.envelope(t, y, 0.1)
    real = np.isfinite(drawn_y)
    assert real.sum() <= 2 * figure_lines.ENVELOPE_BUCKETS + 4 and np.count_nonzero(~real) == 1
    i = np.searchsorted(t, drawn_t[real])
    np.testing.assert_array_equal(t[i], drawn_t[real])
    np.testing.assert_array_equal(y[i], drawn_y[real])
    assert drawn_y[real].max() == y.max() and drawn_y[real].min() == y.min()
    gap = np.flatnonzero(~real)[0]
    assert drawn_t[gap - 1] < 1000.0 < 1005.0 < drawn_t[gap + 1]
    short_t, short_y = figure_lines.envelope(t[:9600], y[:9600], 0.1)  # a short run's line: all of it
    np.testing.assert_array_equal(short_t, t[:9600])
    np.testing.assert_array_equal(short_y, y[:9600])


def test_whole_run_figure_lines_kept_when_compared_are_the_envelopes_of_the_whole_series(validated, read32):
    # validate keeps no whole-run series, only what Figures 12 and 15 draw, reduced when each
    # comparison is made; the truth is the envelope of the whole series, taken afterwards from
    # the run aligned again and each model run resampled whole (as the figures drew them before)
    report = validated
    run = align_recording(read32, PARAMS, float32_values=True)
    gap = run.max_gap_s
    starts = {"estimated": (run.start.phi_rad, run.start.omega_rad_s), "nominal": ((math.pi / 6, 0.0), (0.0, 0.0))}
    drawn = {("mujoco", "estimated"), ("reference", "estimated"), ("reference", "nominal")}
    assert set(report.lines) == {(e, r, q) for e, r in drawn for q in ("phi1", "omega2")}
    models = {}  # each model run (20 minutes) computed once, for both of its quantities
    for (engine, release, quantity), lines in report.lines.items():
        assert all(len(getattr(report.case(engine, release).comparisons[quantity], n)) == 0 for n in SERIES)
        if (engine, release) not in models:
            models[engine, release] = model_series(
                engine, report.params, starts[release], run.duration_s + 0.02, dtype=np.float32
            )
        t_model, values = models[engine, release]
        t, measured, at = run.series(quantity)
        assert len(t) > figure_lines.ENVELOPE_ABOVE  # 20 minutes at 80 Hz: drawn as envelopes
        computed = resample(t_model, values[quantity], np.clip(at, 0.0, t_model[-1])).astype(np.float32)
        for got, series in (
            (lines.computed, computed),
            (lines.measured, measured if (engine, release) == ("mujoco", "estimated") else None),
            (lines.difference, computed - measured if release == "estimated" else None),
        ):
            if series is None:
                assert got is None
                continue
            assert got is not None and len(got[0]) <= 2 * figure_lines.ENVELOPE_BUCKETS + 4
            expected = figure_lines.envelope(t, series.astype(float), gap)
            np.testing.assert_array_equal(got[0], expected[0])
            np.testing.assert_array_equal(got[1], expected[1])


def test_angles_block_by_block_equal_the_whole_run_unwrapped_twist():
    # a swing that wraps around many times across swing_frame.ANGLE_BLOCK boundaries
    phi = np.cumsum(np.random.default_rng(0).normal(0.0, 0.3, 3 * ANGLE_BLOCK + 77))
    quat = rotations.pendulum_quat_wxyz(phi)
    axis = relative_axis(quat, quat[0])
    frame = SwingFrame(np.eye(3)[2], np.eye(3)[1], np.eye(3)[0], 0.4, axis, quat[0].copy(), 0.1, False, 0.0)
    whole = np.unwrap(twist_angle(quat, quat[0], axis)) + 0.1
    assert np.ptp(whole) > 100.0
    np.testing.assert_allclose(frame.angle(quat), whole, rtol=0, atol=1e-12)


def test_sensor_values_read_as_float32_align_as_the_float64_ones(read64, read32, aligned64):
    # the BNO055's 16-bit outputs in float32: the same values to 1e-7 of each, the run aligned from
    # them the same to far below the sensor's resolution (quaternion LSB 6e-5, gyro 1.1e-3 rad/s)
    full, half = read64, read32
    for n in NODES:
        a, b = full.imu[n], half.imu[n]
        np.testing.assert_array_equal(b.t_ns, a.t_ns)
        np.testing.assert_array_equal(b.stamp_ns, a.stamp_ns)
        for name in ("quat_wxyz", "gyro_rad_s", "accel_m_s2"):
            assert getattr(b, name).dtype == np.float32
            np.testing.assert_array_equal(getattr(b, name), getattr(a, name).astype(np.float32))
    run64, run32 = aligned64, align_recording(half, PARAMS)
    assert run32.start.time_s == pytest.approx(run64.start.time_s, abs=1e-6)
    for n64, n32 in zip(run64.nodes, run32.nodes, strict=True):
        assert n32.phi_rad.dtype == np.float64
        np.testing.assert_allclose(n32.phi_rad, n64.phi_rad, rtol=0, atol=1e-6)
        np.testing.assert_allclose(n32.omega_rad_s, n64.omega_rad_s, rtol=0, atol=1e-6)
