"""The sweep's light path (issue 24): the fast kernel's pass reduced on the fly and the frequency by
a short transform with exact refinement give today's features, checked against the stored-motion
path and the padded transform they replace."""

import math

import numpy as np
import pytest

from pendsim_mj.engines import fast_planar
from pendsim_mj.estimation.analysis import second_peak_ratio_batch, spectral_peak_hz_batch
from pendsim_mj.estimation.spectral_peaks import RATIO_EXACT_FROM, peaks_and_ratios
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sweep.plan import SweepPlan
from pendsim_mj.sweep.run import run_task


@pytest.mark.parametrize("driven", [False, True], ids=["undriven: the fused pass", "driven: blocks folded"])
def test_the_summary_pass_reduces_the_states_of_integrate_bit_for_bit(driven):
    rng = np.random.default_rng(3)
    k, nstep, every = 70, 600, 3  # 70: one full chunk of 64 and a remainder
    coef = fast_planar.coefficients([DEFAULT_PARAMS] * k)
    phi0, omega0 = rng.uniform(-2.5, 2.5, (k, 2)), rng.uniform(-4.0, 4.0, (k, 2))
    inputs = rng.uniform(-0.05, 0.05, (k, nstep, fast_planar.NINPUT)) if driven else None  # held torques, N m
    head = 40
    stats, phi = fast_planar.summarise(coef, phi0, omega0, nstep, 0.01, head_samples=head, save_every=every,
                                       keep_phi=True, inputs=inputs)  # fmt: skip
    states = fast_planar.integrate(coef, phi0, omega0, nstep, 0.01, save_every=every, inputs=inputs)  # (n, 5, k)
    row = {name: stats[i] for i, name in enumerate(fast_planar.SUMMARY_ROWS)}
    mag = np.abs(states[:, :2])
    n = len(states)
    assert np.array_equal(phi, states[:, :2].transpose(2, 1, 0))
    assert np.array_equal(np.stack([row["amp1"], row["amp2"]]), mag.max(axis=0))
    assert np.array_equal(np.stack([row["head1"], row["head2"]]), mag[: head + 1].max(axis=0))
    assert np.array_equal(np.stack([row["head1_index"], row["head2_index"]]), mag[: head + 1].argmax(axis=0))
    tail = mag[n - 1 - head :]
    assert np.array_equal(np.stack([row["tail1"], row["tail2"]]), tail.max(axis=0))
    assert np.array_equal(np.stack([row["tail1_index"], row["tail2_index"]]), n - 1 - head + tail.argmax(axis=0))
    energy = fast_planar.kinetic_energy(states[:, 2], states[:, 3], coef) + fast_planar.potential_energy(
        states[:, 0], states[:, 1], coef
    )
    scale = np.abs(energy).max()
    for name, expected in (("energy_start", energy[0]), ("energy_max", energy.max(0)), ("energy_end", energy[-1])):
        assert np.abs(row[name] - expected).max() <= 1e-13 * scale, name
    ends = np.stack([row[q] for q in ("phi1_end", "phi2_end", "omega1_end", "omega2_end", "dissipated_end")])
    assert np.array_equal(ends, states[-1]) and not row["nonfinite"].any()


def _padded(t, rows):
    return spectral_peak_hz_batch(t, rows), second_peak_ratio_batch(t, rows)


def test_the_short_transform_gives_the_padded_transforms_peak_and_ratio_on_awkward_rows():
    rng = np.random.default_rng(4)
    t = np.arange(2001) * 0.01
    rows = []
    for _ in range(60):  # two tones at random spacing (down to inside one main lobe) and heights
        f1, df = rng.uniform(0.3, 8.0), rng.uniform(0.02, 1.0)
        rows.append(np.sin(2 * np.pi * f1 * t) + rng.uniform(0.5, 1.0) * np.sin(2 * np.pi * (f1 + df) * t + 1.0))
    rows.append(0.3 * t + 0.05 * np.sin(2 * np.pi * 1.3 * t))  # a drift (a pendulum going over the top) and a swing
    rows.append(np.sin(2 * np.pi * 49.9 * t))  # next to Nyquist
    rows.append(rng.normal(size=len(t)))  # noise: many near-equal peaks
    rows.append(np.exp(-0.2 * t) * np.sin(2 * np.pi * 0.9 * t))  # a free decay
    rows += [np.zeros_like(t), np.full_like(t, 0.7), np.where(t < 5, np.nan, 1.0)]
    x = np.array(rows)
    freq, ratio = peaks_and_ratios(t, x)
    f0, r0 = _padded(t, x)
    assert np.array_equal(np.isnan(freq), np.isnan(f0)) and np.array_equal(np.isnan(ratio), np.isnan(r0))
    ok = ~np.isnan(f0)
    assert np.abs(freq - f0)[ok].max() <= 1e-8
    exact = ok & (r0 >= RATIO_EXACT_FROM)
    assert exact.sum() >= 55 and np.abs(ratio - r0)[exact].max() <= 1e-8
    assert np.abs(ratio - r0)[ok].max() < RATIO_EXACT_FROM
    assert freq[-3] == freq[-2] == ratio[-3] == ratio[-2] == 0.0  # zero, constant: no frequency, no second peak
    # a pure tone: its second peak is the window's side lobe (0.027), estimated, not reported as 0
    tone = np.sin(2 * np.pi * 0.87 * t + 0.3)[None]
    tone_ratio, padded_ratio = peaks_and_ratios(t, tone)[1][0], second_peak_ratio_batch(t, tone)[0]
    assert 0.01 < padded_ratio < RATIO_EXACT_FROM and abs(tone_ratio - padded_ratio) < 0.01


