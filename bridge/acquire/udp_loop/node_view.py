"""What a controller sees of the rig's two nodes over UDP, sample by sample: the state it takes.

Each node's datagrams are received as ``pendsim acquire`` receives them: stamped with the
kernel's arrival time (``datagrams.read_stamped``), decoded by the node's codec (every field
range-checked; ``packets``) and handed to the node's trusted timeline (``timeline.Timeline``:
its clock fit, from the packets that agree with their neighbours, maps device time onto the
host's monotonic clock; packets off the timeline are counted as implausible when it decides
them). A controller cannot wait for the timeline's decision (50-100 ms), so a sample is *used* at
once when:

- the node's timeline is established (its clock fit spans 0.25 s: before that the node is
  "waiting" and no state is formed);
- it is newer (device time) than the newest used (a reordered or repeated packet is not);
- it did not arrive earlier than its device time allows (``timeline.AHEAD_S`` before the fit's
  line: the same rule as the timeline's ``time_ahead``), nor later than ``silent_s`` after it.

From a used sample: the swing angle from the fused orientation about the hinge
(``estimation.swing_frame.SwingFrame.angle``: the twist from the frame's reference orientation)
and the rate from the gyro's hinge axis (``SwingFrame.rate``); the instant it was taken is its
device time mapped to host time. At a control instant the state is each node's newest sample
carried forward by its age, phi + omega * age, as ``pendsim_mj.control.observe.NodeObserver``
does in simulation. The age counts from the instant the sample's *value* stands for: a BNO055
node reads the chip's latest fused output (100 Hz), on average half a fusion period older than
the node's stamp, so ``value_age_s`` (default 5 ms) is added; 0 for nodes that stamp their values'
own instants. A node from which no sample was used for ``silent_s`` is silent.

The default frames (``model_frames``) are the nodes as the model mounts them (x tangential, y
toward the pivot, z along the hinge) with the BNO055's world frame the model's (heading 0);
nodes glued on by hand need their frames from a recording (``estimation.node_alignment``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.swing_frame import SwingFrame
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import FUSION_RATE_HZ
from pendsim_mj.units import seconds

from ..packets import GROUP_SLICES, Packet, PacketError, StreamFormat
from ..ports import NodeSpec
from ..timeline import AHEAD_S, Timeline

SILENT_S = 0.05  # no sample used for this long: the node is silent (4 samples at 80 Hz), s
VALUE_AGE_S = 0.5 / FUSION_RATE_HZ  # a BNO055 sample's value: on average half a fusion period old, s


def model_frames(params: RigParams = DEFAULT_PARAMS) -> tuple[SwingFrame, SwingFrame]:
    """The swing frames of nodes mounted as the model mounts them (module docstring): hinge axis
    z, toward the pivot y, tangential x, the reference the site's orientation at phi = 0."""
    z, y, x = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])
    return tuple(
        SwingFrame(
            hinge_axis=z, toward_pivot=y, tangential=x, radius_m=radius, quat_axis=z,
            reference_quat_wxyz=rotations.IMU_SITE_QUAT_WXYZ.copy(), angle_offset_rad=0.0, mirrored=False,
            fit_rms_m_s2=0.0,
        )
        for radius in (params.om1_m, params.om2_m)
    )  # type: ignore[return-value]  # fmt: skip


@dataclasses.dataclass(frozen=True)
class ViewCounters:
    """One node's datagrams as the controller took them.

    Attributes:
      received: datagrams on the node's port.
      used: samples that became the node's newest (fed the state).
      malformed: datagrams that are no valid packet of the node, per reason (``packets``).
      stale: valid packets not newer than the newest used (reordered, repeated).
      waiting: valid packets that came before the node's timeline was established.
      off_time: valid packets that arrived too early (ahead of the clock fit) or too late.
      implausible: packets the timeline refused when it decided them, per reason (``timeline``).
      lost: sequence numbers skipped between used samples.
    """

    received: int = 0
    used: int = 0
    malformed: tuple[tuple[str, int], ...] = ()
    stale: int = 0
    waiting: int = 0
    off_time: int = 0
    implausible: tuple[tuple[str, int], ...] = ()
    lost: int = 0


