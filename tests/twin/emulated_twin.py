"""The twin on ``pendsim nodes``'s data, offline: the emulator's plan (every node sample as its
packet carries it, in the order they are sent) fed into a ``TwinSession`` of the paper's rig."""

from __future__ import annotations

from pendsim_bridge.acquire.emulator import plan
from pendsim_bridge.acquire.packets import GROUP_SLICES
from pendsim_bridge.cli import build_parser
from pendsim_bridge.commands.nodes import spec_from
from pendsim_mj.twin.session import TwinSession


def twin_on_nodes(nodes: list[str]) -> TwinSession:
    """The twin after ``pendsim nodes`` with these options (e.g. ``--duration-s``, ``--hold-s``)."""
    p = plan(spec_from(build_parser().parse_args(["nodes", *nodes])))
    session = TwinSession()
    q, g, a = GROUP_SLICES["quat"], GROUP_SLICES["gyro"], GROUP_SLICES["accel"]
    for t, k, i in p.sent_in_time_order():
        row = p.streams[k].rows[i]
        session.take(k, t, row[q], row[g], row[a])
        session.drain()
    return session
