"""A 2 GB file that is not what it claims (zeros; an MCAP magic then zeros; a LabVIEW header then
zeros; one 2 GB line of digits) is refused in one line with bounded memory: each command runs in
a subprocess that reports its own peak resident memory (``VmHWM`` of /proc/self/status), which must stay
below 300 MB (pendsim's imports alone take about 150 MB). Before the fix, import and
``sweep --cases`` took 4.3 GB, inspect and recover 2.2 GB.

The files are sparse (``truncate``): 2 GB on paper, a few blocks on the disk.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

SIZE = 2 << 30
LIMIT_KB = 300 * 1024
RUNNER = """
import contextlib, io, json, sys
from pendsim_bridge.cli import main
err = io.StringIO()
with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
    code = main(json.loads(sys.argv[1]))
# VmHWM: the peak of this process image since exec (getrusage's ru_maxrss also counts the parent's
# memory at fork: a pytest process of 370 MB would make every child look as large)
peak_kb = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM:"))
print(json.dumps({"code": code, "stderr": err.getvalue(), "peak_kb": peak_kb}))
"""
CASES = {
    "import csv of zeros": ("zeros.csv", b"", ["import", "{f}", "-o", "{d}/x.mcap"], "not a text file"),
    "import one long line": ("long.csv", b"t_s,gx\n" + b"1" * (1 << 20), ["import", "{f}", "-o", "{d}/x.mcap"],
                             "is over 65536 characters"),
    "import lvm of zeros": ("head.lvm", b"LabVIEW Measurement\t\n", ["import", "{f}", "-o", "{d}/x.mcap"],
                            "not a text file"),
    "sweep --cases zeros": ("zeros.csv", b"", ["sweep", "--cases", "{f}", "-o", "{d}/sweep"], "not text"),
    "inspect magic and zeros": ("zeros.mcap", b"\x89MCAP0\r\n", ["inspect", "{f}"], "no Header record"),
    "recover magic and zeros": ("zeros.mcap", b"\x89MCAP0\r\n", ["recover", "{f}", "{d}/fixed.mcap"],
                                "no Header record"),
}  # fmt: skip


@pytest.mark.parametrize("name", list(CASES))
def test_a_2_gb_file_that_is_not_data_is_refused_with_bounded_memory(tmp_path, name):
    filename, head, argv, message = CASES[name]
    path = tmp_path / filename
    with open(path, "wb") as f:
        f.write(head)
        if name == "import one long line":  # the line goes on, digits to 2 GB, no newline
            f.truncate(SIZE)
            f.seek(len(head))
            f.write(b"1" * (64 << 20))  # the first 64 MB real digits; the rest is a hole (NUL bytes)
        f.truncate(SIZE)
    out = tmp_path / "out"
    out.mkdir()
    args = [a.format(f=path, d=out) for a in argv]
    done = subprocess.run(
        [sys.executable, "-c", RUNNER, json.dumps(args)], capture_output=True, text=True, timeout=300, cwd=out
    )
    result = json.loads(done.stdout.splitlines()[-1])
    lines = result["stderr"].splitlines()
    assert result["code"] == 2 and len(lines) == 1 and message in lines[0], result["stderr"]
    assert result["peak_kb"] < LIMIT_KB, f"peak {result['peak_kb'] / 1024:.0f} MB"
    assert os.listdir(out) == []
