"""mypy is clean on both packages, as installed: pendsim_mj and pendsim_bridge (the folder bridge/);
the public modules are clean under ``mypy --strict``."""

import os
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
STRICT_OVERRIDES = [o for o in PYPROJECT["tool"]["mypy"]["overrides"] if o.get("disallow_untyped_defs")]
STRICT_MODULES: tuple[str, ...] = tuple(STRICT_OVERRIDES[0]["module"]) if STRICT_OVERRIDES else ()
"""The modules a script imports from (docs/api.md), held to strict mode's per-module flags in
pyproject.toml for every mypy run, and checked here with ``mypy --strict`` itself."""


def _mypy(*args: str) -> subprocess.CompletedProcess[str]:
    # mypy cannot follow setuptools' editable-install import hook, so it reads the packages through
    # links named as they are installed.
    links = ROOT / ".mypy_root"
    links.mkdir(exist_ok=True)
    for name, target in (("pendsim_mj", "pendsim_mj"), ("pendsim_bridge", "bridge")):
        link = links / name
        if not link.is_symlink():
            link.symlink_to(Path("..") / target)
    cmd = [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"), *args]
    return subprocess.run(cmd, cwd=links, capture_output=True, text=True, env={**os.environ, "MYPYPATH": ""})


def test_mypy_is_clean_on_both_packages():
    out = _mypy("--cache-dir", str(ROOT / ".mypy_cache"), "-p", "pendsim_mj", "-p", "pendsim_bridge")
    assert out.returncode == 0, out.stdout + out.stderr


def test_mypy_strict_is_clean_on_the_public_modules():
    # --strict for these modules only: the modules they import are read, their errors not reported
    # (silent); strict mode changes every module's options, so its cache is kept apart.
    modules = [arg for name in STRICT_MODULES for arg in ("-m", name)]
    out = _mypy("--cache-dir", str(ROOT / ".mypy_cache" / "strict"), "--strict", "--follow-imports=silent", *modules)
    assert out.returncode == 0, out.stdout + out.stderr


def test_every_facade_is_held_to_strict():
    # one override holds the list, and every package front door that declares __all__ is on it
    assert len(STRICT_OVERRIDES) == 1
    facades = {
        ".".join([name, *init.parent.relative_to(ROOT / folder).parts])
        for name, folder in (("pendsim_mj", "pendsim_mj"), ("pendsim_bridge", "bridge"))
        for init in (ROOT / folder).rglob("__init__.py")
        if "__all__" in init.read_text()
    }
    assert facades - set(STRICT_MODULES) == set()


def test_both_packages_ship_py_typed():
    assert (ROOT / "pendsim_mj" / "py.typed").is_file()
    assert (ROOT / "bridge" / "py.typed").is_file()
