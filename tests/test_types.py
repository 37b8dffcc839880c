"""mypy is clean on both packages, as installed: pendsim_mj and pendsim_bridge (the folder bridge/);
the public modules are clean under ``mypy --strict``."""

import os
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# The modules a script imports from (docs/api.md): the facades, and the rig's parameters and drives.
# pyproject.toml sets strict mode's per-module flags on the same list, for every mypy run.
STRICT_MODULES = (
    "pendsim_mj", "pendsim_mj.lazy", "pendsim_mj.units", "pendsim_mj.rig", "pendsim_mj.rig.params",
    "pendsim_mj.rig.drives", "pendsim_mj.engines", "pendsim_mj.engines.protocol", "pendsim_mj.engines.trajectory",
    "pendsim_mj.engines.simulation", "pendsim_mj.engines.reference", "pendsim_mj.sensors", "pendsim_mj.estimation",
    "pendsim_mj.allan", "pendsim_mj.nonlinear", "pendsim_mj.sweep",
    "pendsim_bridge", "pendsim_bridge.io", "pendsim_bridge.io.mcap", "pendsim_bridge.io.recording",
)  # fmt: skip


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


def test_pyproject_holds_the_same_modules_to_strict_flags():
    overrides = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"]["overrides"]
    strict = [o for o in overrides if o.get("disallow_untyped_defs")]
    assert len(strict) == 1 and tuple(strict[0]["module"]) == STRICT_MODULES


def test_both_packages_ship_py_typed():
    assert (ROOT / "pendsim_mj" / "py.typed").is_file()
    assert (ROOT / "bridge" / "py.typed").is_file()
