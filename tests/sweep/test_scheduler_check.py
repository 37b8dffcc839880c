"""``sweep --scheduler`` at an address that is not a Dask scheduler: one line, exit 2, nothing
written, within the check's few seconds. Real sockets on loopback: a silent TCP listener, one that
greets like another protocol (SSH), one that closes at once, an HTTP server (as the dashboard's
port is), and a real Dask scheduler and worker (in this process, over TCP).

Before the check, the HTTP server gave a 40-line traceback ("Unable to allocate 3.07 EiB") and a
silent listener hung without output."""

from __future__ import annotations

import contextlib
import http.server
import logging
import socket
import threading
import time

import pytest

from pendsim_bridge.cli import main
from pendsim_bridge.run.sweep import check_scheduler
from pendsim_mj.errors import ParameterError

HANG_BOUND_S = 30.0  # the check gives up after 5 s; this only catches a hang


@pytest.fixture
def listener():
    """A loopback TCP listener that treats each connection as ``behaviour`` says."""
    servers = []

    def start(behaviour: str) -> str:
        srv = socket.socket()
        srv.bind(("127.0.0.1", 0))
        srv.listen()
        servers.append(srv)

        def serve() -> None:
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            with conn:
                if behaviour == "ssh":
                    conn.sendall(b"SSH-2.0-OpenSSH_9.6\r\n")
                if behaviour != "close":
                    conn.settimeout(HANG_BOUND_S)
                    with contextlib.suppress(OSError):
                        conn.recv(1 << 16)  # until the client gives up

        threading.Thread(target=serve, daemon=True).start()
        return f"tcp://127.0.0.1:{srv.getsockname()[1]}"

    yield start
    for srv in servers:
        srv.close()


@pytest.fixture
def web_server():
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"tcp://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def _sweep(address: str, tmp_path, capsys) -> tuple[str, float]:
    start = time.monotonic()
    code = main(["sweep", "--vary", "phi1_deg=10:20:2", "--duration-s", "1", "--scheduler", address,
                 "-o", str(tmp_path / "out")])  # fmt: skip
    took = time.monotonic() - start
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("pendsim: error: "), captured.err
    assert list(tmp_path.iterdir()) == []
    return lines[0], took


@pytest.mark.parametrize(
    ("behaviour", "message"),
    [
        ("silent", "is not a Dask scheduler: it sent no Dask handshake within 5 s"),
        ("ssh", "is not a Dask scheduler: it answered b'SSH-2.0-'..., not a Dask handshake"),
        ("close", "is not a Dask scheduler: the connection failed"),
    ],
)
def test_a_tcp_listener_that_is_not_dask_is_one_line(listener, tmp_path, capsys, behaviour, message):
    line, took = _sweep(listener(behaviour), tmp_path, capsys)
    assert message in line, line
    assert took < HANG_BOUND_S


def test_a_web_server_such_as_the_dashboard_is_one_line(web_server, tmp_path, capsys):
    line, took = _sweep(web_server, tmp_path, capsys)
    assert f"'{web_server}' is not a Dask scheduler: it sent no Dask handshake" in line, line
    assert "give the scheduler's port" in line
    assert took < HANG_BOUND_S


def test_a_malformed_address_is_named():
    for bad in ("127.0.0.1:8786", "tcp://127.0.0.1", "tcp://127.0.0.1:99999", "tcp://:8786"):
        with pytest.raises(ParameterError, match="scheduler must be tcp://HOST:PORT"):
            check_scheduler(bad)


def test_a_real_scheduler_passes_and_its_worker_is_named_as_one():
    from dask.distributed import LocalCluster

    with LocalCluster(
        n_workers=1,
        threads_per_worker=1,
        processes=False,
        protocol="tcp",
        host="127.0.0.1",
        dashboard_address=None,
        silence_logs=logging.ERROR,
    ) as cluster:
        check_scheduler(cluster.scheduler_address)
        worker = next(iter(cluster.workers.values())).address
        with pytest.raises(ParameterError, match="is not a Dask scheduler: it is a Dask Worker"):
            check_scheduler(worker)
