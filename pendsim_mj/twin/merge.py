"""Both nodes' samples put into one time order for the estimator, which takes samples in time
order only.

Each node's own samples come in order (the receiver's timeline sees to that), but the two nodes
sample on their own clocks and their packets cross the network separately: M1's sample at 1.000 s
may arrive after M2's at 1.004 s. A sample is held until the other node has a sample at least as
new (then nothing older can come from it) or until it has waited ``hold_s`` (the other node lost
a packet or went silent); then it is released. A sample that arrives older than one already
released is *late*: it is not released (the estimator cannot go back) and is counted; its
instant is kept so that a replay of the twin's recording leaves it out too.

With both nodes at 80 Hz a sample waits for the other node's next sample, on average half a
period (6 ms); ``hold_s`` bounds the wait when that sample is lost.

**Known sample period** (``period_s``): a node samples on its own clock every period, so once the
other node has sent a sample at t_o, its next one is at t_o + period. A sample older than that
(with ``PERIOD_MARGIN`` to spare) has nothing older to wait for and goes at once: at 80 Hz almost
every sample, so the average wait falls from half a period to none (the instants are the nodes'
own, mapped onto the twin's clock: the network's jitter does not move them). A sample that does
wait, for the other node's next sample, waits until it comes, or until nothing has come from that
node for ``hold_s`` since its last sample arrived (the sample was lost: 7.5 ms after it was due
at the default hold), or ``hold_s`` after its own arrival, whichever is first.
"""

from __future__ import annotations

import collections
import dataclasses
import math
from typing import Generic, TypeVar

from pendsim_mj.errors import ParameterError

DEFAULT_HOLD_S = 0.02  # s: longer than one 80 Hz period (12.5 ms) plus the network's usual jitter
PERIOD_MARGIN = 0.1  # of a period: a node's next sample is taken to come no sooner than 0.9 periods after its last

T = TypeVar("T")


@dataclasses.dataclass(frozen=True)
class Held(Generic[T]):
    """A sample waiting: its node (0, 1), its instant (s), what it carries, when it came (s)."""

    node: int
    t_s: float
    item: T
    arrived_s: float


class SampleMerger(Generic[T]):
    """Merges two nodes' in-order samples into one time order (module docstring).

    Args:
      hold_s: the longest a sample waits for the other node, s.
      nodes: how many nodes feed it (1 or 2).
      period_s: the nodes' sample period, s (None: not known, every sample waits for the other
        node to reach its instant).
    """

    def __init__(self, hold_s: float = DEFAULT_HOLD_S, nodes: int = 2, *, period_s: float | None = None) -> None:
        if not (math.isfinite(hold_s) and 0 <= hold_s <= 10):
            raise ParameterError(f"hold_s must be in [0, 10] s, got {hold_s!r}")
        if nodes not in (1, 2):
            raise ParameterError(f"nodes must be 1 or 2, got {nodes!r}")
        if period_s is not None and not (math.isfinite(period_s) and 0 < period_s <= 10):
            raise ParameterError(f"period_s must be in (0, 10] s, got {period_s!r}")
        self.hold_s = float(hold_s)
        self.nodes = nodes
        self.period_s = period_s
        self._queues: list[collections.deque[Held[T]]] = [collections.deque() for _ in range(nodes)]
        self._newest = [-math.inf] * nodes  # the newest instant seen from each node
        self._newest_arrived = [-math.inf] * nodes  # when each node's newest sample arrived
        self.released_s = -math.inf  # the newest instant released
        self.late: list[tuple[int, float]] = []  # (node, t_s) of samples that came too late

    def push(self, node: int, t_s: float, item: T, arrived_s: float) -> bool:
        """A node's sample at instant ``t_s`` that came at ``arrived_s`` (both s on one clock);
        False (and counted late) if it is older than what was released."""
        if t_s < self.released_s:
            self.late.append((node, t_s))
            return False
        self._queues[node].append(Held(node, t_s, item, arrived_s))
        if t_s >= self._newest[node]:
            self._newest[node], self._newest_arrived[node] = t_s, arrived_s
        return True

    def _waits_on(self, head: Held[T], other: int, now_s: float) -> bool:
        """Whether ``head`` must still wait for node ``other``'s next sample (module docstring)."""
        newest = self._newest[other]
        if newest >= head.t_s:
            return False
        if self.period_s is None or newest == -math.inf:
            return True
        if newest + (1.0 - PERIOD_MARGIN) * self.period_s > head.t_s:
            return False  # its next sample is newer than this one
        return now_s - self._newest_arrived[other] < self.hold_s  # not yet given up as lost

    def pop(self, now_s: float, *, final: bool = False) -> list[Held[T]]:
        """The samples that may go now (in time order): each one whose instant the other node has
        reached (or, with ``period_s``, whose next sample will be newer, or is given up as lost),
        or which has waited ``hold_s``; everything with ``final``."""
        out: list[Held[T]] = []
        queues = self._queues
        while True:
            head: Held[T] | None = None
            for q in queues:  # the oldest head (the lower node on a tie), in plain loops: called per sample
                if q and (head is None or (q[0].t_s, q[0].node) < (head.t_s, head.node)):
                    head = q[0]
            if head is None:
                break
            if not (final or now_s - head.arrived_s >= self.hold_s) and any(
                self._waits_on(head, n, now_s) for n in range(self.nodes) if n != head.node
            ):
                break
            queues[head.node].popleft()
            self.released_s = max(self.released_s, head.t_s)
            out.append(head)
        return out

    def waiting(self) -> int:
        return sum(len(q) for q in self._queues)

    def due_s(self) -> float:
        """When the next sample goes even if no other comes (its arrival plus ``hold_s``, on the
        arrivals' clock; inf when none waits): until then ``pop`` releases nothing new unless
        another sample is pushed."""
        heads = [q[0] for q in self._queues if q]
        if not heads:
            return math.inf
        head = min(heads, key=lambda h: (h.t_s, h.node))
        due = head.arrived_s + self.hold_s
        if self.period_s is not None:
            for n in range(self.nodes):
                if n != head.node and self._newest[n] > -math.inf:
                    due = min(due, self._newest_arrived[n] + self.hold_s)
        return due
