"""``pendsim acquire``: receive both nodes' UDP packets and write them as a pendsim recording.

One socket per node (bound to 127.0.0.1 unless told otherwise), one loop:

1. every datagram is stamped with the host's monotonic clock as it is read and decoded by the
   node's codec (``packets``: every field range-checked); the node's timeline (``timeline``)
   feeds its clock fit (``clock.ClockFit``) with the packets that agree with their neighbours and
   refuses those that do not fit the established timeline; the rest are accounted
   (``accounting.NodeStream``);
2. every 50 ms, each node's samples whose turn has come (in sequence order, within the reorder
   window) get their log time, the device time mapped to host time by the current fit, on one
   UTC base for both nodes, and go to the file (``sink``) and the live view;
3. every second: a ``/diagnostics`` message and the status line; at least every half second the
   samples every node has passed are written and handed to the OS.

The first samples of a node wait until its clock fit spans ``WARMUP_S``. Stops after
``duration_s``, on SIGINT or SIGTERM: what arrived before the stop and still waits in the OS is
read, everything still waiting is written, then the summary. The
file is written under a temporary name beside the output and published when closed; if writing
fails (full disk, ...) or the process is killed, that temporary file stays for ``pendsim recover``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import ipaddress
import json
import math
import selectors
import shutil
import signal
import socket
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from pendsim_mj import __version__
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import SAMPLE_RATE_HZ
from pendsim_mj.units import nanoseconds, seconds

from ..errors import OutputError
from ..io import ros2
from ..io.outputs import describe_os_error, publish, replace_hint, temporary_sibling
from ..signals import signal_handlers
from .accounting import NodeCounters, NodeStream
from .clock import MAX_DRIFT_PPM, ClockFit, ClockRelation, jitter_summary_ms, residuals_s
from .datagrams import listen_udp, read_stamped
from .packets import PacketError, StreamFormat
from .ports import BNO055_NDOF, DEFAULT_NODES, NodeSpec, check_nodes
from .sink import RecordingSink
from .timeline import Timeline

TICK_S = 0.05  # release and live-view cadence
FLUSH_S = 0.5  # write to the file at least this often
DIAGNOSTICS_S = 1.0  # /diagnostics and the status line
WARMUP_S = 0.5  # device time a node's clock fit spans before its first samples are released
STAMP_REANCHOR_S = 1.0  # a header stamp further than this from its log time starts a new stamp origin
STALE_S = 2.0  # a node silent this long no longer holds back the writing of the others
STOP_DRAIN_S = 2.0  # at the stop, datagrams already received are read for at most this long


@dataclasses.dataclass(frozen=True)
class AcquireSpec:
    """What to acquire and how.

    Attributes:
      nodes: the nodes and their ports.
      bind: the address the sockets listen on (127.0.0.1: this machine only).
      stream: the packet format.
      rate_hz: the nodes' nominal sample rate (numbers the samples of formats without sequence
        numbers; recorded in the metadata).
      duration_s: stop after this long (None: on Ctrl-C or SIGTERM).
      reorder_window_s: how long a sample waits for missing earlier ones, s.
      params: the rig (metadata, the mounts; the MJCF if ``mjcf_xml`` is None).
      mjcf_xml: the MJCF to attach (None: the model built from ``params``).
      mjcf_source: where ``mjcf_xml`` came from, for the metadata.
      compression: chunk compression.
    """

    nodes: tuple[NodeSpec, ...] = DEFAULT_NODES
    bind: str = "127.0.0.1"
    stream: StreamFormat = dataclasses.field(default_factory=StreamFormat)
    rate_hz: float = SAMPLE_RATE_HZ
    duration_s: float | None = None
    reorder_window_s: float = 0.2
    params: RigParams = DEFAULT_PARAMS
    mjcf_xml: str | None = None
    mjcf_source: str = "built by pendsim from the rig parameters"
    compression: str = "zstd"

    def __post_init__(self) -> None:
        check_nodes(self.nodes)
        if not (math.isfinite(self.rate_hz) and 0 < self.rate_hz <= 100_000):
            raise ParameterError(f"rate_hz must be in (0, 100000] Hz, got {self.rate_hz!r}")
        if self.duration_s is not None and not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ParameterError(f"duration_s must be a finite number > 0 s, got {self.duration_s!r}")
        if not (math.isfinite(self.reorder_window_s) and 0 <= self.reorder_window_s <= 10):
            raise ParameterError(f"reorder window must be in [0, 10] s, got {self.reorder_window_s!r}")


@dataclasses.dataclass(frozen=True)
class NodeResult:
    """What one node delivered: counters, its clock against the host's, the residual jitter."""

    name: str
    port: int
    counters: NodeCounters
    drift_ppm: float  # the node clock's rate error against the host's (+: fast); NaN if unknown
    jitter_p50_ms: float  # residual delay beyond the fitted minimum: median
    jitter_p99_ms: float  # and 99th percentile
    host_dropped: int = 0  # datagrams this host's socket buffer dropped (counted in lost as well)
    stamp_clock: ClockRelation | None = None  # the final fit from header stamp to log time (s since the start)


