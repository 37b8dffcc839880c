"""Show an .rrd file: Rerun's web viewer served to a browser, or the desktop viewer.

Both run Rerun's own binary (the one the rerun-sdk wheel ships in ``rerun_cli``; the ``rerun``
script beside this Python is only a launcher that would start the binary as a grandchild, out of
reach). The served viewer belongs to pendsim:

- it runs in a new session, so it is the leader of its own process group, and every exit path
  (Ctrl-C, SIGTERM, SIGHUP, an exception) ends the whole group: SIGTERM, then SIGKILL after
  ``STOP_TIMEOUT_S``; on Linux it also gets SIGTERM if pendsim itself is killed (PR_SET_PDEATHSIG);
- "serving on URL" is printed only once both ports (the web viewer's and the gRPC data port, the
  next one) are listening, owned by that process group; a port in use, an address that is not this
  machine's, or a server that stops during startup is a ``ProcessError`` (one line, exit 2);
- the URL printed opens the recording (``?url=rerun+http://HOST:GRPC/proxy``): the bare web port
  shows Rerun's welcome page only.

The desktop viewer (``spawn_viewer``) is the user's window: it is started detached and outlives
pendsim, and its data port listens on loopback only.
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import errno
import importlib.util
import ipaddress
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO

from ..errors import ProcessError
from ..signals import signal_handlers

STARTUP_TIMEOUT_S = 30.0
"""How long the served viewer may take to listen on both ports (it takes about 1 s)."""
STOP_TIMEOUT_S = 5.0
"""How long the viewer's process group gets to end after SIGTERM before SIGKILL."""
SPAWN_CHECK_S = 2.0
"""How long ``spawn_viewer`` watches the desktop viewer for an immediate failure."""
LOOPBACK = "127.0.0.1"
_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
_PR_SET_PDEATHSIG = 1


