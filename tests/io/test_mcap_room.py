"""The MCAP room (bridge/io/mcap/): its facade exports what other code uses, importing it leaves
numba out of the process, and its modules stay small and free of import cycles."""

import ast
import subprocess
import sys
from pathlib import Path

import pendsim_bridge.io.mcap as mcap_room
from pendsim_bridge.io.mcap import reader

ROOM = Path(mcap_room.__file__).parent


def _local_imports(path: Path) -> set[str]:
    """The room's modules that ``path`` imports (function-local imports included)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            if node.module:
                found.add(node.module.split(".")[0])
            else:  # from . import name: a module of the room, or a name of its facade
                found |= {a.name if (ROOM / f"{a.name}.py").exists() else "__init__" for a in node.names}
    return found


def test_every_name_the_facade_exports_resolves_to_its_module_s_object():
    for name in mcap_room.__all__:
        value = getattr(mcap_room, name)
        assert value is not None, name
        if hasattr(reader, name):
            assert value is getattr(reader, name), name


def test_the_reader_module_still_offers_the_reader_api():
    for name in reader.__all__:
        assert getattr(reader, name) is not None, name
    for name in ("McapFile", "McapContents", "ChannelData", "read_mcap", "scan_mcap"):
        assert name in reader.__all__


def test_importing_the_facade_imports_no_numba():
    code = "import sys, pendsim_bridge.io.mcap; print(sorted(m for m in sys.modules if m.split('.')[0] == 'numba'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_no_module_of_the_room_is_over_800_lines():
    long = {p.name: n for p in ROOM.glob("*.py") if (n := len(p.read_text().splitlines())) > 800}
    assert not long, long


def test_the_room_s_modules_import_one_another_without_a_cycle():
    graph = {p.stem: _local_imports(p) for p in ROOM.glob("*.py")}
    graph["__init__"] = set()  # the facade imports the room; no module of the room imports it
    for p in ROOM.glob("*.py"):
        if p.stem != "__init__":
            assert "__init__" not in graph[p.stem], f"{p.name} imports the facade"
    done: set[str] = set()

    def visit(module: str, path: tuple[str, ...]) -> None:
        assert module not in path, " -> ".join((*path, module))
        if module in done:
            return
        for other in sorted(graph.get(module, ())):
            visit(other, (*path, module))
        done.add(module)

    for module in sorted(graph):
        visit(module, ())