@dataclasses.dataclass(frozen=True)
class AcquireResult:
    """A finished acquisition."""

    path: Path
    duration_s: float
    stop_reason: str  # "duration", "interrupted" (SIGINT) or "terminated" (SIGTERM)
    nodes: tuple[NodeResult, ...]
    messages: int
    size_bytes: int
    live_batches: int


class LiveSink(Protocol):
    """The live view's side of the loop (``live.LiveView``)."""

    batches: int

    def add(self, node: str, t_ns: NDArray[np.int64], rows: NDArray[np.float64]) -> None: ...

    def send(self) -> None: ...

    def close(self) -> None: ...


class _Node:
    """The state of one node in the loop."""

    def __init__(self, spec: NodeSpec, stream: StreamFormat, rate_hz: float, window_ns: int) -> None:
        self.spec = spec
        self.codec = stream.codec(spec.name, spec.node_id)
        self.stream = NodeStream(window_ns=window_ns, seq_modulus=self.codec.seq_modulus, rate_hz=rate_hz)
        self.timeline = Timeline(rate_hz=rate_hz, has_seq=self.codec.has_seq, seq_modulus=self.codec.seq_modulus)
        self.device_s: list[float] = []  # accepted packets: device time and arrival (s since start)
        self.arrival_s: list[float] = []
        self.last_read_ns = 0  # when the loop last read one (a loop behind its sockets reads old datagrams)
        self.last_sample_ns = 0  # when it last read a packet that was accepted (malformed ones hold nothing back)
        self.last_log_ns = -1  # latest log time released
        self.stamp_anchor: tuple[int, int] | None = None  # (device time us, header stamp ns) of the stamps' origin
        self.last_stamp_ns = -1  # latest header stamp released
        self.stamp_origins = 0  # how many origins the stamps had (more than one: the node restarted)
        self.sock: socket.socket | None = None
        self.previous = NodeCounters()
        self.host_dropped = 0  # datagrams this host's socket dropped (its buffer was full)

    @property
    def clock(self) -> ClockFit:
        """The node's clock fit (the timeline's: fed with the packets that fit it)."""
        return self.timeline.clock

    def receive(self, data: bytes, arrival_ns: int, start_ns: int) -> bool:
        """Decode one datagram and hand it to the timeline; True if a sample was accepted since
        (the timeline decides a packet once its neighbours have arrived)."""
        try:
            packet = self.codec.decode(data)
        except PacketError as exc:
            self.stream.count_malformed(exc.reason)
            return False
        self.timeline.add(packet, arrival_ns, seconds(arrival_ns - start_ns))
        return self.settle(arrival_ns, start_ns)

    def settle(self, now_ns: int, start_ns: int, *, final: bool = False) -> bool:
        """Account the packets the timeline has decided; True if a sample was accepted."""
        accepted = False
        for decision in self.timeline.decide(seconds(now_ns - start_ns), final=final):
            if decision.reason is not None:
                self.stream.count_implausible(decision.reason)
            elif self.stream.offer(decision.packet, decision.arrival_ns) == "accepted":
                self.device_s.append(decision.packet.device_time_us * 1e-6)
                self.arrival_s.append(seconds(decision.arrival_ns - start_ns))
                accepted = True
        return accepted

    def line(self) -> ClockRelation | None:
        return self.clock.relation() if self.clock.count else None

    def jitter_ms(self, since: int = 0) -> tuple[float, float]:
        line = self.line()
        if line is None:
            return math.nan, math.nan
        return jitter_summary_ms(
            residuals_s(line, np.asarray(self.device_s[since:]), np.asarray(self.arrival_s[since:]))
        )


