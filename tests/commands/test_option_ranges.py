"""Every numeric option of every command has a range: walked from the parsers themselves.

The test walks ``pendsim``'s argparse tree (every command and verb), classifies each option that
takes a value by its argument type, and gives each numeric one absurd values (1e300, -1e300, nan,
inf), inside whatever form the option takes (``--set NAME=VALUE``, ``--vary NAME=FROM:TO:NUM``, a
drive's ``sine:AMP,FREQ``, ...). Each must be refused as ``pendsim`` refuses bad input: exit 2, one
line ``pendsim: error: ...`` that names the option (or the input inside it), and nothing written in
the working folder. An option whose type the test does not know fails the test until it is
classified here: a new numeric option cannot slip in without a range.
"""

from __future__ import annotations

import argparse
import os

import pytest

from pendsim_bridge import cli
from pendsim_bridge.cli import build_parser, main

ABSURD = ("1e300", "-1e300", "nan", "inf")

# Argument types that hold no number a user gives as a quantity (files, names, closed choices,
# addresses); each is checked elsewhere (tests/commands/test_bad_input.py and the rooms' tests).
NOT_NUMERIC = {
    "Path",
    "input_file",
    "mcap_file",
    "choice",
    "bind_address",
    "topic_list",
    "column map",
    "column_list",
    "field map",
    "units",
    "time",  # --start-utc: a UTC date and time (tests/acquire/test_import.py)
    "damping_choice",  # identified | recorded | B1,B2: probed below as B1,B2
    "axis_remap",  # two hex bytes, checked against the BNO055's registers (tests/sensors)
    "LIST",  # twin --track: parameter names (tests/commands/test_cli_twin.py)
}
# Untyped (string) options: what they hold.
UNTYPED = {
    "--vary": ("phi1_deg=0:{}:3", "phi1_deg=10:{}", "phi1_deg={}", "c1_n_m=1:{}:3"),
    "--scheduler": None,  # an address (tests/run/test_sweep_dask.py: checked to be a scheduler)
    "--features": None,  # names
    "--parameters": None,  # names
    "--bind": None,  # an address (acquire; tests/acquire)
    "--host": None,  # an address (nodes; tests/acquire)
    "--actuator-host": None,  # an address (control --rig; tests/acquire/test_control_udp.py)
}
# Types whose value is a form with numbers inside: the absurd value goes into each template.
TEMPLATES = {
    "assignment": ("phi1_deg={}", "c1_n_m={}", "b1_n_m_s={}", "support_x_frequency_hz={}"),
    "signal": ("sine:{},1", "sine:1,{}", "sine:1,1,{}", "stepped:1,0.5,{},3,2", "chirp:1,0.5,2,{}"),
    "NAME=PORT": ("m1={}",),
    "[NAME=]PPM": ("{}", "m2={}"),
    "[NAME=]S": ("{}", "m2={}"),
    "speed": ("{}",),
    "damping_choice": ("{},0.001", "0.001,{}"),
    "added_mass": ("1:M1:{}@0.4", "1:M1:0.05@{}", "{}:M1:0.05@0.4"),
    # pendsim nodes --fault (tests/acquire/test_rig_faults.py)
    "fault": (
        *("stiffness:c1*{}@1", "stiffness:{}%@1", "damping:m1={}@1", "mount:m1={}deg@1", "clock:m1={}@1"),
        *("stiffness:-5%@{}", "stiffness:-5%@1..{}", "damping:m1*2@{}~5"),
    ),
}
# Positional arguments a probe must give for the option to be reached (none: options are parsed
# in the order given, so a bad option before a missing positional is named first).


def _options() -> list[tuple[tuple[str, ...], str, argparse.Action]]:
    found = []

    def walk(parser: argparse.ArgumentParser, path: tuple[str, ...]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, (*path, name))
            elif action.option_strings and action.nargs != 0:
                found.append((path, action.option_strings[-1], action))

    walk(build_parser(), ())
    return found


OPTIONS = _options()


def _probes() -> list[tuple[tuple[str, ...], str, str, str]]:
    """(command path, option, value, what the message must name)."""
    probes = []
    for path, flag, action in OPTIONS:
        kind = getattr(action.type, "__name__", None) if action.type is not None else None
        if kind is None:
            assert flag in UNTYPED, f"{' '.join(path)} {flag}: untyped option; classify it in this test"
            forms = UNTYPED[flag] or ()
        elif hasattr(action.type, "low") and hasattr(action.type, "high"):  # options.float_in, int_in
            forms = ("{}",)
        elif kind in TEMPLATES:
            forms = TEMPLATES[kind]
        else:
            assert kind in NOT_NUMERIC, f"{' '.join(path)} {flag}: argument type {kind!r}; classify it in this test"
            continue
        for form in forms:
            for value in ABSURD:
                text = form.format(value)
                names = flag if form == "{}" else (flag, form.partition("=")[0])
                probes.append((path, flag, text, names))
    return probes


PROBES = _probes()


@pytest.fixture(scope="module")
def parser():
    return build_parser()


def test_the_walk_finds_every_command_and_the_numeric_options_of_the_issue():
    commands = {path[0] for path, _, _ in OPTIONS}
    assert {"simulate", "record", "sweep", "analyze", "replay", "acquire", "nodes", "import", "view"} <= commands
    flags = {(path, flag) for path, flag, _, _ in PROBES}
    assert (("sweep",), "--vary") in flags and (("sweep",), "--set") in flags
    assert (("analyze", "bifurcation"), "--to") in flags
    assert len(PROBES) > 1000


@pytest.mark.parametrize(
    ("path", "flag", "value", "names"), PROBES, ids=[f"{' '.join(p)} {f} {v}" for p, f, v, _ in PROBES]
)
def test_an_absurd_number_is_refused_in_one_line_and_writes_nothing(
    parser, tmp_path, monkeypatch, capsys, path, flag, value, names
):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(cli, "build_parser", lambda: parser)  # the same parser, built once for speed
    code = main(
        [*path, f"{flag}={value}" if value.startswith("-") else flag, *([] if value.startswith("-") else [value])]
    )
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("pendsim: error: "), err
    wanted = (names,) if isinstance(names, str) else names
    assert any(n in lines[0] for n in wanted), lines[0]
    assert "required" not in lines[0], lines[0]  # refused for its value, not for a missing argument
    assert os.listdir(tmp_path) == []
