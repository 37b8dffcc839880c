"""The rig's sensor nodes: their names, what they are, and which UDP port each sends to
(``--node m1=5601``, shared by acquire and the emulator)."""

from __future__ import annotations

import dataclasses

from pendsim_mj.errors import ParameterError
from pendsim_mj.sensors.bno055 import FUSION_RATE_HZ

NODE_NAMES = ("m1", "m2")
# What the rig's nodes are, as pendsim/imu metadata: BNO055s in NDOF mode, fused at 100 Hz.
BNO055_NDOF = {"fusion_timing": "true", "fusion_rate_hz": str(FUSION_RATE_HZ)}


@dataclasses.dataclass(frozen=True)
class NodeSpec:
    """A node's name (m1 or m2) and the UDP port it sends to."""

    name: str
    port: int

    def __post_init__(self) -> None:
        if self.name not in NODE_NAMES:
            raise ParameterError(f"unknown node {self.name!r}; allowed: {', '.join(NODE_NAMES)}")
        if not 1 <= self.port <= 65535:
            raise ParameterError(f"port of {self.name} must be in [1, 65535], got {self.port}")

    @property
    def node_id(self) -> int:
        """The id the node puts in its packets: 1 for m1, 2 for m2."""
        return NODE_NAMES.index(self.name) + 1


DEFAULT_NODES = (NodeSpec("m1", 5601), NodeSpec("m2", 5602))


def parse_node(text: str) -> NodeSpec:
    """``m1=5601`` to a NodeSpec."""
    name, sep, port = text.partition("=")
    if not sep:
        raise ParameterError(f"bad node {text!r}: expected NAME=PORT, e.g. m1=5601")
    try:
        number = int(port)
    except ValueError:
        raise ParameterError(f"bad node {text!r}: port {port!r} is not a number") from None
    return NodeSpec(name.strip(), number)


def check_nodes(nodes: tuple[NodeSpec, ...]) -> tuple[NodeSpec, ...]:
    """At least one node, each name and port once; sorted m1, m2."""
    if not nodes:
        raise ParameterError("give at least one node, e.g. --node m1=5601")
    for what in ("node", "port"):
        values = [str(n.name if what == "node" else n.port) for n in nodes]
        twice = sorted({v for v in values if values.count(v) > 1})
        if twice:
            raise ParameterError(f"{what} {twice[0]} given twice")
    return tuple(sorted(nodes, key=lambda n: n.name))