def _bind(spec: NodeSpec, address: str) -> socket.socket:
    return listen_udp(address, spec.port, what=f"node {spec.name}", option="--node")


def _is_loopback(address: str) -> bool:
    try:
        return ipaddress.ip_address(address).is_loopback
    except ValueError:
        return False


@contextlib.contextmanager
def stop_signals() -> Iterator[list[str]]:
    """SIGINT and SIGTERM set a flag (the loop ends cleanly) instead of raising; restored after."""
    reason: list[str] = []
    names = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated"}

    def handler(signum: int, frame: object) -> None:
        reason.append(names[signal.Signals(signum)])

    with signal_handlers(dict.fromkeys(names, handler)):
        yield reason


def _utc_iso(t_ns: int) -> str:
    return datetime.datetime.fromtimestamp(seconds(t_ns), tz=datetime.UTC).isoformat(timespec="microseconds")


def acquisition_metadata(spec: AcquireSpec, start_utc_ns: int) -> dict[str, dict[str, str]]:
    """The metadata records saying how the data were acquired."""
    nodes = {n.name: {"port": n.port, "node_id": n.node_id} for n in spec.nodes}
    return {
        "pendsim/acquisition": {
            "source": "udp",
            "nodes": json.dumps(nodes),
            "bind": spec.bind,
            **spec.stream.describe(),
            "rate_hz": repr(spec.rate_hz),
            "reorder_window_s": repr(spec.reorder_window_s),
            "start_utc": _utc_iso(start_utc_ns),
            "start_time_ns": str(start_utc_ns),
            "host": socket.gethostname(),
            "pendsim_version": __version__,
            "mjcf": spec.mjcf_source,
            "time_base": "log time = device time mapped to host UTC by a lower-envelope fit (docs/acquisition.md)",
        },
        # Read by validate and allan: the nominal rate, and the rig's nodes are BNO055s in NDOF mode,
        # fused at 100 Hz (validate finds where each chip's fusion ticks fall from the data).
        "pendsim/imu": {"sample_rate_hz": json.dumps(spec.rate_hz), **BNO055_NDOF},
    }


def say_on_stderr(line: str) -> None:  # the live loops' default ``say``
    print(line, file=sys.stderr, flush=True)


class StatusLine:
    """The live status line on stderr: rewritten in place on a terminal, every 10 s otherwise."""

    def __init__(self, write: Callable[[str], None] | None) -> None:
        self.tty = write is None and sys.stderr.isatty()
        self.write = write or say_on_stderr
        self.last_plain = 0.0
        self.shown = False

    def show(self, text: str, elapsed_s: float) -> None:
        if self.tty:  # one line in place: cut to the terminal's width
            width = shutil.get_terminal_size((120, 24)).columns - 1
            sys.stderr.write("\r\x1b[2K" + text[:width])
            sys.stderr.flush()
            self.shown = True
        elif elapsed_s - self.last_plain >= 10.0:
            self.last_plain = elapsed_s
            self.write(text)

    def say(self, text: str) -> None:  # a line of its own (an event), below the status line
        self.end()
        self.write(text)

    def end(self) -> None:
        """End the line in place (idempotent)."""
        if self.tty and self.shown:
            self.shown = False
            sys.stderr.write("\n")
            sys.stderr.flush()


