"""A sweep whose disk fills up midway: one error line naming the file and the real cause, and
nothing of the failed run left behind (its parts, its partial zarr store, sweep.json, the folder
it made), while files that were there before stay untouched.

Two real failures: a small tmpfs that fills up (mounting needs root: skipped elsewhere), and, on
any machine, a file size limit (RLIMIT_FSIZE with SIGXFSZ ignored: writes past it fail with EFBIG).
Each run prints, from inside, what the folder held after every task it wrote, so the test knows
that parts and a zarr store really existed before the failure removed them.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ARGS = ["sweep", "--vary", "phi1_deg=10:60:40", "--duration-s", "5", "--trajectories", "--no-plots",
        "--cases-per-task", "4"]  # fmt: skip
RUNNER = """
import contextlib, io, json, os, resource, signal, sys
from pathlib import Path
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead
from pendsim_bridge.cli import main
from pendsim_bridge.run import sweep

out = Path(sys.argv[2])
write_task = sweep.SweepStore.write_task

def recorded(self, result, table):
    path = write_task(self, result, table)
    held = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
    print(json.dumps({"held": held}), flush=True)  # a pipe: not limited
    return path

sweep.SweepStore.write_task = recorded
limit = int(sys.argv[3])
if limit:
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
err = io.StringIO()
with contextlib.redirect_stderr(err):
    code = main(json.loads(sys.argv[1]) + ["-o", str(out)])
print(json.dumps({"code": code, "stderr": err.getvalue()}), flush=True)
"""


def _run(out: Path, limit: int) -> tuple[list[list[str]], int, str]:
    env = {**os.environ, "MPLBACKEND": "Agg", "NUMBA_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-c", RUNNER, json.dumps(ARGS), str(out), str(limit)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    assert lines and "code" in lines[-1], done.stderr
    return [line["held"] for line in lines[:-1]], lines[-1]["code"], lines[-1]["stderr"]


def _check(folder: Path, out: Path, held: list[list[str]], code: int, err: str, cause: str) -> None:
    lines = err.splitlines()
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith(f"pendsim: error: cannot write '{out}") and lines[0].endswith(cause), lines[0]
    assert "standard output" not in lines[0] and ".partial" not in lines[0]
    # the run got somewhere before the disk filled: parts, the zarr store and sweep.json existed
    assert held, "the disk filled before the first task: choose a larger limit"
    assert "sweep.json" in held[-1] and "trajectories.zarr" in held[-1]
    assert any(name.startswith("parts/part-") for name in held[-1])
    assert not out.exists()  # all of it removed
    assert (folder / "older.txt").read_text() == "kept\n"  # what was there before: untouched


def test_a_sweep_past_the_file_size_limit_names_the_cause_and_removes_what_it_started(tmp_path):
    (tmp_path / "older.txt").write_text("kept\n")
    out = tmp_path / "sweep"
    held, code, err = _run(out, 96 * 1024)  # one zarr chunk of all 40 cases outgrows it after a few tasks
    _check(tmp_path, out, held, code, err, "file too large (the file size limit of this process or file system)")


@pytest.fixture
def small_disk(tmp_path):
    folder = tmp_path / "disk"
    folder.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root; the file size limit test covers the same path")
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=200k", "pendsim-small", str(folder)])
    if mounted.returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        yield folder
    finally:
        with contextlib.suppress(OSError):
            subprocess.run(["umount", "-l", str(folder)], check=False)


def test_a_sweep_that_fills_a_real_disk_says_so_and_removes_what_it_started(small_disk):
    (small_disk / "older.txt").write_text("kept\n")
    out = small_disk / "sweep"
    held, code, err = _run(out, 0)
    _check(small_disk, out, held, code, err, "no space left on the device")
    assert sorted(p.name for p in small_disk.iterdir()) == ["older.txt"]  # no hidden temporary names either
