"""Every command that writes, on a full disk: exit 2, one line ``pendsim: error: cannot write
...: no space left on the device``, and nothing left on the disk (no partial file, no temporary
name, no half-filled folder).

The full disk is real: a small tmpfs, filled up. Mounting needs root; elsewhere the commands run
in a subprocess under a file size limit (RLIMIT_FSIZE with SIGXFSZ ignored, so writes fail with
EFBIG, "file too large"): the same failure path, named differently.
"""

import contextlib
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pendsim_bridge.cli import main

COMMANDS = {
    "simulate -o": ["simulate", "--duration-s", "1", "-o", "{out}/x.npz"],
    "simulate --rerun": ["simulate", "--duration-s", "1", "--rerun", "{out}/x.rrd"],
    "record": ["record", "--duration-s", "2", "-o", "{out}/r.mcap"],
    "recover": ["recover", "{rec}", "{out}/f.mcap"],
    "replay -o": ["replay", "{rec}", "-o", "{out}/p.mcap"],
    "replay --rerun": ["replay", "{rec}", "--quiet", "--rerun", "{out}/p.rrd"],
    "view --save": ["view", "{rec}", "--save", "{out}/v.rrd"],
    "validate -o": ["validate", "{rec}", "-o", "{out}/val", "--damping", "recorded", "--no-plots"],
    "identify --write": ["identify", "{rec}", "--write", "{out}/b.json"],
    "allan --plot-dir": ["allan", "{static}", "--plot-dir", "{out}/allan"],
    "compare": ["compare", "--duration-s", "2", "-o", "{out}/cmp"],
    "demo": ["demo", "--duration-s", "10", "-o", "{out}/demo"],
    "sweep": ["sweep", "--vary", "phi1_deg=10:20:2", "--duration-s", "1", "-o", "{out}/sweep"],
}
RUNNER = """
import contextlib, io, json, resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead
from pendsim_bridge.cli import main
resource.setrlimit(resource.RLIMIT_FSIZE, (16, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(argv)
    print(json.dumps({"code": code, "stderr": err.getvalue()}), flush=True)
"""


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("inputs")
    rec, static = folder / "rec.mcap", folder / "static.mcap"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["record", "-o", str(rec), "--duration-s", "6", "--hold-s", "1"]) == 0
        assert main(["record", "--static", "-o", str(static), "--duration-s", "5"]) == 0
    return {"rec": str(rec), "static": str(static)}


def _mount_full_tmpfs(folder: Path) -> bool:
    folder.mkdir()
    if os.geteuid() != 0:
        return False
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "pendsim-full", str(folder)], capture_output=True)
    if done.returncode != 0:
        return False
    with open(folder / "filler", "wb", buffering=0) as f, contextlib.suppress(OSError):
        while True:
            f.write(b"\0" * 4096)
    return True


@pytest.fixture(scope="module")
def full_disk(tmp_path_factory, inputs):
    """(folder, how, results): a full tmpfs (results None: run in-process), or a normal folder
    with every command already run under a file size limit (results per command)."""
    folder = tmp_path_factory.mktemp("full") / "disk"
    if _mount_full_tmpfs(folder):
        try:
            yield folder, "no space left on the device", None
        finally:
            subprocess.run(["umount", "-l", str(folder)], check=False)
        return
    argvs = [[a.format(out=folder, **inputs) for a in argv] for argv in COMMANDS.values()]
    env = {**os.environ, "MPLBACKEND": "Agg"}
    out = subprocess.run(
        [sys.executable, "-c", RUNNER, json.dumps(argvs)], capture_output=True, text=True, timeout=600, env=env
    )
    results = [json.loads(line) for line in out.stdout.splitlines()]
    assert len(results) == len(COMMANDS), out.stderr
    yield (
        folder,
        "file too large (the file size limit of this process or file system)",
        dict(zip(COMMANDS, results, strict=True)),
    )


@pytest.mark.parametrize("name", list(COMMANDS))
def test_a_full_disk_is_one_error_line_and_leaves_nothing(full_disk, inputs, capsys, name):
    folder, cause, results = full_disk
    before = sorted(p.name for p in folder.iterdir())
    if results is None:
        code = main([a.format(out=folder, **inputs) for a in COMMANDS[name]])
        err = capsys.readouterr().err
    else:
        code, err = results[name]["code"], results[name]["stderr"]
    lines = err.splitlines()
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith(f"pendsim: error: cannot write '{folder}") and lines[0].endswith(cause), lines[0]
    assert ".partial" not in lines[0]  # the name the user gave, not the temporary one
    assert sorted(p.name for p in folder.iterdir()) == before  # hidden temporary names included