def acquire(
    spec: AcquireSpec,
    output: str | Path,
    *,
    replace: bool = False,
    live: LiveSink | None = None,
    say: Callable[[str], None] = say_on_stderr,
    status: Callable[[str], None] | None = None,
) -> AcquireResult:
    """Receive the nodes' packets and write the recording to ``output``.

    Args:
      spec: nodes, format, duration, rig.
      output: the .mcap file (published when complete; until then a temporary file beside it).
      replace: replace an existing output.
      live: a live view fed in batches.
      say: where the startup lines go (stderr).
      status: where the status line goes (default: stderr, in place on a terminal).

    Raises:
      ParameterError: a port cannot be bound (nothing is written).
      OutputError: the output exists, or writing failed; in the latter case the message names
        the temporary file that holds what was written (``pendsim recover`` reads it).
    """
    output = Path(output)
    if not replace and (output.exists() or output.is_symlink()):
        raise OutputError(f"output {str(output)!r} exists; choose another name or pass {replace_hint()} to replace it")
    window_ns = nanoseconds(spec.reorder_window_s)
    nodes = [_Node(n, spec.stream, spec.rate_hz, window_ns) for n in spec.nodes]
    selector = selectors.DefaultSelector()
    try:
        for node in nodes:
            node.sock = _bind(node.spec, spec.bind)
            selector.register(node.sock, selectors.EVENT_READ, node)
        try:
            partial = temporary_sibling(output)
        except OSError as exc:
            raise OutputError(f"cannot write {str(output)!r}: {describe_os_error(exc)}") from None
        return _run(spec, output, partial, nodes, selector, replace=replace, live=live, say=say, status=status)
    finally:
        for node in nodes:
            if node.sock is not None:
                node.sock.close()
        selector.close()


def _run(
    spec: AcquireSpec,
    output: Path,
    partial: Path,
    nodes: list[_Node],
    selector: selectors.BaseSelector,
    *,
    replace: bool,
    live: LiveSink | None,
    say: Callable[[str], None],
    status: Callable[[str], None] | None,
) -> AcquireResult:
    from pendsim_mj.rig.model import exact_mjcf  # start-up: MuJoCo, once the acquisition runs

    start_ns = time.monotonic_ns()
    utc_ns = time.time_ns() - start_ns  # host monotonic -> UTC, fixed for the run
    start_utc_ns = start_ns + utc_ns
    mjcf = spec.mjcf_xml if spec.mjcf_xml is not None else exact_mjcf(spec.params)
    try:
        sink = RecordingSink(
            partial,
            nodes=tuple(n.spec.name for n in nodes),
            groups=spec.stream.groups(),
            params=spec.params,
            mjcf_xml=mjcf,
            metadata=acquisition_metadata(spec, start_utc_ns),
            start_time_ns=start_utc_ns,
            diagnostics=True,
            compression=spec.compression,
        )
    except OutputError:
        partial.unlink(missing_ok=True)
        raise
    listening = ", ".join(f"{n.spec.name} on {spec.bind}:{n.spec.port}" for n in nodes)
    say(f"listening: {listening} ({spec.stream.format}); writing {partial} until done, then {output}")
    if not _is_loopback(spec.bind):
        say(f"note: bound to {spec.bind}: these ports are reachable from the network")
    listen_ns = time.monotonic_ns()  # a node not heard from yet is waited for from here (not from the set-up)
    status_line = StatusLine(status)
    deadline = start_ns + nanoseconds(spec.duration_s) if spec.duration_s is not None else None
    next_tick = start_ns
    next_flush = start_ns + nanoseconds(FLUSH_S)
    next_diag = start_ns + nanoseconds(DIAGNOSTICS_S)
    diag_marks = [0] * len(nodes)
    stop_reason = "duration"
    try:
        with stop_signals() as stop:
            while True:
                now = time.monotonic_ns()
                if stop:
                    stop_reason = stop[0]
                    break
                if deadline is not None and now >= deadline:
                    break
                wake = min(next_tick, deadline) if deadline is not None else next_tick
                for key, _ in selector.select(max(0.0, seconds(wake - now))):
                    _drain(key.data, start_ns)
                now = time.monotonic_ns()
                if now >= next_tick:
                    next_tick = now + nanoseconds(TICK_S)
                    _release(nodes, now, sink, live, utc_ns, start_ns, final=False)
                    if live is not None:
                        live.send()
                if now >= next_diag:
                    next_diag += nanoseconds(DIAGNOSTICS_S)
                    statuses = _diagnostics(nodes, diag_marks, now)
                    sink.add_diagnostics(now + utc_ns, statuses)
                    status_line.show(_status_text(nodes, seconds(now - start_ns)), seconds(now - start_ns))
                if now >= next_flush:
                    next_flush = now + nanoseconds(FLUSH_S)
                    sink.flush(_settled_ns(nodes, now, listen_ns))
            _drain_at_stop(selector, start_ns, time.monotonic_ns())
            now = time.monotonic_ns()
            _release(nodes, now, sink, live, utc_ns, start_ns, final=True)
            status_line.end()
            sink.add_diagnostics(now + utc_ns, _diagnostics(nodes, diag_marks, now))
            results = tuple(_node_result(n, start_utc_ns) for n in nodes)
            sink.add_metadata(
                "pendsim/acquisition_result", _result_metadata(results, seconds(now - start_ns), stop_reason)
            )
            sink.close()
            if sink.samples == 0:  # nothing a recording could hold: no file, one line saying why
                partial.unlink(missing_ok=True)
                raise RecordingError(_nothing_arrived(results, spec, seconds(now - start_ns)))
            if live is not None:
                live.send()
            publish(partial, output, replace=replace)
    except OutputError as exc:
        status_line.end()
        raise OutputError(f"{exc}; what was written is in {str(partial)!r} (pendsim recover reads it)") from None
    except OSError as exc:  # publishing
        raise OutputError(
            f"cannot publish {str(output)!r}: {describe_os_error(exc)}; the recording is in {str(partial)!r}"
        ) from None
    return AcquireResult(
        path=output,
        duration_s=seconds(now - start_ns),
        stop_reason=stop_reason,
        nodes=results,
        messages=sink.messages,
        size_bytes=output.stat().st_size,
        live_batches=live.batches if live is not None else 0,
    )


