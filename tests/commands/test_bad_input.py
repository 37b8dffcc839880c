"""Bad command lines, probed by the hundred: every one is exit 2 with exactly one stderr line
``pendsim: error: ...``, no traceback, nothing written, existing files untouched.

The numeric probes are generated from the parser itself: every option whose type has a checked
range (``float_in``, ``int_in``, ``--speed``) gets values below and above its range, non-finite and
non-numeric ones. Hand-written probes cover JSON parameter files, special files (FIFOs, devices,
/proc), folders as outputs, names with newlines, existing outputs without --force. A few run the
installed console script: a closed pipe, a diverging MuJoCo run, an unreadable name.
"""

import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from pendsim_bridge import cli
from pendsim_bridge.cli import build_parser, main

EXE = str(Path(sys.executable).with_name("pendsim"))
POSITIONAL = {  # a file for the commands that need one: the option fails before it is read
    "validate": ["rec.mcap"], "identify": ["rec.mcap"], "view": ["rec.mcap"], "replay": ["rec.mcap"],
    "allan": ["rec.mcap"], "inspect": ["rec.mcap"], "recover": ["rec.mcap", "out.mcap"],
    "record": ["-o", "out.mcap"],
}  # fmt: skip
KEPT = {"keep.npz": b"old npz", "keep.mcap": b"old mcap", "keep.rrd": b"old rrd", "keep.json": b"{}"}


def _bad_values(low: float, high: float, low_open: bool, integer: bool) -> list[str]:
    below = low if low_open else (low - 1 if integer else low - max(1e-3, abs(low) * 0.5))
    above = high + 1 if integer else high * 10 + 1
    values = [repr(below) if not integer else str(int(below)), repr(above) if not integer else str(int(above))]
    values += ["nan", "abc"]
    if integer:
        values += ["1.5"]
    return values


def _commands(parser, prefix: tuple[str, ...] = ()):
    """(words, parser) of every command and sub-command (``analyze backbone``, ...)."""
    for action in parser._actions:
        if action.__class__.__name__ == "_SubParsersAction":
            for name, subparser in action.choices.items():
                yield (*prefix, name), subparser
                yield from _commands(subparser, (*prefix, name))


def _generated() -> list[tuple[str, list[str]]]:
    probes = []
    for words, subparser in _commands(build_parser()):
        for action in subparser._actions:
            kind = action.type
            if not action.option_strings or not hasattr(kind, "low"):
                continue
            integer = isinstance(kind.low, int) and isinstance(kind.high, int)
            for value in _bad_values(kind.low, kind.high, kind.low_open, integer):
                where = POSITIONAL.get(words[0], [])
                probes.append((words[0], [*words[1:], *where, f"{action.option_strings[-1]}={value}"]))
    return probes


