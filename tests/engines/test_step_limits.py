"""What a run at too large a step is told: the largest stable RK4 step of the linearised rig and
what sets it (a diverged run), and the energy balance's verdict on a run that does not diverge
but is not resolved (``RunSummary.unresolved``)."""

import dataclasses
import math

import numpy as np
import pytest

from pendsim_bridge.cli import main
from pendsim_mj.engines import dispatch
from pendsim_mj.engines.reference import diverged_advice
from pendsim_mj.engines.stability import rk4_stable_step_s
from pendsim_mj.errors import SimulationDiverged
from pendsim_mj.estimation.analysis import summarize
from pendsim_mj.rig.params import DEFAULT_PARAMS


def test_rk4s_stable_step_is_its_known_stability_interval_on_each_axis():
    # RK4's stability region: [-2.7852935634, 0] on the real axis, up to 2 sqrt 2 on the imaginary one
    assert rk4_stable_step_s(np.array([-1.0])) == pytest.approx(2.7852935634, rel=1e-5)
    assert rk4_stable_step_s(np.array([-100.0])) == pytest.approx(0.027852935634, rel=1e-5)
    assert rk4_stable_step_s(np.array([2j, -2j])) == pytest.approx(math.sqrt(2), rel=1e-5)
    assert rk4_stable_step_s(np.array([0.0, 3.0])) == math.inf  # nothing the step can do about these


def _limit_s(advice: str) -> float:
    return float(advice.split(" below ")[1].split(" s,")[0])


@pytest.mark.parametrize("engine", ["mujoco", "fast", "reference"])
def test_a_diverged_runs_message_names_the_damping_and_a_step_that_is_stable(engine):
    # b1 = 1000 N m s: the decay rate b1/J1 sets the step; the stated limit is checked by running
    # just below it (stable) and just above it (diverges), on each engine
    stiff = dataclasses.replace(DEFAULT_PARAMS, b1_n_m_s=1000.0)
    start = (np.radians([30.0, 0.0]), np.zeros(2))
    with pytest.raises(SimulationDiverged) as caught:
        dispatch.run(engine, stiff, *start, 0.5, 0.01)
    text = str(caught.value)
    assert "b1_n_m_s = 1000 N m s" in text and "M1's damping" in text
    limit = _limit_s(text)
    assert limit == pytest.approx(2.7853 * stiff.j1_kg_m2 / 1000.0, rel=0.02)  # -b1/J1 on the real axis
    stable = dispatch.run(engine, stiff, *start, 2000 * 0.95 * limit, 0.95 * limit)
    assert np.all(np.isfinite(stable.phi_rad)) and abs(stable.phi_rad[-1, 0]) < abs(stable.phi_rad[0, 0])
    with pytest.raises(SimulationDiverged):
        dispatch.run(engine, stiff, *start, 2000 * 1.1 * limit, 1.1 * limit)


def test_a_stiff_springs_divergence_is_blamed_on_the_springs_with_their_fastest_mode():
    stiff = dataclasses.replace(DEFAULT_PARAMS, c1_n_m=1e6)
    advice = diverged_advice(stiff, 0.01)
    assert "the springs and gravity" in advice and "Hz" in advice
    limit = _limit_s(advice)
    start = (np.radians([5.0, 0.0]), np.zeros(2))
    assert np.all(np.isfinite(dispatch.run("fast", stiff, *start, 3000 * 0.9 * limit, 0.9 * limit).phi_rad))
    with pytest.raises(SimulationDiverged, match="the springs and gravity"):
        dispatch.run("fast", stiff, *start, 3000 * 1.2 * limit, 1.2 * limit)


def test_a_divergence_the_rig_at_rest_does_not_explain_says_so():
    advice = diverged_advice(DEFAULT_PARAMS, 0.01)  # stable at rest up to 0.3 s
    assert "stable for steps up to" in advice and "large angles" in advice


@pytest.mark.parametrize("engine", ["mujoco", "fast"])
def test_a_run_its_step_does_not_resolve_is_flagged_and_the_suggested_step_resolves_it(engine):
    # a 3000 N/m spring at 10 ms: RK4 takes most of the energy without diverging
    stiff = dataclasses.replace(DEFAULT_PARAMS, c1_n_m=3000.0)
    start = (np.radians([30.0, 0.0]), np.zeros(2))
    coarse = summarize(dispatch.run(engine, stiff, *start, 4.0, 0.01))
    warning = coarse.unresolved_warning()
    assert coarse.unresolved and warning is not None and "--dt-s 0.001" in warning
    fine = summarize(dispatch.run(engine, stiff, *start, 4.0, 0.001))
    assert not fine.unresolved and fine.unresolved_warning() is None
    # the flag is right: the finer step changes the motion (the end amplitude) by far more than 1 %
    assert abs(coarse.end_amplitude_rad[1] - fine.end_amplitude_rad[1]) > 0.1 * fine.end_amplitude_rad[1]
    paper = summarize(dispatch.run(engine, DEFAULT_PARAMS, *start, 4.0, 0.01))
    assert not paper.unresolved and abs(paper.balance_residual_j) < 1e-5 * paper.energy_scale_j