def _drain(node: _Node, start_ns: int, before_ns: float = math.inf) -> int:
    """Read what waits on a node's socket, each datagram with its arrival time (host monotonic ns:
    the kernel's stamp where there is one); those that arrived at or after ``before_ns`` are read
    and left out. How many were taken."""
    sock = node.sock
    assert sock is not None
    taken = 0
    for datagram in read_stamped(sock):
        if datagram.arrival_ns >= before_ns:
            continue
        taken += 1
        if datagram.dropped is not None:
            node.host_dropped = datagram.dropped
        accepted = node.receive(datagram.data, datagram.arrival_ns, start_ns)
        node.last_read_ns = time.monotonic_ns()
        if accepted:
            node.last_sample_ns = node.last_read_ns
    return taken


def _drain_at_stop(selector: selectors.BaseSelector, start_ns: int, stopped_ns: int) -> int:
    """What arrived before the stop and still waits in the OS, read (a loop behind the nodes on a
    busy machine left a node's last datagram there), for at most STOP_DRAIN_S; how many."""
    taken, until_ns = 0, stopped_ns + nanoseconds(STOP_DRAIN_S)
    while ready := selector.select(0):  # at least once, however late (a stalled process)
        now_taken = sum(_drain(key.data, start_ns, stopped_ns) for key, _ in ready)
        taken += now_taken
        if not now_taken or time.monotonic_ns() >= until_ns:
            break  # only what came after the stop is left, or time is up
    return taken


