"""A sweep on the user's rig: ``pendsim sweep --params-file`` (a calibrated or identified rig's
parameters) under the sweep's own base and axes."""

import json

import pyarrow.parquet as pq
import pytest

from pendsim_bridge.cli import main
from pendsim_mj.sweep.plan import SweepPlan

RIG = {"c1_n_m": 6.5, "b1_n_m_s": 0.0009, "m1_kg": 0.215}


def _rows(folder):
    return pq.read_table(folder / "results.parquet").sort_by("case_id").to_pydict()


def test_a_sweep_on_a_parameter_file_runs_that_rig_as_given_by_set(tmp_path):
    (tmp_path / "rig.json").write_text(json.dumps(RIG))
    common = ["--vary", "phi1_deg=10,30", "--duration-s", "8", "--no-plots", "--features", "frequency,energy"]
    assert main(["sweep", *common, "--params-file", str(tmp_path / "rig.json"), "-o", str(tmp_path / "file")]) == 0
    sets = [f"--set={name}={value}" for name, value in RIG.items()]
    assert main(["sweep", *common, *sets, "-o", str(tmp_path / "set")]) == 0
    assert main(["sweep", *common, "-o", str(tmp_path / "paper")]) == 0
    by_file, by_set, paper = _rows(tmp_path / "file"), _rows(tmp_path / "set"), _rows(tmp_path / "paper")
    assert by_file == by_set  # the same rig, bit for bit
    assert by_file["freq1_hz"] != paper["freq1_hz"] and by_file["dissipated_j"] != paper["dissipated_j"]
    recorded = json.loads((tmp_path / "file" / "sweep.json").read_text())["plan"]["base"]
    assert recorded == RIG  # what the sweep ran on is kept with its results (and resumes with them)


def test_the_sweeps_own_base_and_axes_go_over_the_parameter_file():
    plan = SweepPlan.from_mapping({"base": {"b1_n_m_s": 0.002}, "vary": {"c1_n_m": [5.0, 7.0]}})
    on_rig = plan.on_rig(RIG)
    assert dict(on_rig.base) == {"m1_kg": 0.215, "b1_n_m_s": 0.002}  # c1 varied, b1 the sweep's own
    assert on_rig.base_params().m1_kg == 0.215 and on_rig.base_params().b1_n_m_s == 0.002
    cases = on_rig.cases()
    assert sorted(cases.values[:, cases.names.index("c1_n_m")]) == [5.0, 7.0]


def test_a_sweep_definition_file_takes_a_parameter_file_too(tmp_path, capsys):
    (tmp_path / "rig.json").write_text(json.dumps(RIG))
    definition = tmp_path / "sweep.toml"
    definition.write_text('duration_s = 4.0\nfeatures = ["energy"]\n[vary]\nc1_n_m = [5.0, 7.0]\n')
    out = tmp_path / "out"
    assert main(["sweep", str(definition), "--params-file", str(tmp_path / "rig.json"), "-o", str(out)]) == 0
    said = capsys.readouterr().out.splitlines()[-1]  # what of the file the sweep ran on
    rig = tmp_path / "rig.json"
    taken = "b1_n_m_s, m1_kg; not taken: c1_n_m (the sweep varies or sets it itself)"
    assert said == f"rig: from {rig}: {taken}"
    assert json.loads((out / "sweep.json").read_text())["plan"]["base"] == {"b1_n_m_s": 0.0009, "m1_kg": 0.215}
    (tmp_path / "bad.json").write_text('{"c1_nm": 6.5}')
    capsys.readouterr()
    assert main(["sweep", str(definition), "--params-file", str(tmp_path / "bad.json"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bad.json: unknown parameter(s) c1_nm (did you mean 'c1_n_m'?)" in err


@pytest.mark.parametrize("value", [0.5, 50.0])
def test_a_swept_value_far_from_the_files_is_the_axis_value(tmp_path, value):
    (tmp_path / "rig.json").write_text(json.dumps(RIG))
    out = tmp_path / "out"
    args = ["sweep", "--vary", f"c1_n_m={value},6", "--duration-s", "4", "--features", "energy", "--no-plots"]
    assert main([*args, "--params-file", str(tmp_path / "rig.json"), "-o", str(out)]) == 0
    assert sorted(_rows(out)["c1_n_m"]) == sorted([value, 6.0])
