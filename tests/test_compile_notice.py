"""A cold numba cache says so in one line on a terminal, once; a warm one says nothing.

``pendsim allan`` (whose kernels compile in a few seconds) runs twice in a subprocess whose
standard error is a pseudo-terminal, with ``NUMBA_CACHE_DIR`` an empty folder: the first run
compiles and prints ``pendsim: compiling pendsim's numba kernels once (...; cached in DIR)``, the
second loads the cache and prints no such line. numba's "numba:compile" event (what the line
hangs on) fires only for a real compile, so the test takes its truth from numba, not from time.
"""

from __future__ import annotations

import contextlib
import io
import os
import pty
import subprocess
import sys

from pendsim_bridge.cli import _say_compiling, main


def _stderr_on_a_terminal(args: list[str], env: dict[str, str]) -> str:
    leader, follower = pty.openpty()
    try:
        done = subprocess.run(
            [sys.executable, "-m", "pendsim_bridge.cli", *args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
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


def test_a_cold_cache_says_it_compiles_once_and_a_warm_one_says_nothing(tmp_path):
    static = tmp_path / "static.mcap"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["record", "--static", "--duration-s", "5", "-o", str(static)]) == 0
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "MPLBACKEND": "Agg"}
    args = ["allan", str(static), "--no-plots"]
    cold = [line for line in _stderr_on_a_terminal(args, env).splitlines() if "compiling" in line]
    assert len(cold) == 1, cold
    assert cold[0].startswith("pendsim: compiling pendsim's numba kernels once (about 20 s")
    assert f"cached in {cache}" in cold[0]
    assert any(cache.rglob("*.nbi"))  # numba did compile into that folder
    warm = _stderr_on_a_terminal(args, env)
    assert "compiling" not in warm, warm


def test_no_line_when_standard_error_is_not_a_terminal(capsys):
    assert main(["info"]) == 0
    capsys.readouterr()
    _say_compiling("compiling pendsim's numba kernels once")  # what a cold compile calls
    assert capsys.readouterr().err == ""