def _release(
    nodes: list[_Node],
    now_ns: int,
    sink: RecordingSink,
    live: LiveSink | None,
    utc_ns: int,
    start_ns: int,
    *,
    final: bool,
) -> None:
    """Hand each node's released samples, with their log times, to the file and the view."""
    for node in nodes:
        if node.settle(now_ns, start_ns, final=final):
            node.last_sample_ns = now_ns
        if not final and node.clock.span_s < WARMUP_S:
            continue
        released = node.stream.release(now_ns, final=final)
        if not released:
            continue
        line = node.line()
        assert line is not None
        device_us = np.array([a.packet.device_time_us for a in released], dtype=np.int64)
        host_s = np.asarray(line.to_recorder(device_us.astype(np.float64) * 1e-6))
        t_ns = start_ns + utc_ns + nanoseconds(host_s)
        # One time base, monotonic per node: the fit moves a little as it learns.
        # t'_i = max(t_i, t'_(i-1) + 1): strictly increasing, with t'_(-1) the last one released.
        steps = np.arange(len(t_ns), dtype=np.int64)
        t_ns = np.maximum.accumulate(np.maximum(t_ns - steps, node.last_log_ns + 1)) + steps
        node.last_log_ns = int(t_ns[-1])
        stamp_ns = _device_stamps(node, device_us, t_ns)
        rows = np.array([a.packet.row for a in released], dtype=np.float64)
        taken = sink.add_samples(node.spec.name, t_ns, rows, stamp_ns)
        if not np.all(taken):  # older than the file: a node back from a long silence
            node.stream.count_written_late(int(np.count_nonzero(~taken)))
        if live is not None and np.any(taken):
            live.add(node.spec.name, t_ns[taken], rows[taken])


def _device_stamps(node: _Node, device_us: NDArray[np.int64], t_ns: NDArray[np.int64]) -> NDArray[np.int64]:
    """The header stamps (n,) ns of released samples: their device times at rate 1 from an origin
    on the log-time base (the first sample's log time), so that they keep the node's own clock
    exactly. The log times follow the fit as it learns (steps of tens of microseconds early in a
    run, where the fit spans seconds); the stamps do not, and the whole run's clock relation is
    fitted afterwards from (stamp, log time) (``pendsim_mj.estimation.timing.fit_clock``). A device time that
    goes back (a node rebooted) or strays from the log time by more than ``STAMP_REANCHOR_S`` (plus
    twice the largest drift over the time since the origin) starts a new origin there, so stamps
    always increase and stay near the log times."""
    n = len(device_us)
    stamps = np.empty(n, dtype=np.int64)
    i = 0
    while i < n:
        fresh = node.stamp_anchor is None
        if node.stamp_anchor is None:
            node.stamp_anchor = (int(device_us[i]), max(int(t_ns[i]), node.last_stamp_ns + 1))
            node.stamp_origins += 1
        origin_us, origin_ns = node.stamp_anchor
        run = origin_ns + (device_us[i:] - origin_us) * 1000
        # The log times may part from rate-1 stamps by the fitted drift (at most MAX_DRIFT_PPM).
        tolerance_ns = nanoseconds(STAMP_REANCHOR_S) + 2e-6 * MAX_DRIFT_PPM * np.abs(t_ns[i:] - origin_ns)
        bad = (np.diff(run, prepend=node.last_stamp_ns) <= 0) | (np.abs(run - t_ns[i:]) > tolerance_ns)
        good = int(np.argmax(bad)) if bad.any() else len(run)
        good = max(good, 1) if fresh else good  # a new origin always takes its own sample
        stamps[i : i + good] = run[:good]
        if good:
            node.last_stamp_ns = int(run[good - 1])
        i += good
        if i < n:
            node.stamp_anchor = None
    return stamps


def _settled_ns(nodes: list[_Node], now_ns: int, listen_ns: int) -> int | None:
    """The log time up to which every node has released its samples, so that what is written is
    in log-time order across nodes. A node holds the writing back (-1: nothing yet) until it has
    released samples, unless no sample of it has come for STALE_S: since its last one, or since
    ``listen_ns`` (when acquire said it listens) for a node not heard from yet (its first samples
    may be stamped before what the others sent so far); malformed and implausible packets do not
    count. None (everything) when every node is silent that long."""
    settled = None
    for node in nodes:
        heard_ns = node.last_sample_ns or listen_ns
        if now_ns - heard_ns > nanoseconds(STALE_S):
            continue
        if node.last_log_ns < 0:
            return -1
        settled = node.last_log_ns if settled is None else min(settled, node.last_log_ns)
    return settled


