"""The controller's side of the closed loop over UDP (``pendsim control CONTROLLER --rig``): the
rig's nodes in, the actuator's commands out, one control period at a time.

One loop on the host's monotonic clock:

1. between ticks it reads both nodes' sockets (``node_view.NodeView``: each node's clock fit,
   timeline, loss and reordering; a sample is used as soon as it fits) and the actuator's statuses
   (``packets.decode_status``: every field range-checked, a sequence number it never sent refused);
2. every ``dt_s`` (ticks on one schedule from the start; a tick more than a period late is skipped
   and counted, so lateness never accumulates) it forms the state (each node's newest sample
   carried forward by its age) and sends one command: the controller's torques, or a stop (zero
   torque) while a node has no state yet ("waiting") or has gone silent for ``silent_s``
   ("node_silent", said once when found and once when the node is back), or when the controller
   gives torques that are no command (NaN, beyond the packet's +-10 N m: "stop", said once);
3. on its end (duration, Ctrl-C, SIGTERM, an error) it sends a stop ("shutdown") first, then
   closes its sockets.

The result holds per tick the state seen, the ages, the command sent and when, the controller's
log, every status received, and the loop's timing: command sent -> its status back (the round
trip), the newest sample's instant -> command sent, and the ticks' lateness.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import selectors
import socket
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.control.controllers import Controller
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.swing_frame import SwingFrame
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import SAMPLE_RATE_HZ

from ..datagrams import listen_udp, read_stamped
from ..packets import StreamFormat
from ..ports import DEFAULT_NODES, NodeSpec, check_nodes
from ..receiver import say_on_stderr, stop_signals
from .actuator import DEFAULT_ACTUATOR_PORT
from .node_view import SILENT_S, VALUE_AGE_S, NodeView, ViewCounters, model_frames
from .packets import MAX_TORQUE_N_M, ActuatorPacketError, Command, Status, decode_status, encode_command
from .realtime import realtime

Floats = NDArray[np.float64]
SENT_KEPT = 4096  # commands remembered for matching their statuses


@dataclasses.dataclass(frozen=True)
class LoopTiming:
    """The loop's measured latency and jitter, ms (median and 99th percentile).

    Attributes:
      round_trip_ms: command sent -> the actuator's status for it received.
      sample_to_command_ms: the older of the two nodes' newest samples taken -> command sent.
      tick_lateness_ms: a tick's start after its scheduled instant (the loop's jitter).
      compute_ms: a tick's start -> its command sent (state, controller, packet).
    """

    round_trip_ms: tuple[float, float]
    sample_to_command_ms: tuple[float, float]
    tick_lateness_ms: tuple[float, float]
    compute_ms: tuple[float, float]


def _p50_p99(values_s: Floats) -> tuple[float, float]:
    v = np.asarray(values_s, dtype=float)
    v = v[np.isfinite(v)]
    if not len(v):
        return math.nan, math.nan
    p50, p99 = np.percentile(v, [50, 99])
    return float(p50) * 1e3, float(p99) * 1e3


@dataclasses.dataclass(frozen=True)
class RigLoopResult:
    """One run of the loop over UDP (n ticks, m statuses).

    Attributes:
      controller, motors, torque_limit_n_m, dt_s: what ran.
      start_ns: the loop's start on the host's monotonic clock, ns (times below are s after it).
      t_s: (n,) each tick's scheduled instant.
      tick_s: (n,) when it ran.
      sent_s: (n,) when its command was sent.
      seq: (n,) its command's sequence number.
      states: (n, 4) the state the controller took (phi1, phi2 rad; omega1, omega2 rad/s; NaN while
        waiting).
      age_s: (n, 2) each node's newest sample's age at the tick, s (inf: none yet).
      torques_n_m: (n, 2) the torques sent (0 with a stop).
      stop_reason: (n,) "none", or why the command was a stop (``packets.STOP_REASONS``).
      log: (n, len(log_names)) the controller's log after each command (NaN where it was not asked).
      log_names: its columns.
      status_s: (m,) when each status arrived.
      statuses: (m,) the statuses.
      round_trip_s: (n,) command sent -> its status received, s (NaN: none came).
      events: (t_s, text) what the loop said, in order.
      nodes: per node, its counters.
      bad_statuses: datagrams on the command socket that were no valid status, per reason.
      skipped_ticks: ticks skipped because the loop was more than a period late.
      stop: "duration", "interrupted" (SIGINT), "terminated" (SIGTERM), "stopped" (asked to) or
        "actuator_limit" (the actuator refused a torque above its own limit: the loop stops).
    """

    controller: str
    motors: tuple[str, ...]
    torque_limit_n_m: float
    dt_s: float
    start_ns: int
    t_s: Floats
    tick_s: Floats
    sent_s: Floats
    seq: NDArray[np.int64]
    states: Floats
    age_s: Floats
    torques_n_m: Floats
    stop_reason: tuple[str, ...]
    log: Floats
    log_names: tuple[str, ...]
    status_s: Floats
    statuses: tuple[Status, ...]
    round_trip_s: Floats
    events: tuple[tuple[float, str], ...]
    nodes: tuple[tuple[str, ViewCounters], ...]
    bad_statuses: dict[str, int]
    skipped_ticks: int
    stop: str

    def timing(self) -> LoopTiming:
        """Latency and jitter (``LoopTiming``) over the ticks that sent the controller's torques."""
        running = np.array([r == "none" for r in self.stop_reason], dtype=bool)
        oldest = np.max(self.age_s, axis=1) + (self.sent_s - self.tick_s)
        return LoopTiming(
            round_trip_ms=_p50_p99(self.round_trip_s),
            sample_to_command_ms=_p50_p99(oldest[running]),
            tick_lateness_ms=_p50_p99(self.tick_s - self.t_s),
            compute_ms=_p50_p99((self.sent_s - self.tick_s)[running]),
        )


