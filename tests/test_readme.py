"""The README's Python example runs and its shape comments are true; the commands most people need run
exactly as shown (the plain invocations a newcomer types first); its setup commands are the CI's."""

import json
import re
import shlex
from pathlib import Path

from pendsim_bridge.cli import main

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def test_python_example_runs_and_shapes_match_the_comments():
    block = re.search(r"```python\n(.*?)```", README, re.S).group(1)
    namespace: dict = {}
    exec(compile(block, "README.md", "exec"), namespace)
    assert namespace["traj"].phi_rad.shape == (12001, 2)
    assert namespace["traj"].imu_accel_m_s2.shape == (12001, 2, 3)
    assert namespace["batch"].phi_rad.shape == (2, 1001, 2)
    assert namespace["ref"].phi_rad.shape == (2, 1001, 2)


def test_first_lines_give_the_two_setup_commands_and_ci_runs_the_test_one():
    first_block = re.search(r"```bash\n(.*?)```", README, re.S).group(1)
    commands = [line.split("#")[0].strip() for line in first_block.strip().splitlines()]
    assert commands == ["pip install -e . && pendsim demo", 'pip install -e ".[test]" && python -m pytest']
    ci = (ROOT / ".ci" / "run").read_text()
    assert commands[1] in ci


def test_the_commands_most_people_need_run_as_shown(tmp_path, monkeypatch, capsys):
    # The README's second bash block, line by line, in a fresh folder: record -o run.mcap then
    # validate run.mcap is the plain path (the recording starts at the release, no hold).
    block = re.findall(r"```bash\n(.*?)```", README, re.S)[1]
    commands = [shlex.split(line.split("  #")[0]) for line in block.strip().splitlines()]
    assert [c[:2] for c in commands] == [
        ["pendsim", "simulate"], ["pendsim", "record"], ["pendsim", "validate"],
        ["pendsim", "identify"], ["pendsim", "view"], ["pendsim", "inspect"],
    ]  # fmt: skip
    monkeypatch.chdir(tmp_path)
    for words in commands:
        assert main(words[1:]) == 0, words
        text = capsys.readouterr().out
        if words[1] == "validate":
            assert "no hold before the release: the recording starts at its release (at rest within 0.1" in text
            assert "covered: m1 100.0 %" in text
    report = json.loads((tmp_path / "run_validation" / "report.json").read_text())
    assert report["release"]["kind"] == "in motion" and report["release"]["time_s"] == 0.0
    cases = {(c["engine"], c["release"], c["window"]): c["metrics"] for c in report["cases"]}
    short, whole = cases[("mujoco", "estimated", "5 s")]["phi1"], cases[("mujoco", "estimated", "whole")]["phi1"]
    assert short["max_abs"] < 0.01 and short["delta_f"] < 0.005 and whole["delta_f"] < 0.005, (short, whole)
    assert len(list((tmp_path / "run_validation").glob("fig*.png"))) == 7
    assert (tmp_path / "run.rrd").stat().st_size > 0
