"""One node's timeline: which decoded packets fit it, and the clock fit they feed.

A CRC-valid packet with every field in range may still not be the node's: forged, replayed, or
from a glitching node. Its device time is then far from where the node's clock stands, or its
sequence number far from where its device time puts it. Such a packet must neither reach the
file nor move the clock fit (a lower envelope: one point below the true line would drag it down,
and the drift with it), nor push the accounting's sequence frontier past the real samples. Two
rules keep it out, both measured against what the node itself has established:

- **Support feeds the clock fit.** A packet enters the fit only if at least ``SUPPORT_MIN`` of
  its ``NEIGHBOURS`` nearest packets on each side (in arrival order) agree with it: another
  device time, an arrival minus device time within ``SUPPORT_S`` of its own (plus the largest
  drift over their distance), and for formats with sequence numbers a sequence step its device
  time step allows. A real node's packets agree with their neighbours whenever the network does
  not delay them by more than ``SUPPORT_S`` against each other; a packet that agrees with none
  (a random or replayed one) never enters the fit. A packet that does not is still judged below,
  so support decides only what the fit learns from, never whether a sample is kept.
- **The established timeline judges.** Once the fit spans ``ESTABLISH_S`` (with at least
  ``ESTABLISH_POINTS`` points), each packet, in arrival order and after the fit has learned from
  it and its neighbours, is refused as implausible (counted per reason, never written) if:

  - ``time_ahead``: it arrived earlier than its device time allows: more than ``AHEAD_S`` (plus
    twice the largest drift times its device-time distance from the fit's span) before the fit's
    line. Network delay only adds time, so a real packet lies on or above the true line, and
    the fit's line is under every point it learned from;
  - ``time_behind``: it arrived more than ``MAX_DELAY_S`` after the line (more than a node can
    hold back: 60 s of packets exceed an ESP32-C3's memory);
  - ``seq_jump`` (formats with sequence numbers): its sequence number differs from the latest
    point in the fit by more than the device time between them allows at ``SEQ_RATE_FACTOR``
    times the node's rate (the larger of the nominal one and the one measured from the fit's
    points), plus ``SEQ_SLACK`` numbers either way. (Fewer numbers than the time allows is a node
    that stalled: allowed.)

  Before the timeline is established, packets are held (at most ``POOL_MAX``), then judged in
  arrival order; a node that never establishes one (too few packets that agree) is judged, when
  the acquisition ends, against the fit of the packets that did agree, or, if none did, of all.

A packet is decided once ``NEIGHBOURS`` later ones have arrived, or ``DECIDE_LAG_S`` after its
arrival, so accepted packets reach the accounting that much later (their arrival times, which the
reorder window counts from, are kept). No packet sequence can re-anchor the timeline unless it
is consistent with itself in device time, arrival time and sequence: what a sender forging a
whole node in real time could do, and no check without authentication can tell apart.
"""

from __future__ import annotations

import collections
import dataclasses

from .clock import MAX_DRIFT_PPM, ClockFit, ClockRelation
from .packets import Packet

NEIGHBOURS = 4  # packets each side that may support one
SUPPORT_MIN = 2  # how many must agree with it
SUPPORT_S = 2e-3  # their arrival minus device time differ by at most this (plus drift), s
FEED_S = 2e-3  # once established, a packet this close under the fit's line feeds it too, s
ESTABLISH_S = 0.25  # the fit's device-time span that establishes the timeline, s
ESTABLISH_POINTS = 8
AHEAD_S = 0.05  # how far before the fit's line a packet may arrive, s (plus the drift term)
MAX_DELAY_S = 60.0  # how long after the line it may arrive, s
SEQ_RATE_FACTOR = 2.0  # sequence numbers per device second: at most this times the node's rate
SEQ_SLACK = 8  # sequence numbers either way beyond what the rate allows
RATE_SPAN_S = 0.2  # the fit's points measure the node's rate once they span this, s
DECIDE_LAG_S = 0.1  # a packet without enough later neighbours is decided this long after arrival, s
QUARANTINE_S = 0.15  # a packet judged time_ahead is judged again until this long after its arrival, s
POOL_MAX = 8192  # packets held before a timeline is established; then it is forced
IMPLAUSIBLE_REASONS = ("time_ahead", "time_behind", "seq_jump")
_DRIFT = 2 * MAX_DRIFT_PPM * 1e-6  # the largest slope between two clocks within the drift bound