class _Loop:
    """The loop's state (module docstring)."""

    def __init__(
        self,
        controller: Controller,
        views: list[NodeView],
        command_sock: socket.socket,
        dt_s: float,
        say: Callable[[str], None],
    ) -> None:
        self.controller, self.views, self.sock, self.dt_s, self.say = controller, views, command_sock, dt_s, say
        self.start_ns = time.monotonic_ns()
        self.seq = 0
        self.refused_limit = False
        self.sent_ns: dict[int, int] = {}  # seq -> when sent (the latest SENT_KEPT)
        self.round_trip: dict[int, float] = {}
        self.rows: list[tuple[float, float, float, int, Floats, Floats, Floats, str, Floats]] = []
        self.statuses: list[tuple[float, Status]] = []
        self.bad_statuses: dict[str, int] = {}
        self.events: list[tuple[float, str]] = []
        self.silent: set[str] = set()
        self.actuator_state = ("", "")
        self.skipped = 0
        self.unreachable = False
        self.shut_down = False
        self.bad_torques = 0
        self.node_socks: list[socket.socket] = []
        self.last_sent_s = math.nan

    def now_s(self) -> float:
        return (time.monotonic_ns() - self.start_ns) * 1e-9

    def said(self, text: str) -> None:
        self.events.append((self.now_s(), text))
        self.say(text)

    # -- receiving -------------------------------------------------------------------------------

    def read_node(self, view: NodeView, sock: socket.socket) -> None:
        for datagram in read_stamped(sock):
            view.receive(datagram.data, datagram.arrival_ns, self.start_ns)

    def read_statuses(self) -> None:
        for datagram in read_stamped(self.sock):
            arrival_s = (datagram.arrival_ns - self.start_ns) * 1e-9
            try:
                status = decode_status(datagram.data)
            except ActuatorPacketError as exc:
                self.bad_statuses[exc.reason] = self.bad_statuses.get(exc.reason, 0) + 1
                continue
            if self.seq <= 2**32 and status.seq >= self.seq:  # answers a command never sent
                self.bad_statuses["unsent_seq"] = self.bad_statuses.get("unsent_seq", 0) + 1
                continue
            self.statuses.append((arrival_s, status))
            sent = self.sent_ns.get(status.seq)
            if sent is not None and status.seq not in self.round_trip:
                self.round_trip[status.seq] = (datagram.arrival_ns - sent) * 1e-9
            if status.state == "safe" and status.reason == "limit" and not self.refused_limit:
                self.refused_limit = True
                self.said(
                    f"actuator: refused a torque above its limit, which is below this controller's "
                    f"{self.controller.torque_limit_n_m:g} N m: stopping (give the controller the actuator's limit)"
                )
            if (status.state, status.reason) != self.actuator_state:
                self.actuator_state = (status.state, status.reason)
                if status.state == "safe":
                    self.said(f"actuator: zero torque ({status.reason})")
                else:
                    self.said("actuator: applying commands")

    # -- a tick ----------------------------------------------------------------------------------

    def drain(self) -> None:
        """Read what waits on every socket (the newest samples and statuses, before a tick)."""
        for view, sock in zip(self.views, self.node_socks, strict=True):
            self.read_node(view, sock)
        self.read_statuses()

    def tick(self, t_s: float) -> None:
        self.drain()
        tick_s = self.now_s()
        for view in self.views:
            view.settle(tick_s)
        states = [view.state_at(tick_s) for view in self.views]
        state = np.array([states[0][0], states[1][0], states[0][1], states[1][1]])
        age = np.array([states[0][2], states[1][2]])
        log = np.full(len(self.controller.log_names), np.nan)
        torques = np.zeros(2)
        reason = "none"
        for view in self.views:
            name = view.spec.name
            if view.newest is None:
                reason = "waiting"
            elif view.silent(tick_s):
                reason = "node_silent" if reason == "none" else reason
                if name not in self.silent:
                    self.silent.add(name)
                    last = view.used_arrival_s
                    self.said(f"node {name}: silent for {(tick_s - last) * 1e3:.0f} ms; zero torque sent")
            elif name in self.silent:
                self.silent.discard(name)
                self.said(f"node {name}: samples again")
        if reason == "none":
            torques = np.asarray(self.controller(state), dtype=float)
            log = self.controller.log()
            if torques.shape != (2,) or not np.all(np.abs(torques) <= MAX_TORQUE_N_M):  # NaN fails too
                if not self.bad_torques:
                    self.said(f"controller: torques {torques} are no command; zero torque sent")
                self.bad_torques += 1
                torques, reason = np.zeros(2), "stop"
        self.send(Command(self.seq, 0, (float(torques[0]), float(torques[1])), reason != "none", reason))
        self.rows.append((t_s, tick_s, self.last_sent_s, self.seq - 1, state, age, torques, reason, log))

    def send(self, command: Command) -> None:
        """Stamp and send a command (its sequence number the loop's next); remembers when."""
        now_ns = time.monotonic_ns()
        command = dataclasses.replace(command, seq=self.seq % 2**32, time_us=now_ns // 1000)
        packet = encode_command(command)
        try:
            self.sock.send(packet)
        except OSError:  # nobody listens there (ICMP port unreachable): said once
            if not self.unreachable:
                self.unreachable = True
                self.said("actuator: unreachable (nothing listens on its port)")
        self.sent_ns[command.seq] = now_ns
        self.sent_ns.pop(command.seq - SENT_KEPT, None)
        self.last_sent_s = (now_ns - self.start_ns) * 1e-9
        self.seq += 1

    def shutdown(self) -> None:
        """Send the stop that ends the loop (zero torque, reason "shutdown")."""
        self.shut_down = True
        self.send(Command(0, 0, (0.0, 0.0), True, "shutdown"))

    def result(self, stop: str) -> RigLoopResult:
        c = self.controller
        n = len(self.rows)
        cols = list(zip(*self.rows, strict=True)) if n else [()] * 9
        seqs = np.array(cols[3], dtype=np.int64)
        return RigLoopResult(
            controller=c.name,
            motors=tuple(c.motors),
            torque_limit_n_m=c.torque_limit_n_m,
            dt_s=self.dt_s,
            start_ns=self.start_ns,
            t_s=np.array(cols[0], dtype=float),
            tick_s=np.array(cols[1], dtype=float),
            sent_s=np.array(cols[2], dtype=float),
            seq=seqs,
            states=np.array(cols[4], dtype=float).reshape(n, 4),
            age_s=np.array(cols[5], dtype=float).reshape(n, 2),
            torques_n_m=np.array(cols[6], dtype=float).reshape(n, 2),
            stop_reason=tuple(cols[7]),
            log=np.array(cols[8], dtype=float).reshape(n, len(c.log_names)),
            log_names=tuple(c.log_names),
            status_s=np.array([s for s, _ in self.statuses], dtype=float),
            statuses=tuple(st for _, st in self.statuses),
            round_trip_s=np.array([self.round_trip.get(int(s) % 2**32, math.nan) for s in seqs], dtype=float),
            events=tuple(self.events),
            nodes=tuple((v.spec.name, v.counters()) for v in self.views),
            bad_statuses=dict(self.bad_statuses),
            skipped_ticks=self.skipped,
            stop=stop,
        )


def run_rig_loop(
    controller: Controller,
    *,
    nodes: tuple[NodeSpec, ...] = DEFAULT_NODES,
    bind: str = "127.0.0.1",
    actuator: tuple[str, int] = ("127.0.0.1", DEFAULT_ACTUATOR_PORT),
    duration_s: float | None = None,
    dt_s: float = 0.01,
    stream: StreamFormat | None = None,
    rate_hz: float = SAMPLE_RATE_HZ,
    silent_s: float = SILENT_S,
    value_age_s: float = VALUE_AGE_S,
    frames: tuple[SwingFrame, SwingFrame] | None = None,
    should_stop: Callable[[], bool] | None = None,
    realtime_priority: bool = True,
    say: Callable[[str], None] = say_on_stderr,
) -> RigLoopResult:
    """Run ``controller`` on the rig over UDP (module docstring) and return what happened.

    Args:
      controller: any ``pendsim_mj.control`` controller (its period should be ``dt_s``).
      nodes: both nodes and the ports they send to (m1 and m2: the state needs both).
      bind: the address the node ports listen on (127.0.0.1: this machine only).
      actuator: (host, port) of the actuator node.
      duration_s: stop after this long, s (None: on Ctrl-C, SIGTERM or ``should_stop``).
      dt_s: the control period, s.
      stream: the nodes' packet format (default pendsim-v1).
      rate_hz: the nodes' nominal rate, Hz.
      silent_s: a node from which no sample was used for this long is silent: stop sent, s.
      value_age_s: how much older a sample's value is than its stamp (a BNO055's fused output:
        half its 10 ms period on average; 0 for nodes that stamp their values' instants), s.
      frames: each node's swing frame (default ``node_view.model_frames`` of the controller's rig).
      should_stop: asked every tick; True ends the loop (as a signal does).
      realtime_priority: run the loop's thread under real-time scheduling where the OS permits it
        (``realtime.realtime``: root or CAP_SYS_NICE; said when not), its policy back after.
      say: where the loop's lines go (default stderr).

    Raises:
      ParameterError: bad arguments, or a node's port cannot be bound (one line, e.g. "address
        already in use"); nothing was sent.
    """
    nodes = check_nodes(tuple(nodes))
    if [n.name for n in nodes] != ["m1", "m2"]:
        raise ParameterError("the loop needs both nodes, m1 and m2, for the state")
    if not (math.isfinite(dt_s) and 0.001 <= dt_s <= 0.1):
        raise ParameterError(f"the control period must be in [0.001, 0.1] s, got {dt_s!r}")
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
        raise ParameterError(f"duration_s must be a finite number > 0 s, got {duration_s!r}")
    host, port = actuator
    if not 1 <= port <= 65535:
        raise ParameterError(f"the actuator's port must be in [1, 65535], got {port}")
    stream = stream if stream is not None else StreamFormat()
    frames = frames if frames is not None else model_frames(getattr(controller, "params", DEFAULT_PARAMS))
    views = [
        NodeView(n, stream, rate_hz, frames[i], silent_s=silent_s, value_age_s=value_age_s) for i, n in enumerate(nodes)
    ]
    selector = selectors.DefaultSelector()
    socks: list[socket.socket] = []
    loop: _Loop | None = None
    stop = "duration"
    try:
        for view in views:
            socks.append(listen_udp(bind, view.spec.port, what=f"node {view.spec.name}", option="--node"))
            selector.register(socks[-1], selectors.EVENT_READ, view)
        command_sock = listen_udp("::" if ":" in host else "0.0.0.0", 0, what="the actuator's statuses", option="")
        socks.append(command_sock)
        try:
            command_sock.connect((host, port))  # statuses only from the actuator
        except OSError as exc:
            raise ParameterError(f"cannot send to the actuator at {host}:{port}: {exc.strerror or exc}") from None
        selector.register(command_sock, selectors.EVENT_READ, None)
        loop = _Loop(controller, views, command_sock, dt_s, say)
        loop.node_socks = socks[: len(views)]
        controller.reset()
        loop.said(
            f"control loop: {controller.name} every {dt_s * 1e3:g} ms; nodes "
            f"{', '.join(f'{v.spec.name} on {bind}:{v.spec.port}' for v in views)}; actuator {host}:{port}"
        )
        k = 0
        with stop_signals() as signalled, realtime(realtime_priority) as granted:
            if realtime_priority and not granted:
                loop.said("note: real-time scheduling not permitted (needs root or CAP_SYS_NICE): normal priority")
            while True:
                now = loop.now_s()
                if signalled:
                    stop = signalled[0]
                    break
                if should_stop is not None and should_stop():
                    stop = "stopped"
                    break
                if loop.refused_limit:
                    stop = "actuator_limit"
                    break
                if duration_s is not None and now >= duration_s:
                    break
                if now >= k * dt_s:
                    late = math.floor(now / dt_s) - k
                    if late >= 1:  # more than a period behind: skip to the current tick
                        loop.skipped += late
                        k += late
                    loop.tick(k * dt_s)
                    k += 1
                    continue
                wake = k * dt_s if duration_s is None else min(k * dt_s, duration_s)
                for key, _ in selector.select(max(0.0, wake - loop.now_s())):
                    if key.data is None:
                        loop.read_statuses()
                    else:
                        loop.read_node(key.data, key.fileobj)  # type: ignore[arg-type]
        loop.shutdown()
        loop.said(f"control loop: stopped ({stop}); zero torque sent")
        time.sleep(min(0.05, 5 * dt_s))  # the shutdown's status, if it comes
        loop.read_statuses()
        for view in views:
            view.settle(loop.now_s(), final=True)
        return loop.result(stop)
    finally:
        if loop is not None and not loop.shut_down:
            with contextlib.suppress(Exception):  # an error ends the loop: zero torque, if we still can
                loop.shutdown()
        selector.close()
        for s in socks:
            s.close()


__all__ = ["LoopTiming", "RigLoopResult", "run_rig_loop"]
