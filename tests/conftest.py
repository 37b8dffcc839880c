"""Suite-wide check: no process the tests started outlives the suite.

The test process becomes a child subreaper (Linux prctl PR_SET_CHILD_SUBREAPER), so every process
started under it, orphans of launchers included (the ``rerun`` launcher's server, a browser's
helpers), stays its descendant. When the session ends, any descendant still alive fails the run
(it is named, then killed so that it does not spin on after the suite).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

pytest_plugins = ["pytester"]  # test_leftover_processes.py runs an inner session

_PR_SET_CHILD_SUBREAPER = 36
GRACE_S = 3.0
# multiprocessing's resource tracker for the test process itself (started when a test uses a
# process pool or a Dask LocalCluster): the interpreter's own helper, which exits when the test
# process exits (its pipe closes), so it is no leak of pendsim's.
OWN_HELPERS = ("from multiprocessing.resource_tracker import main",)


def _become_subreaper() -> bool:
    if not sys.platform.startswith("linux"):
        return False
    with contextlib.suppress(OSError, AttributeError):
        return ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    return False


def _reap() -> None:
    with contextlib.suppress(ChildProcessError):
        while os.waitpid(-1, os.WNOHANG)[0] > 0:
            pass


def descendants(root: int) -> dict[int, str]:
    """Live (not zombie) descendants of ``root``: pid -> command line (Linux /proc)."""
    children: dict[int, list[int]] = {}
    commands: dict[int, str] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            if fields[0] == "Z":
                continue
            children.setdefault(int(fields[1]), []).append(int(entry.name))
            commands[int(entry.name)] = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError, ValueError):
            continue
    found: dict[int, str] = {}
    stack = list(children.get(root, []))
    while stack:
        pid = stack.pop()
        if pid in commands:
            found[pid] = commands[pid].strip()
            stack.extend(children.get(pid, []))
    return found


def _leftovers() -> dict[int, str]:
    """Descendants of the test process still alive, but for the interpreter's own helpers that are
    its direct children."""
    me = os.getpid()
    return {
        pid: command
        for pid, command in descendants(me).items()
        if not (any(h in command for h in OWN_HELPERS) and _parent(pid) == me)
    }


def _parent(pid: int) -> int:
    with contextlib.suppress(OSError, IndexError, ValueError):
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    return -1


def _sigint_as_by_default() -> None:
    """The suite checks what Ctrl-C does, in this process and in the processes it starts. Started
    from a background job of a non-interactive shell (``nohup pytest &``, some CI runners), this
    process gets SIGINT ignored, and every process it starts inherits that: a served viewer then
    never stops on Ctrl-C (measured: four tests failed, each time, only when the suite was started
    so). So SIGINT gets Python's default handler back here, as in a terminal."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_configure(config: pytest.Config) -> None:
    config._pendsim_subreaper = _become_subreaper()  # type: ignore[attr-defined]
    _sigint_as_by_default()
    if not hasattr(config, "workerinput") and (config.getoption("numprocesses", None) or 0) > 1:
        _warm_kernels()


def _warm_kernels() -> None:
    """The controller of a parallel run compiles the numba kernels first, in two processes at once
    (``warm_kernels.py``), so that its workers and the commands they start load them instead of
    compiling the same ones at the same moment (a cold cache: a fresh clone, as in CI). A part that
    fails says so on stderr; the tests then meet the failure themselves."""
    script = Path(__file__).with_name("warm_kernels.py")
    with tempfile.TemporaryDirectory(prefix="pendsim-warm-") as folder:
        parts = [
            subprocess.Popen([sys.executable, str(script), part, os.path.join(folder, part)])
            for part in ("engine", "measure")
        ]
        for process in parts:
            process.wait()


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    if not getattr(session.config, "_pendsim_subreaper", False):
        return
    deadline = time.monotonic() + GRACE_S
    left = _leftovers()
    while left and time.monotonic() < deadline:
        _reap()
        time.sleep(0.1)
        left = _leftovers()
    _reap()
    if not left:
        return
    for pid in left:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
    time.sleep(0.2)
    _reap()
    lines = "\n".join(f"  pid {pid}: {command[:200]}" for pid, command in sorted(left.items()))
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    message = f"processes started by the tests were still running after the suite (killed now):\n{lines}"
    if reporter is not None:
        reporter.write_sep("=", "leftover processes", red=True)
        reporter.write_line(message)
    else:
        print(message, file=sys.stderr)
    session.exitstatus = pytest.ExitCode.TESTS_FAILED


_WATCHED_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@pytest.fixture(autouse=True)
def _signal_handling_left_as_found():
    """Every test leaves the test process's handlers of SIGINT, SIGTERM and SIGHUP and the main
    thread's signal mask as it found them (else it fails, named, and they are put back). An
    ignored or blocked SIGINT left behind is inherited by every process a later test starts, which
    then cannot be stopped with Ctrl-C: seen once under load as four failures in two files far
    from the cause (a served viewer that did not stop, a deferred Ctrl-C that never came)."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handlers = {s: signal.getsignal(s) for s in _WATCHED_SIGNALS}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    yield
    changed = [f"{signal.Signals(s).name} handler {h!r} -> {signal.getsignal(s)!r}" for s, h in handlers.items()
               if signal.getsignal(s) != h]  # fmt: skip
    now = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    if now != mask:
        changed.append(f"signal mask {sorted(mask)} -> {sorted(now)}")
    if changed:
        for s, h in handlers.items():
            signal.signal(s, h)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        pytest.fail("the test left signal handling changed: " + "; ".join(changed))