def _diagnostics(nodes: list[_Node], marks: list[int], now_ns: int) -> list[ros2.DiagnosticStatus]:
    """One DiagnosticStatus per node: the counters, rates of the last second, clock and jitter."""
    statuses = []
    for i, node in enumerate(nodes):
        counters = node.stream.counters()
        new = {k: v - getattr(node.previous, k) for k, v in counters.as_dict().items() if hasattr(node.previous, k)}
        node.previous = counters
        jitter = node.jitter_ms(marks[i])
        marks[i] = len(node.device_s)
        line = node.line()
        silent_s = seconds(now_ns - node.last_read_ns) if node.last_read_ns else math.inf
        if silent_s > DIAGNOSTICS_S:
            level, message = 3, "no packets" if not counters.received else f"silent for {silent_s:.1f} s"
        elif new["lost"] or new["late"] or new["malformed"] or new["duplicated"] or new["implausible"]:
            level, message = (
                1,
                (
                    f"{new['received']} packets/s, {new['lost']} lost, {new['malformed']} malformed, "
                    f"{new['implausible']} implausible"
                ),
            )
        else:
            level, message = 0, f"{new['received']} packets/s"
        values = [(k, str(v)) for k, v in counters.as_dict().items()]
        values += [
            ("rate_hz", str(new["received"])),
            ("drift_ppm", f"{line.drift_ppm:.3f}" if line is not None else "nan"),
            ("jitter_p50_ms", f"{jitter[0]:.3f}"),
            ("jitter_p99_ms", f"{jitter[1]:.3f}"),
            ("pending", str(node.stream.pending + node.timeline.held)),
            ("host_dropped", str(node.host_dropped)),
        ]
        statuses.append(
            ros2.DiagnosticStatus(
                level, f"pendsim acquire: {node.spec.name}", message, f"{node.spec.name}@udp:{node.spec.port}",
                tuple(values),
            )
        )  # fmt: skip
    return statuses


def _status_text(nodes: list[_Node], elapsed_s: float) -> str:
    parts = [f"{elapsed_s:6.1f} s"]
    for node in nodes:
        c = node.stream.counters()
        line = node.line()
        drift = f"{line.drift_ppm:+.1f} ppm" if line is not None and node.clock.span_s >= WARMUP_S else "- ppm"
        parts.append(
            f"{node.spec.name}: {c.written} ok {c.lost} lost {c.duplicated} dup {c.reordered} reord "
            f"{c.late} late {c.malformed} bad {c.implausible} implausible {drift}"
        )
    return " | ".join(parts)


def _node_result(node: _Node, start_utc_ns: int) -> NodeResult:
    line = node.line()
    p50, p99 = node.jitter_ms()
    drift = line.drift_ppm if line is not None and node.clock.span_s > 0 else math.nan
    counters = node.stream.counters()
    return NodeResult(
        node.spec.name, node.spec.port, counters, drift, p50, p99, node.host_dropped, _stamp_clock(node, start_utc_ns)
    )


def _stamp_clock(node: _Node, start_utc_ns: int) -> ClockRelation | None:
    """The node's final clock fit (over every packet's arrival) as a relation from its header
    stamps to its log times, both s since ``start_utc_ns`` (the metadata's start_time_ns); None
    unless its stamps had one origin and the fit spans ``WARMUP_S``."""
    line = node.line()
    if line is None or node.stamp_origins != 1 or node.stamp_anchor is None or node.clock.span_s < WARMUP_S:
        return None
    origin_us, origin_ns = node.stamp_anchor  # stamp (s since start) = device_s - origin_us 1e-6 + origin_rel_s
    origin_rel_s = seconds(origin_ns - start_utc_ns)
    return ClockRelation(line.offset_s, line.rate, line.stamp0_s - origin_us * 1e-6 + origin_rel_s)


