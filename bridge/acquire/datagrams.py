"""UDP sockets for the nodes' packets, each datagram read with when it arrived: the kernel's own
stamp (Linux: SO_TIMESTAMPNS, CLOCK_REALTIME) mapped onto the host's monotonic clock, so that a
loop that falls behind does not shift arrival times; the socket's count of datagrams its full
buffer dropped (SO_RXQ_OVFL). Used by ``pendsim acquire`` (``receiver``), the twin and the
controller's loop.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import socket
import struct
import sys
import time
from typing import Any

from pendsim_mj.errors import ParameterError
from pendsim_mj.units import NS_PER_S

from ..io.outputs import describe_os_error

RECEIVE_BUFFER_BYTES = 8 << 20
MAX_DATAGRAM = 65535
DRAIN_LIMIT = 4096  # datagrams read from one socket before the loop looks at the others
# Linux: the kernel stamps each datagram as it arrives (SO_TIMESTAMPNS, CLOCK_REALTIME), so a loop
# that falls behind does not shift arrival times; SO_RXQ_OVFL reports datagrams the socket dropped.
SO_TIMESTAMPNS, SO_RXQ_OVFL = 35, 40
ANCILLARY_BYTES = socket.CMSG_SPACE(16) + socket.CMSG_SPACE(4)
TIMESPEC = struct.Struct("@qq")


def listen_udp(address: str, port: int, *, what: str, option: str) -> socket.socket:
    """A non-blocking UDP socket bound to ``address``:``port`` with a large receive buffer and, on
    Linux, the kernel's arrival stamps and drop count on (``read_stamped``).

    Raises:
      ParameterError: the port cannot be bound, in one line naming ``what`` listens there and the
        ``option`` that chooses another port (a port in use: "address already in use").
    """
    family = socket.AF_INET6 if ":" in address else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
        if sys.platform.startswith("linux"):
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
            _wait_for_stamps()  # before the bind: no datagram can come before the stamps are on
        sock.bind((address, port))
        sock.setblocking(False)
    except OSError as exc:
        sock.close()
        cause = (
            f"address already in use (another program listens there); choose another port with {option}"
            if exc.errno == errno.EADDRINUSE
            else describe_os_error(exc)
        )
        raise ParameterError(f"cannot listen on {address}:{port} for {what}: {cause}") from None
    return sock


STAMPS_ON_S = 0.5  # ``listen_udp`` waits at most this long for the kernel to stamp arrivals, s


def _wait_for_stamps(timeout_s: float = STAMPS_ON_S) -> bool:
    """Wait until the kernel stamps datagrams as they arrive (True), at most ``timeout_s``.

    Linux switches arrival stamping on for the whole host when the first socket asks for it, and
    lazily (a deferred work item); a datagram that arrives meanwhile is stamped when it is read
    (the kernel's fill-in for that race), not when it arrived: on a host where no other socket had
    stamps on, the first datagrams after ``listen_udp`` read after a 50 ms wait carried stamps
    50 ms late (measured here), and a stop's drain took them for datagrams that came after the
    stop. So a probe datagram goes to a socket of our own, with stamps on, until it comes back
    stamped before its read began (1.5-1.7 ms on a host where stamps were off, 0.1 ms where on)."""
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        probe.bind(("127.0.0.1", 0))
        probe.settimeout(timeout_s)
        address = probe.getsockname()
        until = time.monotonic() + timeout_s
        while True:
            probe.sendto(b"", address)
            read_ns = time.time_ns()
            _, ancillary, _, _ = probe.recvmsg(1, ANCILLARY_BYTES)
            stamps = [TIMESPEC.unpack_from(v) for _, kind, v in ancillary if kind == SO_TIMESTAMPNS and len(v) >= 16]
            if stamps and stamps[0][0] * NS_PER_S + stamps[0][1] < read_ns:
                return True
            if time.monotonic() >= until:
                return False
            time.sleep(0.001)
    except OSError:  # no loopback, no stamps: the datagrams' arrivals are then when they are read
        return False
    finally:
        probe.close()


@dataclasses.dataclass(frozen=True)
class Stamped:
    """A datagram read from a socket: its bytes, when it arrived (host monotonic ns: the kernel's
    stamp where there is one, else when it was read), its sender, and the socket's count of
    datagrams its full buffer dropped so far (None: not reported)."""

    data: bytes
    arrival_ns: int
    address: Any
    dropped: int | None


CLOCK_PAIR_TRIES = 4  # readings of the two clocks, the tightest kept (``realtime_to_monotonic_ns``)
CLOCK_PAIR_TIGHT_NS = 20_000  # a bracket this narrow is taken at once, ns


def realtime_to_monotonic_ns() -> int:
    """The monotonic clock minus the real-time clock now, ns: the real time read between two
    monotonic readings, the middle of the narrowest of ``CLOCK_PAIR_TRIES`` such brackets (error at
    most half its width). Read once, monotonic then real, a process preempted between the two
    calls (a busy machine; a profiler's pause) got an offset off by the whole pause, and every
    packet of that read an arrival that much early: the clock fit, a lower envelope, follows
    such a point down (a live twin's node instants moved 2.6 ms and their rate 150 ppm)."""
    best_width, best = -1, 0
    for _ in range(CLOCK_PAIR_TRIES):
        before = time.monotonic_ns()
        real = time.time_ns()
        after = time.monotonic_ns()
        width = after - before
        if best_width < 0 or width < best_width:
            best_width, best = width, (before + after) // 2 - real
        if width <= CLOCK_PAIR_TIGHT_NS:
            break
    return best


def read_stamped(sock: socket.socket, limit: int = DRAIN_LIMIT) -> list[Stamped]:
    """What waits on a non-blocking socket (at most ``limit`` datagrams), each with its arrival
    time: the kernel's stamp (SO_TIMESTAMPNS, CLOCK_REALTIME) mapped onto the monotonic clock
    (``realtime_to_monotonic_ns``), so that a loop that falls behind does not shift arrival times."""
    realtime_to_monotonic = realtime_to_monotonic_ns()
    out = []
    for _ in range(limit):
        try:
            data, ancillary, _, address = sock.recvmsg(MAX_DATAGRAM, ANCILLARY_BYTES)
        except (BlockingIOError, InterruptedError):
            break
        except OSError:  # e.g. ICMP errors reported on the socket: nothing to read
            break
        arrival_ns = 0
        dropped = None
        for level, kind, value in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(value) >= 16:
                sec, nsec = TIMESPEC.unpack_from(value)
                arrival_ns = sec * NS_PER_S + nsec + realtime_to_monotonic
            elif level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(value) >= 4:
                dropped = int.from_bytes(value[:4], sys.byteorder)
        out.append(Stamped(data, arrival_ns or time.monotonic_ns(), address, dropped))
    return out


__all__ = ["Stamped", "listen_udp", "read_stamped", "realtime_to_monotonic_ns"]