@dataclasses.dataclass
class _Entry:
    packet: Packet
    arrival_ns: int
    device_s: float
    arrival_s: float
    seq: int | None  # as the packet has it (wrapping at seq_modulus)
    supported: bool = False


@dataclasses.dataclass(frozen=True)
class Decision:
    """A decided packet: ``reason`` None (to the accounting) or one of IMPLAUSIBLE_REASONS."""

    packet: Packet
    arrival_ns: int
    reason: str | None


class Timeline:
    """The timeline of one node.

    Args:
      rate_hz: the node's nominal sample rate (sequence numbers per device second).
      seq_modulus: sequence numbers wrap at this value (None: they do not).
      has_seq: the format carries sequence numbers.
    """

    def __init__(self, *, rate_hz: float, has_seq: bool, seq_modulus: int | None = None) -> None:
        self.clock = ClockFit()
        self.rate_hz = rate_hz
        self.has_seq = has_seq
        self.seq_modulus = seq_modulus
        self.established = False
        self._recent: collections.deque[_Entry] = collections.deque()  # decided, kept as neighbours
        self._waiting: collections.deque[_Entry] = collections.deque()  # arrived, not decided
        self._pool: list[_Entry] = []  # decided before the timeline was established
        self._ahead: list[_Entry] = []  # judged time_ahead, judged again until QUARANTINE_S after arrival
        self._first_fed: tuple[int, float] | None = None  # (unwrapped seq, device s) of the first fed point
        self._last_fed: tuple[int, int, float] | None = None  # (unwrapped seq, seq, device s) of the latest
        self._fed_span: tuple[float, float] | None = None  # device times the fed points span, s

    @property
    def held(self) -> int:
        """Packets not decided yet (waiting for neighbours, or for a timeline)."""
        return len(self._waiting) + len(self._pool) + len(self._ahead)

    def add(self, packet: Packet, arrival_ns: int, arrival_s: float) -> None:
        """A decoded packet arrived (``arrival_s``: the same instant, s on the clock fit's axis)."""
        self._waiting.append(_Entry(packet, arrival_ns, packet.device_time_us * 1e-6, arrival_s, packet.seq))

    def decide(self, now_s: float, *, final: bool = False) -> list[Decision]:
        """The packets decided now, in arrival order (all of them with ``final``)."""
        out: list[Decision] = []
        while self._waiting:
            entry = self._waiting[0]
            if not (final or len(self._waiting) > NEIGHBOURS or now_s - entry.arrival_s >= DECIDE_LAG_S):
                break
            self._waiting.popleft()
            entry.supported = self._supported(entry)
            if self._feeds(entry):
                self._feed(entry)
            self._recent.append(entry)
            if len(self._recent) > NEIGHBOURS:
                self._recent.popleft()
            if self.established:
                out += self._judged([entry], now_s, final=final)
            else:
                self._pool.append(entry)
                ready = self.clock.count >= ESTABLISH_POINTS and self.clock.span_s >= ESTABLISH_S
                if ready or len(self._pool) >= POOL_MAX:
                    out += self._establish(now_s, final=final)
        if final and not self.established and self._pool:
            out += self._establish(now_s, final=final)
        if self._ahead:
            ahead, self._ahead = self._ahead, []
            out += self._judged(ahead, now_s, final=final)
        return out

    def _judged(self, entries: list[_Entry], now_s: float, *, final: bool) -> list[Decision]:
        """Decisions on ``entries``; one judged time_ahead is held back instead (its neighbours may
        be about to move the fit down: a network that held the first packets back) until
        ``QUARANTINE_S`` after its arrival."""
        out = []
        for entry in entries:
            decision = self._judge(entry)
            if decision.reason == "time_ahead" and not final and now_s - entry.arrival_s < QUARANTINE_S:
                self._ahead.append(entry)
            else:
                out.append(decision)
        return out

    # -- the rules --------------------------------------------------------------------------

    def _seq_step(self, later: int, earlier: int) -> int:
        """later - earlier, across a wrap (the nearest) where sequence numbers wrap."""
        m = self.seq_modulus
        return later - earlier if m is None else (later - earlier + m // 2) % m - m // 2

    def _max_rate_hz(self) -> float:
        rate = self.rate_hz
        if self._first_fed is not None and self._last_fed is not None:
            span_s = self._last_fed[2] - self._first_fed[1]
            if span_s >= RATE_SPAN_S:
                rate = max(rate, (self._last_fed[0] - self._first_fed[0]) / span_s)
        return SEQ_RATE_FACTOR * rate

    def _seq_fits(self, seq_step: int, device_step_s: float, max_rate_hz: float) -> bool:
        """A sequence step that a device-time step allows (see the module docstring)."""
        return (
            max_rate_hz * min(device_step_s, 0.0) - SEQ_SLACK
            <= seq_step
            <= max_rate_hz * max(device_step_s, 0.0) + SEQ_SLACK
        )

    def _agree(self, a: _Entry, b: _Entry, max_rate_hz: float) -> bool:
        step_s = b.device_s - a.device_s
        if step_s == 0.0:
            return False
        if abs((b.arrival_s - b.device_s) - (a.arrival_s - a.device_s)) > SUPPORT_S + _DRIFT * abs(step_s):
            return False
        if self.has_seq and a.seq is not None and b.seq is not None:
            return self._seq_fits(self._seq_step(b.seq, a.seq), step_s, max_rate_hz)
        return True

    def _supported(self, entry: _Entry) -> bool:
        max_rate_hz = self._max_rate_hz()
        count = 0
        for other in (*self._recent, *list(self._waiting)[:NEIGHBOURS]):
            if self._agree(entry, other, max_rate_hz):
                count += 1
                if count >= SUPPORT_MIN:
                    return True
        return False

    def _feeds(self, entry: _Entry) -> bool:
        """Whether the clock fit learns from it: supported; once the timeline is established,
        also near its line, and then only with a sequence number that follows the fit's."""
        if not self.established:
            return entry.supported
        return (entry.supported or self._near_line(entry)) and self._seq_follows(entry)

    def _near_line(self, entry: _Entry, line: ClockRelation | None = None) -> bool:
        """Arrived within ``FEED_S`` of the line (the fit's by default)."""
        line = line if line is not None else self.clock.relation()
        return abs(entry.arrival_s - float(line.to_recorder(entry.device_s))) <= FEED_S

    def _seq_follows(self, entry: _Entry) -> bool:
        """Its sequence number fits the latest fed point's (or there is none to compare)."""
        if not self.has_seq or entry.seq is None or self._last_fed is None:
            return True
        step = self._seq_step(entry.seq, self._last_fed[1])
        return self._seq_fits(step, entry.device_s - self._last_fed[2], self._max_rate_hz())

    def _feed(self, entry: _Entry, *, sequence: bool = True) -> None:
        """Into the clock fit (and, with ``sequence``, the sequence reference)."""
        self.clock.add(entry.device_s, entry.arrival_s)
        d = entry.device_s
        self._fed_span = (d, d) if self._fed_span is None else (min(self._fed_span[0], d), max(self._fed_span[1], d))
        if entry.seq is None or not sequence:
            return
        if self._last_fed is None:
            unwrapped = entry.seq
            self._first_fed = (unwrapped, entry.device_s)
        else:
            unwrapped = self._last_fed[0] + self._seq_step(entry.seq, self._last_fed[1])
        if self._last_fed is None or entry.device_s > self._last_fed[2]:
            self._last_fed = (unwrapped, entry.seq, entry.device_s)

    def _judge(self, entry: _Entry) -> Decision:
        line = self.clock.relation()
        expected_s = float(line.to_recorder(entry.device_s))
        lo, hi = self._fed_span if self._fed_span is not None else (entry.device_s, entry.device_s)
        distance_s = max(lo - entry.device_s, entry.device_s - hi, 0.0)
        drift_s = _DRIFT * distance_s
        reason = None
        if entry.arrival_s < expected_s - AHEAD_S - drift_s:
            reason = "time_ahead"
        elif entry.arrival_s > expected_s + MAX_DELAY_S + drift_s:
            reason = "time_behind"
        elif not self._seq_follows(entry):
            reason = "seq_jump"
        return Decision(entry.packet, entry.arrival_ns, reason)

    def _establish(self, now_s: float, *, final: bool) -> list[Decision]:
        """Judge the held packets against the fit: of those supported, refitted with every held
        packet near its line as well (of all of them if none was supported)."""
        pool = self._pool
        if self.clock.count:
            provisional = self.clock.relation()
            self.clock = ClockFit()  # the sequence reference stays that of the supported points
            self._fed_span = None
            for entry in pool:
                if (entry.supported or self._near_line(entry, provisional)) and self._seq_follows(entry):
                    self._feed(entry, sequence=False)
        else:
            for entry in pool:
                self._feed(entry)
        self.established = True
        self._pool = []
        return self._judged(pool, now_s, final=final)


__all__ = ["IMPLAUSIBLE_REASONS", "Decision", "Timeline"]
