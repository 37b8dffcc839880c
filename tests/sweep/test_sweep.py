"""Sweeps: how cases are made, the features against independent computations, the results folder
(Parquet parts, resume, trajectories), the maps, and the pendsim sweep command."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from pendsim_bridge.cli import main
from pendsim_bridge.errors import OutputError
from pendsim_bridge.run.sweep import run_sweep
from pendsim_mj.engines import fast_planar, reference
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.analysis import spectral_peak_hz, swing_frequency_hz
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sweep.features import Features
from pendsim_mj.sweep.plan import PARAMETER_NAMES, CaseTable, SweepPlan, elasticities, parse_vary
from pendsim_mj.sweep.run import run_task

DEG = math.pi / 180
UNDAMPED = DEFAULT_PARAMS.with_overrides(b1_n_m_s=0.0, b2_n_m_s=0.0)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _plan(**kw) -> SweepPlan:
    return SweepPlan.from_mapping(kw)


# -- cases -----------------------------------------------------------------------------------


def test_grid_holds_every_combination_with_the_first_input_slowest():
    plan = _plan(vary={"c1_n_m": {"from": 5.0, "to": 7.0, "num": 3}, "phi1_deg": [10.0, 20.0]})
    table = plan.cases()
    assert table.names == ("c1_n_m", "phi1_deg")
    np.testing.assert_array_equal(table.values, [[5, 10], [5, 20], [6, 10], [6, 20], [7, 10], [7, 20]])
    log = parse_vary("b1_n_m_s=1e-4:1e-2:3:log").grid_values()
    np.testing.assert_allclose(log, [1e-4, 1e-3, 1e-2], rtol=1e-12)


def test_random_and_latin_hypercube_cases_are_seeded_and_inside_their_ranges():
    for method in ("random", "lhs"):
        plan = _plan(
            method=method, samples=500, seed=3, vary={"c1_n_m": {"from": 4, "to": 8}, "phi1_deg": {"from": 0, "to": 90}}
        )
        a, b = plan.cases().values, plan.cases().values
        np.testing.assert_array_equal(a, b)
        assert np.all((a[:, 0] >= 4) & (a[:, 0] < 8) & (a[:, 1] >= 0) & (a[:, 1] < 90))
        other = _plan(
            method=method, samples=500, seed=4, vary={"c1_n_m": {"from": 4, "to": 8}, "phi1_deg": {"from": 0, "to": 90}}
        )
        assert not np.array_equal(a, other.cases().values)
    # a Latin hypercube puts exactly one case in each of the n equal slices of every input
    lhs = _plan(method="lhs", samples=500, vary={"c1_n_m": {"from": 4, "to": 8}, "phi1_deg": {"from": 0, "to": 90}})
    values = lhs.cases().values
    for j, (low, high) in enumerate(((4, 8), (0, 90))):
        slices = np.floor((values[:, j] - low) / (high - low) * 500).astype(int)
        np.testing.assert_array_equal(np.sort(slices), np.arange(500))


def test_a_csv_of_cases_is_read_row_by_row(tmp_path):
    path = tmp_path / "cases.csv"
    path.write_text("c1_n_m,phi1_deg,omega2_rad_s\n5.5,12,0.1\n6.5,-20,0\n")
    plan = _plan(cases=str(path))
    assert plan.method == "csv"
    table = plan.cases()
    assert table.names == ("c1_n_m", "phi1_deg", "omega2_rad_s")
    params, phi0, omega0 = plan.case_inputs(table, np.arange(2))
    np.testing.assert_array_equal(params.column("c1_n_m"), [5.5, 6.5])
    assert [p.c1_n_m for p in params.to_params()] == [5.5, 6.5]
    np.testing.assert_allclose(phi0, [[12 * DEG, 0], [-20 * DEG, 0]])
    np.testing.assert_allclose(omega0, [[0, 0.1], [0, 0]])
    path.write_text("c1_n_m,phi1_deg\n5.5,abc\n")
    with pytest.raises(ParameterError, match=r"line 2: not all numbers"):
        _plan(cases=str(path))
    path.write_text("spring,phi1_deg\n5.5,1\n")
    with pytest.raises(ParameterError, match=r"unknown input 'spring'"):
        _plan(cases=str(path))


def test_a_sensitivity_sweep_scales_each_nonzero_parameter_alone_by_the_step():
    plan = _plan(method="sensitivity", relative_step=0.01)
    table = plan.cases()
    scalable = tuple(n for n in PARAMETER_NAMES if getattr(DEFAULT_PARAMS, n) != 0)
    assert table.names == scalable and "plane_offset_m" not in scalable
    assert len(table) == 1 + 2 * len(scalable)
    base = np.array([getattr(DEFAULT_PARAMS, n) for n in scalable])
    np.testing.assert_array_equal(table.values[0], base)
    for row, name, change in zip(table.values[1:], table.varied[1:], table.relative_change[1:], strict=True):
        j = scalable.index(name)
        assert row[j] == pytest.approx(base[j] * (1 + change), rel=1e-15)
        np.testing.assert_array_equal(np.delete(row, j), np.delete(base, j))


def test_toml_and_json_definitions_give_the_same_plan(tmp_path):
    toml = tmp_path / "s.toml"
    toml.write_text(
        'method = "lhs"\nsamples = 20\nengine = "fast"\nduration_s = 5.0\nfeatures = ["frequency", "decay"]\n'
        "[base]\nphi2_deg = 3.0\n[vary]\nc1_n_m = {from = 5.0, to = 7.0}\nphi1_deg = {from = 10, to = 40}\n"
    )
    from_toml = SweepPlan.load(toml)
    js = tmp_path / "s.json"
    js.write_text(json.dumps(from_toml.to_mapping()))
    from_json = SweepPlan.load(js)
    assert from_json == from_toml
    np.testing.assert_array_equal(from_json.cases().values, from_toml.cases().values)
    assert from_toml.features == ("frequency", "decay") and dict(from_toml.base) == {"phi2_deg": 3.0}


def test_the_definition_file_shown_in_the_docs_loads(tmp_path):
    page = (Path(__file__).resolve().parents[2] / "docs" / "sweeps.md").read_text()
    (tmp_path / "doc.toml").write_text(re.search(r"```toml\n(.*?)```", page, re.S).group(1))
    plan = SweepPlan.load(tmp_path / "doc.toml")
    assert (plan.method, plan.samples, plan.features) == ("lhs", 2000, ("frequency", "decay", "lyapunov"))
    assert plan.cases().names == ("c1_n_m", "phi1_deg", "b2_n_m_s") and dict(plan.base)["b1_n_m_s"] == 0.0005


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"vary": {"spring": [1.0]}}, "vary: unknown input 'spring'; allowed: any RigParams field"),
        ({"vary": {"c1_n_m": [1.0]}, "colour": 1}, "unknown key(s) colour in the sweep definition"),
        ({"vary": {"c1_n_m": {"from": 1.0}}}, "vary c1_n_m: expected keys from, to"),
        ({"method": "random", "vary": {"c1_n_m": {"from": 1, "to": 2}}}, "method random needs samples >= 1"),
        ({"method": "random", "samples": 5, "vary": {"c1_n_m": [1.0, 2.0]}}, "random and lhs need a range"),
        (
            {"method": "lhs", "samples": 5, "vary": {"c1_n_m": {"from": 1, "to": 2, "num": 3}}},
            "vary c1_n_m: lhs draws its 5 cases in the range; give from:to without num (3)",
        ),
        ({"vary": {"c1_n_m": [1.0]}, "base": {"c1_n_m": 2.0}}, "c1_n_m both set (base) and varied"),
        ({"vary": {"c1_n_m": [1.0]}, "base": {"phi1_deg": 2.0, "phi1_rad": 0.1}}, "phi1_deg and phi1_rad give the"),
        ({"method": "sensitivity", "vary": {"c1_n_m": [1.0]}}, "vary does not apply to it"),
        ({"vary": {"c1_n_m": [1.0]}, "relative_step": 0.1}, "applies to a sensitivity sweep only"),
        ({"vary": {"c1_n_m": [1.0]}, "features": ["colour"]}, "unknown feature 'colour'; allowed: frequency"),
        ({"vary": {"c1_n_m": [1.0]}, "engine": "mujoco", "features": ["lyapunov"]}, "lyapunov feature needs the fast"),
        ({"vary": {"c1_n_m": [1.0]}, "duration_s": 1.005}, "must be a whole number of steps"),
        ({"method": "grid"}, "method grid needs at least one varied input"),
        ({"vary": {"c1_n_m": [-1.0]}}, "vary c1_n_m: c1_n_m must be >= 0 N/m, got -1.0"),
        (
            {"vary": {"phi1_deg": {"from": 0, "to": 1e300, "num": 3}}},
            "vary phi1_deg to: phi1_deg must be a finite number in [-180, 180] deg, got 1e+300",
        ),
        (
            {"vary": {"c1_n_m": [1.0]}, "base": {"support_x_frequency_hz": 1e300}},
            "base support_x_frequency_hz must be a finite number in (0, 1000] Hz",
        ),
        ({"vary": {"c1_n_m": [1.0]}, "duration_s": 1e300}, "duration_s must be a finite number in (0, 86400] s"),
        ({"vary": {"j1_kg_m2": [1e-9, 0.03]}}, None),  # see below
    ],
)
def test_bad_definitions_name_what_is_wrong(data, message):
    if message is None:  # each value in its range; the rule between inputs is checked when the cases are made
        plan = _plan(**data)
        with pytest.raises(ParameterError, match=r"case 0: j1_kg_m2 = 1e-09 must exceed m1_kg \* oc1_m\^2"):
            plan.case_inputs(plan.cases(), np.arange(2))
        return
    with pytest.raises(ParameterError, match=re.escape(message)):
        _plan(**data)


# -- features against independent computations -----------------------------------------------


def _reference_runs(plan: SweepPlan):
    table = plan.cases()
    params, phi0, omega0 = plan.case_inputs(table, np.arange(len(table)))
    return table, reference.solve_batch(params.to_params(), phi0, omega0, plan.duration_s, plan.dt_s)


def test_frequency_amplitude_and_energy_features_equal_those_of_the_reference_runs():
    plan = _plan(vary={"phi1_deg": [10.0, 45.0, 80.0], "c2_n_m": [4.0, 8.0]}, duration_s=20.0)
    table, ref = _reference_runs(plan)
    feats = run_task(plan, table, np.arange(len(table))).features
    for i in range(len(table)):
        run = ref.member(i)
        for k in (1, 2):
            assert feats.column(f"freq{k}_hz")[i] == pytest.approx(
                spectral_peak_hz(run.t_s, run.phi_rad[:, k - 1]), abs=1e-9
            )
            assert feats.column(f"amp{k}_rad")[i] == pytest.approx(np.max(np.abs(run.phi_rad[:, k - 1])), abs=1e-10)
            tail = np.max(np.abs(run.phi_rad[-401:, k - 1]))  # the last fifth: 4 s of 20 s
            assert feats.column(f"amp{k}_end_rad")[i] == pytest.approx(tail, abs=1e-10)
        assert feats.column("energy_j")[i] == pytest.approx(run.total_energy_j[0], abs=1e-12)
        assert feats.column("energy_end_j")[i] == pytest.approx(run.total_energy_j[-1], abs=1e-10)
        assert feats.column("dissipated_j")[i] == pytest.approx(run.dissipated_j[-1], abs=1e-10)
    assert not feats.diverged.any()


def test_decay_of_a_pendulum_swinging_alone_is_b_over_2j():
    # springs off: each pendulum is a damped pendulum; at 2 deg its envelope is exp(-b t / (2 J))
    base = {"c1_n_m": 0.0, "c2_n_m": 0.0, "phi1_deg": 2.0, "phi2_deg": 2.0}
    plan = _plan(base=base, vary={"b1_n_m_s": [0.0005, 0.002]}, duration_s=120.0, features=["decay"])
    feats = run_task(plan, plan.cases(), np.arange(2)).features
    expected1 = np.array([0.0005, 0.002]) / (2 * DEFAULT_PARAMS.j1_kg_m2)
    expected2 = DEFAULT_PARAMS.b2_n_m_s / (2 * DEFAULT_PARAMS.j2_kg_m2)
    np.testing.assert_allclose(feats.column("decay1_per_s"), expected1, rtol=2e-3)
    np.testing.assert_allclose(feats.column("decay2_per_s"), expected2, rtol=2e-3)


def test_poincare_samples_lie_on_the_section_by_one_reference_step_from_the_sample_before():
    plan = _plan(vary={"phi1_deg": [30.0, 70.0]}, base={"phi2_deg": -10.0}, duration_s=10.0, features=["poincare"])
    table = plan.cases()
    result = run_task(plan, table, np.arange(2), keep_trajectories=True)
    params = plan.case_inputs(table, np.arange(2))[0].to_params()
    for i in range(2):
        times = result.features.poincare.t_s[i]
        assert 5 <= len(times) <= 12  # about one crossing per period (0.87 Hz) in 10 s
        # cubic Hermite interpolation errs by at most h^4/384 max|f''''| (f: phi, slopes omega; or
        # omega, slopes alpha); max|f''''| is read off the run's own fourth differences
        bound = 1.5 * np.max(np.abs(np.diff(result.trajectories[i], 4, axis=0)), axis=0) / 384 + 1e-11
        k = np.floor(times / plan.dt_s + 1e-12).astype(int)
        states = result.trajectories[i, k]  # phi1, phi2, omega1, omega2 at the sample before
        for j in range(len(times)):
            step = times[j] - k[j] * plan.dt_s
            after = reference.integrate([params[i]], states[j : j + 1, :2], states[j : j + 1, 2:], 1, step)[-1, :, 0]
            assert abs(after[0]) < bound[0] and states[j, 0] < 0 and after[2] > 0  # phi1 = 0, rising
            assert after[1] == pytest.approx(result.features.poincare.phi2_rad[i][j], abs=bound[1])
            assert after[3] == pytest.approx(result.features.poincare.omega2_rad_s[i][j], abs=bound[3])


def _mode1(params: RigParams) -> tuple[float, np.ndarray]:
    """Frequency (Hz) and shape of the lower linearised mode, from the reference's Jacobian."""
    k = reference._coefficients([params])
    jac = np.zeros((4, 4))
    for j in range(4):
        step = np.zeros((5, 1))
        step[j] = 1e-6
        jac[:, j] = (reference.derivative(step, k) - reference.derivative(-step, k))[:4, 0] / 2e-6
    values, vectors = np.linalg.eig(jac)
    upper = np.flatnonzero(values.imag > 0)
    low = upper[np.argmin(values.imag[upper])]
    shape = np.real(vectors[:2, low] / vectors[np.argmax(np.abs(vectors[:2, low])), low])
    return values.imag[low] / (2 * math.pi), shape


