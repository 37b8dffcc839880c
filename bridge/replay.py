"""Scripted replay of a recording: its messages in log-time order, paced or as fast as possible,
cut to a time window and filtered by topic, into a script, a new MCAP file or Rerun.

    from bridge.replay import replay
    for msg in replay("run.mcap", speed=1.0, topics=["/imu/m1"], start_s=5, end_s=15):
        print(msg.t_s, msg.decoded.angular_velocity.z)   # as from a live source

Pacing holds a schedule (message k is due at wall time t0 + (log_time_k - log_time_0) / speed)
rather than sleeping between messages, so lateness does not accumulate; ``ReplayStats`` records
each message's lateness.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable, Collection, Iterator
from pathlib import Path

import numpy as np

from bridge.mcap_reader import McapContents, read_mcap
from bridge.mcap_tools import rewrite
from pendsim_mj.errors import ParameterError


@dataclasses.dataclass(frozen=True)
class ReplayMessage:
    """One message: raw bytes, times, and its ROS 2 decoding on first use."""

    topic: str
    log_time_ns: int
    publish_time_ns: int
    schema_name: str
    data: bytes
    _decoder: Callable[[bytes], object] | None = dataclasses.field(repr=False, default=None)

    @property
    def t_s(self) -> float:
        return self.log_time_ns * 1e-9

    @functools.cached_property
    def decoded(self) -> object:
        """The ROS 2 message (mcap_ros2's dynamic decoder for the channel's schema)."""
        if self._decoder is None:
            raise ParameterError(f"no ROS 2 decoder for schema {self.schema_name!r} on {self.topic}")
        return self._decoder(self.data)


@dataclasses.dataclass
class ReplayStats:
    """What a paced replay did: lateness (s) of each message against its schedule."""

    lateness_s: list[float] = dataclasses.field(default_factory=list)
    messages: int = 0

    def summary(self) -> dict[str, float]:
        late = np.asarray(self.lateness_s) if self.lateness_s else np.zeros(1)
        return {
            "messages": self.messages,
            "p50_ms": float(np.percentile(late, 50) * 1e3),
            "p99_ms": float(np.percentile(late, 99) * 1e3),
            "max_ms": float(late.max() * 1e3),
        }


def _select(contents: McapContents, topics: Collection[str] | None, start_s: float | None, end_s: float | None):
    """(channel id, row index, log time) of the chosen messages, in log-time order."""
    known = {ch.topic for ch in contents.channels.values()}
    if topics is not None:
        unknown = sorted(set(topics) - known)
        if unknown:
            raise ParameterError(f"{contents.path}: no topic {', '.join(unknown)}; topics: {', '.join(sorted(known))}")
    ids, rows, times = [], [], []
    for cid, data in contents.messages.items():
        if topics is not None and contents.channels[cid].topic not in topics:
            continue
        t = data.log_time_ns
        keep = np.ones(len(t), bool)
        if start_s is not None:
            keep &= t >= round(start_s * 1e9)
        if end_s is not None:
            keep &= t <= round(end_s * 1e9)
        index = np.flatnonzero(keep)
        ids.append(np.full(len(index), cid))
        rows.append(index)
        times.append(t[index])
    if not ids:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0, np.int64)
    ids, rows, times = np.concatenate(ids), np.concatenate(rows), np.concatenate(times)
    order = np.lexsort((ids, times))  # by log time, then channel: a stable, total order
    return ids[order], rows[order], times[order]


def _check_window(start_s: float | None, end_s: float | None, speed: float) -> None:
    for name, value in (("start_s", start_s), ("end_s", end_s)):
        if value is not None and not math.isfinite(value):
            raise ParameterError(f"{name} must be finite, got {value}")
    if start_s is not None and end_s is not None and end_s < start_s:
        raise ParameterError(f"end_s = {end_s} s is before start_s = {start_s} s")
    if not (speed > 0):
        raise ParameterError(f"speed must be > 0 (or inf for as fast as possible), got {speed}")


def replay(
    path: str | Path,
    *,
    speed: float = math.inf,
    topics: Collection[str] | None = None,
    start_s: float | None = None,
    end_s: float | None = None,
    loop: bool = False,
    stats: ReplayStats | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[ReplayMessage]:
    """Yield a recording's messages in log-time order.

    Args:
      path: the recording (a damaged one raises RecordingError before anything is yielded).
      speed: 1 = real time, 10 = ten times faster, inf = as fast as possible.
      topics: only these topics (an unknown topic is an error).
      start_s, end_s: the window, in the recording's log time, s.
      loop: start again from the beginning of the window after its end (until the caller stops).
      stats: filled with each message's lateness when paced.
    """
    _check_window(start_s, end_s, speed)
    contents = read_mcap(path, strict=True)
    ids, rows, times = _select(contents, topics, start_s, end_s)
    decoders = _decoders(contents)
    while True:
        wall0, log0 = clock(), int(times[0]) if len(times) else 0
        for cid, row, t in zip(ids, rows, times, strict=True):
            if math.isfinite(speed):
                due = wall0 + (int(t) - log0) * 1e-9 / speed
                wait = due - clock()
                if wait > 0:
                    sleep(wait)
                if stats is not None:
                    stats.lateness_s.append(max(0.0, clock() - due))
            data = contents.messages[cid]
            payload = data.payloads[row]
            channel = contents.channels[cid]
            schema = contents.schemas.get(channel.schema_id)
            if stats is not None:
                stats.messages += 1
            yield ReplayMessage(
                topic=channel.topic,
                log_time_ns=int(t),
                publish_time_ns=int(data.publish_time_ns[row]),
                schema_name=schema.name if schema else "",
                data=payload.tobytes() if isinstance(payload, np.ndarray) else bytes(payload),
                _decoder=decoders.get(channel.schema_id),
            )
        if not loop or not len(times):
            return


def _decoders(contents: McapContents) -> dict[int, Callable[[bytes], object]]:
    from mcap_ros2._dynamic import generate_dynamic

    out = {}
    for sid, schema in contents.schemas.items():
        if schema.encoding == "ros2msg":
            try:
                out[sid] = generate_dynamic(schema.name, schema.data.decode())[schema.name]
            except Exception:  # a schema mcap_ros2 cannot parse: raw bytes only
                continue
    return out


def replay_to_mcap(
    path: str | Path,
    output: str | Path,
    *,
    topics: Collection[str] | None = None,
    start_s: float | None = None,
    end_s: float | None = None,
    shift_to_zero: bool = False,
) -> int:
    """Write the chosen window and topics to a new MCAP (schemas, channels, metadata and
    attachments kept; log times moved so the window starts at 0 with ``shift_to_zero``).
    Returns the number of messages written."""
    _check_window(start_s, end_s, math.inf)
    contents = read_mcap(path, strict=True)
    ids, rows, times = _select(contents, topics, start_s, end_s)
    shift = int(times[0]) if shift_to_zero and len(times) else 0

    def chosen(cid: int, _data) -> np.ndarray | None:
        if topics is not None and contents.channels[cid].topic not in topics:
            return None
        return rows[ids == cid]

    return rewrite(contents, output, rows=chosen, shift_ns=shift, library="pendsim replay")


def log_to_rerun(message: ReplayMessage) -> None:
    """Log one replayed message to the current Rerun recording on the 'log_time' timeline:
    Imu -> angular velocity and acceleration scalars; JointState -> positions and velocities."""
    import rerun as rr

    rr.set_time("log_time", duration=message.t_s)
    m = message.decoded
    if message.schema_name == "sensor_msgs/msg/Imu":
        for name, v in (("gyro", m.angular_velocity), ("accel", m.linear_acceleration)):
            rr.log(f"/replay{message.topic}/{name}", rr.Scalars([v.x, v.y, v.z]))
    elif message.schema_name == "sensor_msgs/msg/JointState":
        rr.log(f"/replay{message.topic}/position", rr.Scalars(list(m.position)))
        rr.log(f"/replay{message.topic}/velocity", rr.Scalars(list(m.velocity)))
