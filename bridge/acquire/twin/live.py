"""``pendsim twin`` on live packets: both nodes' UDP streams into the twin's pipeline
(``run.twin.TwinPipeline``) as they arrive.

Each node's datagrams are received as the controller's loop receives them
(``node_view.NodeView``: stamped with the kernel's arrival time, decoded with every field
range-checked, the node's clock fit mapping device time to the host's monotonic clock; a sample is
used at once when it is the node's newest and fits the node's timeline). A used sample goes to the
pipeline with its instant (device time mapped to host time, s since the twin's start) and its
arrival; the pipeline puts both nodes in one time order and takes them into the twin. The twin's
clock is the host's monotonic clock from the start; its recording's log times are UTC from there.

Packets that the timeline decides later were off it, and reordered packets (older than the
node's newest used), are not used (counted per node in the summary's metadata).
"""

from __future__ import annotations

import collections
import contextlib
import math
import selectors
import socket
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pendsim_mj.errors import ParameterError
from pendsim_mj.sensors.bno055 import SAMPLE_RATE_HZ
from pendsim_mj.twin.estimator import warm_up as estimator_warm_up

from ...report.twin_views import TwinView
from ...signals import interrupts_deferred
from ..datagrams import listen_udp, read_stamped
from ..packets import PacketError, StreamFormat
from ..ports import DEFAULT_NODES, NodeSpec, check_nodes
from ..receiver import say_on_stderr, stop_signals
from ..udp_loop.node_view import NodeView, ViewCounters, model_frames
from .pipeline import TwinPipeline, TwinResult, TwinSpec, close_sink, open_sink
from .summary import Narrator, status_text

SETTLE_S = 0.05  # the nodes' timelines decide this often (``receiver.TICK_S``), s
IDLE_WAIT_S = 0.05  # the loop's longest sleep with no packet and no sample due, s
JUMP_PACKETS = 5  # packets in a row whose arrival minus device time agree among themselves within
JUMP_AGREE_S = 0.025  # this (s: a loaded host's arrival jitter) and differ from the node's recent ones
JUMP_MIN_S = 0.05  # by more than JUMP_MIN_S, all the same way: the node's clock jumped; its timeline
JUMP_ANYWAY = 40  # starts anew from the packets that follow (and after this many held out in a row, whatever)
RECENT_PACKETS = 40  # the node's recent packets' arrival minus device time: their median is its offset


