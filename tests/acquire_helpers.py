"""Helpers for the end-to-end acquisition tests: free UDP ports on loopback and ``pendsim``
subprocesses whose output is read as it comes."""

from __future__ import annotations

import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

PENDSIM = [sys.executable, "-m", "pendsim_bridge.cli"]
START_TIMEOUT_S = 120.0  # a cold start on a loaded 2-core machine takes seconds


def free_udp_ports(count: int) -> list[int]:
    """Ports free on 127.0.0.1 right now (the OS picks them)."""
    sockets = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(count)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


class Pendsim:
    """A ``pendsim`` subprocess whose stdout and stderr lines are collected by threads."""

    def __init__(self, args: list[str], *, cwd: Path, preexec_fn=None) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.process = subprocess.Popen(
            [*PENDSIM, *args], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
            preexec_fn=preexec_fn,
        )  # fmt: skip
        self.lines: queue.Queue[tuple[str, str]] = queue.Queue()
        self.out: list[str] = []
        self.err: list[str] = []
        for stream, store, name in ((self.process.stdout, self.out, "out"), (self.process.stderr, self.err, "err")):
            threading.Thread(target=self._read, args=(stream, store, name), daemon=True).start()

    def _read(self, stream, store: list[str], name: str) -> None:
        for line in stream:
            store.append(line.rstrip("\n"))
            self.lines.put((name, line))

    def wait_for(self, text: str, timeout_s: float = START_TIMEOUT_S) -> str:
        """Block until a line containing ``text`` appears (fails if the process ends first)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                _, line = self.lines.get(timeout=0.1)
            except queue.Empty:
                if self.process.poll() is not None and self.lines.empty():
                    break
                continue
            if text in line:
                return line
        raise AssertionError(f"no line with {text!r}; stdout {self.out}, stderr {self.err}")

    def finish(self, timeout_s: float = 60.0) -> int:
        code = self.process.wait(timeout=timeout_s)
        time.sleep(0.05)  # let the reader threads take the last lines
        return code

    def signal(self, signum: int = signal.SIGTERM) -> None:
        self.process.send_signal(signum)

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


def process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True