def test_light_path_features_equal_the_stored_motion_path_on_1000_cases():
    # 1000 random releases, some over the top, with varied springs and damping: the light path
    # (no stored trajectory) and the stored-motion path (kept trajectories) of the same cases
    plan = SweepPlan.from_mapping({
        "method": "random", "samples": 1000, "seed": 5, "duration_s": 30.0,
        "features": ["frequency", "amplitude", "decay", "energy"],
        "vary": {"phi1_deg": {"from": -170, "to": 170}, "phi2_deg": {"from": -170, "to": 170},
                 "omega1_deg_s": {"from": -300, "to": 300}, "c1_n_m": {"from": 3, "to": 12},
                 "b2_n_m_s": {"from": 0, "to": 0.02}},
    })  # fmt: skip
    table = plan.cases()
    ids = np.arange(len(table))
    light = run_task(plan, table, ids).features
    full = run_task(plan, table, ids, keep_trajectories=True).features
    assert light.names == full.names and np.array_equal(light.diverged, full.diverged)
    assert not light.diverged.all()
    col = {name: (light.column(name), full.column(name)) for name in light.names}
    for name in ("amp1_rad", "amp2_rad", "amp1_end_rad", "amp2_end_rad"):
        assert np.array_equal(*col[name], equal_nan=True), name
    for name in ("decay1_per_s", "decay2_per_s", "energy_j", "energy_end_j", "dissipated_j"):
        a, b = col[name]
        assert np.array_equal(np.isnan(a), np.isnan(b)), name
        assert np.nanmax(np.abs(a - b)) <= 1e-12 * max(1.0, np.nanmax(np.abs(b))), name
    for name in ("freq1_hz", "freq2_hz"):
        a, b = col[name]
        assert np.nanmax(np.abs(a - b)) <= 1e-8, name
    for k in (1, 2):
        a, b = light.quality[f"freq{k}_peak_ratio"], full.quality[f"freq{k}_peak_ratio"]
        exact = b >= RATIO_EXACT_FROM
        assert np.nanmax(np.abs(a - b)[exact]) <= 1e-8 and np.nanmax(np.abs(a - b)) < RATIO_EXACT_FROM
        assert np.array_equal(light.quality[f"freq{k}_ambiguous"], full.quality[f"freq{k}_ambiguous"])


def test_a_diverging_case_is_flagged_on_the_light_path_as_on_the_stored_one():
    # springs 1e5 times stiffer: the 10 ms step is far beyond the fast mode's stability limit
    plan = SweepPlan.from_mapping({"vary": {"c1_n_m": [6.0, 1e6]}, "duration_s": 5.0,
                                   "features": ["frequency", "amplitude"]})  # fmt: skip
    table = plan.cases()
    light = run_task(plan, table, np.arange(2)).features
    full = run_task(plan, table, np.arange(2), keep_trajectories=True).features
    assert light.diverged.tolist() == full.diverged.tolist() == [False, True]
    assert np.isnan(light.values[1]).all() and math.isfinite(light.column("freq1_hz")[0])


def test_tasks_are_ranges_of_case_ids_cut_at_the_gaps_a_resume_leaves():
    from pendsim_bridge.run.sweep import contiguous_tasks

    tasks = contiguous_tasks(np.array([0, 1, 2, 3, 7, 8, 9, 12]), 3)
    assert [t.tolist() for t in tasks] == [[0, 1, 2], [3], [7, 8, 9], [12]]
    assert contiguous_tasks(np.zeros(0, dtype=np.int64), 3) == []


def test_results_are_streamed_part_by_part_into_row_groups_in_case_order(tmp_path, monkeypatch):
    # parts of 7 cases; two of them deleted and recomputed by a resume with tasks of 10 (which
    # must not span the gap); results.parquet written in row groups of 16 rows
    import pyarrow.parquet as pq

    from pendsim_bridge.run import sweep as sweep_run

    plan = SweepPlan.from_mapping({"method": "random", "samples": 100, "seed": 2, "duration_s": 2.0,
                                   "features": ["amplitude", "energy"],
                                   "vary": {"phi1_deg": {"from": 5, "to": 90}}})  # fmt: skip
    sweep_run.run_sweep(plan, tmp_path / "whole", cases_per_task=7, progress=False, plots=False)
    out = tmp_path / "resumed"
    sweep_run.run_sweep(plan, out, cases_per_task=7, progress=False, plots=False)
    for first in (7, 21):
        (out / "parts" / f"part-{first:09d}.parquet").unlink()
    (out / "results.parquet").unlink()
    monkeypatch.setattr(sweep_run, "ROW_GROUP_ROWS", 16)
    summary = sweep_run.run_sweep(plan, out, cases_per_task=10, progress=False, plots=False)
    assert (summary.computed, summary.resumed, summary.tasks) == (14, 86, 2)
    for part in (out / "parts").glob("part-*.parquet"):
        ids = pq.read_table(part, columns=["case_id"]).column("case_id").to_numpy()
        assert np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))) and int(part.stem[5:]) == ids[0]
    streamed = pq.ParquetFile(out / "results.parquet")
    assert streamed.metadata.num_row_groups == 7 and streamed.metadata.row_group(0).num_rows == 16
    got, expected = streamed.read(), pq.read_table(tmp_path / "whole" / "results.parquet")
    assert got.schema.metadata == expected.schema.metadata and got.column_names == expected.column_names
    for name in got.column_names:
        assert np.array_equal(got.column(name).to_numpy(), expected.column(name).to_numpy(), equal_nan=True), name