def test_sensitivity_elasticities_equal_those_of_the_linearised_mode_frequency():
    # a small release in the shape of mode 1 of the undamped rig: freq1 is that mode's frequency,
    # whose elasticities follow from the linearised equations (eigenvalues) with the same +/-1 %
    f0, shape = _mode1(UNDAMPED)
    amplitude = 0.3 * DEG
    names = ["c1_n_m", "c2_n_m", "j1_kg_m2", "j2_kg_m2", "m1_kg", "oc2_m", "l04_m", "om1_m"]
    base = {"b1_n_m_s": 0.0, "b2_n_m_s": 0.0, "phi1_rad": amplitude * shape[0], "phi2_rad": amplitude * shape[1]}
    plan = _plan(method="sensitivity", parameters=names, base=base, duration_s=60.0, features=["frequency"])
    table = plan.cases()
    feats = run_task(plan, table, np.arange(len(table))).features
    measured = elasticities(table, feats.values)[:, feats.names.index("freq1_hz")]
    expected = []
    for name in names:
        value = getattr(UNDAMPED, name)
        lo, _ = _mode1(UNDAMPED.with_overrides(**{name: value * 0.99}))
        hi, _ = _mode1(UNDAMPED.with_overrides(**{name: value * 1.01}))
        expected.append((hi - lo) / (0.02 * f0))
    np.testing.assert_allclose(measured, expected, atol=2e-3)
    assert measured[names.index("om1_m")] == 0.0  # the IMU mount does not move the dynamics


