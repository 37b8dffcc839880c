"""Where a chip's fusion ticks fall (pendsim_mj.estimation.timing.fusion_phase), against the truth of the
sensor model and of the node emulator, over many seeds and phases.

80 Hz samples of 100 Hz fusion on one clock fall at four phases of the 10 ms fusion period, 2.5 ms
apart: every phase between two of them assigns each sample to the same tick, so the values' own
smoothness tells the stretch and nothing within it (the value instants move alike). Hence the
stated tolerance, an eighth of the period (half a stretch) plus half the 0.25 ms search step;
what it pins exactly is the pattern of ticks. Samples on a clock that drifts against the ticks
sweep over the stretch and pin the phase closer. ``fusion_phase_stretch`` gives the stretch, for a
fit against the other node (through the model) to choose within."""

import math

import numpy as np
import pytest

from pendsim_bridge.acquire.emulator import EmulatorSpec, NodeClock, fused_samples, plan
from pendsim_bridge.run.record import RecordSpec
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.estimation.timing import fused_value_instants, fusion_phase, fusion_phase_stretch
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, sample_imu
from pendsim_mj.sensors.imperfections import Imperfections

FUSION_HZ = 100.0
PERIOD_S = 1.0 / FUSION_HZ
STEP_S = 0.00025  # fusion_phase's search step
LOCKED_TOLERANCE_S = PERIOD_S / 8 + STEP_S / 2


def _phase_error_s(estimate_s: float, truth_s: float) -> float:
    """estimate - truth on the circle of one fusion period, in [-period/2, period/2)."""
    return (estimate_s - truth_s + PERIOD_S / 2) % PERIOD_S - PERIOD_S / 2


def test_the_phase_is_within_an_eighth_period_and_the_tick_pattern_exact_on_the_sensor_model():
    swing = simulate(DEFAULT_PARAMS, (math.pi / 6, 0.0), (0.0, 0.0), 8.0)
    rng = np.random.default_rng(3)
    errors = []
    for seed in range(10):
        truth = tuple(float(p) for p in rng.uniform(0.0, PERIOD_S, 2))
        imu = sample_imu(swing, Bno055(seed=seed, imperfections=Imperfections(fusion_phase_s=truth)))
        for k in range(2):
            estimate = fusion_phase(imu.t_s, imu.gyro_rad_s[:, k], FUSION_HZ)
            errors.append(_phase_error_s(estimate, truth[k]))
            assert imu.value_t_s is not None
            offset = fused_value_instants(imu.t_s, FUSION_HZ, estimate) - imu.value_t_s[:, k]
            assert np.ptp(offset) < 1e-9  # every sample on its own tick: one common shift
            lo, hi = fusion_phase_stretch(imu.t_s, FUSION_HZ, estimate)
            assert hi - lo == pytest.approx(PERIOD_S / 4, abs=1e-9)  # 80 Hz on 100 Hz: four sample phases
            assert lo < truth[k] + PERIOD_S * round((estimate - truth[k]) / PERIOD_S) <= hi  # the truth is in it
    errors_ms = np.abs(errors) * 1e3
    assert errors_ms.max() <= LOCKED_TOLERANCE_S * 1e3
    assert errors_ms.mean() < 0.9  # the truth lies anywhere in its stretch: about a quarter period on average


@pytest.fixture(scope="module")
def emulated():
    run = RecordSpec(duration_s=28.0, hold_s=2.0, imu=Bno055(seed=1))
    return run, fused_samples(run)


