"""One node's stream: sequence tracking, the reorder window, and the counters.

Every datagram on a node's port is counted as ``received`` and is exactly one of:

- **malformed**: not a valid packet of this node (``reason`` per ``packets.MALFORMED_REASONS``);
- **implausible**: a valid packet that does not fit the node's timeline (``reason`` per
  ``timeline.IMPLAUSIBLE_REASONS``: device time or sequence number far from where the node's
  clock and stream stand); dropped;
- **duplicated**: a sequence number already seen;
- **late**: a sequence number seen for the first time after its slot was closed (the stream had
  moved past it for longer than the reorder window); dropped;
- accepted: held in the reorder window, then released in sequence order (and written). An
  accepted packet that arrived after one with a higher sequence number is also **reordered**.

A sample is released as soon as every earlier sequence number is released or given up (so an
in-order stream waits for nothing), or once it has waited ``window_ns`` since it arrived; then the
missing numbers before it are counted **lost** (and a lost number that turns up later moves from
lost to late). So for the sequence numbers from the first to the last released,
``written + lost + late_after_loss == last - first + 1``; numbers before the first or after the last
packet received are not known to exist and are not counted.

Formats without sequence numbers get them from the device time at the nominal rate:
round((t - t_first) * rate).
"""

from __future__ import annotations

import dataclasses
import heapq
from collections import Counter
from typing import NamedTuple

from pendsim_mj.sensors.bno055 import SAMPLE_RATE_HZ

from .packets import MALFORMED_REASONS, Packet
from .timeline import IMPLAUSIBLE_REASONS

SEEN_HORIZON = 1 << 20  # sequence numbers remembered behind the released frontier (duplicates, late)


@dataclasses.dataclass(frozen=True)
class NodeCounters:
    """A snapshot of one node's counters (see the module docstring)."""

    received: int = 0
    written: int = 0
    lost: int = 0
    duplicated: int = 0
    reordered: int = 0
    late: int = 0
    malformed: int = 0
    malformed_reasons: tuple[tuple[str, int], ...] = ()
    implausible: int = 0
    implausible_reasons: tuple[tuple[str, int], ...] = ()

    def as_dict(self) -> dict[str, int]:
        """Every counter by name (reasons as ``malformed.REASON`` and ``implausible.REASON``)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if not f.name.endswith("_reasons")}
        out.update({f"malformed.{reason}": n for reason, n in self.malformed_reasons})
        out.update({f"implausible.{reason}": n for reason, n in self.implausible_reasons})
        return out


class Accepted(NamedTuple):
    """A released sample: extended sequence number, arrival (host ns) and the packet."""

    seq: int
    arrival_ns: int
    packet: Packet


class NodeStream:
    """Sequence tracking and the reorder window of one node.

    Args:
      window_ns: how long a sample waits for the missing ones before it (ns).
      seq_modulus: sequence numbers wrap at this value (pendsim-v1: 2**32), or None.
      rate_hz: nominal sample rate, to number samples of formats without sequence numbers.
    """

    def __init__(self, *, window_ns: int, seq_modulus: int | None = None, rate_hz: float = SAMPLE_RATE_HZ) -> None:
        self.window_ns = window_ns
        self.seq_modulus = seq_modulus
        self.rate_hz = rate_hz
        self._heap: list[tuple[int, int, Packet]] = []
        self._seen: set[int] = set()
        self._frontier: int | None = None  # highest sequence number released or given up
        self._first_released: int | None = None
        self._max_seq: int | None = None
        self._first_time_us: int | None = None
        self.received = 0
        self.written = 0
        self.lost = 0
        self.duplicated = 0
        self.reordered = 0
        self.late = 0
        self.malformed: Counter[str] = Counter()
        self.implausible: Counter[str] = Counter()

    # -- arrival ---------------------------------------------------------------------------

    def count_malformed(self, reason: str) -> None:
        """A datagram that did not decode."""
        assert reason in MALFORMED_REASONS, reason
        self.received += 1
        self.malformed[reason] += 1

    def count_implausible(self, reason: str) -> None:
        """A valid packet the node's timeline refused."""
        assert reason in IMPLAUSIBLE_REASONS, reason
        self.received += 1
        self.implausible[reason] += 1

    def sequence_of(self, packet: Packet) -> int:
        """The packet's sequence number, unwrapped (or inferred from its device time)."""
        if packet.seq is None:
            if self._first_time_us is None:
                self._first_time_us = packet.device_time_us
            return round((packet.device_time_us - self._first_time_us) * 1e-6 * self.rate_hz)
        if self.seq_modulus is None or self._max_seq is None:
            return packet.seq
        m = self.seq_modulus
        return self._max_seq + ((packet.seq - self._max_seq + m // 2) % m - m // 2)

    def offer(self, packet: Packet, arrival_ns: int) -> str:
        """A valid packet arrived. Returns "accepted", "duplicated" or "late"."""
        self.received += 1
        seq = self.sequence_of(packet)
        if seq in self._seen:
            self.duplicated += 1
            return "duplicated"
        self._seen.add(seq)
        if self._frontier is not None and seq <= self._frontier:
            self.late += 1
            if self._first_released is not None and self._first_released < seq and seq > self._frontier - SEEN_HORIZON:
                self.lost -= 1  # it was counted lost when the stream moved past it
            return "late"
        if self._max_seq is not None and seq < self._max_seq:
            self.reordered += 1
        if self._max_seq is None or seq > self._max_seq:
            self._max_seq = seq
        heapq.heappush(self._heap, (seq, arrival_ns, packet))
        return "accepted"

    # -- release ----------------------------------------------------------------------------

    def release(self, now_ns: int, *, final: bool = False) -> list[Accepted]:
        """Samples whose turn has come, in sequence order (all of them with ``final``)."""
        out: list[Accepted] = []
        heap = self._heap
        while heap:
            seq, arrival_ns, packet = heap[0]
            contiguous = self._frontier is not None and seq == self._frontier + 1
            if not (contiguous or final or arrival_ns + self.window_ns <= now_ns):
                break
            heapq.heappop(heap)
            if self._frontier is None:
                self._first_released = seq
            else:
                self.lost += seq - self._frontier - 1
            self._frontier = seq
            out.append(Accepted(seq, arrival_ns, packet))
        self.written += len(out)
        if out and len(self._seen) > 2 * SEEN_HORIZON:
            assert self._frontier is not None
            floor = self._frontier - SEEN_HORIZON
            self._seen = {s for s in self._seen if s > floor}
        return out

    def count_written_late(self, count: int) -> None:
        """Released samples the file had already passed (after a silence of the node): late."""
        self.written -= count
        self.late += count

    @property
    def pending(self) -> int:
        """Samples waiting in the reorder window."""
        return len(self._heap)

    def counters(self) -> NodeCounters:
        return NodeCounters(
            received=self.received,
            written=self.written,
            lost=self.lost,
            duplicated=self.duplicated,
            reordered=self.reordered,
            late=self.late,
            malformed=sum(self.malformed.values()),
            malformed_reasons=tuple(sorted(self.malformed.items())),
            implausible=sum(self.implausible.values()),
            implausible_reasons=tuple(sorted(self.implausible.items())),
        )