def rerun_command() -> list[str]:
    """The Rerun binary shipped with rerun-sdk (``rerun_cli/rerun``), else the ``rerun`` launcher
    beside this Python."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        binary = Path(spec.origin).with_name("rerun")
        if binary.is_file() and os.access(binary, os.X_OK):
            return [str(binary)]
    return [str(Path(sys.executable).with_name("rerun"))]


def is_loopback(bind: str) -> bool:
    """True if ``bind`` is a loopback address (reachable from this machine only)."""
    return ipaddress.ip_address(bind).is_loopback


def url_host(bind: str) -> str:
    """The host to put in a URL for a server bound to ``bind`` (loopback for the wildcards)."""
    address = ipaddress.ip_address(bind)
    if address.is_unspecified:
        return LOOPBACK if address.version == 4 else "[::1]"
    return f"[{address}]" if address.version == 6 else str(address)


def viewer_url(bind: str, web_port: int, grpc_port: int) -> str:
    """The web viewer's URL that opens the served recording (not Rerun's welcome page)."""
    host = url_host(bind)
    return f"http://{host}:{web_port}/?url=rerun%2Bhttp://{host}:{grpc_port}/proxy"


def live_grpc_url(bind: str, web_port: int) -> str:
    """Where the SDK's gRPC sink streams into a live server (``start_live_server``) bound to
    ``bind`` on ``web_port``: its proxy on ``web_port + 1``."""
    return f"rerun+http://{url_host(bind)}:{web_port + 1}/proxy"


def check_port_free(bind: str, port: int) -> None:
    """Bind ``(bind, port)`` briefly, as the server will; raise ProcessError if that fails."""
    address = ipaddress.ip_address(bind)
    family = socket.AF_INET6 if address.version == 6 else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as Rust's TcpListener does
        try:
            probe.bind((bind, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise ProcessError(
                    f"port {port} on {bind} is in use (another server?); choose another with --port "
                    "(the web viewer uses PORT, the data port PORT + 1)"
                ) from None
            if exc.errno == errno.EADDRNOTAVAIL:
                raise ProcessError(f"--bind {bind} is not an address of this machine") from None
            reason = os.strerror(exc.errno) if exc.errno else str(exc)
            raise ProcessError(f"cannot listen on {bind} port {port}: {reason}") from None


def _socket_inodes_of_group(pgid: int) -> set[int]:
    """Inodes of the sockets the processes of group ``pgid`` hold open (Linux /proc)."""
    inodes: set[int] = set()
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            if os.getpgid(int(entry.name)) != pgid:
                continue
            for fd in os.scandir(f"/proc/{entry.name}/fd"):
                target = os.readlink(fd.path)
                if target.startswith("socket:["):
                    inodes.add(int(target[8:-1]))
        except (OSError, ValueError):
            continue
    return inodes


def _listening_inodes(port: int) -> set[int]:
    """Inodes of TCP sockets listening on ``port`` (IPv4 and IPv6, Linux /proc/net)."""
    found: set[int] = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with contextlib.suppress(OSError):
            for line in Path(table).read_text().splitlines()[1:]:
                fields = line.split()
                if len(fields) > 9 and fields[3] == "0A" and int(fields[1].rsplit(":", 1)[1], 16) == port:
                    found.add(int(fields[9]))
    return found


def listening_here(port: int) -> bool:
    """True if this process holds a socket listening on TCP ``port`` (Linux /proc; elsewhere False)."""
    if not Path("/proc/net/tcp").exists():
        return False
    own: set[int] = set()
    with contextlib.suppress(OSError):
        for fd in os.scandir("/proc/self/fd"):
            with contextlib.suppress(OSError):
                target = os.readlink(fd.path)
                if target.startswith("socket:["):
                    own.add(int(target[8:-1]))
    return bool(_listening_inodes(port) & own)


def listening(pgid: int, ports: tuple[int, ...], bind: str) -> bool:
    """True if every port is listening, held by process group ``pgid`` where Linux's /proc tells
    (else: accepts a connection)."""
    if Path("/proc/net/tcp").exists():
        owned = _socket_inodes_of_group(pgid)
        return all(_listening_inodes(port) & owned for port in ports)
    host = url_host(bind).strip("[]")
    for port in ports:
        try:
            socket.create_connection((host, port), timeout=0.5).close()
        except OSError:
            return False
    return True


def _libc_prctl() -> Callable[..., int] | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl: Callable[..., int] = ctypes.CDLL(None, use_errno=True).prctl
        return prctl
    except (OSError, AttributeError):
        return None


_prctl = _libc_prctl()


def die_with_parent(parent_pid: int) -> Callable[[], None] | None:
    """A preexec function: the child gets SIGTERM when pendsim ends, even by SIGKILL."""
    if _prctl is None:
        return None
    prctl = _prctl

    def preexec() -> None:
        prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent_pid:  # pendsim ended before the line above
            os._exit(1)

    return preexec


def _last_line(log: IO[bytes]) -> str:
    """The most telling line of a child's output: the last error, else the last line."""
    log.seek(0)
    lines = [_ANSI.sub("", raw).strip() for raw in log.read().decode("utf-8", "replace").splitlines()]
    lines = [line for line in lines if line and not line.startswith(("Troubleshooting", "Report bugs", "For more"))]
    errors = [line for line in lines if re.search(r"\b(error|ERROR|WARN|panicked)\b", line)]
    chosen = (errors or lines or ["(no output)"])[-1]
    return " ".join(chosen.split())[:300]


class Stopped(BaseException):
    """SIGTERM or SIGHUP arrived (raised in the main thread, like KeyboardInterrupt for SIGINT)."""


