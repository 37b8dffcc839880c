"""Scripted replay of a recording: its messages in log-time order, paced or as fast as possible,
cut to a time window and filtered by topic, into a script, a new MCAP file or Rerun.

    from .replay import replay
    for msg in replay("run.mcap", speed=1.0, topics=["/imu/m1"], start_s=5, end_s=15):
        print(msg.t_s, msg.decoded.angular_velocity.z)   # as from a live source

Pacing holds a schedule (message k is due at wall time t0 + (log_time_k - log_time_0) / speed)
rather than sleeping between messages, so lateness does not accumulate; ``ReplayStats`` records
each message's lateness.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import time
from collections.abc import Callable, Collection, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.units import nanoseconds, seconds

from ..io import ros2
from ..io.mcap.reader import ChannelData, McapContents, read_mcap, scan_mcap
from ..io.mcap.tools import rewrite


@dataclasses.dataclass(frozen=True)
class ReplayMessage:
    """One message: raw bytes, times, and its ROS 2 decoding on first use."""

    topic: str
    log_time_ns: int
    publish_time_ns: int
    schema_name: str
    data: bytes
    _decoder: Callable[[bytes], Any] | None = dataclasses.field(repr=False, default=None)
    recording_start_ns: int = 0  # the recording's t = 0 (UTC log time)

    @property
    def t_s(self) -> float:
        """Seconds since the recording's start."""
        return seconds(self.log_time_ns - self.recording_start_ns)

    @functools.cached_property
    def decoded(self) -> Any:
        """The ROS 2 message (mcap_ros2's decoder for the channel's schema)."""
        if self._decoder is None:
            raise ParameterError(f"no ROS 2 decoder for schema {self.schema_name!r} on {self.topic}")
        try:
            return self._decoder(self.data)
        except Exception as exc:  # struct.error, IndexError, UnicodeDecodeError: not this type
            raise RecordingError(
                f"topic {self.topic}: a message at log time {self.log_time_ns} ns does not decode as "
                f"{self.schema_name} ({type(exc).__name__})"
            ) from None


@dataclasses.dataclass(frozen=True)
class Lateness:
    """Percentiles of a paced replay's lateness, ms, over ``messages`` messages."""

    messages: int
    p50_ms: float
    p99_ms: float
    max_ms: float


@dataclasses.dataclass
class ReplayStats:
    """What a paced replay did: lateness (s) of each message against its schedule."""

    lateness_s: list[float] = dataclasses.field(default_factory=list)
    messages: int = 0

    def summary(self) -> Lateness:
        late = np.asarray(self.lateness_s) if self.lateness_s else np.zeros(1)
        return Lateness(
            messages=self.messages,
            p50_ms=float(np.percentile(late, 50) * 1e3),
            p99_ms=float(np.percentile(late, 99) * 1e3),
            max_ms=float(late.max() * 1e3),
        )


def _select(
    contents: McapContents, topics: Collection[str] | None, start_s: float | None, end_s: float | None, start_ns: int
):
    """(channel id, row index, log time) of the chosen messages, in log-time order; the window is
    in seconds since the recording's start ``start_ns``."""
    _check_topics(contents.path, {ch.topic for ch in contents.channels.values()}, topics)
    ids, rows, times = [], [], []
    for cid, data in contents.messages.items():
        if topics is not None and contents.channels[cid].topic not in topics:
            continue
        index = np.flatnonzero(_in_window(data.log_time_ns, start_s, end_s, start_ns))
        ids.append(np.full(len(index), cid))
        rows.append(index)
        times.append(data.log_time_ns[index])
    if not ids:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0, np.int64)
    all_ids, all_rows, all_times = np.concatenate(ids), np.concatenate(rows), np.concatenate(times)
    order = np.lexsort((all_ids, all_times))  # by log time, then channel: a stable, total order
    return all_ids[order], all_rows[order], all_times[order]


def _check_topics(path: Path, known: set[str], topics: Collection[str] | None) -> None:
    if topics is not None:
        unknown = sorted(set(topics) - known)
        if unknown:
            raise ParameterError(f"{path}: no topic {', '.join(unknown)}; topics: {', '.join(sorted(known))}")