def test_pendsim_simulate_warns_of_a_run_its_step_does_not_resolve(capsys):
    assert main(["simulate", "--set", "c1_n_m=3000", "--duration-s", "4"]) == 0
    err = capsys.readouterr().err
    assert err.count("pendsim: warning: dt_s = 0.01 s does not resolve this run") == 1 and "--dt-s 0.001" in err
    assert main(["simulate", "--set", "c1_n_m=3000", "--duration-s", "4", "--dt-s", "0.001"]) == 0
    assert main(["simulate", "--duration-s", "4"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_pendsim_simulate_of_a_diverging_damping_names_it(capsys):
    assert main(["simulate", "--set", "b1_n_m_s=1000", "--duration-s", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pendsim: error: simulation diverged") and err.count("\n") == 1
    assert "M1's damping (b1_n_m_s = 1000 N m s" in err and "or the stiffness" not in err


def test_pendsim_record_warns_of_a_run_its_step_does_not_resolve_and_the_file_says_so(tmp_path, capsys):
    from mcap.reader import make_reader

    def metadata(path):
        with open(path, "rb") as f:
            return {m.name: m.metadata for m in make_reader(f).iter_metadata()}

    stiff, paper = tmp_path / "stiff.mcap", tmp_path / "paper.mcap"
    assert main(["record", "-o", str(stiff), "--set", "c1_n_m=3000", "--duration-s", "4"]) == 0
    err = capsys.readouterr().err
    assert err.count("pendsim: warning: dt_s = 0.01 s does not resolve this run") == 1 and "--dt-s 0.001" in err
    unresolved = metadata(stiff)["pendsim/unresolved"]
    assert float(unresolved["energy_residual_j"]) > 0.1 and unresolved["warning"] in err
    assert main(["record", "-o", str(paper), "--duration-s", "4"]) == 0
    assert "warning" not in capsys.readouterr().err and "pendsim/unresolved" not in metadata(paper)


def test_following_the_suggested_steps_resolves_a_very_stiff_spring_in_two_reruns():
    stiff = dataclasses.replace(DEFAULT_PARAMS, c1_n_m=1e6)
    start = (np.radians([5.0, 0.0]), np.zeros(2))
    dt_s, reruns = 0.002, 0
    while (warning := summarize(dispatch.run("fast", stiff, *start, 1.0, dt_s)).unresolved_warning()) is not None:
        dt_s, reruns = float(warning.split("--dt-s ")[1].split(" ")[0]), reruns + 1
        assert reruns <= 2, warning
    assert reruns >= 1 and dt_s <= 1e-4


def test_pendsim_validate_gives_no_verdict_where_its_model_step_does_not_resolve_the_rig(tmp_path, capsys):
    stiff, paper = tmp_path / "stiff.mcap", tmp_path / "paper.mcap"
    assert main(["record", "-o", str(stiff), "--set", "c1_n_m=3000", "--duration-s", "6", "--hold-s", "1"]) == 0
    assert main(["record", "-o", str(paper), "--duration-s", "6", "--hold-s", "1"]) == 0
    capsys.readouterr()
    assert main(["validate", str(stiff), "-o", str(tmp_path / "v1"), "--no-plots"]) == 1
    err = capsys.readouterr().err
    assert "pendsim: warning: the model: dt_s = 0.01 s does not resolve this run" in err
    assert "the model's run is not resolved by its step" in err
    assert main(["validate", str(paper), "-o", str(tmp_path / "v2"), "--no-plots"]) == 0
    assert "does not resolve" not in capsys.readouterr().err


def test_an_unknown_or_zero_fastest_mode_leaves_it_out_of_the_warning():
    from pendsim_mj.estimation.analysis import unresolved_warning

    for fastest in (0.0, math.nan):  # a rig without springs or gravity; the spatial model
        warning = unresolved_warning(1.0, 0.5, 0.01, fastest)
        assert warning is not None and "fastest mode" not in warning and "--dt-s 0.001" in warning
    assert unresolved_warning(1e-4, 0.5, 0.01, 1.0) is None  # within 1e-3 of the scale
