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
"""

from __future__ import annotations

import collections
import dataclasses
import math
from typing import Generic, TypeVar

from pendsim_mj.errors import ParameterError

DEFAULT_HOLD_S = 0.02  # s: longer than one 80 Hz period (12.5 ms) plus the network's usual jitter

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
    """

    def __init__(self, hold_s: float = DEFAULT_HOLD_S, nodes: int = 2) -> None:
        if not (math.isfinite(hold_s) and 0 <= hold_s <= 10):
            raise ParameterError(f"hold_s must be in [0, 10] s, got {hold_s!r}")
        if nodes not in (1, 2):
            raise ParameterError(f"nodes must be 1 or 2, got {nodes!r}")
        self.hold_s = float(hold_s)
        self.nodes = nodes
        self._queues: list[collections.deque[Held[T]]] = [collections.deque() for _ in range(nodes)]
        self._newest = [-math.inf] * nodes  # the newest instant seen from each node
        self.released_s = -math.inf  # the newest instant released
        self.late: list[tuple[int, float]] = []  # (node, t_s) of samples that came too late

    def push(self, node: int, t_s: float, item: T, arrived_s: float) -> bool:
        """A node's sample at instant ``t_s`` that came at ``arrived_s`` (both s on one clock);
        False (and counted late) if it is older than what was released."""
        if t_s < self.released_s:
            self.late.append((node, t_s))
            return False
        self._queues[node].append(Held(node, t_s, item, arrived_s))
        self._newest[node] = max(self._newest[node], t_s)
        return True

    def pop(self, now_s: float, *, final: bool = False) -> list[Held[T]]:
        """The samples that may go now (in time order): each one whose instant the other node has
        reached, or which has waited ``hold_s``; everything with ``final``."""
        out: list[Held[T]] = []
        queues = self._queues
        while True:
            heads = [q[0] for q in queues if q]
            if not heads:
                break
            head = min(heads, key=lambda h: (h.t_s, h.node))
            others_reached = all(self._newest[n] >= head.t_s for n in range(self.nodes) if n != head.node)
            if not (final or others_reached or now_s - head.arrived_s >= self.hold_s):
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
        return head.arrived_s + self.hold_s
