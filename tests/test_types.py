"""mypy is clean on both packages, as installed: pendsim_mj and pendsim_bridge (the folder bridge/)."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_mypy_is_clean_on_both_packages():
    # mypy cannot follow setuptools' editable-install import hook, so it reads the packages through
    # links named as they are installed.
    links = ROOT / ".mypy_root"
    links.mkdir(exist_ok=True)
    for name, target in (("pendsim_mj", "pendsim_mj"), ("pendsim_bridge", "bridge")):
        link = links / name
        if not link.is_symlink():
            link.symlink_to(Path("..") / target)
    cmd = [
        sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
        "--cache-dir", str(ROOT / ".mypy_cache"), "-p", "pendsim_mj", "-p", "pendsim_bridge",
    ]  # fmt: skip
    out = subprocess.run(cmd, cwd=links, capture_output=True, text=True, env={**os.environ, "MYPYPATH": ""})
    assert out.returncode == 0, out.stdout + out.stderr


def test_both_packages_ship_py_typed():
    assert (ROOT / "pendsim_mj" / "py.typed").is_file()
    assert (ROOT / "bridge" / "py.typed").is_file()
