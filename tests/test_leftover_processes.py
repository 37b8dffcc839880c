"""The suite's own guard (conftest.py) fails a session that leaves a process running, orphans of
a launcher included, and ends that process."""

import os
import textwrap
import time
from pathlib import Path

CONFTEST = Path(__file__).with_name("conftest.py")


def _inner_conftest() -> str:
    """The suite's conftest for an inner session (no pytester plugin, a short grace period)."""
    text = CONFTEST.read_text().replace('pytest_plugins = ["pytester"]', "")
    return text.replace("GRACE_S = 3.0", "GRACE_S = 0.5")


def test_a_session_that_leaves_a_process_behind_fails_and_the_process_is_ended(pytester, tmp_path):
    pidfile = tmp_path / "orphan.pid"
    pytester.makeconftest(_inner_conftest())
    pytester.makepyfile(
        test_leak=textwrap.dedent(
            f"""
            import subprocess

            def test_starts_an_orphan():
                # a launcher that starts a long-lived process and exits: the process is orphaned
                subprocess.run(["sh", "-c", "sleep 60 & echo $! > {pidfile}"], check=True)
            """
        )
    )
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    assert result.ret == 1
    result.stdout.fnmatch_lines(["*leftover processes*", "*pid *: sleep 60*"])
    pid = int(pidfile.read_text())
    deadline = time.monotonic() + 5
    while Path(f"/proc/{pid}").exists() and time.monotonic() < deadline:
        try:
            if Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z":
                break
        except OSError:
            break
        time.sleep(0.05)
    alive = Path(f"/proc/{pid}").exists() and Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    if alive:  # never leave it running, even when the test fails
        os.kill(pid, 9)
    assert not alive


def test_a_clean_session_passes(pytester):
    pytester.makeconftest(_inner_conftest())
    pytester.makepyfile(test_clean="def test_nothing():\n    assert True\n")
    assert pytester.runpytest_subprocess("-p", "no:cacheprovider").ret == 0