@pytest.mark.parametrize(
    ("drift_ppm", "tolerance_ms"), [(0.0, LOCKED_TOLERANCE_S * 1e3), (50.0, 1.125), (-300.0, 0.25)]
)
def test_the_emulators_phase_is_found_within_its_tolerance_on_the_recorders_clock(emulated, drift_ppm, tolerance_ms):
    """The emulator's chips fuse at 100 Hz on true time (ticks at whole 10 ms from its start); an
    acquired recording stamps each sample with the true instant plus one unknown offset C, so
    the true phase on the stamps' clock is C mod 10 ms. Node clocks drifting against the ticks
    (seeded sample phases, random C) narrow the stretch."""
    run, samples = emulated
    rng = np.random.default_rng(int(abs(drift_ppm)))
    worst_ms = 0.0
    for seed in range(20):
        clocks = (("m1", NodeClock(drift_ppm)), ("m2", NodeClock(-drift_ppm / 2)))
        the_plan = plan(EmulatorSpec(run, clocks=clocks, seed=seed), samples)
        for stream in the_plan.streams:
            offset_s = float(rng.uniform(0.0, 1000.0))
            estimate = fusion_phase(stream.t_s + offset_s, stream.rows[:, 4:7], FUSION_HZ)
            error_s = _phase_error_s(estimate, offset_s % PERIOD_S)
            worst_ms = max(worst_ms, abs(error_s) * 1e3)
            lo, hi = fusion_phase_stretch(stream.t_s + offset_s, FUSION_HZ, estimate)
            if drift_ppm == 0:  # locked: the truth is in the estimate's stretch, a quarter period wide
                assert lo - 1e-9 < estimate - error_s <= hi + 1e-9 and hi - lo > PERIOD_S / 4 - 1e-5
            else:  # the samples' phases sweep over the period: a narrower stretch
                assert hi - lo < PERIOD_S / 4 - 1e-4
    assert worst_ms <= tolerance_ms


def test_the_stretch_is_where_every_sample_keeps_its_tick():
    """Its definition, checked by brute force: inside, the value instants move alike; a step past
    either end moves some sample to another tick."""
    rng = np.random.default_rng(8)
    for drift_ppm in (0.0, 20.0, -70.0):
        stamp_s = 37.0 + rng.uniform(0, 0.0125) + np.arange(2400) * 0.0125 * (1 + drift_ppm * 1e-6)
        phase = float(rng.uniform(0, PERIOD_S))
        lo, hi = fusion_phase_stretch(stamp_s, FUSION_HZ, phase)
        assert lo < phase <= hi and hi - lo <= PERIOD_S / 4 + 1e-9
        at = fused_value_instants(stamp_s, FUSION_HZ, phase)
        for inside in np.linspace(lo, hi, 9)[1:]:
            assert np.ptp(fused_value_instants(stamp_s, FUSION_HZ, inside) - at) < 1e-9
        for outside in (lo - 1e-7, hi + 1e-7):
            assert np.ptp(fused_value_instants(stamp_s, FUSION_HZ, outside) - at) > PERIOD_S / 2


def _plain_second_difference_sums(t, v, max_step_s):
    """The roughness sums written out directly: gathered triples, no shared differences."""
    h = np.diff(t)
    h1, h2 = h[:-1], h[1:]
    ok = (h1 > 0) & (h2 > 0) & (h1 <= max_step_s) & (h2 <= max_step_s)
    if not ok.any():
        return 0.0, 0
    h1, h2 = h1[ok, None], h2[ok, None]
    d1 = (v[1:-1][ok] - v[:-2][ok]) / h1
    d2 = (v[2:][ok] - v[1:-1][ok]) / h2
    second = 2.0 * (d2 - d1) / (h1 + h2)
    return float(np.sum(second * second)), int(second.size)


@pytest.mark.parametrize("seed", range(4))
def test_the_roughness_sums_equal_the_plain_computation_bit_for_bit_with_gaps_and_repeats(seed):
    from pendsim_mj.estimation.timing import _second_difference_sums

    rng = np.random.default_rng(seed)
    n = 5000
    step = rng.uniform(0.010, 0.015, n - 1)
    step[rng.integers(0, n - 1, 8 * seed)] = rng.choice([0.0, 0.5], 8 * seed)  # repeats and gaps (none at seed 0)
    t = np.concatenate([[0.0], np.cumsum(step)])
    v = rng.normal(size=(n, 3))
    for max_step_s in (0.03, 0.0125):
        for phase_s in (0.0, 0.0031):
            instants = fused_value_instants(t, FUSION_HZ, phase_s)
            assert _second_difference_sums(instants, v, max_step_s) == _plain_second_difference_sums(
                instants, v, max_step_s
            )
            dv = np.diff(v, axis=0)
            assert _second_difference_sums(instants, v, max_step_s, dv) == _plain_second_difference_sums(
                instants, v, max_step_s
            )