def test_a_diverging_case_is_flagged_and_its_features_are_nan():
    plan = _plan(vary={"c1_n_m": [6.0, 1e6]}, duration_s=5.0, features=["frequency", "energy", "poincare"])
    feats = run_task(plan, plan.cases(), np.arange(2)).features
    np.testing.assert_array_equal(feats.diverged, [False, True])
    assert np.all(np.isfinite(feats.values[0])) and np.all(np.isnan(feats.values[1]))
    assert len(feats.poincare.t_s[1]) == 0


@pytest.mark.parametrize("engine", ["mujoco", "spatial"])
def test_a_mujoco_case_gives_the_same_bits_on_one_thread_or_in_a_share_of_two(engine):
    # the MuJoCo engines split a task's cases into one share per thread: a case's result must not
    # depend on the split (nor on which cases share its rollout)
    plan = _plan(vary={"c1_n_m": [4.0, 6.0, 8.0], "phi1_deg": [30.0, 100.0]}, duration_s=4.0, engine=engine,
                 features=["frequency", "amplitude", "energy", "poincare"], trajectories=True)  # fmt: skip
    table = plan.cases()
    one = run_task(plan, table, np.arange(6), nthread=1, keep_trajectories=True)
    two = run_task(plan, table, np.arange(6), nthread=2, keep_trajectories=True)
    np.testing.assert_array_equal(one.features.values, two.features.values)
    np.testing.assert_array_equal(one.trajectories, two.trajectories)
    alone = run_task(plan, CaseTable(table.names, table.values[4:5]), np.array([4]), nthread=1).features
    np.testing.assert_array_equal(alone.values[0], two.features.values[4])


def test_a_diverging_mujoco_case_is_flagged_in_its_share_and_its_motion_is_nan():
    # the spring of case 2 makes RK4 at 10 ms unstable; it lies in the second share of two
    plan = _plan(vary={"c1_n_m": [6.0, 7.0, 1e6]}, duration_s=3.0, engine="mujoco",
                 features=["frequency", "energy"], trajectories=True)  # fmt: skip
    task = run_task(plan, plan.cases(), np.arange(3), nthread=2, keep_trajectories=True)
    np.testing.assert_array_equal(task.features.diverged, [False, False, True])
    assert np.all(np.isfinite(task.features.values[:2])) and np.all(np.isnan(task.features.values[2]))
    assert np.all(np.isfinite(task.trajectories[:2])) and np.all(np.isnan(task.trajectories[2]))


