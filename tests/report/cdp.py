"""A headless Chromium driven over the DevTools protocol on a pipe (no WebSocket library, no
Playwright): just enough to open a page and take screenshots. The browser runs in its own
session; ``close()`` ends its whole process group.

Rerun's web viewer needs WebGL2: here through ANGLE on SwiftShader (software rendering).
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pendsim_bridge.report.serve import stop_group

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_browser() -> str | None:
    """A Chromium executable on PATH (Debian's ``chromium`` first), or None."""
    return next((found for name in CANDIDATES if (found := shutil.which(name))), None)


class CdpError(RuntimeError):
    """The browser failed, closed or answered with an error."""


class Chromium:
    """``with Chromium(exe) as browser: page = browser.open(url); browser.screenshot(page)``."""

    def __init__(self, executable: str, *, width: int = 1600, height: int = 1000) -> None:
        self.profile = tempfile.mkdtemp(prefix="pendsim-chromium-")
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()
        arguments = [
            executable, "--headless=new", "--no-sandbox", "--remote-debugging-pipe", "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", f"--window-size={width},{height}",
            f"--user-data-dir={self.profile}", "--no-first-run", "--no-default-browser-check",
            "--disable-dev-shm-usage", "--disable-extensions", "--mute-audio", "about:blank",
        ]  # fmt: skip
        # the protocol pipe is fd 3 (commands in) and fd 4 (answers out) of the browser
        wrapper = (
            "import os, sys; os.dup2(int(sys.argv[1]), 3); os.dup2(int(sys.argv[2]), 4); "
            "os.execv(sys.argv[3], sys.argv[3:])"
        )
        self.proc = subprocess.Popen(
            [sys.executable, "-c", wrapper, str(to_browser_r), str(from_browser_w), *arguments],
            pass_fds=(to_browser_r, from_browser_w),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._buffer = b""
        self._id = 0

    def __enter__(self) -> Chromium:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def call(self, method: str, params: dict | None = None, *, session: str | None = None, timeout_s: float = 60):
        """Send one command and return its result."""
        self._id += 1
        message: dict = {"id": self._id, "method": method, "params": params or {}}
        if session is not None:
            message["sessionId"] = session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            while b"\0" not in self._buffer:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise CdpError(f"no answer to {method} within {timeout_s} s")
                ready, _, _ = select.select([self._from_browser], [], [], left)
                if ready:
                    chunk = os.read(self._from_browser, 1 << 20)
                    if not chunk:
                        raise CdpError("the browser closed the protocol pipe")
                    self._buffer += chunk
            raw, self._buffer = self._buffer.split(b"\0", 1)
            reply = json.loads(raw)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise CdpError(f"{method}: {reply['error']}")
                return reply.get("result", {})

    def open(self, url: str) -> str:
        """A new page showing ``url``; returns its session id."""
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        self.call("Page.enable", session=session)
        self.call("Page.navigate", {"url": url}, session=session)
        return session

    def screenshot(self, session: str, path: Path) -> Path:
        """The page as PNG."""
        data = self.call("Page.captureScreenshot", {"format": "png"}, session=session, timeout_s=120)["data"]
        path.write_bytes(base64.b64decode(data))
        return path

    def evaluate(self, session: str, expression: str):
        """A JavaScript expression's value."""
        return self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True}, session=session)[
            "result"
        ].get("value")

    def close(self) -> None:
        """End the browser's whole process group and remove its profile."""
        for fd in (self._to_browser, self._from_browser):
            with contextlib.suppress(OSError):
                os.close(fd)
        stop_group(self.proc, timeout_s=10)
        shutil.rmtree(self.profile, ignore_errors=True)
