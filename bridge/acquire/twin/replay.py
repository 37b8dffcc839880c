"""``pendsim twin --replay REC``: the twin on a recording, its samples fed at the recording's own
pace (``speed`` 1), faster, or as fast as it can (``speed`` 0), through the same pipeline as live
(``twin.TwinPipeline``), so that a replay gives what the live run gave.

The samples' instants are on the recording's clock:
- a recording by ``pendsim acquire``: its nodes' stamps through the clock relation it fitted, as
  ``validate`` reads them;
- another with header stamps (``pendsim record`` with a latency, a ROS 2 bag): the stamps through
  the relation fitted to the log times (``timing.fit_clock``, as validate does: a log time is an
  arrival, late by a varying latency, and two can be equal);
- the log times, where the stamps are no clock.
The twin's recording keeps that clock (same UTC start). A recording written by the twin itself
lists the samples that came too late live; they are left out here too. A driven recording's
torques (``/drive``) are the motor torques the twin's model is given.

The twin runs on the rig in ``spec`` (the command gives it the recording's own, with
``--params-file``/``--set`` on top); where that differs from what the recording states
(``pendsim/rig_parameters``), e.g. a rig calibrated from it, the differences are said.

Refused (``RecordingError``, one line): a file that is not a readable recording, one without both
nodes' IMU topics, a run of the spatial model, a drive other than hinge torques.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.errors import RecordingError
from pendsim_mj.estimation.alignment import NodeSamples
from pendsim_mj.estimation.timing import fit_clock
from pendsim_mj.rig.drives import NCHANNEL
from pendsim_mj.rig.params import RigParams
from pendsim_mj.units import nanoseconds

from ...io import twin_topics
from ...io.measured import fusion_rate_of, node_samples
from ...io.recording import read_recording
from ...io.recording_layout import DRIVE_LAYOUT, DRIVE_TOPIC, imu_topic
from ...report.twin_views import TwinView
from ..sink import RecordingSink
from .pipeline import TwinPipeline, TwinResult, TwinSpec, close_sink, open_sink
from .summary import Narrator, status_text

RIG_TOLERANCE = 1e-9  # relative: parameters that differ by more are said to differ


def differing_parameters(recorded: RigParams, twin: RigParams) -> list[str]:
    """The parameters in which two rigs differ (relative tolerance ``RIG_TOLERANCE``): "name
    recorded -> twin's", the largest relative difference first."""
    a, b = recorded.as_dict(), twin.as_dict()
    out: list[tuple[float, str]] = []  # (relative difference, text): the largest first
    for name, value in a.items():
        other = b.get(name)
        if isinstance(value, (int, float)) and isinstance(other, (int, float)):
            relative = abs(value - other) / max(abs(value), abs(other), 1e-300)
            if relative > RIG_TOLERANCE:
                out.append((relative, f"{name} {value:.6g} -> {other:.6g}"))
        elif value != other:
            out.append((math.inf, f"{name} {value!r} -> {other!r}"))
    return [text for _, text in sorted(out, key=lambda d: -d[0])]


def _noted_events(metadata: dict[str, dict[str, str]]) -> list[tuple[float, str]]:
    """What a live twin saw of the transport and noted (a node's clock jump), from its recording:
    a replay's samples are already on the corrected clock, so it says them again from here."""
    text = metadata.get(twin_topics.TWIN_RESULT_METADATA, {}).get("events")
    if not text:
        return []
    try:
        events = [(float(t), str(what)) for t, what in json.loads(text)]
    except (ValueError, TypeError):
        raise RecordingError(
            "the recording's pendsim/twin_result 'events' entry is not a list of [t_s, text]"
        ) from None
    return [(t, what) for t, what in events if "its clock jumped" in what and math.isfinite(t)]


def _late_samples(metadata: dict[str, dict[str, str]]) -> frozenset[tuple[int, int]]:
    text = metadata.get(twin_topics.TWIN_RESULT_METADATA, {}).get("late")
    if not text:
        return frozenset()
    try:
        return frozenset((int(n), int(t)) for n, t in json.loads(text))
    except (ValueError, TypeError):
        raise RecordingError("the recording's pendsim/twin_result 'late' entry is not a list of [node, t_ns]") from None


def _fusion_rate_hz(metadata: dict[str, dict[str, str]], recorded: float | None) -> float | None:
    """The nodes' fusion rate: as the twin that wrote the recording took it, else from its node
    model (``measured.fusion_rate_of``; None: values at their own instants)."""
    text = metadata.get(twin_topics.TWIN_METADATA, {}).get("fusion_rate_hz")
    if text is None:
        return recorded
    if text == "none":
        return None
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and 0 < value <= 10_000):
        raise RecordingError(
            f"the recording's pendsim/twin fusion_rate_hz {text!r} is not 'none' or a rate in (0, 10000] Hz"
        )
    return value