def test_mujoco_engines_give_the_features_of_the_fast_engine():
    # the planar MuJoCo model agrees with the planar equations to 1e-9 rad (tests/engines/test_physics.py);
    # the spatial variant with the planes 0 m apart stays in its plane, so it agrees too
    vary = {"phi1_deg": [20.0, 50.0]}
    fast = run_task(_plan(vary=vary, duration_s=10.0), _plan(vary=vary).cases(), np.arange(2)).features
    for engine in ("mujoco", "spatial"):
        plan = _plan(vary=vary, duration_s=10.0, engine=engine, base={"plane_offset_m": 0.0})
        feats = run_task(plan, plan.cases(), np.arange(2)).features
        assert feats.names == fast.names
        for name in fast.names:  # MuJoCo's dissipated energy is a 4th-order quadrature, not RK4's own
            tol = 1e-6 if name == "dissipated_j" else 1e-8
            np.testing.assert_allclose(feats.column(name), fast.column(name), rtol=tol, err_msg=name)
    spatial = _plan(vary=vary, duration_s=10.0, engine="spatial")
    assert spatial.base_params().plane_offset_m == 0.050  # the paper's offset unless given


def test_a_drive_sweep_gives_the_features_of_the_driven_reference_runs():
    # a horizontal support shake from rest across the first mode: the rig gains energy from the
    # input (never flagged as divergence) and the features are those of the reference's runs
    base = {"support_x_amplitude_m_s2": 0.3, "phi1_deg": 0.0, "torque_m2_amplitude_n_m": 0.002,
            "torque_m2_frequency_hz": 1.1}  # fmt: skip
    plan = _plan(vary={"support_x_frequency_hz": [0.6, 0.87, 1.2]}, base=base, duration_s=20.0,
                 features=["frequency", "amplitude", "energy"])  # fmt: skip
    table = plan.cases()
    drives = plan.case_drives(table, np.arange(3))
    assert [d.support_x.frequency_hz for d in drives] == [0.6, 0.87, 1.2] and drives[0].torque_m2.amplitude == 0.002
    feats = run_task(plan, table, np.arange(3)).features
    params, phi0, omega0 = plan.case_inputs(table, np.arange(3))
    ref = reference.solve_batch(params.to_params(), phi0, omega0, 20.0, drive=drives)
    assert not feats.diverged.any() and np.all(feats.column("energy_end_j") > feats.column("energy_j"))
    for i in range(3):
        run = ref.member(i)
        assert feats.column("freq1_hz")[i] == pytest.approx(spectral_peak_hz(run.t_s, run.phi_rad[:, 0]), abs=1e-9)
        assert feats.column("amp1_rad")[i] == pytest.approx(np.max(np.abs(run.phi_rad[:, 0])), abs=1e-10)
        assert feats.column("energy_end_j")[i] == pytest.approx(run.total_energy_j[-1], abs=1e-10)
    with pytest.raises(ParameterError, match="the sweep drives pivot_z: set or vary pivot_z_frequency_hz too"):
        bad = _plan(vary={"pivot_z_amplitude_m_s2": [1.0]})
        bad.case_drives(bad.cases(), np.arange(1))


# -- the results folder ----------------------------------------------------------------------

SMALL = {"method": "random", "samples": 40, "vary": {"c1_n_m": {"from": 5, "to": 7}, "phi1_deg": {"from": 5, "to": 60}},
         "duration_s": 3.0, "features": ["frequency", "amplitude", "poincare"]}  # fmt: skip


def test_results_hold_one_row_per_case_with_inputs_features_and_the_definition(tmp_path):
    plan = _plan(**SMALL)
    summary = run_sweep(plan, tmp_path / "out", cases_per_task=7, progress=False, plots=False)
    assert (summary.ncases, summary.computed, summary.resumed, summary.tasks) == (40, 40, 0, 6)
    table = pq.read_table(summary.results)
    assert table.column_names[:4] == ["case_id", "c1_n_m", "phi1_deg", "diverged"]
    np.testing.assert_array_equal(table.column("case_id").to_numpy(), np.arange(40))
    np.testing.assert_array_equal(table.column("c1_n_m").to_numpy(), plan.cases().values[:, 0])
    direct = run_task(plan, plan.cases(), np.arange(40)).features
    np.testing.assert_array_equal(table.column("freq1_hz").to_numpy(), direct.column("freq1_hz"))
    assert table.column("poincare_t_s").to_pylist()[3] == direct.poincare.t_s[3].tolist()
    meta = json.loads(table.schema.metadata[b"pendsim.sweep"])
    assert SweepPlan.from_mapping(meta["plan"]) == plan


def test_an_interrupted_sweep_resumes_without_redoing_finished_cases(tmp_path):
    plan = _plan(**SMALL)
    whole = run_sweep(plan, tmp_path / "whole", cases_per_task=7, progress=False, plots=False)

    def stop_after_two(done: int) -> None:
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(plan, tmp_path / "cut", cases_per_task=7, progress=False, plots=False, on_task_done=stop_after_two)
    assert sorted(p.name for p in (tmp_path / "cut" / "parts").iterdir()) == [
        "part-000000000.parquet",
        "part-000000007.parquet",
    ]
    assert not (tmp_path / "cut" / "results.parquet").exists()
    again = run_sweep(plan, tmp_path / "cut", cases_per_task=5, progress=False, plots=False)
    assert (again.resumed, again.computed, again.tasks) == (14, 26, 6)
    assert pq.read_table(again.results).equals(pq.read_table(whole.results))


def test_a_folder_holding_another_sweep_is_refused_and_left_untouched(tmp_path):
    run_sweep(_plan(**SMALL), tmp_path / "out", progress=False, plots=False)
    before = {p: p.read_bytes() for p in (tmp_path / "out").rglob("*") if p.is_file()}
    other = _plan(**{**SMALL, "seed": 1})
    with pytest.raises(OutputError, match="holds a different sweep") as refused:
        run_sweep(other, tmp_path / "out", progress=False, plots=False)
    assert "differs from this definition in plan.seed: 0 there, 1 here" in str(refused.value)  # what differs
    assert "sha256" not in str(refused.value)
    assert {p: p.read_bytes() for p in (tmp_path / "out").rglob("*") if p.is_file()} == before
    (tmp_path / "stuff").mkdir()
    (tmp_path / "stuff" / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="is not a sweep's results folder"):
        run_sweep(other, tmp_path / "stuff", progress=False, plots=False)


