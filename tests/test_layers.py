"""The house's floor plan, read from the source: no import cycle, the physics never imports the
bridge, the reference solver never imports MuJoCo, the bridge's layers point one way only, and no
module or folder grows past what a reader can hold.

The graph is static (``ast``, no module is imported): every import counts, at the top of a module,
under ``if TYPE_CHECKING:`` and inside functions (a local import still makes the one module need
the other), with relative imports resolved. ``from package import name`` is an edge to the
submodule ``package.name`` when there is one, else to the package.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"pendsim_mj": ROOT / "pendsim_mj", "pendsim_bridge": ROOT / "bridge"}
MAX_LINES = 800
MAX_MODULES_PER_FOLDER = 15
ONE_MODULE_PER_VERB = ROOT / "bridge" / "commands"  # a folder of one module per CLI verb: not counted
REFERENCE = "pendsim_mj.engines.reference"

BRIDGE_LAYERS = (
    ("errors", "signals", "heap"),  # utilities every layer may use
    ("io",),  # files: MCAP, ROS 2, recordings, atomic outputs
    ("report",),  # what people see: tables, figures, Rerun views
    ("run",),  # the runs: record, validate, replay, sweep, demo
    ("acquire",),  # measured data in: live acquisition, the node emulator, lab-file imports
    ("options",),  # the command line's argument types and shared options
    ("commands",),  # one module per verb
    ("cli",),  # the parser and the exit codes
)
"""The bridge's layers, lowest first: a module imports only modules of its own layer or a lower
one. The package's own ``__init__`` (a facade) sits above them all."""


def _modules() -> dict[str, Path]:
    """Every module of both packages by its dotted name (a package by its ``__init__``)."""
    out = {}
    for package, folder in PACKAGES.items():
        for path in sorted(folder.rglob("*.py")):
            parts = [package, *path.relative_to(folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> Iterator[str]:
    """The absolute names each import statement of a module asks for (one per imported name)."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                source = ".".join([*base, *([node.module] if node.module else [])])
            else:
                source = node.module or ""
            for alias in node.names:
                yield f"{source}.{alias.name}" if f"{source}.{alias.name}" in MODULES else source


def _graph() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """(edges between the packages' modules, the outside top-level packages each imports)."""
    edges: dict[str, set[str]] = {}
    outside: dict[str, set[str]] = {}
    for name, path in MODULES.items():
        edges[name], outside[name] = set(), set()
        for target in _imports(name, path):
            parts = target.split(".")
            while parts and ".".join(parts) not in MODULES:
                parts.pop()
            if parts:
                if ".".join(parts) != name:
                    edges[name].add(".".join(parts))
            elif target.split(".")[0] not in PACKAGES:
                outside[name].add(target.split(".")[0])
    return edges, outside


EDGES, OUTSIDE = _graph()


def _cycle(edges: dict[str, set[str]]) -> list[str] | None:
    """One import cycle (its modules in order, the first repeated at the end), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(module: str) -> list[str] | None:
        state[module] = 1
        path.append(module)
        for target in sorted(edges[module]):
            if state.get(target) == 1:
                return [*path[path.index(target) :], target]
            if target not in state:
                found = visit(target)
                if found:
                    return found
        path.pop()
        state[module] = 2
        return None

    for module in sorted(edges):
        if module not in state:
            found = visit(module)
            if found:
                return found
    return None


def _bridge_layer(module: str) -> int:
    parts = module.split(".")
    if len(parts) == 1:  # the package's facade
        return len(BRIDGE_LAYERS)
    layer = next((k for k, names in enumerate(BRIDGE_LAYERS) if parts[1] in names), None)
    assert layer is not None, f"{module} belongs to no layer: name its place in BRIDGE_LAYERS"
    return layer


def test_the_graph_reads_every_module_and_resolves_relative_imports():
    assert "pendsim_bridge.run.validate" in MODULES and "pendsim_mj.engines.reference" in MODULES
    assert "pendsim_bridge.io.recording_layout" in EDGES["pendsim_bridge.io.recording_writer"]  # from .x import
    assert "pendsim_bridge.io.ros2" in EDGES["pendsim_bridge.io.recording_layout"]  # from . import x
    assert "pendsim_bridge.heap" in EDGES["pendsim_bridge.run.validate"]  # from .. import x
    assert "pendsim_mj.rig.params" in EDGES[REFERENCE]


def test_the_cycle_finder_finds_a_cycle_and_names_it():
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycle(edges) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle():
    cycle = _cycle(EDGES)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_the_physics_never_imports_the_bridge():
    for module, targets in EDGES.items():
        if module.startswith("pendsim_mj"):
            bridge = sorted(t for t in targets if t.startswith("pendsim_bridge"))
            assert not bridge, f"{module} imports {bridge}"


def test_the_reference_solver_and_what_it_imports_never_import_mujoco():
    reached, todo = set(), [REFERENCE]
    while todo:
        module = todo.pop()
        if module not in reached:
            reached.add(module)
            todo += EDGES[module]
    importers = sorted(m for m in reached if "mujoco" in OUTSIDE[m])
    assert not importers, f"{REFERENCE} reaches MuJoCo through {importers}"


def test_the_bridge_layers_point_down():
    upward = [
        f"{module} -> {target}"
        for module, targets in EDGES.items()
        if module.startswith("pendsim_bridge")
        for target in sorted(targets)
        if target.startswith("pendsim_bridge") and _bridge_layer(target) > _bridge_layer(module)
    ]
    assert not upward, "imports from a higher layer: " + "; ".join(upward)


def test_no_command_imports_another():
    """A verb's module (one that registers a parser) takes shared options from ``options`` or a
    shared module of ``commands``, never from another verb."""
    verbs = {
        name
        for name, path in MODULES.items()
        if name.startswith("pendsim_bridge.commands.")
        and any(isinstance(n, ast.FunctionDef) and n.name == "register" for n in ast.parse(path.read_text()).body)
    }
    assert len(verbs) > 10
    crossing = [f"{v} -> {t}" for v in sorted(verbs) for t in sorted(EDGES[v] & verbs)]
    assert not crossing, "commands importing commands: " + "; ".join(crossing)


def test_no_module_is_over_800_lines():
    long = {str(p.relative_to(ROOT)): n for p in MODULES.values() if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines: {long}"


def test_no_folder_holds_more_than_15_modules():
    folders = {p.parent for p in MODULES.values()} - {ONE_MODULE_PER_VERB}
    crowded = {
        str(f.relative_to(ROOT)): n
        for f in folders
        if (n := sum(1 for p in f.glob("*.py") if p.name != "__init__.py")) > MAX_MODULES_PER_FOLDER
    }
    assert not crowded, f"folders of more than {MAX_MODULES_PER_FOLDER} modules: {crowded}"


def test_every_room_is_a_package_the_wheel_installs():
    # pyproject.toml lists the packages one by one (bridge/ installs as pendsim_bridge): a room
    # left out of the list would be missing from a wheel, though an editable install finds it
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {
        ".".join([name, *init.parent.relative_to(folder).parts])
        for name, folder in PACKAGES.items()
        for init in folder.rglob("__init__.py")
    }
    assert found - listed == set()
