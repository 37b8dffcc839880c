"""A recording's MJCF attachment is data from outside: MuJoCo compiles it only without external
references (include, files, meshes, textures, height fields, plugins, asset folders) and within
size limits; otherwise `view` warns and draws the rig from the recorded parameters."""

import contextlib
import dataclasses
import io

import pytest
import rerun as rr

from pendsim_bridge.cli import main
from pendsim_bridge.io.mcap.reader import read_mcap
from pendsim_bridge.io.mcap.tools import rewrite
from pendsim_bridge.io.recording import MJCF_ATTACHMENT
from pendsim_mj.errors import ModelError
from pendsim_mj.rig.drives import Target
from pendsim_mj.rig.mjcf_guard import MAX_BYTES, MAX_ELEMENTS, check_untrusted, compile_untrusted
from pendsim_mj.rig.model import SPATIAL, exact_mjcf

OWN = exact_mjcf()


def _with(extra_asset: str = "", extra_world: str = "", compiler: str = "") -> str:
    xml = OWN.replace("</asset>", f"{extra_asset}</asset>").replace("<worldbody>", f"<worldbody>{extra_world}")
    return xml.replace("<compiler ", f"<compiler {compiler} ") if compiler else xml


HOSTILE = {
    "include": (_with(extra_world='<include file="/etc/passwd"/>'), "<include>, which includes another file"),
    "mesh": (_with('<mesh name="m" file="/etc/hostname"/>'), "<mesh>, which loads a mesh"),
    "texture": (_with('<texture name="t" type="2d" file="/etc/x.png"/>'), "<texture>, which loads or builds"),
    "builtin texture": (
        _with('<texture name="t" type="2d" builtin="checker" width="100000" height="100000"/>'),
        "<texture>",
    ),
    "hfield": (
        _with('<hfield name="h" nrow="100000" ncol="100000" size="1 1 1 1"/>'),
        "<hfield>, which loads or allocates a height field",
    ),
    "plugin": (OWN.replace("<worldbody>", '<extension><plugin plugin="x"/></extension><worldbody>'), "<extension>"),
    "asset folder": (_with(compiler='meshdir="/etc"'), "names a file or folder (meshdir='/etc')"),
    "skin": (_with('<skin name="s" file="/etc/skin"/>'), "<skin>"),
    "memory": (OWN.replace("<worldbody>", '<size memory="100G"/><worldbody>'), "<size>, which sets memory sizes"),
    "replicate": (_with(extra_world='<replicate count="100000"><site/></replicate>'), "<replicate>"),
    "entities": ('<!DOCTYPE m [<!ENTITY x "y">]>' + OWN, "declares a DOCTYPE or entities"),
    "too long": (OWN.replace("<worldbody>", "<worldbody><!--" + "x" * MAX_BYTES + "-->"), "bytes, over the limit"),
    "too many": (_with(extra_world='<site size="0.01"/>' * MAX_ELEMENTS), f"over {MAX_ELEMENTS} elements"),
    "not mujoco": ("<html/>", "root element is <html>"),
    "not xml": ("<mujoco", "not well-formed XML"),
}


@pytest.mark.parametrize("variant", ["planar", "spatial", "driven"])
def test_pendsims_own_mjcf_is_accepted_and_compiles(variant):
    xml = {
        "planar": OWN,
        "spatial": exact_mjcf(variant=SPATIAL),
        "driven": exact_mjcf(drive_targets=tuple(Target)),
    }[variant]
    model = compile_untrusted(xml)
    assert model.ntendon == 4 and model.body("m1").id > 0 and model.body("m2").id > 0
    assert model.nu == (len(Target) if variant == "driven" else 0)


@pytest.mark.parametrize("name", list(HOSTILE))
def test_hostile_mjcf_is_refused_with_the_reason_before_mujoco_sees_it(name):
    xml, reason = HOSTILE[name]
    with pytest.raises(ModelError) as info:
        check_untrusted(xml)
    assert reason in str(info.value) and "\n" not in str(info.value)


def test_a_file_mujoco_would_include_is_never_read(tmp_path, monkeypatch):
    """The include target adds a body if read; the guard refuses first, and MuJoCo itself would
    have read it (the proof that the refusal matters)."""
    intruder = tmp_path / "intruder.xml"
    intruder.write_text('<mujoco><body name="intruder"><geom size="0.1"/></body></mujoco>')  # into the worldbody
    xml = _with(extra_world=f'<include file="{intruder}"/>')
    import mujoco

    assert mujoco.MjModel.from_xml_string(xml).body("intruder").id > 0  # unguarded: MuJoCo opens the file
    with pytest.raises(ModelError, match="includes another file"):
        compile_untrusted(xml)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("guard") / "run.mcap"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["record", "-o", str(path), "--duration-s", "6", "--hold-s", "1"]) == 0
    return path


def _with_attachment(recording, path, xml: str):
    contents = read_mcap(recording, strict=True)
    attachment = contents.attachments[MJCF_ATTACHMENT]
    replaced = {**contents.attachments, MJCF_ATTACHMENT: dataclasses.replace(attachment, data=xml.encode())}
    rewrite(dataclasses.replace(contents, attachments=replaced), path)
    return path


def _labels(rrd) -> str:
    text = []
    for chunk in rr.chunk.RrdReader(str(rrd)).stream():
        if chunk.is_static:
            text.append(str(chunk.to_record_batch().to_pylist()))
    return " ".join(text)


def test_view_of_a_recording_with_a_hostile_attachment_warns_and_draws_from_the_parameters(recording, tmp_path, capsys):
    intruder = tmp_path / "intruder.xml"
    intruder.write_text('<mujoco><body name="intruder"><geom name="intruder_geom" size="0.1"/></body></mujoco>')
    hostile = _with_attachment(recording, tmp_path / "hostile.mcap", _with(extra_world=f'<include file="{intruder}"/>'))
    assert main(["view", str(hostile), "--save", str(tmp_path / "hostile.rrd")]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("pendsim: compiling")]
    assert len(err) == 1 and err[0].startswith("pendsim: warning: ignoring the recording's MJCF attachment")
    assert "includes another file" in err[0] and "drawing the rig from the recorded parameters" in err[0]
    drawn = _labels(tmp_path / "hostile.rrd")
    assert "intruder_geom" not in drawn and "m1_disk" in drawn  # the rig, from the parameters
    # the same recording with its own attachment: no warning
    assert main(["view", str(recording), "--save", str(tmp_path / "own.rrd")]) == 0
    assert capsys.readouterr().err == ""  # (a cold cache's line is said once per process: by the first view)


def test_a_recording_whose_attachment_is_not_utf8_still_views_and_validates_its_data(recording, tmp_path, capsys):
    contents = read_mcap(recording, strict=True)
    attachment = contents.attachments[MJCF_ATTACHMENT]
    garbled = dataclasses.replace(attachment, data=b"<mujoco>\xff\xfe\x80</mujoco>")
    path = tmp_path / "garbled.mcap"
    rewrite(dataclasses.replace(contents, attachments={**contents.attachments, MJCF_ATTACHMENT: garbled}), path)
    assert main(["view", str(path), "--save", str(tmp_path / "garbled.rrd")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) <= 1 and all(line.startswith("pendsim: warning: ") for line in err)
    assert "m1_disk" in _labels(tmp_path / "garbled.rrd")