def test_a_corrupted_part_is_named_and_never_read_as_results(tmp_path):
    plan = _plan(**SMALL)
    run_sweep(plan, tmp_path / "out", cases_per_task=10, progress=False, plots=False)
    part = tmp_path / "out" / "parts" / "part-000000010.parquet"
    part.write_bytes(part.read_bytes()[:200])
    with pytest.raises(OutputError, match=r"part-000000010.parquet' is unreadable.*delete it and run again"):
        run_sweep(plan, tmp_path / "out", progress=False, plots=False)
    part.unlink()
    again = run_sweep(plan, tmp_path / "out", progress=False, plots=False)
    assert (again.resumed, again.computed) == (30, 10)


def test_trajectories_go_to_a_chunked_zarr_store_equal_to_the_kernel(tmp_path):
    import zarr

    plan = _plan(**{**SMALL, "trajectories": True, "save_every": 5})
    run_sweep(plan, tmp_path / "out", cases_per_task=9, progress=False, plots=False)
    group = zarr.open_group(str(tmp_path / "out" / "trajectories.zarr"), mode="r")
    phi, omega, t = group["phi_rad"], group["omega_rad_s"], group["t_s"][:]
    assert phi.shape == omega.shape == (40, 61, 2) and phi.chunks[1:] == (61, 2)
    np.testing.assert_allclose(t, np.arange(61) * 0.05)
    table = plan.cases()
    params, phi0, omega0 = plan.case_inputs(table, np.arange(40))
    states = fast_planar.integrate(fast_planar.coefficients(params), phi0, omega0, 300, 0.01, save_every=5)
    np.testing.assert_array_equal(phi[:], states[:, :2].transpose(2, 0, 1))
    np.testing.assert_array_equal(omega[:], states[:, 2:4].transpose(2, 0, 1))


def test_maps_are_drawn_for_one_and_two_inputs(tmp_path):
    one = _plan(vary={"c1_n_m": [4.0, 6.0, 8.0]}, duration_s=3.0, features=["frequency", "poincare"])
    line = run_sweep(one, tmp_path / "one", progress=False)
    assert sorted(p.name for p in line.maps) == ["freq1_hz.png", "freq2_hz.png", "poincare_phi2_rad.png"]
    two = _plan(vary={"c1_n_m": [4.0, 8.0], "phi1_deg": [10.0, 20.0, 30.0]}, duration_s=3.0, features=["energy"])
    heat = run_sweep(two, tmp_path / "two", progress=False)
    assert sorted(p.name for p in heat.maps) == ["dissipated_j.png", "energy_end_j.png", "energy_j.png"]
    for path in (*line.maps, *heat.maps):
        assert path.read_bytes().startswith(PNG_MAGIC) and path.stat().st_size > 5000


def test_an_input_varied_on_a_log_scale_is_drawn_on_a_log_axis_with_geometric_cells(tmp_path, monkeypatch):
    from pendsim_bridge.report import figures

    drawn = {}
    save = figures.save_figure

    def keep_scales(fig, path, **kw):
        ax = fig.axes[0]
        meshes = [c.get_coordinates() for c in ax.collections if hasattr(c, "get_coordinates")]
        drawn[Path(path).parent.parent.name] = (ax.get_xscale(), ax.get_yscale(), meshes)
        return save(fig, path, **kw)

    monkeypatch.setattr(figures, "save_figure", keep_scales)
    damping = {"from": 1e-4, "to": 1e-2, "num": 3, "scale": "log"}
    run_sweep(_plan(vary={"b1_n_m_s": damping}, duration_s=2.0, features=["energy"]), tmp_path / "line", progress=False)
    assert drawn["line"][:2] == ("log", "linear")
    grid = _plan(vary={"phi1_deg": [30.0, 10.0], "b1_n_m_s": damping}, duration_s=2.0, features=["energy"])
    run_sweep(grid, tmp_path / "heat", progress=False)
    xscale, yscale, (corners,) = drawn["heat"]
    assert (xscale, yscale) == ("log", "linear")
    x_edges, y_edges = corners[0, :, 0], corners[:, 0, 1]
    # cells centred on 1e-4, 1e-3, 1e-2 in ln x: edges a factor sqrt(10) apart; the unsorted list sorted
    np.testing.assert_allclose(x_edges, 10.0 ** np.array([-4.5, -3.5, -2.5, -1.5]), rtol=1e-12)
    np.testing.assert_allclose(y_edges, [0.0, 20.0, 40.0])
    log_range = {"from": 1e-4, "to": 1e-2, "scale": "log"}
    listed = _plan(vary={"b1_n_m_s": [1e-2, 1e-4, 1e-3]}, duration_s=2.0, features=["energy"])
    run_sweep(listed, tmp_path / "listed", progress=False)
    assert drawn["listed"][:2] == ("log", "linear")  # positive values over two decades
    narrow = _plan(vary={"phi1_deg": [10.0, 30.0, 50.0]}, duration_s=2.0, features=["energy"])
    run_sweep(narrow, tmp_path / "narrow", progress=False)
    assert drawn["narrow"][:2] == ("linear", "linear")
    rand = _plan(method="random", samples=6, vary={"phi1_deg": {"from": 5, "to": 20}, "b1_n_m_s": log_range},
                 duration_s=2.0, features=["energy"])  # fmt: skip
    run_sweep(rand, tmp_path / "scatter", progress=False)
    assert drawn["scatter"][:2] == ("log", "linear")


def test_a_run_without_a_full_cycle_has_no_frequency():
    """An overdamped hinge (b1 = 0.5 N m s/rad: M1 creeps back to rest) has its spectrum's largest
    peak at the lowest bin, a few micro-hertz: not a swing. The swinging case beside it keeps the
    estimate ``pendsim simulate`` prints."""
    plan = _plan(vary={"b1_n_m_s": [1e-3, 0.5]}, duration_s=20.0, features=["frequency"])
    table, ref = _reference_runs(plan)
    feats = run_task(plan, table, np.arange(2)).features
    creeping = ref.member(1)
    assert spectral_peak_hz(creeping.t_s, creeping.phi_rad[:, 0]) * 20.0 < 1.0  # under one cycle in the run
    freq = feats.column("freq1_hz")
    assert freq[0] == pytest.approx(spectral_peak_hz(ref.member(0).t_s, ref.member(0).phi_rad[:, 0]), abs=1e-9)
    assert np.isnan(freq[1]) and np.isnan(feats.quality["freq1_peak_ratio"][1])
    assert not feats.quality["freq1_ambiguous"][1]


