"""A node whose clock drifts against its chip's fusion (``pendsim nodes --clock-drift-ppm``: the
node samples on its own clock, the chip fuses on true time): its samples cross the fusion ticks,
and the twin puts each crossing sample's value on the tick that explains it. A chip fusing on a
clock that drifts against the twin's (``pendsim record --clock-drift-ppm``): its ticks move, and
the twin's moving grid of phases follows them."""

from __future__ import annotations

import contextlib
import io
import json
import math

import numpy as np
from mcap.reader import make_reader

from pendsim_bridge.acquire.emulator import plan
from pendsim_bridge.acquire.packets import GROUP_SLICES
from pendsim_bridge.cli import build_parser, main
from pendsim_bridge.commands.nodes import spec_from
from pendsim_mj.rig.params import DEFAULT_PARAMS
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


def test_a_chip_fusing_on_a_node_clock_that_drifts_against_the_twins_is_followed(tmp_path):
    """``pendsim record --clock-drift-ppm 50``: M2's node, and its chip's fusion with it, run 50 ppm
    fast; the replay maps M2's stamps to the recorder's clock, on which M2's fusion ticks then move
    by -50 us every second (ticks every 10 ms / (1 + 50e-6)). The twin's moving grid follows that
    drift (the recording's own setting is the truth); on the fixed grid alone M2's NIS was 24 after
    90 s and the damping on M2 a third of the rig's."""
    recording, twin = tmp_path / "drift.mcap", tmp_path / "twin.mcap"
    said = io.StringIO()
    with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
        assert main(["record", "--clock-drift-ppm", "50", "--duration-s", "60", "-o", str(recording)]) == 0
        assert main(["twin", "--replay", str(recording), "--speed", "0", "-o", str(twin)]) == 0
    (line,) = [x for x in said.getvalue().splitlines() if x.startswith("fusion timing:")]
    assert "(m2 -" in line and "m1" not in line, line  # said, for M2 alone
    with open(twin, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["pendsim/twin_result"]
    m1, m2 = json.loads(meta["learned"])
    assert abs(m2["phase_drift_ppm"] + 50.0) < 10.0, m2
    assert abs(m1["phase_drift_ppm"]) < 5.0, m1  # M1's chip fuses on the recorder's clock
    nis = json.loads(meta["nis_mean"])
    assert max(nis) < 3.0, nis
    b2, sigma_b2 = json.loads(meta["parameters"])["b2_n_m_s"][:2]
    assert abs(b2 - DEFAULT_PARAMS.b2_n_m_s) < 3 * sigma_b2, (b2, sigma_b2)