class _TwinNodeView(NodeView):
    """A node as the twin sees it: ``NodeView``, and a clock that jumped (set anew, a reboot)
    noticed and followed. A node's timeline would take a jump in as a steep drift (its packets
    support each other), mapping the node's samples to wrong instants for seconds; here a packet
    whose arrival minus device time is more than ``JUMP_MIN_S`` from the node's recent median is
    held out, and once ``JUMP_PACKETS`` in a row agree among themselves, the node's timeline starts
    anew (``jumps`` keeps when and by how much; the twin says it). A lone packet that far off (a
    network stall) is left out."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._args, self._kwargs = args, kwargs
        self._recent: collections.deque[float] = collections.deque(maxlen=RECENT_PACKETS)
        self._odd: list[float] = []  # arrival minus device time of the packets held out in a row, s
        self.jumps: list[tuple[float, float]] = []  # (arrival s, jump s)
        self.held_out = 0

    def receive(self, data: bytes, arrival_ns: int, start_ns: int) -> bool:
        try:
            packet = self.codec.decode(data)
        except PacketError:
            return super().receive(data, arrival_ns, start_ns)  # counted there
        arrival_s = (arrival_ns - start_ns) * 1e-9
        off = arrival_s - packet.device_time_us * 1e-6
        base = statistics.median(self._recent) if len(self._recent) >= JUMP_PACKETS else off
        if abs(off - base) > JUMP_MIN_S:
            self._odd.append(off)
            self.held_out += 1
            odd = self._odd[-JUMP_PACKETS:]
            agree = max(odd) - min(odd) <= JUMP_AGREE_S and (min(odd) > base or max(odd) < base)
            if (len(self._odd) >= JUMP_PACKETS and agree) or len(self._odd) >= JUMP_ANYWAY:
                self.jumps.append((arrival_s, base - statistics.median(odd)))
                counts, malformed, implausible = dict(self._counts), dict(self._malformed), dict(self._implausible)
                NodeView.__init__(self, *self._args, **self._kwargs)  # type: ignore[arg-type]
                self._counts, self._malformed, self._implausible = counts, malformed, implausible
                self._recent.clear()
                self._odd = []
            return False
        self._odd.clear()
        self._counts["received"] += 1
        used = self._take(packet, arrival_ns, start_ns)  # decoded once
        if used:
            self._recent.append(off)
        return used


DRAIN_S = 2.0  # at the stop, datagrams already received are taken in for at most this long, s


def run_twin_live(
    spec: TwinSpec,
    *,
    output: Path | None,
    replace: bool = False,
    nodes: tuple[NodeSpec, ...] = DEFAULT_NODES,
    bind: str = "127.0.0.1",
    stream: StreamFormat | None = None,
    rate_hz: float = SAMPLE_RATE_HZ,
    duration_s: float | None = None,
    views_for: Callable[[int], tuple[TwinView, ...]] | None = None,
    should_stop: Callable[[], bool] | None = None,
    say: Callable[[str], None] = say_on_stderr,
    status: Callable[[str], None] | None = None,
) -> TwinResult:
    """Run the twin on the nodes' packets until ``duration_s``, Ctrl-C, SIGTERM or ``should_stop``;
    ``views_for(start_utc_ns)`` opens the live views (closed at the end, on every exit path).
    ``say`` gets a line for each event as it happens (listening, a node's clock jump, each alarm,
    within a second: "twin: alarm: ...", the health checks held or resumed); ``status`` once a second the status line
    (``summary.status_text``).

    Raises:
      ParameterError: a port cannot be bound (nothing is written).
      OutputError: the output exists, or writing failed.
      RecordingError: no node sample arrived (nothing is written).
    """
    nodes = check_nodes(tuple(nodes))
    if [n.name for n in nodes] != ["m1", "m2"]:
        raise ParameterError(
            "the twin needs both nodes, m1 and m2: give --node for each (e.g. --node m1=5701 --node m2=5702), "
            "or neither for the defaults m1=5601 m2=5602"
        )
    stream = stream if stream is not None else StreamFormat()
    frames = model_frames(spec.params)  # NodeView's own state (unused here) needs one; the twin learns its own
    node_views = [_TwinNodeView(n, stream, rate_hz, frames[i]) for i, n in enumerate(nodes)]
    selector = selectors.DefaultSelector()
    socks: list[socket.socket] = []
    partial: Path | None = None
    views: tuple[TwinView, ...] = ()
    pipeline: TwinPipeline | None = None
    try:
        for view in node_views:
            socks.append(listen_udp(bind, view.spec.port, what=f"node {view.spec.name}", option="--node"))
            selector.register(socks[-1], selectors.EVENT_READ, view)
        start_ns = time.monotonic_ns()
        start_utc_ns = time.time_ns()
        views = views_for(start_utc_ns) if views_for is not None else ()
        sink = None
        if output is not None:
            sink, partial = open_sink(
                output,
                replace=replace,
                spec=spec,
                source="live",
                groups=stream.groups(),
                node_names=("m1", "m2"),
                start_utc_ns=start_utc_ns,
            )
        session = spec.session()
        with interrupts_deferred():  # numba's callbacks would swallow a Ctrl-C meanwhile
            estimator_warm_up()  # the kernels loaded before the first packet, not behind it
        pipeline = TwinPipeline(
            spec, session, sink=sink, node_names=("m1", "m2"), start_utc_ns=start_utc_ns, views=views,
            period_s=1.0 / rate_hz,
        )  # fmt: skip

        def now_s() -> float:
            return (time.monotonic_ns() - start_ns) * 1e-9

        say(
            f"twin: listening on {', '.join(f'{v.spec.name} {bind}:{v.spec.port}' for v in node_views)}"
            + (f"; writing {partial} until done, then {output}" if output is not None else "")
        )
        stop = "duration"
        next_settle_s = 0.0
        narrate = Narrator(say, start_utc_ns)

        def take(key: selectors.SelectorKey, before_ns: float = math.inf) -> int:
            """The datagrams waiting on one node's socket into the pipeline (those that arrived
            before ``before_ns``; later ones are read and dropped); how many arrived before it."""
            view = key.data
            jumps = len(view.jumps)
            node = 0 if view is node_views[0] else 1
            before = 0
            for datagram in read_stamped(key.fileobj):  # type: ignore[arg-type]
                before += datagram.arrival_ns < before_ns
                if datagram.arrival_ns < before_ns and view.receive(datagram.data, datagram.arrival_ns, start_ns):
                    assert view.newest is not None
                    _, taken_s, row, _, _ = view.newest
                    arrived = (datagram.arrival_ns - start_ns) * 1e-9
                    pipeline.push(node, taken_s, np.asarray(row, dtype=float), arrived)
            for at_s, jump_s in view.jumps[jumps:]:
                text = f"{view.spec.name}: its clock jumped by {jump_s:+.3f} s; its timeline restarted"
                session.note(at_s, text)
                say(f"twin: {text}")
            return before

        with stop_signals() as signalled:
            while True:
                now = now_s()
                if signalled:
                    stop = signalled[0]
                    break
                if should_stop is not None and should_stop():
                    stop = "stopped"
                    break
                if duration_s is not None and now >= duration_s:
                    break
                # asleep until a packet comes, the merger's next sample is due (it waited for the
                # other node long enough) or, at the latest, the timelines' next decision
                wait = min(IDLE_WAIT_S, pipeline.merger.due_s() - now)
                if duration_s is not None:
                    wait = min(wait, duration_s - now)
                for key, _ in selector.select(max(0.0, wait)):
                    take(key)
                now = now_s()
                pipeline.step(now, clock=now_s)
                if now >= next_settle_s:  # the timelines decide at acquire's cadence, not at every packet
                    next_settle_s = now + SETTLE_S
                    for view in node_views:
                        view.settle(now)
                if pipeline.tick(now, session.estimator.t_s):  # once a second: new alarms, events; the status
                    narrate(pipeline)
                    if status is not None:
                        status(status_text(pipeline, now))
        # what arrived before the stop and waits in the OS is taken in (a twin behind the nodes on a
        # busy machine lost the last seconds of a run at its stop), for at most DRAIN_S
        stopped_ns, until = time.monotonic_ns(), time.monotonic() + DRAIN_S
        while time.monotonic() < until and (ready := selector.select(0)):
            if not sum(take(key, stopped_ns) for key, _ in ready):  # only what came after the stop is left
                break
            pipeline.step(now_s(), clock=now_s)
        pipeline.finish()
        narrate(pipeline)  # what came after the last second's
        duration = now_s()
        messages = 0
        path = None
        if sink is not None and output is not None and partial is not None:
            messages = close_sink(pipeline, partial, output, replace=replace, stop_reason=stop, duration_s=duration)
            path = output
        elif session.samples == (0, 0):
            from pendsim_mj.errors import RecordingError

            raise RecordingError("no node sample arrived")
        packets = tuple(_packets(view.counters()) for view in node_views)
        return TwinResult(
            path, duration, stop, session.summary(), tuple(pipeline.merger.late), pipeline.latency_ms(), messages,
            packets, start_utc_ns,
        )  # fmt: skip
    finally:
        selector.close()
        for s in socks:
            s.close()
        if pipeline is not None:
            with contextlib.suppress(Exception):  # an error ends the run: the views' thread goes too
                pipeline.stop_views()
        for v in views:
            v.close()


def _packets(c: ViewCounters) -> tuple[int, int, int, int]:
    """(received, used, before the clock fit, otherwise not used) of one node (``TwinResult.packets``)."""
    other = c.stale + c.off_time + sum(n for _, n in c.malformed) + sum(n for _, n in c.implausible)
    return c.received, c.used, c.waiting, other


__all__ = ["run_twin_live"]