def test_a_pendulum_that_goes_over_the_top_has_no_swing_frequency():
    """Released near the top (phi2 at 146.6 deg as in a new user's random sweep, phi1 at 170 deg)
    M1 turns over and over: the reference run's phi1 passes pi many times, and the peak of its
    angle's spectrum is the ramp of the turns, just above one cycle in 30 s (1.11 cycles on the
    fast engine, 2026-11-28): it passed the one-cycle rule and coloured the map's corners. No
    swing frequency there; the case beside it, released at 30 deg, keeps the reference's own."""
    plan = _plan(vary={"phi1_deg": [30.0, 170.0]}, base={"phi2_deg": 146.6202}, duration_s=30.0, features=["frequency"])
    table, ref = _reference_runs(plan)
    feats = run_task(plan, table, np.arange(2)).features
    assert np.max(np.abs(ref.member(1).phi_rad[:, 0])) > 4 * np.pi  # turned over, again and again
    freq = feats.column("freq1_hz")
    assert np.isnan(freq[1]) and np.isnan(feats.quality["freq1_peak_ratio"][1])
    assert not feats.quality["freq1_ambiguous"][1]
    swinging = ref.member(0)
    assert np.max(np.abs(swinging.phi_rad[:, 0])) < np.pi
    assert freq[0] == pytest.approx(spectral_peak_hz(swinging.t_s, swinging.phi_rad[:, 0]), abs=1e-9)


def test_a_swing_frequency_needs_a_full_cycle_and_no_turn():
    peak = np.array([0.8, 0.02, 0.8, 0.05, np.nan])
    largest = np.array([0.5, 0.5, np.pi + 1e-9, 4.0, 0.5])
    got = swing_frequency_hz(peak, 30.0, largest)
    assert got[0] == 0.8 and np.all(np.isnan(got[1:]))  # < 1 cycle in 30 s; over the top (just, far); none
    assert swing_frequency_hz(np.array(0.8), 30.0, np.array(np.pi)) == 0.8  # at the top exactly: not over it


def test_frequency_maps_ring_the_cases_whose_frequency_is_ambiguous(tmp_path, monkeypatch):
    from pendsim_bridge.report import figures

    rings = {}
    save = figures.save_figure

    def keep_rings(fig, path, **kw):
        ax = fig.axes[0]
        red = [line for line in ax.lines if line.get_markeredgecolor() == "tab:red" and line.get_marker() == "o"]
        rings[Path(path).stem] = (ax.get_title(), [tuple(line.get_xdata()) for line in red])
        return save(fig, path, **kw)

    monkeypatch.setattr(figures, "save_figure", keep_rings)
    # M1 released alone swings M2 in both modes about equally (freq2 ambiguous); M1's own peak is clear
    out = tmp_path / "rings"
    run_sweep(_plan(vary={"phi1_deg": [5.0, 20.0, 40.0]}, duration_s=20.0, features=["frequency"]), out, progress=False)
    flags = pq.read_table(out / "results.parquet").sort_by("case_id").to_pydict()
    assert flags["freq2_ambiguous"] == [True, True, True] and flags["freq1_ambiguous"] == [False] * 3
    title, ringed = rings["freq2_hz"]
    assert "3 ambiguous: ringed" in title and ringed == [(5.0, 20.0, 40.0)]
    title, ringed = rings["freq1_hz"]
    assert "ambiguous" not in title and ringed == []


def test_a_random_map_marks_a_turned_over_pendulum_as_no_frequency_not_as_diverged(tmp_path, monkeypatch):
    # a new user's random map of releases up to the top drew every turning case as a red "diverged"
    # cross (the run said 0 diverged): a value the feature does not have is not a failure
    from pendsim_bridge.report import figures

    legends = {}
    save = figures.save_figure

    def keep_legend(fig, path, **kw):
        legend = fig.axes[0].get_legend()
        legends[Path(path).stem] = [t.get_text() for t in legend.get_texts()] if legend else []
        return save(fig, path, **kw)

    monkeypatch.setattr(figures, "save_figure", keep_legend)
    plan = _plan(method="random", samples=30, seed=3, duration_s=10.0, features=["frequency", "amplitude"],
                 vary={"phi1_deg": {"from": 100, "to": 180}, "phi2_deg": {"from": -180, "to": 180}})  # fmt: skip
    out = tmp_path / "turns"
    run_sweep(plan, out, progress=False)
    rows = pq.read_table(out / "results.parquet").to_pydict()
    turned = [a > np.pi for a in rows["amp1_rad"]]
    assert any(turned) and not any(rows["diverged"])
    assert all(math.isnan(f) for f, t in zip(rows["freq1_hz"], turned, strict=True) if t)
    assert legends["freq1_hz"] == ["no swing frequency (turned over, or < 1 cycle)"]


# -- the command ----------------------------------------------------------------------------