HANDWRITTEN = [
    # parameters via --set and JSON files
    ("simulate", "--set c1_n_m=1e300"), ("simulate", "--set l01_m=1e300"), ("simulate", "--set g_m_s2=1e300"),
    ("simulate", "--set m1_kg=1e-300"), ("simulate", "--set j1_kg_m2=1e-300"), ("simulate", "--set c1_n_m=nan"),
    ("simulate", "--set c1_n_m=-inf"), ("simulate", "--duration-s 1e309"), ("simulate", "--phi1-deg -inf"),
    ("record -o out.mcap", "--seed 99999999999999999999999999999999999999"), ("simulate", "--set =1"),
    ("simulate", "--set nothing"),
    ("simulate", "--set b1_n_m_s=true"), ("record -o out.mcap", "--set plane_offset_m=1e9"),
    ("simulate", "--params-file bool.json"), ("simulate", "--params-file string.json"),
    ("simulate", "--params-file null.json"), ("simulate", "--params-file nested.json"),
    ("simulate", "--params-file deep.json"), ("simulate", "--params-file list.json"),
    ("simulate", "--params-file bigint.json"), ("simulate", "--params-file inf.json"),
    ("simulate", "--params-file nan.json"), ("simulate", "--params-file latin1.json"),
    ("simulate", "--params-file huge.json"), ("simulate", "--params-file duplicate.json"),
    ("simulate", "--params-file unknown.json"), ("simulate", "--params-file empty.json"),
    ("simulate", "--params-file out_of_range.json"), ("validate rec.mcap", "--params-file bool.json"),
    # special files as inputs
    ("simulate", "--params-file fifo"), ("simulate", "--params-file /dev/zero"),
    ("simulate", "--params-file /proc/self/environ"), ("simulate", "--params-file ."),
    ("simulate", "--params-file missing.json"), ("inspect", "fifo"), ("inspect", "/dev/zero"),
    ("inspect", "."), ("inspect", "/proc/self/status"), ("view", "fifo"), ("replay", "/dev/null"),
    ("validate", "fifo"), ("identify", "/dev/zero"), ("allan", "fifo"), ("recover", "fifo out.mcap"),
    ("inspect", "'new\nline.mcap'"), ("view", "'new\nline.mcap'"),
    # outputs: folders, FIFOs, devices, /proc, missing folders, existing files, wrong suffixes
    ("simulate --duration-s 1", "-o /proc/self/x.npz"), ("simulate --duration-s 1", "-o adir.npz"),
    ("simulate --duration-s 1", "-o fifo.npz"), ("simulate --duration-s 1", "-o /dev/null.npz"),
    ("simulate --duration-s 1", "-o /dev/null"), ("simulate --duration-s 1", "-o missing/x.npz"),
    ("simulate --duration-s 1", "-o keep.json/x.npz"), ("simulate --duration-s 1", "-o keep.npz"),
    ("simulate --duration-s 1", "--rerun keep.rrd"), ("simulate --duration-s 1", "--rerun /proc/x.rrd"),
    ("simulate --duration-s 1", "--rerun adir.rrd"), ("simulate --duration-s 1", "-o 'new\nline/x.npz'"),
    ("simulate --duration-s 1", "--force -o fifo.npz"), ("simulate --duration-s 1", "--force -o adir.npz"),
    ("record --duration-s 1", "-o keep.mcap"), ("record --duration-s 1", "-o /proc/self/r.mcap"),
    ("record --duration-s 1", "-o adir.mcap"), ("record --duration-s 1", "-o out.txt"),
    ("view rec.mcap", "--save keep.rrd"), ("view rec.mcap", "--save /proc/x.rrd"),
    ("view rec.mcap", "--save adir.rrd"), ("view rec.mcap", "--save x.mcap"),
    ("replay rec.mcap", "-o keep.mcap"), ("replay rec.mcap", "-o /proc/self/x.mcap"),
    ("replay rec.mcap", "--rerun keep.rrd"), ("replay rec.mcap", "-o rec.mcap --force"),
    ("recover rec.mcap", "keep.mcap"), ("recover rec.mcap", "/proc/self/x.mcap"), ("recover rec.mcap", "adir.mcap"),
    ("recover rec.mcap", "rec.mcap --force"), ("identify rec.mcap", "--write keep.json"),
    ("identify rec.mcap", "--write /proc/self/x.json"), ("validate rec.mcap", "-o keep.json"),
    ("validate rec.mcap", "-o /proc/self/v"), ("validate rec.mcap", "-o fifo"), ("validate rec.mcap", "-o keepdir"),
    ("allan rec.mcap", "--plot-dir keep.json"), ("allan rec.mcap", "--plot-dir /proc/self/a"),
    ("allan rec.mcap", "--plot-dir /dev/null"), ("compare --duration-s 1", "-o keep.json"),
    ("compare --duration-s 1", "-o /proc/self/c"), ("compare --duration-s 1", "-o keepdir"),
    ("compare --duration-s 1", "--rerun keep.rrd"), ("demo", "-o keep.json"), ("demo", "-o /proc/self/d"),
    ("demo", "-o keepdir"), ("demo", "-o /dev/null"),
    # options
    ("validate rec.mcap", "--damping 1e300,1e300"), ("validate rec.mcap", "--damping 1,2,3"),
    ("validate rec.mcap", "--damping nan,1"), ("validate rec.mcap", "--max-delta -1"),
    ("validate rec.mcap", "--max-iae nan"), ("replay rec.mcap", "--speed 0"), ("replay rec.mcap", "--speed -1"),
    ("replay rec.mcap", "--loop -o x.mcap"), ("view rec.mcap", "--bind nonsense"), ("view rec.mcap", "--bind ''"),
    ("view rec.mcap", "--bind 999.1.1.1"), ("simulate", "--engine simulink"), ("record -o o.mcap", "--model static"),
    ("record -o o.mcap", "--compression bzip2"), ("compare", "--fixed-points-plane m3"), ("simulate", "--bogus"),
    ("bogus", ""), ("simulate", "--duration-s 1.005"), ("simulate", "--duration-s 0.001 --dt-s 0.01"),
    ("simulate", "--duration-s 86400 --dt-s 0.0001"), ("compare", "--engine reference --duration-s 1"),
    # drives and alignment
    ("simulate", "--torque1-n-m sine:1e300,1"), ("simulate", "--torque1-n-m sine:1,-1"),
    ("simulate", "--torque1-n-m sine:nan,1"), ("simulate", "--torque1-n-m bogus:1"),
    ("simulate", "--torque1-n-m csv:fifo"), ("simulate", "--torque1-n-m csv:/dev/zero"),
    ("simulate", "--torque1-n-m csv:missing.csv"), ("simulate", "--torque1-n-m csv:bool.json"),
    ("simulate", "--support-x-m-s2 stepped:1,1,2,0.5,3"), ("view rec.mcap", "--release-s -1"),
    ("validate rec.mcap", "--release-s nan"), ("identify rec.mcap", "--release-s 1e300"),
    ("analyze", ""), ("analyze backbone", "-o keep.json"), ("analyze tongues", "-o /proc/self/t"),
    ("analyze lyapunov", "-o fifo"),
]  # fmt: skip