def _in_window(t_ns: np.ndarray, start_s: float | None, end_s: float | None, start_ns: int) -> np.ndarray:
    keep = np.ones(len(t_ns), bool)
    if start_s is not None:
        keep &= t_ns >= start_ns + nanoseconds(start_s)
    if end_s is not None:
        keep &= t_ns <= start_ns + nanoseconds(end_s)
    return keep


def recording_start_ns(metadata: dict[str, dict[str, str]], first_log_ns: int) -> int:
    """A recording's t = 0: ``pendsim/run`` start_time_ns if valid, else its first message."""
    text = metadata.get("pendsim/run", {}).get("start_time_ns", "")
    return int(text) if text.isdigit() and int(text) < 2**63 else first_log_ns


def is_latched(channel: Any) -> bool:
    """A transient-local channel (rosbag2's offered_qos_profiles durability 1): its last
    message before a cut is still in force after it (/tf_static)."""
    qos = channel.metadata.get("offered_qos_profiles", "")
    return "durability: 1" in qos or "durability: transient_local" in qos


def _check_start_within(path: str | Path, start_s: float | None, start_ns: int, last_ns: int) -> None:
    """A window that starts after the recording's last message is an error naming its length."""
    if start_s is not None and start_ns + nanoseconds(start_s) > last_ns:
        lasts = seconds(max(0, last_ns - start_ns))
        raise ParameterError(
            f"the window starts at {start_s:g} s, after the end of {path}: its messages run from 0 to {lasts:.3f} s "
            "after its start"
        )


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
      start_s, end_s: the window, in seconds since the recording's start (``pendsim/run``
        start_time_ns, else its first message).
      loop: start again from the beginning of the window after its end (until the caller stops).
      stats: filled with each message's lateness when paced.
    """
    _check_window(start_s, end_s, speed)
    mcap = scan_mcap(path)
    if mcap.problems:
        error = mcap.error_text()
        mcap.close()
        raise RecordingError(error)
    mcap.close()
    while True:
        wall0: float | None = None
        log0 = 0
        for message in _messages(path, topics, start_s, end_s):
            if wall0 is None:
                wall0, log0 = clock(), message.log_time_ns
            if math.isfinite(speed):
                due = wall0 + seconds(message.log_time_ns - log0) / speed
                wait = due - clock()
                if wait > 0:
                    sleep(wait)
                if stats is not None:
                    stats.lateness_s.append(max(0.0, clock() - due))
            if stats is not None:
                stats.messages += 1
            yield message
        if not loop or wall0 is None:
            return


def _messages(
    path: str | Path, topics: Collection[str] | None, start_s: float | None, end_s: float | None
) -> Iterator[ReplayMessage]:
    """The chosen messages in log-time order: chunk by chunk when the file's chunks do not
    overlap in time (pendsim's files), else after reading it whole."""
    mcap = scan_mcap(path)
    try:
        refs = mcap.chunk_refs
        _check_topics(Path(path), {ch.topic for ch in mcap.channels.values()}, topics)
        start_ns = recording_start_ns(mcap.metadata, min((r.start_ns for r in refs), default=0))
        _check_start_within(path, start_s, start_ns, max((r.end_ns for r in refs), default=start_ns))
        overlapping = any(b.start_ns < a.end_ns for a, b in itertools.pairwise(refs))
        decoders = _decoders(mcap.schemas)
        if overlapping:
            chunks: Iterator[dict[int, ChannelData]] = iter([_whole(path)])
        else:
            chunks = (c.channels for c in mcap.chunks())
        for channels in chunks:
            if mcap.problems:
                raise RecordingError(mcap.error_text())
            ids, rows, times = [], [], []
            for cid, data in channels.items():
                channel = mcap.channels.get(cid)
                if channel is None or (topics is not None and channel.topic not in topics):
                    continue
                index = np.flatnonzero(_in_window(data.log_time_ns, start_s, end_s, start_ns))
                ids.append(np.full(len(index), cid))
                rows.append(index)
                times.append(data.log_time_ns[index])
            if not ids:
                continue
            all_ids, all_rows, all_times = np.concatenate(ids), np.concatenate(rows), np.concatenate(times)
            for k in np.lexsort((all_ids, all_times)):
                cid, row = int(all_ids[k]), int(all_rows[k])
                data = channels[cid]
                channel = mcap.channels[cid]
                schema = mcap.schemas.get(channel.schema_id)
                payload = data.payloads[row]
                yield ReplayMessage(
                    topic=channel.topic,
                    log_time_ns=int(all_times[k]),
                    publish_time_ns=int(data.publish_time_ns[row]),
                    schema_name=schema.name if schema else "",
                    data=payload.tobytes() if isinstance(payload, np.ndarray) else bytes(payload),
                    _decoder=decoders.get(channel.schema_id),
                    recording_start_ns=start_ns,
                )
    finally:
        mcap.close()


def _whole(path: str | Path) -> dict[int, ChannelData]:
    return read_mcap(path, strict=True).messages


def _decoders(schemas: dict[int, Any]) -> dict[int, Callable[[bytes], Any]]:
    out = {}
    for sid, schema in schemas.items():
        if schema.encoding == "ros2msg":
            try:
                out[sid] = ros2.decoder_for(schema)
            except ValueError:  # a schema mcap_ros2 cannot parse: raw bytes only
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
    keep_unverified: bool = False,
) -> int:
    """Write the chosen window and topics to a new MCAP (schemas, channels, metadata and
    attachments kept; the window in seconds since the recording's start; log times moved so the
    window starts at 0 with ``shift_to_zero``). A latched (transient-local) channel such as
    /tf_static keeps its last message from before the window, stamped at the window's start.
    Content no CRC covers is left out unless ``keep_unverified``. Returns the messages written."""
    _check_window(start_s, end_s, math.inf)
    contents = read_mcap(path, strict=True)
    first = min((int(d.log_time_ns[0]) for d in contents.messages.values() if len(d)), default=0)
    start_ns = recording_start_ns(contents.metadata, first)
    last = max((int(d.log_time_ns.max()) for d in contents.messages.values() if len(d)), default=start_ns)
    _check_start_within(path, start_s, start_ns, last)
    ids, rows, times = _select(contents, topics, start_s, end_s, start_ns)
    window_ns = start_ns + nanoseconds(start_s) if start_s is not None else None
    shift = int(times[0]) if shift_to_zero and len(times) else 0
    if shift_to_zero and window_ns is not None:
        shift = window_ns
    for cid, channel in contents.channels.items():
        data = contents.messages.get(cid)
        if window_ns is None or data is None or not is_latched(channel):
            continue
        if topics is not None and channel.topic not in topics:
            continue
        before = np.flatnonzero(data.log_time_ns < window_ns)
        if len(before):  # the latched message in force at the window's start, moved there
            data.log_time_ns[before[-1]] = window_ns
            data.publish_time_ns[before[-1]] = max(int(data.publish_time_ns[before[-1]]), window_ns)
            ids, rows = np.append(ids, cid), np.append(rows, before[-1])

    def chosen(cid: int, _data: ChannelData) -> np.ndarray | None:
        if topics is not None and contents.channels[cid].topic not in topics:
            return None
        return np.sort(rows[ids == cid])

    return rewrite(
        contents, output, rows=chosen, shift_ns=shift, library="pendsim replay", keep_unverified=keep_unverified
    )


def log_to_rerun(message: ReplayMessage) -> None:
    """Log one replayed message to the current Rerun recording on the 'log_time' timeline:
    Imu -> angular velocity and acceleration scalars; JointState -> positions and velocities."""
    import rerun as rr  # start-up: Rerun, only for a replay into Rerun

    rr.set_time("log_time", duration=message.t_s)
    m = message.decoded
    if message.schema_name == "sensor_msgs/msg/Imu":
        for name, v in (("gyro", m.angular_velocity), ("accel", m.linear_acceleration)):
            rr.log(f"/replay{message.topic}/{name}", rr.Scalars([v.x, v.y, v.z]))
    elif message.schema_name == "sensor_msgs/msg/JointState":
        rr.log(f"/replay{message.topic}/position", rr.Scalars(list(m.position)))
        rr.log(f"/replay{message.topic}/velocity", rr.Scalars(list(m.velocity)))
