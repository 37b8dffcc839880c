"""The sweep room's facade, ``pendsim_mj.sweep`` (sweep plans, tasks and features): each
exported name is its module's own object, the docstring names every module of the room, and
importing the room imports neither MuJoCo nor numba (each name is imported on first use)."""

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import pendsim_mj.sweep as room

HEAVY = ("mujoco", "numba")


def test_every_exported_name_is_its_modules_own_object():
    assert len(set(room.__all__)) == len(room.__all__)
    for name in room.__all__:
        home = importlib.import_module(f"pendsim_mj.sweep.{room._HOME[name]}")
        assert getattr(room, name) is getattr(home, name), name
    assert set(room.__all__) <= set(dir(room))


def test_an_unknown_name_is_an_attribute_error_naming_it():
    with pytest.raises(AttributeError, match="no_such_name"):
        _ = room.no_such_name


def test_the_docstring_names_every_module_of_the_room():
    modules = sorted(p.stem for p in Path(room.__file__).parent.glob("*.py") if p.stem != "__init__")
    assert [m for m in modules if f"``{m}``" not in (room.__doc__ or "")] == []


def test_importing_the_room_imports_no_heavy_library():
    code = f"import sys, pendsim_mj.sweep; print(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
