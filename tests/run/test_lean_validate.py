"""Validation in bounded memory (issue 16): what ``validate`` holds of a long run in float32 (the
aligned run's values, the model's quantities, the figures' computed lines) and the in-place,
one-byte-a-sample helpers equal the float64, whole-array computation to float32 rounding. The
truth is the same recording taken the whole-array way (float64 everywhere), and plain loops."""

import math

import numpy as np
import pytest

from pendsim_bridge.io.measured import align_recording, recorded_params
from pendsim_bridge.io.recording import DRIVE_TOPIC, NODES, imu_topic, read_recording
from pendsim_bridge.run.record import RecordSpec, record
from pendsim_bridge.run.validate import model_series, validate
from pendsim_mj.estimation.analysis import _hysteresis_sign, noise_level
from pendsim_mj.estimation.quantities import VALIDATED
from pendsim_mj.estimation.validation import compare, resample

VALUES = ("phi_rad", "omega_rad_s", "tangential_m_s2", "normal_m_s2", "off_hinge_gyro_rad_s")


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """A 40 s free decay from 30 deg after a 1 s hold (the default BNO055 nodes)."""
    path = tmp_path_factory.mktemp("lean") / "short.mcap"
    record(RecordSpec(duration_s=40.0, hold_s=1.0), path)
    return path


def _aligned(path, float32_values: bool):
    rec = read_recording(path, topics=[*(imu_topic(n) for n in NODES), DRIVE_TOPIC], sensor_float32=True)
    return align_recording(rec, recorded_params(rec), float32_values=float32_values)


def test_float32_values_are_the_float64_run_rounded_and_the_instants_unchanged(short_run):
    whole, lean = _aligned(short_run, False), _aligned(short_run, True)
    assert lean.start == whole.start
    for w, n in zip(whole.nodes, lean.nodes, strict=True):
        assert n.t_s.dtype == np.float64 and n.value_t_s.dtype == np.float64
        np.testing.assert_array_equal(n.t_s, w.t_s)
        np.testing.assert_array_equal(n.value_t_s, w.value_t_s)
        for name in VALUES:
            assert getattr(n, name).dtype == np.float32, name
            np.testing.assert_array_equal(getattr(n, name), getattr(w, name).astype(np.float32), err_msg=name)
        assert n.coverage == w.coverage and n.before_start == w.before_start


def test_validate_metrics_equal_the_float64_whole_array_comparison(short_run):
    # the whole-array way: the float64 run, the model's float64 series, one comparison each
    report = validate(short_run, damping="recorded")
    run = _aligned(short_run, False)
    start = run.start
    t_model, values = model_series("mujoco", report.params, (start.phi_rad, start.omega_rad_s), run.duration_s + 0.02)
    case = report.case("mujoco", "estimated", "whole")
    for q in VALIDATED:
        t, measured, at = run.series(q)
        expected = compare(t, measured, resample(t_model, values[q.name], np.clip(at, 0.0, t_model[-1])))
        got = case.comparisons[q.name]
        # float32 rounds a value by 6e-8 of its size: the errors move by a few of those at most
        atol = 4 * float(np.spacing(np.float32(np.max(np.abs(measured)))))
        assert got.max_abs == pytest.approx(expected.max_abs, abs=atol), q.name
        assert got.rms == pytest.approx(expected.rms, abs=atol), q.name
        assert got.iae == pytest.approx(expected.iae, abs=atol * run.duration_s), q.name
        for f in ("f_measured_hz", "f_computed_hz", "f_measured_fft_hz", "f_computed_fft_hz"):
            assert getattr(got, f) == pytest.approx(getattr(expected, f), rel=1e-6), (q.name, f)
        if len(got.computed):  # a figure's line: float32, the float64 one rounded
            assert got.computed.dtype == np.float32
            np.testing.assert_allclose(got.computed, expected.computed, rtol=0, atol=atol)


def test_a_comparison_keeps_float32_series_as_given():
    t = np.arange(400) * 0.01
    measured = np.sin(2 * math.pi * t).astype(np.float32)
    computed = np.sin(2 * math.pi * 1.01 * t)
    kept = compare(t, measured, computed, series=("t_s", "measured", "computed"))
    assert kept.measured is measured and kept.computed.dtype == np.float64
    whole = compare(t, measured.astype(float), computed)
    assert kept.max_abs == whole.max_abs and kept.iae == whole.iae and kept.f_measured_hz == whole.f_measured_hz


def _sides_by_loop(y: np.ndarray, band: float):
    """+1 / -1: the side of +-band last left, the first side before it; None if fewer than two
    samples leave the band."""
    sides = [1 if v > band else -1 if v < -band else 0 for v in y]
    if sum(1 for s in sides if s) < 2:
        return None
    first = next(s for s in sides if s)
    out, last = [], first
    for s in sides:
        last = s or last
        out.append(last)
    return np.array(out)


def test_hysteresis_sides_in_one_byte_a_sample_equal_a_plain_loop():
    rng = np.random.default_rng(7)
    for _ in range(200):
        y = rng.normal(size=int(rng.integers(3, 300))) * rng.uniform(0.1, 3.0)
        band = float(rng.uniform(0.0, 2.0))
        expected, got = _sides_by_loop(y, band), _hysteresis_sign(y, band)
        if expected is None:
            assert got is None
        else:
            np.testing.assert_array_equal(got, expected)


def test_noise_level_in_place_is_the_median_absolute_deviation_of_second_differences():
    x = np.random.default_rng(3).normal(0.0, 0.2, 10_001) + np.sin(np.linspace(0, 20, 10_001))
    d2 = x[2:] - 2 * x[1:-1] + x[:-2]
    expected = 1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0)
    before = x.copy()
    assert noise_level(x) == pytest.approx(expected, rel=1e-12)
    np.testing.assert_array_equal(x, before)  # the caller's series untouched
