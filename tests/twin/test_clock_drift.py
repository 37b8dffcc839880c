"""A node whose clock drifts against its chip's fusion (``pendsim nodes --clock-drift-ppm``: the
node samples on its own clock, the chip fuses on true time): its samples cross the fusion ticks,
and the twin puts each crossing sample's value on the tick that explains it."""

from __future__ import annotations

import math

import numpy as np

from pendsim_bridge.acquire.emulator import plan
from pendsim_bridge.acquire.packets import GROUP_SLICES
from pendsim_bridge.cli import build_parser
from pendsim_bridge.commands.nodes import spec_from
from pendsim_mj.twin import session as twin_session
from pendsim_mj.twin.session import TwinSession

NODES = ["nodes", "--duration-s", "24", "--hold-s", "2", "--seed", "2", "--phi1-deg", "36.4", "--heading-deg", "40",
         "--mount-misalignment-deg", "2", "--fusion-error-deg", "0.2", "--loss", "0.02",
         "--clock-drift-ppm", "m2=30"]  # fmt: skip


def _m2_nis_after_10_s() -> tuple[float, TwinSession]:
    """M2's mean NIS from 10 s after the start, when one of its sample phases crosses a tick."""
    p = plan(spec_from(build_parser().parse_args(NODES)))
    events = p.sent_in_time_order()
    session = TwinSession()
    q, g, a = GROUP_SLICES["quat"], GROUP_SLICES["gyro"], GROUP_SLICES["accel"]
    nis = []
    for t, k, i in events:
        row = p.streams[k].rows[i]
        session.take(k, t, row[q], row[g], row[a])
        est = session.drain().estimates
        nis += [v for tt, n, v in zip(est.t_s, est.node, est.nis, strict=True) if n == 1 and tt > 10.0]
    return float(np.mean(nis)), session


def test_a_sample_crossing_a_fusion_tick_is_put_on_the_tick_that_explains_it(monkeypatch):
    nis, session = _m2_nis_after_10_s()
    assert session._ticks_moved[1] > 0 and session._ticks_moved[0] == 0  # M1's clock does not drift
    assert nis < 3.0
    assert not session.summary().alarms
    monkeypatch.setattr(twin_session, "TICK_MISS_Z", math.inf)  # values where the learned phase puts them
    unmoved, _ = _m2_nis_after_10_s()
    assert unmoved > 2 * nis  # what the crossing does without it