class NodeView:
    """One node as the controller sees it (module docstring).

    Args:
      spec: the node and its port.
      stream: the packet format (it must carry the orientation and the gyro).
      rate_hz: the node's nominal rate.
      frame: the node's swing frame.
      silent_s: no sample used for this long: silent, s.
      value_age_s: how much older a sample's value is than its stamp, on average, s.
    """

    def __init__(
        self,
        spec: NodeSpec,
        stream: StreamFormat,
        rate_hz: float,
        frame: SwingFrame,
        *,
        silent_s: float = SILENT_S,
        value_age_s: float = VALUE_AGE_S,
    ) -> None:
        if not {"quat", "gyro"} <= set(stream.groups()):
            raise ParameterError("a controller needs each node's orientation and gyro: the format must carry both")
        if not (math.isfinite(silent_s) and 0 < silent_s <= 10):
            raise ParameterError(f"silent_s must be in (0, 10] s, got {silent_s!r}")
        if not (math.isfinite(value_age_s) and 0 <= value_age_s <= 1):
            raise ParameterError(f"value_age_s must be in [0, 1] s, got {value_age_s!r}")
        self.spec, self.frame, self.silent_s, self.value_age_s = spec, frame, float(silent_s), float(value_age_s)
        self.codec = stream.codec(spec.name, spec.node_id)
        self.timeline = Timeline(rate_hz=rate_hz, has_seq=self.codec.has_seq, seq_modulus=self.codec.seq_modulus)
        # the newest used sample: device s, taken s (host), its row, (phi, omega) once computed, seq
        self.newest: tuple[float, float, tuple[float, ...], tuple[float, float] | None, int | None] | None = None
        self.used_arrival_s = -math.inf  # arrival of the newest used sample, s since the start
        self._counts = {"received": 0, "used": 0, "stale": 0, "waiting": 0, "off_time": 0, "lost": 0}
        self._malformed: dict[str, int] = {}
        self._implausible: dict[str, int] = {}

    def receive(self, data: bytes, arrival_ns: int, start_ns: int) -> bool:
        """One datagram that arrived at ``arrival_ns`` (host monotonic) in a loop started at
        ``start_ns``; True if its sample became the node's newest."""
        self._counts["received"] += 1
        try:
            packet = self.codec.decode(data)
        except PacketError as exc:
            self._malformed[exc.reason] = self._malformed.get(exc.reason, 0) + 1
            return False
        return self._take(packet, arrival_ns, start_ns)

    def _take(self, packet: Packet, arrival_ns: int, start_ns: int) -> bool:
        """``receive`` of a datagram decoded (counted as received already)."""
        arrival_s = seconds(arrival_ns - start_ns)
        self.timeline.add(packet, arrival_ns, arrival_s)
        if not self.timeline.established:
            self._counts["waiting"] += 1
            return False
        device_s = packet.device_time_us * 1e-6
        if self.newest is not None and device_s <= self.newest[0]:
            self._counts["stale"] += 1
            return False
        taken_s = float(self.timeline.clock.relation().to_recorder(device_s))
        if not taken_s - AHEAD_S <= arrival_s <= taken_s + self.silent_s:
            self._counts["off_time"] += 1
            return False
        if self.newest is not None and packet.seq is not None and self.newest[4] is not None:
            modulus = self.codec.seq_modulus or 2**63
            self._counts["lost"] += max(0, (packet.seq - self.newest[4]) % modulus - 1)
        self.newest = (device_s, taken_s, packet.row, None, packet.seq)
        self.used_arrival_s = arrival_s
        self._counts["used"] += 1
        return True

    def settle(self, now_s: float, *, final: bool = False) -> None:
        """Let the timeline decide what it can (its clock fit learns; refusals are counted)."""
        for decision in self.timeline.decide(now_s, final=final):
            if decision.reason is not None:
                self._implausible[decision.reason] = self._implausible.get(decision.reason, 0) + 1

    def state_at(self, now_s: float) -> tuple[float, float, float]:
        """(phi rad, omega rad/s, age s) at ``now_s`` (s since the start): the newest sample carried
        forward by its value's age (its stamp's plus ``value_age_s``); NaN and inf before the first."""
        if self.newest is None:
            return math.nan, math.nan, math.inf
        device_s, taken_s, row, swing, seq = self.newest
        if swing is None:  # the newest sample's angle and rate, once (only the newest is ever needed)
            values = np.asarray(row)
            phi = float(self.frame.angle(values[GROUP_SLICES["quat"]][None])[0])
            omega = float(self.frame.rate(values[GROUP_SLICES["gyro"]][None])[0])
            swing = (phi, omega)
            self.newest = (device_s, taken_s, row, swing, seq)
        phi, omega = swing
        age = now_s - taken_s + self.value_age_s
        return phi + omega * age, omega, age

    def silent(self, now_s: float) -> bool:
        """No sample used for ``silent_s`` (or none yet)."""
        return now_s - self.used_arrival_s > self.silent_s

    def counters(self) -> ViewCounters:
        c = self._counts
        return ViewCounters(
            received=c["received"], used=c["used"], malformed=tuple(sorted(self._malformed.items())),
            stale=c["stale"], waiting=c["waiting"], off_time=c["off_time"],
            implausible=tuple(sorted(self._implausible.items())), lost=c["lost"],
        )  # fmt: skip


__all__ = ["SILENT_S", "VALUE_AGE_S", "NodeView", "ViewCounters", "model_frames"]