def test_the_sensitivity_of_the_phi1_frequency_at_30_deg_runs_from_one_command_and_ranks_parameters(tmp_path, capsys):
    out = tmp_path / "sens"
    assert main(["sweep", "--sensitivity", "--features", "frequency", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    ranking = json.loads((out / "sensitivity.json").read_text())["features"]["freq1_hz"]["ranking"]
    values = [abs(r["elasticity"]) for r in ranking if r["elasticity"] is not None]
    assert values == sorted(values, reverse=True) and len(ranking) == len(SweepPlan(method="sensitivity").cases().names)
    # M1 at 30 deg swings mostly as a pendulum of its own: its inertia, gravity moment and the
    # coupling springs come first (f ~ sqrt(m g OC / J): elasticities near -1/2 and +1/2)
    assert ranking[0]["parameter"] == "j1_kg_m2" and -0.55 < ranking[0]["elasticity"] < -0.45
    assert {r["parameter"] for r in ranking[1:4]} == {"m1_kg", "oc1_m", "g_m_s2"}
    lines = text.splitlines()
    assert lines[0].startswith("sweep of 59 cases (sensitivity, fast engine, 30 s at 0.01 s) in this process, serially")
    assert (
        "sensitivity of freq1_hz" in text
        and lines[lines.index(next(x for x in lines if x.startswith("sensitivity of"))) + 1].split()[0] == "j1_kg_m2"
    )
    assert (out / "maps" / "sensitivity_freq1_hz.png").read_bytes().startswith(PNG_MAGIC)
    # the parameters a relative step cannot move are named, not left out in silence (59 = 1 + 2 x 29)
    zero = [name for name, value in RigParams().as_dict().items() if value == 0]
    assert len(zero) == 3 and f"not stepped: {', '.join(zero)} (0 in the base" in text


def test_a_definition_file_runs_and_a_second_run_resumes(tmp_path, capsys):
    definition = tmp_path / "grid.toml"
    definition.write_text(
        'duration_s = 2.0\nfeatures = ["amplitude"]\n[vary]\nphi1_deg = {from = 10, to = 50, num = 5}\n'
    )
    out = tmp_path / "res"
    assert main(["sweep", str(definition), "-o", str(out), "--no-plots"]) == 0
    assert "computed 5 in" in capsys.readouterr().out
    assert main(["sweep", str(definition), "-o", str(out), "--no-plots"]) == 0
    text = capsys.readouterr().out
    assert "computed 0 in" in text and "5 already done" in text


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "nothing to sweep: give a definition file, --vary NAME=SPEC"),
        (["--vary", "spring=1:2:3"], "unknown input 'spring'"),
        (["--vary", "phi_1_deg=1:2:3"], "unknown input 'phi_1_deg' (did you mean 'phi1_deg'?)"),
        (["--vary", "c1_n_m=1:x:3"], "argument --vary: c1_n_m: not a number: 'x'"),
        (["--vary", "c1_n_m"], "expected NAME=FROM:TO:NUM"),
        (["--vary", "c1_n_m=1:2", "--features", "colour"], "unknown feature 'colour'"),
        (["--vary", "c1_n_m=-5,1"], "vary c1_n_m: c1_n_m must be >= 0 N/m, got -5.0"),
        (["--vary", "phi1_deg=0:1e300:3"], "vary phi1_deg to: phi1_deg must be a finite number in [-180, 180] deg"),
        (["--vary", "phi1_deg=0:10:3", "--set", "phi1_deg=1e300"], "argument --set: phi1_deg must be a finite"),
        (["--vary", "j1_kg_m2=1e-9,0.03"], None),
        (["--random", "5", "--vary", "c1_n_m=1,2"], "random and lhs need a range"),
        (["--random", "5", "--vary", "c1_n_m=1:2:4"], "random draws its 5 cases in the range; give from:to without"),
        (["--vary", "c1_n_m=1:2:3", "--vary", "c1_n_m=1:3:3"], "c1_n_m given more than once; vary each input once"),
        (["--vary", "c1_n_m=1:2:3", "--set", "c1_n_m=2"], "c1_n_m both set (base) and varied"),
        # a new user's trial (2026-11-28): each of these ran, resolved or ignored without a word
        (["--vary", "phi1_deg=5:10:2", "--vary", "phi1_rad=0.1:0.2:2"], "phi1_deg and phi1_rad give the same release"),
        (["--vary", "phi1_deg=5:10:2", "--set", "phi1_rad=0.1"], "phi1_rad and phi1_deg give the same release state"),
        (["--vary", "omega2_deg_s=1,2", "--set", "omega2_rad_s=0"], "give the same release state; give it once"),
        (["--sensitivity", "--vary", "phi1_deg=5:10:2"], "a sensitivity sweep steps each parameter about its base"),
        (["--relative-step", "0.1", "--vary", "phi1_deg=5:10:2"], "relative_step (--relative-step) applies to a sens"),
        (["--parameters", "c1_n_m", "--vary", "phi1_deg=5:10:2"], "parameters (--parameters) applies to a sensitivity"),
        (["--random", "10", "--vary", "c1_n_m=8:4"], "random draws between from and to, low to high: give 4:8"),
        (["--lhs", "10", "--vary", "c1_n_m=4:4"], "a range of zero width (4:4) gives one case again and again"),
        (["--vary", "c1_n_m=4:4:3"], "set c1_n_m instead (--set c1_n_m=4)"),
        (["--vary", "phi1_deg=10,10,20"], "vary phi1_deg: the list names 10 more than once"),
        (
            ["--vary", "c1_n_m=5,6", "--set", "torque_m1_frequency_hz=1000", "--set", "torque_m1_amplitude_n_m=0.01"],
            "the torque_m1 drive reaches 1000 Hz: a step of 0.01 s gives it 0.1 steps a period",
        ),
        (["--vary", "c1_n_m=1:2:3:lin"], "expected FROM:TO[:log] or FROM:TO:NUM[:log], got '1:2:3:lin'"),
        (["--vary", "c1_nm=1,2"], "argument --vary: unknown input 'c1_nm' (did you mean 'c1_n_m'?); allowed:"),
        (
            ["--vary", "c1_n_m=1:2:3", "--engine", "mujoco", "--features", "lyapunov"],
            "lyapunov feature needs the fast engine",
        ),
        (["--vary", "c1_n_m=1:2:3", "--workers", "0"], "argument --workers: must be an integer in [1, 1024]"),
        (["--vary", "c1_n_m=1:2:3", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not allowed with argument"),
        (
            ["--vary", "c1_n_m=5:7:3", "--scheduler", "tcp://127.0.0.1:9"],
            "cannot reach the Dask scheduler at 'tcp://127.0.0.1:9'",
        ),
    ],
)
def test_bad_input_gives_one_line_exit_2_and_writes_nothing(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    assert main(["sweep", *args]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pendsim: error: "), captured.err
    if message is not None:
        assert message in lines[0]
    else:
        assert "case 0: j1_kg_m2 = 1e-09 must exceed" in lines[0]
    assert captured.out == "" and list(tmp_path.iterdir()) == []


def test_a_definition_file_and_sweep_options_together_are_refused(tmp_path, capsys):
    definition = tmp_path / "s.json"
    definition.write_text(json.dumps({"vary": {"c1_n_m": [5.0]}}))
    assert main(["sweep", str(definition), "--vary", "c2_n_m=1,2", "-o", str(tmp_path / "o")]) == 2
    assert "give the sweep in" in capsys.readouterr().err and not (tmp_path / "o").exists()
    definition.write_text("{not json")
    assert main(["sweep", str(definition), "-o", str(tmp_path / "o")]) == 2
    assert "is not valid JSON" in capsys.readouterr().err


def _linear_phi2_peak_ratio(phi0_rad) -> float:
    """The ratio of mode 1's and mode 2's amplitudes in phi2 (smaller over larger) for a small
    release from rest, from the linearised modes: phi0 = sum c_i u_i."""
    from pendsim_mj.nonlinear import linear_modes

    shapes = linear_modes(UNDAMPED).shapes
    parts = np.abs(shapes[1] * np.linalg.solve(shapes, np.asarray(phi0_rad)))
    return float(parts.min() / parts.max())


def test_a_frequency_with_two_peaks_of_similar_height_is_flagged_in_the_parquet_row(tmp_path):
    # M2 released at 0 swings in both modes about equally: which peak is freq2 can flip
    plan = _plan(vary={"phi1_deg": [4.0, 30.0]}, base={"b1_n_m_s": 0.0, "b2_n_m_s": 0.0}, duration_s=60.0,
                 features=["frequency"])  # fmt: skip
    run_sweep(plan, tmp_path / "out", progress=False, plots=False)
    rows = pq.read_table(tmp_path / "out" / "results.parquet").sort_by("case_id").to_pydict()
    assert rows["freq2_ambiguous"] == [True, True] and rows["freq1_ambiguous"] == [False, False]
    assert all(r < 0.1 for r in rows["freq1_peak_ratio"])  # M1: one peak (and the window's side lobes)
    # at 4 deg the motion is linear: the two peaks' heights are the modal amplitudes in phi2
    expected = _linear_phi2_peak_ratio([math.radians(4.0), 0.0])
    assert expected > 0.8 and rows["freq2_peak_ratio"][0] == pytest.approx(expected, abs=0.02)


def test_a_release_in_one_mode_has_one_spectral_peak():
    from pendsim_mj.estimation.analysis import second_peak_ratio_batch
    from pendsim_mj.nonlinear import linear_modes

    shapes = linear_modes(UNDAMPED).shapes
    tr = fast_planar.solve_batch(UNDAMPED, phi0_rad=[np.radians(3.0) * shapes[:, 0], np.radians(3.0) * shapes[:, 1]],
                                 duration_s=60.0)  # fmt: skip
    ratio = second_peak_ratio_batch(tr.t_s, tr.phi_rad[..., 1])
    assert np.all(ratio < 0.05)  # the Hann window's side lobes: 0.027


@pytest.mark.parametrize("engine", ["fast", "mujoco"])
def test_a_run_the_step_does_not_resolve_is_flagged_by_its_energy_balance_and_a_finer_step_changes_it(engine):
    # a 3000 N/m spring at 10 ms: RK4 loses most of the energy without diverging and the features
    # look plausible; its energy balance flags it, and a 1 ms step indeed gives other features,
    # while the rig's own springs balance to 1e-6 of m1 g OC1 and keep theirs
    def features(dt_s: float) -> Features:
        plan = _plan(vary={"c1_n_m": [6.0, 3000.0]}, duration_s=4.0, dt_s=dt_s, engine=engine,
                     features=["frequency", "amplitude", "energy"])  # fmt: skip
        return run_task(plan, plan.cases(), np.arange(2)).features

    coarse, fine = features(0.01), features(0.001)
    scale = DEFAULT_PARAMS.m1_kg * DEFAULT_PARAMS.g_m_s2 * DEFAULT_PARAMS.oc1_m
    residual = coarse.quality["energy_residual_j"]
    assert coarse.quality["unresolved"].tolist() == [False, True] and not fine.quality["unresolved"][0]
    assert abs(residual[0]) < 1e-5 * scale and abs(residual[1]) > 0.1 * scale
    amp = coarse.names.index("amp2_end_rad")
    assert coarse.values[0, amp] == pytest.approx(fine.values[0, amp], rel=1e-3)
    assert abs(coarse.values[1, amp] - fine.values[1, amp]) > 0.1 * fine.values[1, amp]


def test_dry_friction_is_in_the_energy_balance_on_every_engine_and_a_drive_is_not_checked():
    # MuJoCo's frictionloss (a soft constraint) counted by the reference's law: its balance closes
    # within the unresolved limit and its dissipated energy agrees with the fast engine's
    scale = DEFAULT_PARAMS.m1_kg * DEFAULT_PARAMS.g_m_s2 * DEFAULT_PARAMS.oc1_m
    dissipated = {}
    for engine in ("mujoco", "fast"):
        plan = _plan(vary={"friction1_n_m": [0.0, 2e-3, 1e-2]}, duration_s=6.0, engine=engine, features=["energy"])
        features = run_task(plan, plan.cases(), np.arange(3)).features
        residual = features.quality["energy_residual_j"]
        assert np.all(np.abs(residual) < 3e-4 * scale) and not features.quality["unresolved"].any()
        dissipated[engine] = features.values[:, features.names.index("dissipated_j")]
    assert np.all(dissipated["mujoco"][1:] - dissipated["mujoco"][0] > 0.01 * scale)  # friction took a share
    assert dissipated["mujoco"] == pytest.approx(dissipated["fast"], rel=0.02, abs=1e-3 * scale)
    base = {"support_x_amplitude_m_s2": 0.3, "support_x_frequency_hz": 0.87}
    driven = _plan(vary={"phi1_deg": [0.0, 10.0]}, base=base, duration_s=3.0, features=["energy"])
    quality = run_task(driven, driven.cases(), np.arange(2)).features.quality
    assert np.isnan(quality["energy_residual_j"]).all() and not quality["unresolved"].any()


def test_pendsim_sweep_warns_of_cases_its_step_does_not_resolve(tmp_path, capsys):
    assert main(["sweep", "--vary", "c1_n_m=6,3000", "--duration-s", "3", "--no-plots", "-o", str(tmp_path / "s")]) == 0
    out = capsys.readouterr().out
    assert "warning: 1 case not resolved at dt_s = 0.01 s (column 'unresolved'" in out and "smaller --dt-s" in out
    table = pq.read_table(tmp_path / "s" / "results.parquet")
    assert table.column("unresolved").to_pylist() == [False, True]
