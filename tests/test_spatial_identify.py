"""The spatial model against recordings: identify --model spatial finds the tilt stiffness and
damping a spatial record was made with; validate --model spatial says which model fits better."""

import json

import pytest

from pendsim_bridge.cli import main
from pendsim_mj.params import DEFAULT_PARAMS

TRUE = {"tilt_stiffness_n_m_rad": 3.0, "tilt_damping_n_m_s_rad": 0.0015}  # defaults: 2.0 and 0.0007


@pytest.fixture(scope="module")
def spatial_record(tmp_path_factory):
    """20 s from the spatial model (50 mm, tilt values off the defaults), held 1 s, with noise."""
    path = tmp_path_factory.mktemp("spatial") / "spatial.mcap"
    sets = [a for name, value in TRUE.items() for a in ("--set", f"{name}={value}")]
    assert main(["record", "--model", "spatial", "--duration-s", "20", "--hold-s", "1", *sets, "-o", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def planar_record(tmp_path_factory):
    path = tmp_path_factory.mktemp("planar") / "planar.mcap"
    assert main(["record", "--duration-s", "20", "--hold-s", "1", "-o", str(path)]) == 0
    return path


def test_identify_spatial_finds_the_tilt_stiffness_and_damping_of_a_spatial_record(spatial_record, tmp_path, capsys):
    written = tmp_path / "tilt.json"
    assert main(["identify", str(spatial_record), "--model", "spatial", "--write", str(written)]) == 0
    text = capsys.readouterr().out
    values = json.loads(written.read_text())
    assert set(values) == {"tilt_stiffness_n_m_rad", "tilt_damping_n_m_s_rad", "b1_n_m_s", "b2_n_m_s"}
    # started from the assumed defaults (2.0, 0.0007), 50 % and 114 % away
    assert values["tilt_stiffness_n_m_rad"] == pytest.approx(TRUE["tilt_stiffness_n_m_rad"], rel=0.01)
    assert values["tilt_damping_n_m_s_rad"] == pytest.approx(TRUE["tilt_damping_n_m_s_rad"], rel=0.03)
    assert values["b1_n_m_s"] == pytest.approx(DEFAULT_PARAMS.b1_n_m_s, rel=0.03)
    assert values["b2_n_m_s"] == pytest.approx(DEFAULT_PARAMS.b2_n_m_s, rel=0.03)
    assert "tilt_stiffness_n_m_rad" in text and "+-" in text and "95 % intervals" in text
    # the written values drive record --model spatial
    again = tmp_path / "again.mcap"
    assert (
        main(["record", "--model", "spatial", "--duration-s", "1", "--params-file", str(written), "-o", str(again)])
        == 0
    )


def test_validate_spatial_prefers_the_spatial_model_for_a_spatial_record(spatial_record, tmp_path, capsys):
    out = tmp_path / "v"
    assert main(["validate", str(spatial_record), "--model", "spatial", "--no-plots", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    choice = json.loads((out / "report.json").read_text())["model_choice"]
    assert choice["better"] == "spatial" and "the spatial model fits better" in text
    assert choice["overall"]["spatial"] < 0.2 * choice["overall"]["planar"]
    assert choice["quantities"]["phi1"]["better"] == "spatial"
    assert set(choice["quantities"]["phi1"]["rms"]) == {"planar", "spatial"}


def test_validate_spatial_prefers_the_planar_model_for_a_planar_record(planar_record, tmp_path, capsys):
    out = tmp_path / "v"
    assert main(["validate", str(planar_record), "--model", "spatial", "--no-plots", "-o", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["model_choice"]["better"] == "planar"
    assert report["model_choice"]["plane_offset_m"] == 0.05  # a planar rig's offset is unknown: the paper's
    # without --model spatial the report is the planar one, unchanged
    capsys.readouterr()
    assert main(["validate", str(planar_record), "--no-plots", "-o", str(tmp_path / "p")]) == 0
    assert "model_choice" not in json.loads((tmp_path / "p" / "report.json").read_text())
    assert "planar vs spatial" not in capsys.readouterr().out


@pytest.mark.parametrize("command", ["identify", "validate"])
@pytest.mark.parametrize("value", ["spacial", "", "SPATIAL"])
def test_a_bad_model_is_one_error_line_exit_2(planar_record, capsys, command, value):
    assert main([command, str(planar_record), "--model", value]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("pendsim: error: ") and "--model" in err[0]