def _instants(samples: NodeSamples) -> NDArray[np.float64]:
    """A node's sample instants on the recording's clock (s; module docstring)."""
    log = np.asarray(samples.log_t_s, dtype=float)
    if samples.stamp_s is None:
        return log
    clock = fit_clock(samples.stamp_s, log)  # None: stamps that do not increase, or no clock's rate
    return log if clock is None else clock.to_recorder(samples.stamp_s)


def replay(
    spec: TwinSpec,
    recording: str | Path,
    *,
    output: Path | None,
    replace: bool = False,
    speed: float = 1.0,
    views_for: Callable[[int], tuple[TwinView, ...]] | None = None,
    say: Callable[[str], None] = print,
    status: Callable[[str], None] | None = None,
) -> TwinResult:
    """Run the twin on a recording (module docstring); ``speed`` 0: as fast as it can;
    ``views_for(start_utc_ns)`` opens the live views (closed at the end, on every exit path)."""
    from ..packets import GROUP_SLICES, ROW_FIELDS

    path = Path(recording)
    rec = read_recording(path, topics={imu_topic("m1"), imu_topic("m2"), DRIVE_TOPIC})
    if rec.metadata.get("pendsim/run", {}).get("model") == "spatial":
        raise RecordingError(
            f"{path} is a run of the spatial model (the pendulums tilt out of their planes); the twin models "
            "the planar rig: replay a planar recording (pendsim record --model planar, the default)"
        )
    if "pendsim/rig_parameters" in rec.metadata:
        differ = differing_parameters(rec.params(), spec.params)
        if differ:  # said, not refused: the rig given is the recording's better known (calibrated)
            say(
                f"twin: the rig given differs from the one {path.name} states ({'; '.join(differ[:3])}"
                f"{f'; {len(differ)} in all' if len(differ) > 3 else ''}): the twin runs on the rig given"
            )
    m1, m2 = node_samples(rec)
    torque_t, torque = None, None
    drive = rec.drive_input_s
    if drive is not None:
        torque_t, held = drive
        if np.any(held[:, 2:] != 0):
            raise RecordingError(f"{path}: its drive moves the support; the twin models hinge torques only")
        torque = held[:, :2]
    skip = _late_samples(rec.metadata)
    noted = _noted_events(rec.metadata)
    rows: list[NDArray[np.float64]] = []
    for samples in (m1, m2):
        r = np.zeros((len(samples.log_t_s), len(ROW_FIELDS)))
        r[:, GROUP_SLICES["quat"]] = samples.quat_wxyz
        r[:, GROUP_SLICES["gyro"]] = samples.gyro_rad_s
        r[:, GROUP_SLICES["accel"]] = samples.accel_m_s2
        rows.append(r)
    times = np.concatenate([_instants(m1), _instants(m2)])
    if not np.all(np.isfinite(times)):
        raise RecordingError(f"{path}: a sample's time is not finite")
    node = np.concatenate([np.zeros(len(m1.log_t_s), np.int64), np.ones(len(m2.log_t_s), np.int64)])
    index = np.concatenate([np.arange(len(m1.log_t_s)), np.arange(len(m2.log_t_s))])
    recorded = _Recorded(rows, times, node, index, np.lexsort((node, times)), torque_t, torque, skip, noted)
    start_utc_ns = int(rec.start_time_ns)
    spec = dataclasses.replace(spec, fusion_rate_hz=_fusion_rate_hz(rec.metadata, fusion_rate_of(rec)))
    del rec
    views = views_for(start_utc_ns) if views_for is not None else ()
    try:
        return _run(spec, path, recorded, start_utc_ns, output=output, replace=replace, speed=speed, views=views,
                    say=say, status=status)  # fmt: skip
    finally:
        for v in views:
            v.close()


@dataclasses.dataclass(frozen=True)
class _Recorded:
    """A recording's samples as the replay feeds them: each node's rows (``packets.ROW_FIELDS``),
    every sample's instant (s), node and row index, their time order; the drive's torques (None:
    a free run); the samples to leave out and the events to say again (a twin's own recording)."""

    rows: list[NDArray[np.float64]]
    times: NDArray[np.float64]
    node: NDArray[np.int64]
    index: NDArray[np.int64]
    order: NDArray[np.int64]
    torque_t: NDArray[np.float64] | None
    torque: NDArray[np.float64] | None
    skip: frozenset[tuple[int, int]]
    noted: list[tuple[float, str]]

    def torques_at(self, t_s: float) -> tuple[float, float]:
        """The drive's hinge torques held at ``t_s`` (N m)."""
        if self.torque is None or self.torque_t is None:
            return 0.0, 0.0
        k = int(np.searchsorted(self.torque_t, t_s, side="right")) - 1
        return (float(self.torque[k, 0]), float(self.torque[k, 1])) if k >= 0 else (0.0, 0.0)