def _nothing_arrived(results: tuple[NodeResult, ...], spec: AcquireSpec, duration_s: float) -> str:
    """The error when no IMU sample arrived from any node: what each port received."""
    parts = []
    for r in results:
        c = r.counters
        got = f"{c.received} packet(s)" if c.received else "no packets"
        reasons = [*c.malformed_reasons, *c.implausible_reasons]
        if reasons:
            got += " (" + ", ".join(f"{k} {v}" for k, v in reasons) + ")"
        parts.append(f"{r.name} port {r.port}: {got}")
    return (
        f"no IMU sample arrived in {duration_s:.1f} s ({'; '.join(parts)}); nothing written. "
        f"Is each node sending {spec.stream.format} packets to {spec.bind} and its port?"
    )


def _result_metadata(results: tuple[NodeResult, ...], duration_s: float, stop_reason: str) -> dict[str, str]:
    out = {"duration_s": f"{duration_s:.3f}", "stop_reason": stop_reason}
    for r in results:
        for k, v in r.counters.as_dict().items():
            out[f"{r.name}.{k}"] = str(v)
        out[f"{r.name}.drift_ppm"] = f"{r.drift_ppm:.3f}"
        out[f"{r.name}.jitter_p50_ms"] = f"{r.jitter_p50_ms:.3f}"
        out[f"{r.name}.jitter_p99_ms"] = f"{r.jitter_p99_ms:.3f}"
        out[f"{r.name}.host_dropped"] = str(r.host_dropped)
        if r.stamp_clock is not None:
            c = r.stamp_clock
            out[f"{r.name}.stamp_clock"] = json.dumps({"offset_s": c.offset_s, "rate": c.rate, "stamp0_s": c.stamp0_s})
    return out


def _number(value: float, width: int, decimals: int) -> str:
    """A table cell: "-" where there is no value (a node with too few packets for a clock fit)."""
    return f"{value:{width}.{decimals}f}" if math.isfinite(value) else f"{'-':>{width}}"


def samples_text(nodes: tuple[NodeResult, ...]) -> str:
    """The samples written per node: "2560 IMU samples per node" or "2560 (m1) and 2391 (m2) IMU
    samples" (as ``pendsim record`` says it)."""
    written = [r.counters.written for r in nodes]
    if len(nodes) > 1 and len(set(written)) == 1:
        return f"{written[0]} IMU samples per node"
    return " and ".join(f"{r.counters.written} ({r.name})" for r in nodes) + " IMU samples"


def summary(result: AcquireResult) -> str:
    """The lines printed at the end."""
    lines = [
        f"wrote {result.path}: {result.duration_s:.1f} s, {samples_text(result.nodes)}, "
        f"{result.size_bytes / 1e6:.2f} MB (stopped: {result.stop_reason})"
    ]
    head = f"  {'node':4} {'port':>5} {'received':>9} {'written':>8} {'lost':>6} {'dup':>5} {'reord':>6}"
    lines.append(f"{head} {'late':>5} {'bad':>5} {'impl':>5} {'drift ppm':>10} {'jitter p50/p99 ms':>18}")
    for r in result.nodes:
        c = r.counters
        lines.append(
            f"  {r.name:4} {r.port:5d} {c.received:9d} {c.written:8d} {c.lost:6d} {c.duplicated:5d} "
            f"{c.reordered:6d} {c.late:5d} {c.malformed:5d} {c.implausible:5d} {_number(r.drift_ppm, 10, 2)} "
            f"{_number(r.jitter_p50_ms, 8, 3)} / {_number(r.jitter_p99_ms, 7, 3)}"
        )
        if c.malformed_reasons:
            lines.append("       malformed: " + ", ".join(f"{k} {v}" for k, v in c.malformed_reasons))
        if c.implausible_reasons:
            lines.append(
                "       implausible (off the node's timeline): "
                + ", ".join(f"{k} {v}" for k, v in c.implausible_reasons)
            )
        if r.host_dropped:
            lines.append(f"       {r.host_dropped} of the lost were dropped by this host (acquire read too slowly)")
    for r in result.nodes:
        if not r.counters.received:
            lines.append(
                f"  {r.name}: no packets arrived on port {r.port} (is the node sending to this host and port?)"
            )
    return "\n".join(lines)


__all__ = ["AcquireResult", "AcquireSpec", "NodeResult", "acquire", "summary"]