@contextlib.contextmanager
def _signals_stop() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise ``Stopped`` (main thread only)."""
    installer = os.getpid()

    def raise_stopped(signum: int, frame: object) -> None:
        if os.getpid() != installer:  # a forked worker (multiprocessing): end as by default
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        raise Stopped(signal.Signals(signum).name)

    with signal_handlers(dict.fromkeys((signal.SIGTERM, signal.SIGHUP), raise_stopped)):
        yield


@contextlib.contextmanager
def _signals_wait() -> Iterator[None]:
    """Within the block, SIGINT, SIGTERM and SIGHUP wait (so that stopping is never cut short);
    the first one is delivered when it ends. (Ignoring them instead would lose a Ctrl-C, and an
    ignored SIGINT left behind is inherited by every process started later.)"""
    noted: list[int] = []

    def note(signum: int, frame: object) -> None:
        noted.append(signum)

    try:
        with signal_handlers(dict.fromkeys((signal.SIGINT, signal.SIGTERM, signal.SIGHUP), note)):
            yield
    finally:
        if noted:
            signal.raise_signal(noted[0])


def stop_group(proc: subprocess.Popen[bytes], *, timeout_s: float = STOP_TIMEOUT_S) -> None:
    """End ``proc``'s process group (``proc`` leads it): SIGTERM, then SIGKILL after ``timeout_s``;
    reap ``proc``. The leader is reaped only after the last signal to the group, so the group id
    cannot have been reused."""
    pgid = proc.pid
    with _signals_wait():
        with contextlib.suppress(ProcessLookupError):
            os.killpg(pgid, signal.SIGTERM)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with contextlib.suppress(ChildProcessError):
                info = os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
                if info is not None:
                    break
            time.sleep(0.02)
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pgid, signal.SIGKILL)  # any member left (the launcher's child, a straggler)
        proc.wait()


@dataclasses.dataclass(frozen=True)
class Served:
    """A served viewer, ready: its URL and process group."""

    url: str
    pgid: int


@contextlib.contextmanager
def served_viewer(
    rrd: str | Path,
    *,
    bind: str = LOOPBACK,
    port: int = 9090,
    startup_timeout_s: float = STARTUP_TIMEOUT_S,
) -> Iterator[tuple[Served, subprocess.Popen[bytes]]]:
    """Start Rerun's web viewer on ``rrd`` and yield once it listens; end it on leaving the block,
    however the block is left.

    Args:
      rrd: the .rrd file (passed as an absolute path: a name like ``-x.rrd`` is no option).
      bind: the IP address to listen on.
      port: the web viewer's port; the gRPC data port is ``port + 1``.
      startup_timeout_s: how long to wait for both ports.

    Raises:
      ProcessError: a bad address or port, a port in use, or the server stopped or did not listen
        during startup (with its last message).
    """
    try:
        ipaddress.ip_address(bind)
    except ValueError:
        raise ProcessError(f"--bind must be an IP address such as {LOOPBACK}, got {bind!r}") from None
    if not 1 <= port <= 65534:
        raise ProcessError(f"--port must be in [1, 65534] (the data port is PORT + 1), got {port}")
    path = Path(rrd).resolve()
    if not path.is_file():
        raise ProcessError(f"cannot serve {str(rrd)!r}: no such file")
    ports = (port, port + 1)
    for p in ports:
        check_port_free(bind, p)
    # The server starts empty and the file is sent into it (``_send_file``): given the file on its
    # command line, Rerun 0.41's server keeps a thread spinning at full CPU for as long as it runs.
    command = [
        *rerun_command(), "--serve-web", "--bind", bind, "--web-viewer-port", str(port), "--port", str(port + 1),
        "--server-memory-limit", server_memory_limit(path),
    ]  # fmt: skip
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(
            command,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its own process group, out of the terminal's Ctrl-C
            preexec_fn=die_with_parent(os.getpid()),  # prctl only: safe with threads
        )
        try:
            deadline = time.monotonic() + startup_timeout_s
            while not listening(proc.pid, ports, bind):
                if proc.poll() is not None:
                    raise ProcessError(f"the Rerun server stopped during startup: {_last_line(log)}")
                if time.monotonic() > deadline:
                    raise ProcessError(
                        f"the Rerun server did not listen on ports {port} and {port + 1} within "
                        f"{startup_timeout_s:g} s: {_last_line(log)}"
                    )
                time.sleep(0.1)
            _send_file(path, f"rerun+http://{url_host(bind)}:{port + 1}/proxy", log)
            if proc.poll() is not None:
                raise ProcessError(f"the Rerun server stopped during startup: {_last_line(log)}")
            yield Served(viewer_url(bind, port, port + 1), proc.pid), proc
            if proc.poll() is not None:
                raise ProcessError(f"the Rerun server stopped: {_last_line(log)}")
        finally:
            stop_group(proc)


def start_live_server(bind: str, port: int) -> subprocess.Popen[bytes]:
    """Rerun's web viewer with no file, for a live view that streams into it (the SDK's gRPC sink
    on ``port + 1``): in its own process group (end it with ``stop_group``; it also ends if pendsim
    is killed); returns once both ports listen, owned by that group.

    Raises:
      ProcessError: a port in use, an address not of this machine, or a server that did not start.
    """
    ports = (port, port + 1)
    for p in ports:
        check_port_free(bind, p)
    command = [
        *rerun_command(), "--serve-web", "--bind", bind, "--web-viewer-port", str(port), "--port", str(port + 1),
    ]  # fmt: skip
    server = subprocess.Popen(
        command,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        preexec_fn=die_with_parent(os.getpid()),
    )
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while not listening(server.pid, ports, bind):
        if server.poll() is not None or time.monotonic() > deadline:
            stop_group(server)
            raise ProcessError(f"the Rerun web viewer did not start on {bind} ports {port} and {port + 1}")
        time.sleep(0.1)
    return server


SEND_TIMEOUT_S = 300.0
"""How long sending the file into the served viewer may take."""


def server_memory_limit(rrd: Path) -> str:
    """The served viewer's buffer (``--server-memory-limit``): it keeps everything sent to it for
    the viewers that connect later, so it gets four times the file (decoded chunks take more
    room than the file's), at least Rerun's default 1 GiB."""
    return f"{max(1024, 4 * (rrd.stat().st_size >> 20))}MiB"


def _send_file(rrd: Path, url: str, log: IO[bytes]) -> None:
    """Send an .rrd file into the server at ``url`` (a recording stream of this process, with the
    file's own recording and blueprint, disconnected once everything is sent).

    Raises:
      ProcessError: the file could not be sent within SEND_TIMEOUT_S.
    """
    import rerun as rr  # start-up: Rerun, only when a file is sent

    stream = rr.RecordingStream("pendsim_serve", recording_id=uuid.uuid4())
    try:
        stream.connect_grpc(url)
        rr.log_file_from_path(rrd, recording=stream)
        stream.flush(timeout_sec=SEND_TIMEOUT_S)
    except Exception as exc:  # a timeout or a severed connection (the server's own line says why)
        raise ProcessError(f"cannot send {str(rrd)!r} to the Rerun server: {exc}; {_last_line(log)}") from None
    finally:
        stream.disconnect()


def _say(line: str) -> None:
    print(line, flush=True)


def _warn(line: str) -> None:
    print(f"pendsim: warning: {line}", file=sys.stderr, flush=True)


def serve_web(
    rrd: str | Path,
    *,
    bind: str = LOOPBACK,
    port: int = 9090,
    say: Callable[[str], None] = _say,
    warn: Callable[[str], None] = _warn,
    startup_timeout_s: float = STARTUP_TIMEOUT_S,
) -> str:
    """Serve a file to a web browser until Ctrl-C, SIGTERM or SIGHUP; the server ends with it.

    Prints (``say``) "serving FILE on URL" once the server listens. Returns how it was stopped
    ("SIGINT", "SIGTERM", "SIGHUP").

    Raises:
      ProcessError: see ``served_viewer``; also if the server stops by itself.
    """
    if not is_loopback(bind):
        warn(
            f"--bind {bind} serves the recording to other machines on the network, without a password; "
            f"--bind {LOOPBACK} keeps it on this machine"
        )
    try:
        with (
            _signals_stop(),
            served_viewer(rrd, bind=bind, port=port, startup_timeout_s=startup_timeout_s) as (
                served,
                proc,
            ),
        ):
            say(f"serving {rrd} on {served.url} (Ctrl-C stops)")
            proc.wait()
    except KeyboardInterrupt:
        return "SIGINT"
    except Stopped as stop:
        return str(stop)
    raise ProcessError("the Rerun server stopped by itself")


def spawn_viewer(
    rrd: str | Path, *, port: int | None = None, check_s: float = SPAWN_CHECK_S
) -> subprocess.Popen[bytes]:
    """Open the desktop viewer on a file, its data port on loopback only. It is the user's window:
    detached (its own session), it runs on after pendsim exits.

    Raises:
      ProcessError: the viewer stopped within ``check_s`` with an error (no display, ...).
    """
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(
            viewer_command(rrd, port=port),
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            code = proc.wait(timeout=check_s)
        except subprocess.TimeoutExpired:
            return proc  # running: the user's window now
        if code != 0:
            raise ProcessError(f"the Rerun viewer did not start: {_last_line(log)}")
    return proc


def viewer_command(rrd: str | Path, *, port: int | None = None) -> list[str]:
    """The desktop viewer's command line: loopback only, the file as an absolute path."""
    extra = ["--port", str(port)] if port is not None else []
    return [*rerun_command(), "--bind", LOOPBACK, *extra, str(Path(rrd).resolve())]
