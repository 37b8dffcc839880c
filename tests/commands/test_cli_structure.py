"""The command line stays thin: cli.py small, each command's run() short, every closed set a
choice, and the installed package name pendsim_bridge used everywhere (never a bare 'bridge')."""

import ast
import re
from pathlib import Path

from pendsim_bridge.cli import build_parser
from pendsim_bridge.commands import COMMANDS

ROOT = Path(__file__).resolve().parents[2]


def test_cli_module_is_under_400_lines():
    assert len((ROOT / "bridge" / "cli.py").read_text().splitlines()) < 400


def test_every_command_run_function_is_at_most_40_lines():
    for path in sorted((ROOT / "bridge" / "commands").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and (node.name == "run" or node.name.startswith("_cmd_")):
                length = node.end_lineno - node.lineno + 1
                assert length <= 40, f"{path.name}:{node.name} is {length} lines"


def test_every_command_module_registers_a_parser_with_its_handler():
    parser = build_parser()
    subparsers = next(a for a in parser._actions if a.dest == "command")
    names = set(subparsers.choices)
    assert len(names) == len(COMMANDS)
    for name, sub in subparsers.choices.items():
        assert callable(sub.get_default("handler")), name


def test_no_module_imports_the_folder_name_bridge():
    pattern = re.compile(r"^\s*(from|import)\s+bridge\b", re.M)
    for folder in ("pendsim_mj", "bridge", "tests", "bench"):
        for path in (ROOT / folder).rglob("*.py"):
            assert not pattern.search(path.read_text()), path


def test_pendsim_mj_never_imports_the_bridge():
    # every import statement, function-local ones included (the docstrings may name the bridge);
    # tests/test_layers.py checks the same on the resolved import graph
    pattern = re.compile(r"^\s*(from|import)\s+pendsim_bridge\b", re.M)
    for path in (ROOT / "pendsim_mj").rglob("*.py"):
        assert not pattern.search(path.read_text()), path
