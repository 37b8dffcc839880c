"""A cold numba cache says so in one line, once, before the command's results, on a terminal and
on a pipe alike; a warm one says nothing. pendsim's kernels are cached in the user's cache folder, not beside the
source, unless ``NUMBA_CACHE_DIR`` says otherwise.

``pendsim allan`` (whose kernels compile in a few seconds) runs twice in a subprocess whose
standard output and error are a pseudo-terminal, with ``NUMBA_CACHE_DIR`` an empty folder: the
first run compiles and prints ``pendsim: compiling the numba kernels this command needs, once (...; cached in
DIR)`` before its table, the second loads the cache and prints no such line. numba's
"numba:compile" event (what the line hangs on) fires only for a real compile, so the test takes
its truth from numba, not from time. The cache folder's rule is checked on the smallest kernel
(``chunk_kernel._u64``, compiled in about a second), with numba's own hit and miss counts.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import pty
import subprocess
import sys
from pathlib import Path

import numba

from pendsim_bridge.cli import main
from pendsim_mj import compile_notice


def _stderr_on_a_terminal(args: list[str], env: dict[str, str]) -> str:
    """What the command wrote to a terminal (standard output and error both: in the order written)."""
    leader, follower = pty.openpty()
    try:
        done = subprocess.run(
            [sys.executable, "-m", "pendsim_bridge.cli", *args],
            stdin=subprocess.DEVNULL,
            stdout=follower,
            stderr=follower,
            env=env,
            timeout=600,
        )
        os.close(follower)
        follower = -1
        chunks = []
        with contextlib.suppress(OSError):  # EIO once everything written is read
            while chunk := os.read(leader, 65536):
                chunks.append(chunk)
    finally:
        if follower >= 0:
            os.close(follower)
        os.close(leader)
    assert done.returncode == 0, b"".join(chunks)
    return b"".join(chunks).decode(errors="replace")


def _static_and_an_empty_cache(tmp_path: Path) -> tuple[Path, Path, dict[str, str]]:
    """A 5 s static recording, an empty numba cache folder and the environment that points at it."""
    static = tmp_path / "static.mcap"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["record", "--static", "--duration-s", "5", "-o", str(static)]) == 0
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    return static, cache, {**os.environ, "NUMBA_CACHE_DIR": str(cache), "MPLBACKEND": "Agg"}


def test_a_cold_cache_says_it_compiles_once_and_a_warm_one_says_nothing(tmp_path):
    static, cache, env = _static_and_an_empty_cache(tmp_path)
    args = ["allan", str(static), "--no-plots"]
    lines = _stderr_on_a_terminal(args, env).splitlines()
    cold = [line for line in lines if "compiling" in line]
    assert len(cold) == 1, cold
    assert cold[0].startswith("pendsim: compiling the numba kernels this command needs, once (about ")
    assert cold[0].endswith(f"cached in {cache})")
    table = next(i for i, line in enumerate(lines) if line.startswith("m1"))  # the first result row
    assert lines.index(cold[0]) < table, lines  # said before the results, while compiling
    assert any(cache.rglob("*.nbi"))  # numba did compile into that folder
    warm = _stderr_on_a_terminal(args, env)
    assert "compiling" not in warm, warm


def _allan_on_a_pipe(static: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "pendsim_bridge.cli", "allan", str(static), "--no-plots"],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )


def test_the_line_is_also_said_when_standard_error_is_a_pipe(tmp_path):
    """A notebook cell (``!pendsim ...``) or a log file is not a terminal: a first run there is
    as slow and must say why (a progress bar is for terminals only, this one line is not)."""
    static, cache, env = _static_and_an_empty_cache(tmp_path)
    done = _allan_on_a_pipe(static, env)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("pendsim: compiling the numba kernels this command needs"), lines
    assert lines[0].endswith(f"cached in {cache})") and "\r" not in done.stderr
    again = _allan_on_a_pipe(static, env)
    assert again.returncode == 0 and again.stderr == ""  # warm: nothing on a pipe either


_SMALLEST_KERNEL = """
import json, os
import numpy as np
from pendsim_bridge.io.mcap import chunk_kernel
from pendsim_mj import compile_notice
chunk_kernel._u64(np.zeros(8, np.uint8), 0)
kernel = chunk_kernel._u64
print(json.dumps({
    "variable": os.environ.get("NUMBA_CACHE_DIR"), "path": kernel._cache._cache_path,
    "hits": sum(kernel.stats.cache_hits.values()), "misses": sum(kernel.stats.cache_misses.values()),
    "line": compile_notice.message(kernel),
}))
"""


def _smallest_kernel(tmp_path: Path, **env: str) -> dict:
    clean = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    done = subprocess.run(
        [sys.executable, "-c", _SMALLEST_KERNEL],
        env={**clean, **env},
        cwd=tmp_path,  # no .numba_config.yaml here
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    result: dict = json.loads(done.stdout)
    return result


def test_kernels_are_cached_per_numba_version_in_the_users_cache_folder_not_beside_the_source(tmp_path):
    xdg = tmp_path / "xdg"
    folder = xdg / "pendsim" / f"numba-{numba.__version__}-{compile_notice.sources_digest()}"
    first = _smallest_kernel(tmp_path, XDG_CACHE_HOME=str(xdg))
    assert first["variable"] == str(folder)  # set for child processes too
    assert Path(first["path"]).parent == folder  # numba's subfolder per source folder, in pendsim's
    assert (first["misses"], first["hits"]) == (1, 0)
    assert first["line"].endswith(f"cached in {folder})")  # the cache folder, not one of numba's subfolders
    again = _smallest_kernel(tmp_path, XDG_CACHE_HOME=str(xdg))  # a new process loads, compiles nothing
    assert (again["misses"], again["hits"]) == (0, 1)


def test_an_explicit_numba_cache_dir_is_respected(tmp_path):
    mine = tmp_path / "mine"
    result = _smallest_kernel(tmp_path, NUMBA_CACHE_DIR=str(mine), XDG_CACHE_HOME=str(tmp_path / "xdg"))
    assert result["variable"] == str(mine)
    assert Path(result["path"]).parent == mine
    assert not (tmp_path / "xdg").exists()


def test_without_a_writable_cache_folder_the_kernels_still_run_and_the_line_says_so(tmp_path):
    blocked = tmp_path / "a-file"
    blocked.write_text("")  # the user's cache folder cannot be made under a file (even as root)
    result = _smallest_kernel(tmp_path, XDG_CACHE_HOME=str(blocked))
    assert result["misses"] == 1
    assert "not kept: no writable cache folder, set NUMBA_CACHE_DIR" in result["line"]
    assert not Path(result["variable"]).exists()  # the temporary folder went with the process


def test_the_cache_folder_changes_when_a_helper_another_file_inlines_changes(tmp_path, monkeypatch):
    # summary_kernel inlines kernel's RK4 step: numba would reload its stale compiled code after
    # an edit to kernel.py alone, so the folder is keyed on the whole package's sources
    import shutil

    package = tmp_path / "pendsim_mj" / "engines" / "fast_planar"
    shutil.copytree(Path(compile_notice.__file__).parent / "engines" / "fast_planar", package,
                    ignore=shutil.ignore_patterns("__pycache__"))  # fmt: skip
    monkeypatch.setattr(compile_notice, "__file__", str(tmp_path / "pendsim_mj" / "compile_notice.py"))
    before = compile_notice.sources_digest()
    assert before == compile_notice.sources_digest() and len(before) == 8
    kernel = package / "kernel.py"
    kernel.write_text(kernel.read_text().replace("h6 = h / 6.0", "h6 = h * (1.0 / 6.0)"))
    assert compile_notice.sources_digest() != before
