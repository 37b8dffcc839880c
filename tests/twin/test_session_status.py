"""What the twin says while its estimate has not started (the status line and the estimator's
/diagnostics): which node it has not heard, or what each node's measurement still learns. A new
user's trial read "waiting for both nodes" while both were sending, held still before the release."""

from __future__ import annotations

import math

from pendsim_bridge.acquire.emulator import plan
from pendsim_bridge.acquire.packets import GROUP_SLICES
from pendsim_bridge.cli import build_parser
from pendsim_bridge.commands.nodes import spec_from
from pendsim_mj.twin.session import TwinSession


def test_before_the_start_the_twin_says_which_node_is_silent_and_then_what_it_learns():
    p = plan(spec_from(build_parser().parse_args(["nodes", "--duration-s", "6", "--hold-s", "2"])))
    session = TwinSession()
    q, g, a = GROUP_SLICES["quat"], GROUP_SLICES["gyro"], GROUP_SLICES["accel"]
    said = []
    for t, k, i in p.sent_in_time_order():
        if not said:
            assert session.waiting_text() == "waiting for m1 and m2's samples"
        row = p.streams[k].rows[i]
        if k == 1 and session.samples[1] == 0 and session.samples[0] > 0:
            assert session.waiting_text() == "waiting for m2's samples"
        session.take(k, t, row[q], row[g], row[a])
        session.drain()
        if math.isnan(session.started_s):
            said.append((t, session.waiting_text()))
    assert not math.isnan(session.started_s)  # it started after the release
    held = [text for t, text in said if 0.5 < t < 1.5]  # both nodes sending, held still
    assert held and all(text.startswith("learning (the nodes must swing): m1 fusion phase: ") for text in held)
    assert all("m2 fusion phase: " in text for text in held)
