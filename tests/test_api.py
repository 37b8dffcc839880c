"""The public API: what the facades export, that importing them stays light, and that every example
of docs/api.md runs.

The page's ```python blocks run in order, each in a fresh namespace (so every block shows its own
imports) and all in one empty folder (so the recording its "Record" section makes is the one the
later sections read); a failing block's traceback points at its line in docs/api.md.
"""

from __future__ import annotations

import ast
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

import pendsim_bridge
import pendsim_bridge.io
import pendsim_mj
import pendsim_mj.allan
import pendsim_mj.estimation
import pendsim_mj.rig
import pendsim_mj.sensors
import pendsim_mj.sweep

ROOT = Path(__file__).resolve().parent.parent
API_PAGE = ROOT / "docs" / "api.md"
# every facade that imports its names on first use (pendsim_mj.lazy); the engines' and the MCAP
# room's facades have tests of their own (tests/engines, tests/io)
FACADES = (
    pendsim_mj, pendsim_mj.rig, pendsim_mj.sensors, pendsim_mj.estimation, pendsim_mj.allan, pendsim_mj.sweep,
    pendsim_bridge, pendsim_bridge.io,
)  # fmt: skip
ROOMS = (
    pendsim_mj.rig,
    pendsim_mj.sensors,
    pendsim_mj.estimation,
    pendsim_mj.allan,
    pendsim_mj.sweep,
    pendsim_bridge.io,
)
HEAVY = ("mujoco", "numba", "matplotlib", "rerun", "scipy", "dask", "pyarrow", "allantools")


def python_blocks(text: str) -> list[tuple[int, str]]:
    """Each ```python block of a page with the line it starts on (1-based)."""
    return [(text.count("\n", 0, m.start(1)) + 1, m.group(1)) for m in re.finditer(r"```python\n(.*?)```", text, re.S)]


def test_the_issue_s_import_line_works():
    from pendsim_mj import Drive, RigParams, Trajectory, simulate
    from pendsim_mj.engines.simulation import simulate as defined
    from pendsim_mj.engines.trajectory import Trajectory as defined_trajectory
    from pendsim_mj.rig.drives import Drive as defined_drive
    from pendsim_mj.rig.params import RigParams as defined_params

    assert (simulate, Trajectory, RigParams, Drive) == (defined, defined_trajectory, defined_params, defined_drive)


def test_the_recording_api_is_exported():
    from pendsim_bridge import RecordSpec, identify, read_mcap, read_recording, record, validate
    from pendsim_bridge.io.recording import read_recording as defined

    assert read_recording is defined
    assert all(callable(f) for f in (RecordSpec, identify, read_mcap, record, validate))


@pytest.mark.parametrize("facade", FACADES, ids=lambda m: m.__name__)
def test_every_name_in_all_is_its_defining_modules_object_and_dir_lists_it(facade):
    assert len(set(facade.__all__)) == len(facade.__all__)
    for name, source in facade._LAZY.items():
        module = importlib.import_module(importlib.util.resolve_name(source, facade.__name__))
        expected = module if module.__name__ == f"{facade.__name__}.{name}" else getattr(module, name)
        assert getattr(facade, name) is expected, name
    for name in facade.__all__:
        assert getattr(facade, name) is not None, name
    assert set(facade.__all__) <= set(dir(facade))
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        facade.no_such_name  # noqa: B018


@pytest.mark.parametrize("facade", FACADES, ids=lambda m: m.__name__)
def test_what_mypy_sees_is_what_the_facade_gives(facade):
    # The names imported under TYPE_CHECKING (for mypy and editors) are the ones __getattr__ imports
    # on first use, from the same modules; with the eager imports they make up __all__.
    tree = ast.parse(Path(facade.__file__).read_text())
    typing_block = next(n for n in tree.body if isinstance(n, ast.If) and ast.unparse(n.test) == "TYPE_CHECKING")
    seen = {}
    for node in typing_block.body:
        assert isinstance(node, ast.ImportFrom)
        module = importlib.util.resolve_name("." * node.level + (node.module or ""), facade.__name__)
        for alias in node.names:
            # `from pendsim_mj import nonlinear`: a submodule exported as itself
            seen[alias.name] = f"{module}.{alias.name}" if module == facade.__name__ else module
    lazy = {name: importlib.util.resolve_name(source, facade.__name__) for name, source in facade._LAZY.items()}
    assert seen == lazy
    eager = set(facade.__all__) - set(lazy)
    assert eager <= set(vars(facade)), "a name in __all__ is neither imported nor lazy"
    assert set(lazy) <= set(facade.__all__)


@pytest.mark.parametrize("room", ROOMS, ids=lambda m: m.__name__)
def test_a_rooms_docstring_names_every_module_of_the_room(room):
    folder = Path(room.__file__).parent
    modules = sorted(p.stem if p.suffix else p.name for p in folder.iterdir() if _is_module(p))
    assert [m for m in modules if f"``{m}``" not in (room.__doc__ or "")] == []


def _is_module(path: Path) -> bool:
    return (path.suffix == ".py" and path.stem != "__init__") or (path / "__init__.py").is_file()


def test_importing_the_packages_imports_no_engine_kernel_or_plotting():
    code = (
        f"import sys, {', '.join(f.__name__ for f in FACADES)}\n"
        "from pendsim_mj import DEFAULT_PARAMS, Drive, RigParams, Sine\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_lazy_name_imports_its_module_on_first_use():
    code = (
        "import sys, pendsim_mj\n"
        "assert 'mujoco' not in sys.modules\n"
        "simulate = pendsim_mj.simulate\n"
        "assert 'mujoco' in sys.modules and 'simulate' in vars(pendsim_mj)\n"
        "assert pendsim_mj.nonlinear is sys.modules['pendsim_mj.nonlinear']\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_the_api_page_has_an_example_per_area():
    headings = re.findall(r"^## (.+)$", API_PAGE.read_text(), re.M)
    for area in ("Simulate", "Drives", "Record", "Read", "Validate", "Identify", "Sweep", "Analyze", "Allan"):
        assert any(h.startswith(area) for h in headings), area
    text = API_PAGE.read_text()
    for heading in headings:
        section = text.split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]
        assert "```python" in section, heading


def test_every_example_of_the_api_page_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    text = API_PAGE.read_text()
    blocks = python_blocks(text)
    assert len(blocks) >= 10
    for line, code in blocks:
        # padded so that a traceback names the block's own line in docs/api.md
        exec(compile("\n" * (line - 1) + code, str(API_PAGE), "exec"), {"__name__": "__main__"})
    assert (tmp_path / "run.mcap").is_file()
