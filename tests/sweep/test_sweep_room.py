"""The sweep room's facade, ``pendsim_mj.sweep`` (sweep plans, tasks and features): each
exported name is its module's own object and what mypy sees, the docstring names every module of
the room, and importing the room imports neither MuJoCo nor numba (each name is imported on first
use)."""

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import pendsim_mj.sweep as room

HEAVY = ("mujoco", "numba")


def test_every_exported_name_is_its_modules_own_object():
    assert len(set(room.__all__)) == len(room.__all__)
    assert set(room.__all__) == set(room._LAZY)
    for name in room.__all__:
        assert getattr(room, name) is getattr(importlib.import_module(room._LAZY[name]), name), name
    assert set(room.__all__) <= set(dir(room))
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        room.no_such_name  # noqa: B018


def test_what_mypy_sees_is_what_the_facade_gives():
    tree = ast.parse(Path(room.__file__).read_text())
    typing_block = next(n for n in tree.body if isinstance(n, ast.If) and ast.unparse(n.test) == "TYPE_CHECKING")
    seen = {
        alias.name: node.module
        for node in typing_block.body
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    }
    assert seen == room._LAZY


def test_the_docstring_names_every_module_of_the_room():
    modules = sorted(p.stem for p in Path(room.__file__).parent.glob("*.py") if p.stem != "__init__")
    assert [m for m in modules if f"``{m}``" not in (room.__doc__ or "")] == []


def test_importing_the_room_imports_no_heavy_library():
    code = f"import sys, pendsim_mj.sweep; print(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