def _cases() -> list[tuple[str, list[str]]]:
    cases = _generated()
    for head, tail in HANDWRITTEN:
        words = shlex.split(f"{head} {tail}")
        cases.append((words[0], words[1:]))
    return cases


CASES = _cases()


def test_the_probe_list_covers_every_ranged_option_of_every_command():
    commands = {command for command, _ in CASES}
    assert len(CASES) >= 300
    assert {"simulate", "record", "validate", "identify", "view", "replay", "compare", "demo", "analyze"} <= commands


@pytest.fixture(scope="module")
def probe_dir(tmp_path_factory):
    """The files the probes name: a junk recording, JSON files, FIFOs, folders, and existing
    outputs that must stay untouched."""
    tmp_path = tmp_path_factory.mktemp("probes")
    (tmp_path / "rec.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\0" * 64)
    for name, content in KEPT.items():
        (tmp_path / name).write_bytes(content)
    (tmp_path / "adir.npz").mkdir()
    (tmp_path / "adir.mcap").mkdir()
    (tmp_path / "adir.rrd").mkdir()
    (tmp_path / "keepdir").mkdir()
    (tmp_path / "keepdir" / "report.json").write_text("{}")
    (tmp_path / "keepdir" / "summary.json").write_text("{}")
    (tmp_path / "keepdir" / "run.mcap").write_text("x")
    os.mkfifo(tmp_path / "fifo")
    os.mkfifo(tmp_path / "fifo.npz")
    files = {
        "bool.json": '{"b1_n_m_s": true}',
        "string.json": '{"b1_n_m_s": "0.001"}',
        "null.json": '{"b1_n_m_s": null}',
        "nested.json": '{"b1_n_m_s": {"value": 0.001}}',
        "deep.json": "[" * 100000 + "]" * 100000,
        "list.json": "[0.001, 0.002]",
        "bigint.json": '{"b1_n_m_s": 1' + "0" * 5000 + "}",
        "inf.json": '{"b1_n_m_s": 1e400}',
        "nan.json": '{"b1_n_m_s": NaN}',
        "huge.json": '{"b1_n_m_s": 0.001, "pad": "' + "x" * 1_100_000 + '"}',
        "duplicate.json": '{"b1_n_m_s": 0.001, "b1_n_m_s": 0.002}',
        "unknown.json": '{"spring": 1.0}',
        "misspelt.json": '{"c1_nm": 6.2, "om_1_m": 0.4, "b1_n_m_s": 0.0007}',
        "empty.json": "",
        "out_of_range.json": '{"c1_n_m": 1e300}',
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    (tmp_path / "latin1.json").write_bytes('{"b1_n_m_s": 0.001, "note": "café"}'.encode("latin-1"))
    return tmp_path


@pytest.fixture
def workspace(probe_dir, monkeypatch):
    monkeypatch.chdir(probe_dir)
    return probe_dir


def _snapshot(folder: Path) -> dict[str, tuple[int, int, int, int]]:
    """Every entry (hidden temporary files included): mode, inode, size, modification time."""
    found = {}
    for path in sorted(folder.rglob("*")):
        st = path.lstat()
        found[str(path.relative_to(folder))] = (st.st_mode, st.st_ino, st.st_size, st.st_mtime_ns)
    return found


@pytest.fixture(scope="module")
def parser():
    return build_parser()


@pytest.mark.parametrize(("command", "args"), CASES, ids=[shlex.join([c, *a])[:90] for c, a in CASES])
def test_bad_command_line_is_one_error_line_exit_2_and_touches_nothing(
    workspace, parser, monkeypatch, capsys, command, args
):
    # the same parser, built once for speed (as in test_option_ranges): each main() here only parses
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    before = _snapshot(workspace)
    assert all((workspace / name).read_bytes() == content for name, content in KEPT.items())
    assert main([command, *args]) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("pendsim: error: "), captured.err
    assert "Traceback" not in captured.err and "Traceback" not in captured.out
    assert _snapshot(workspace) == before  # nothing new, nothing changed, no temporary file left


def test_parameter_files_name_what_is_wrong(workspace, capsys):
    expected = {
        "bool.json": "'b1_n_m_s' must be a finite number, got true",
        "nested.json": "is nested; a parameter file is one JSON object of numbers",
        "deep.json": "is nested",
        "bigint.json": "is not a parameter file: Exceeds the limit (4300 digits)",
        "latin1.json": "is not UTF-8 text",
        "huge.json": "is over 1000000 bytes",
        "duplicate.json": "names 'b1_n_m_s' twice",
        "nan.json": "'b1_n_m_s' must be a finite number, got \"NaN\"",
        "out_of_range.json": "c1_n_m must be 0 or between 1e-09 and 1e+06 N/m, got 1e+300",
        "unknown.json": "unknown.json: unknown parameter(s) spring; allowed: b1_n_m_s",
        "misspelt.json": "misspelt.json: unknown parameter(s) c1_nm (did you mean 'c1_n_m'?), om_1_m (did you mean "
        "'om1_m'?); allowed:",
    }
    for name, message in expected.items():
        assert main(["simulate", "--params-file", name]) == 2
        assert message in capsys.readouterr().err, name


def test_a_parameter_file_in_other_units_runs_with_a_warning_naming_the_file(workspace, capsys):
    # c1 given in N/mm: allowed (another rig), but said on standard error, once, before the run
    Path("n_per_mm.json").write_text('{"c1_n_m": 0.006173, "b1_n_m_s": 0.0001}')
    assert main(["simulate", "--params-file", "n_per_mm.json", "--duration-s", "1", "-o", "run.csv"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err == [
        "pendsim: warning: n_per_mm.json: c1_n_m = 0.006173 N/m is 1/1000 of the paper's rig's (6.173 N/m): "
        "a unit slip? (used as given)"
    ]


def test_a_rig_made_impossible_by_a_given_value_names_where_it_was_given(workspace, capsys):
    # a mass in grams: warned about, then the paper's inertia cannot hold it; the error says which
    # value came from which file or option
    Path("grams.json").write_text('{"m1_kg": 150}')
    assert main(["simulate", "--params-file", "grams.json", "--duration-s", "1", "-o", "grams_run.csv"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and err[0].startswith("pendsim: warning: grams.json: m1_kg = 150 kg is 710.1 times")
    assert err[1].startswith("pendsim: error: j1_kg_m2 = 0.02592 must exceed m1_kg * oc1_m^2")
    assert err[1].endswith("(m1_kg from grams.json; the others are the rig's own)")
    assert main(["simulate", "--params-file", "grams.json", "--set", "j1_kg_m2=10", "--set", "m1_kg=160"]) == 2
    last = capsys.readouterr().err.splitlines()[-1]
    assert last.endswith("(m1_kg from --set, j1_kg_m2 from --set; the others are the rig's own)")
    assert not Path("grams_run.csv").exists()


def test_a_run_option_given_as_a_parameter_is_named(workspace, capsys):
    assert main(["simulate", "--set", "phi1_deg=10"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "unknown parameter(s) phi1_deg (this command's --phi1-deg, not a rig parameter); allowed: b1_n_m_s" in err
    assert main(["validate", "missing.mcap", "--set", "phi1_deg=10"]) == 2  # the file is checked first
    assert main(["simulate", "--set", "c1_nm=3"]) == 2  # a misspelt parameter is not an option: no such hint
    assert "not a rig parameter" not in capsys.readouterr().err
    Path("start.json").write_text('{"phi1_deg": 10}')  # in a parameter file, and a sweep's fixed input
    assert main(["simulate", "--params-file", "start.json"]) == 2
    assert "start.json: unknown parameter(s) phi1_deg (this command's --phi1-deg, not a rig parameter)" in (
        capsys.readouterr().err
    )
    assert main(["sweep", "--vary", "c1_n_m=5,6", "--params-file", "start.json", "-o", "never"]) == 2
    assert "start.json: unknown parameter(s) phi1_deg (a sweep's input, not a rig parameter: --set or --vary)" in (
        capsys.readouterr().err
    )
    assert main(["sweep", "--vary", "c1_n_m=5,6", "--set", "dt_s=0.001", "-o", "never"]) == 2
    assert "unknown input 'dt_s' (this command's --dt-s, not a rig parameter)" in capsys.readouterr().err
    # a recording given as a parameter file: said so, with the command that makes one of its rig
    Path("r.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(2_000_000))
    assert main(["simulate", "--params-file", "r.mcap"]) == 2
    assert "r.mcap is a recording, not a parameter file; its rig as one: pendsim info r.mcap --json" in (
        capsys.readouterr().err
    )
    # a drive faster than the step: named by this command's option
    assert main(["simulate", "--torque1-n-m", "sine:0.01,49"]) == 2
    assert "the torque_m1 drive (--torque1-n-m) reaches 49 Hz: a step of 0.01 s gives it 2 steps a period" in (
        capsys.readouterr().err
    )
    # a sweep's drive input on a command that takes a drive as one option and a signal
    assert main(["simulate", "--set", "torque_m1_frequency_hz=1", "--set", "torque_m1_amplitude_n_m=0.01"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "(a sweep's drive input; here a drive is one option and a signal: --torque1" in err
    # a name without its unit, or in capitals: its likely spelling, not an option (--b1 sets b1_n_m_s)
    for given, meant in (("b1", "b1_n_m_s"), ("C1_N_M", "c1_n_m")):
        assert main(["simulate", "--set", f"{given}=0.001"]) == 2
        err = capsys.readouterr().err
        assert f"unknown parameter(s) {given} (did you mean {meant!r}?); allowed:" in err, err
    assert not Path("never").exists()
    for value in ("fast", "1"):  # a run setting given as a parameter, whatever its value
        assert main(["simulate", "--set", f"engine={value}"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "unknown parameter(s) engine (this command's --engine, not a rig" in err
        assert main(["sweep", "--vary", "c1_n_m=5,6", "--set", f"engine={value}", "-o", "never"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "unknown input 'engine' (this command's --engine, not a rig" in err


def test_a_file_name_with_a_newline_keeps_the_error_on_one_line(workspace, capsys):
    assert main(["inspect", "two\nlines.mcap"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "two lines.mcap" in err


def test_a_closed_pipe_ends_quietly():
    out = subprocess.run(f"{shlex.quote(EXE)} info | head -1", shell=True, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.startswith("Rig parameters") and out.stderr == ""


def test_a_diverging_mujoco_run_is_one_line_with_mujocos_warning_and_no_log_file(tmp_path):
    # the spatial model with a very stiff bearing: MuJoCo itself flags the state as unstable
    args = ["compare", "--duration-s", "2", "--set", "tilt_stiffness_n_m_rad=1e6", "-o", "c"]
    out = subprocess.run([EXE, *args], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    lines = out.stderr.splitlines()
    assert out.returncode == 2 and len(lines) == 1, out.stderr
    assert lines[0].startswith("pendsim: error: simulation diverged") and "MuJoCo: Nan, Inf or huge value" in lines[0]
    assert "WARNING" not in out.stdout + out.stderr
    assert list(tmp_path.iterdir()) == []  # no MUJOCO_LOG.TXT, no output folder


def test_names_that_are_not_utf8_print_escaped_not_as_a_traceback(tmp_path):
    name = os.fsdecode(b"run-\xff.npz")
    env = {**os.environ, "LC_ALL": "C.UTF-8", "PYTHONIOENCODING": "utf-8"}
    out = subprocess.run(
        [EXE, "simulate", "--duration-s", "1", "-o", name], cwd=tmp_path, capture_output=True, env=env, timeout=120
    )
    assert out.returncode == 0 and b"Traceback" not in out.stderr, out.stderr
    assert b"wrote run-\\udcff.npz" in out.stdout  # escaped on the terminal
    assert os.path.exists(os.path.join(os.fsencode(tmp_path), b"run-\xff.npz"))  # the name as given