class _DriveCopy:
    """A driven recording's ``/drive`` copied into the twin's recording as the replay reaches it
    (a replay of the twin's recording then gives the twin the same torques)."""

    def __init__(self, sink: RecordingSink, recorded: _Recorded, start_utc_ns: int) -> None:
        assert recorded.torque_t is not None and recorded.torque is not None
        self.sink = sink
        self.channel = sink.register(DRIVE_TOPIC, twin_topics.SCHEMA)
        self.start_utc_ns = start_utc_ns
        self.t_ns = start_utc_ns + nanoseconds(recorded.torque_t)
        self.held = np.zeros((len(recorded.torque), NCHANNEL))
        self.held[:, :2] = recorded.torque  # hinge torques only (a drive of the support is refused)
        self.next = 0

    def upto(self, t_s: float) -> None:
        """Add the drive's rows up to ``t_s`` (s on the recording's clock; inf: the rest), before
        the file has been written up to them (the sink drops older messages)."""
        end = len(self.t_ns)
        if not math.isinf(t_s):
            end = int(np.searchsorted(self.t_ns, self.start_utc_ns + nanoseconds(t_s), "right"))
        if end > self.next:
            n = end - self.next
            size = np.full(n, NCHANNEL)
            payloads = DRIVE_LAYOUT.encode(
                n, size=size, stride=size, data_offset=np.zeros(n), data=self.held[self.next : end]
            )
            self.sink.add(self.channel, self.t_ns[self.next : end], payloads)
            self.next = end


def _run(
    spec: TwinSpec,
    path: Path,
    recorded: _Recorded,
    start_utc_ns: int,
    *,
    output: Path | None,
    replace: bool,
    speed: float,
    views: tuple[TwinView, ...],
    say: Callable[[str], None],
    status: Callable[[str], None] | None,
) -> TwinResult:
    from ..receiver import stop_signals

    sink, partial = None, None
    if output is not None:
        sink, partial = open_sink(
            output,
            replace=replace,
            spec=spec,
            source=f"replay of {path.name}",
            groups=("quat", "gyro", "accel"),
            node_names=("m1", "m2"),
            start_utc_ns=start_utc_ns,
        )
    drive = _DriveCopy(sink, recorded, start_utc_ns) if sink is not None and recorded.torque is not None else None
    session = spec.session()
    for t, what in recorded.noted:
        session.note(t, what)
    pipeline = TwinPipeline(
        spec, session, sink=sink, node_names=("m1", "m2"), start_utc_ns=start_utc_ns, views=views, skip=recorded.skip
    )
    times, order = recorded.times, recorded.order
    say(
        f"twin: replaying {path} ({len(times)} samples"
        + (f", {speed:g}x its pace)" if speed else ", as fast as it can)")
        + (f"; writing {partial} until done, then {output}" if output is not None else "")
    )
    narrate = Narrator(say, pipeline.start_utc_ns)
    wall0 = time.monotonic()
    t_first = float(times[order[0]]) if len(order) else 0.0
    stop = "end of recording"
    try:
        with stop_signals() as signalled:
            for i in order:
                if signalled:
                    stop = signalled[0]
                    break
                t = float(times[i])
                if speed > 0:
                    delay = wall0 + (t - t_first) / speed - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                n = int(recorded.node[i])
                torques = recorded.torques_at if recorded.torque is not None else (0.0, 0.0)  # held mid-interval
                pipeline.push(n, t, recorded.rows[n][recorded.index[i]], t, torques)
                if drive is not None:
                    drive.upto(t + 1.0)  # ahead of what the file is given (its flushes trail)
                pipeline.step(t)
                if pipeline.tick(time.monotonic() - wall0 if speed else t, session.estimator.t_s):
                    narrate(pipeline)  # as live: new alarms and events, once a second
                    if status is not None:
                        status(status_text(pipeline, t - t_first))
        pipeline.finish()
        narrate(pipeline)  # what came after the last second's
        if drive is not None:
            drive.upto(math.inf)
    finally:
        with contextlib.suppress(Exception):  # on an error too: the views' thread ends before they close
            pipeline.stop_views()
    duration = time.monotonic() - wall0
    messages, written = 0, None
    if sink is not None and partial is not None and output is not None:
        messages = close_sink(pipeline, partial, output, replace=replace, stop_reason=stop, duration_s=duration)
        written = output
    return TwinResult(
        written, duration, stop, session.summary(), tuple(pipeline.merger.late), (math.nan, math.nan), messages,
        start_utc_ns=pipeline.start_utc_ns,
    )  # fmt: skip
