"""``pendsim twin``: the twin beside the rig, on live packets (``acquire.udp_loop.twin_loop``) or on
a recording replayed at its own pace (``replay``), through one pipeline (``TwinPipeline``):

1. each node sample (its instant on the twin's clock, its row) goes into the merger
   (``pendsim_mj.twin.merge``: both nodes in one time order);
2. what the merger releases goes to the recording's measured topics (``/imu/mN``: the layout of
   ``pendsim acquire``, so ``validate``, ``view`` and ``replay`` read it) and into the twin
   (``pendsim_mj.twin.session.TwinSession``);
3. what the twin produced goes to the recording's twin topics (``io.twin_topics``) and to the live
   views; once a second, ``/diagnostics`` (the health status) and the status line; every half
   second the file is written up to what can no longer change and handed to the OS, so a killed
   twin loses at most about a second (the temporary file is for ``pendsim recover``).

The recording is written under a temporary name beside the output and published when complete.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pendsim_mj import __version__
from pendsim_mj.errors import RecordingError
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import FUSION_RATE_HZ
from pendsim_mj.twin.estimator import TRACKABLE, Forecast
from pendsim_mj.twin.health import WHAT, Alarm
from pendsim_mj.twin.measurement import Learned
from pendsim_mj.twin.merge import DEFAULT_HOLD_S, Held, SampleMerger
from pendsim_mj.twin.outputs import Estimates, ParameterCheck
from pendsim_mj.twin.session import (
    DEFAULT_TRACK,
    FORECAST_STEP_S,
    NODE_PARAMETERS,
    TwinOutput,
    TwinSession,
    TwinSummary,
)
from pendsim_mj.units import nanoseconds, seconds

from ...errors import OutputError
from ...io import ros2, twin_topics
from ...io.outputs import describe_os_error, publish, replace_hint, temporary_sibling
from ...report.twin_views import TwinView
from ..packets import GROUP_SLICES
from ..sink import RecordingSink

Torques = tuple[float, float] | Callable[[float], tuple[float, float]]
"""A sample's hinge torques: held since the last one (N m), or the drive as a function of time."""
FLUSH_S = 0.5
DIAGNOSTICS_S = 1.0
VIEW_S = 0.2  # live views are given what the twin produced and sent this often, s (5 a second: each
# batch costs Rerun a fixed part; from their own thread, ``ViewFeeder``)
PUBLISH_S = 0.05  # what the twin produced is taken from it this often, s (an alarm's /diagnostics: the
# health status then); the file is given it in batches (every VIEW_S with views, else every FLUSH_S)
KEEP_S = 0.1  # the file is written up to this long before the newest sample released


@dataclasses.dataclass(frozen=True)
class TwinSpec:
    """How the twin runs.

    Attributes:
      params: the rig the twin models.
      track: the rig's parameters tracked and monitored (``pendsim_mj.twin.session.RIG_PARAMETERS``;
        the node states are tracked always).
      forecast_horizon_s, forecast_every_s: the forecasts.
      threshold, persist_s, baseline_s: the health monitor's.
      hold_s: the merger's longest wait for the other node, s.
      fusion_rate_hz: the nodes' fusion rate (a BNO055 in NDOF mode: 100 Hz; the twin learns where
        its ticks fall); None for nodes that stamp their values' own instants.
    """

    params: RigParams = DEFAULT_PARAMS
    track: tuple[str, ...] = DEFAULT_TRACK
    forecast_horizon_s: float = 2.0
    forecast_every_s: float = 1.0
    threshold: float = 5.0
    persist_s: float = 3.0
    baseline_s: float = 0.0
    hold_s: float = DEFAULT_HOLD_S
    fusion_rate_hz: float | None = FUSION_RATE_HZ

    def session(self) -> TwinSession:
        """A twin that runs as this spec says."""
        return TwinSession(
            self.params,
            track=self.track,
            forecast_horizon_s=self.forecast_horizon_s,
            forecast_every_s=self.forecast_every_s,
            threshold=self.threshold,
            persist_s=self.persist_s,
            baseline_s=self.baseline_s,
            fusion_rate_hz=self.fusion_rate_hz,
        )

    def metadata(self, source: str) -> dict[str, str]:
        return {
            "source": source,
            "track": ",".join(self.track + NODE_PARAMETERS),
            "forecast_horizon_s": repr(self.forecast_horizon_s),
            "forecast_every_s": repr(self.forecast_every_s),
            "threshold_sigma": repr(self.threshold),
            "persist_s": repr(self.persist_s),
            "baseline_s": repr(self.baseline_s),
            "hold_s": repr(self.hold_s),
            "fusion_rate_hz": "none" if self.fusion_rate_hz is None else repr(self.fusion_rate_hz),
            "pendsim_version": __version__,
        }


@dataclasses.dataclass(frozen=True)
class TwinResult:
    """A twin's run.

    Attributes:
      path: the recording written (None: none asked for).
      duration_s: how long it ran (wall time), s.
      stop_reason: "duration", "end of recording", "interrupted", "terminated".
      summary: the twin's figures.
      late: samples that came after later ones had been taken in (node, t_s).
      latency_ms: (p50, p99) from a sample's arrival to its estimate (live; NaN in a replay as fast
        as possible).
      messages: messages written.
      packets: live, per node: (datagrams received, samples used, packets before its clock fit was
        established, others not used: stale, off time, malformed or implausible); () in a replay.
      start_utc_ns: UTC of the twin's t = 0, ns (the alarms' times of day).
    """

    path: Path | None
    duration_s: float
    stop_reason: str
    summary: TwinSummary
    late: tuple[tuple[int, float], ...]
    latency_ms: tuple[float, float]
    messages: int
    packets: tuple[tuple[int, int, int, int], ...] = ()
    start_utc_ns: int | None = None


class ViewFeeder:
    """The live views fed from their own thread: the twin's loop gathers what it has for them
    (``add_*``) and hands it over in one piece with ``send`` (non-blocking), so that a view's
    encoding (Rerun's every few hundred ms) never holds up a sample's estimate. The thread applies
    each call to every view in order, then sends the views' batches, at most once every
    ``VIEW_S`` (what came meanwhile goes in the next one: a replay faster than real time); ``stop``
    sends what is left and ends the thread (the views themselves are closed by whoever opened
    them). An error in a view ends the feeding and is raised by ``stop``."""

    def __init__(self, views: tuple[TwinView, ...]) -> None:
        self.views = views
        self._calls: list[tuple[str, tuple[object, ...]]] = []
        self._queue: queue.SimpleQueue[list[tuple[str, tuple[object, ...]]] | None] = queue.SimpleQueue()
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="pendsim-twin-views", daemon=True)
        self._thread.start()

    def add_estimates(self, est: Estimates) -> None:
        self._calls.append(("add_estimates", (est,)))

    def add_forecast(self, made_at_s: float, forecast: Forecast) -> None:
        self._calls.append(("add_forecast", (made_at_s, forecast)))

    def add_parameters(self, check: ParameterCheck) -> None:
        self._calls.append(("add_parameters", (check,)))

    def add_alarm(self, alarm: Alarm) -> None:
        self._calls.append(("add_alarm", (alarm,)))

    def add_diagnostics(self, t_s: float, statuses: list[ros2.DiagnosticStatus]) -> None:
        self._calls.append(("add_diagnostics", (t_s, statuses)))

    def send(self) -> None:
        """Hand what was added since the last call to the thread (one item: one wake-up)."""
        if self._calls:
            calls, self._calls = self._calls, []
            self._queue.put(calls)

    def close(self) -> None:
        self.stop()

    def _run(self) -> None:
        sent = -math.inf
        while True:
            batches = [self._queue.get()]
            if batches[0] is not None:
                time.sleep(max(0.0, sent + VIEW_S - time.monotonic()))
            with contextlib.suppress(queue.Empty):
                while True:
                    batches.append(self._queue.get_nowait())
            if self.error is None:  # a failed view is fed no more
                try:
                    for calls in batches:
                        for name, args in calls or ():
                            for view in self.views:
                                getattr(view, name)(*args)
                    for view in self.views:
                        view.send()
                except BaseException as exc:  # raised again by stop, in the twin's thread
                    self.error = exc
            sent = time.monotonic()
            if None in batches:
                break

    def stop(self) -> None:
        """Send what is queued, end the thread; raise a view's error if one failed."""
        if self._thread.is_alive():
            self.send()
            self._queue.put(None)
            self._thread.join()
        if self.error is not None:
            error, self.error = self.error, None
            raise error


class TwinPipeline:
    """Samples in, the twin's outputs out (module docstring).

    Args:
      spec: how the twin runs.
      session: the twin.
      sink: the recording (``acquire.sink.RecordingSink`` with ``diagnostics``), or None.
      node_names: the nodes' names, M1's first.
      start_utc_ns: UTC of the twin's t = 0 (log times are this plus the instants).
      views: live views.
      skip: (node, t_s) of samples to leave out (a replay of a twin's recording: those that came
        too late live).
      period_s: the nodes' sample period (live: a sample whose instant is older than the other
        node's next goes at once, ``merge.SampleMerger``); None: each waits for the other node.
    """

    def __init__(
        self,
        spec: TwinSpec,
        session: TwinSession,
        *,
        sink: RecordingSink | None,
        node_names: tuple[str, str],
        start_utc_ns: int,
        views: tuple[TwinView, ...] = (),
        skip: frozenset[tuple[int, int]] = frozenset(),
        period_s: float | None = None,
    ) -> None:
        self.spec, self.session, self.sink = spec, session, sink
        self.feeder = ViewFeeder(views) if views else None
        self.views: tuple[TwinView | ViewFeeder, ...] = (self.feeder,) if self.feeder is not None else ()
        self.node_names, self.start_utc_ns = node_names, start_utc_ns
        self.merger: SampleMerger[tuple[NDArray[np.float64], Torques]] = SampleMerger(spec.hold_s, period_s=period_s)
        self.skip = skip
        self._channels: dict[str, int] = {}
        self._forecast_points = 0
        self._estimate_logged_s = -math.inf
        if sink is not None:
            self._register()
        self.latency_s: list[float] = []
        self._unwritten: list[Held[tuple[NDArray[np.float64], Torques]]] = []
        self._next_flush_s = -math.inf
        self._next_diag_s = -math.inf
        self._next_view_s = -math.inf
        self._next_collect_s = -math.inf
        # drained from the twin, not yet written or shown: each output with its alarms' statuses
        self._collected: list[tuple[TwinOutput, list[tuple[float, list[ros2.DiagnosticStatus]]]]] = []
        self.alarms: list[Alarm] = []

    def _register(self) -> None:
        sink = self.sink
        assert sink is not None
        names = self.session.estimator.track
        self._estimate_layout = twin_topics.layout(twin_topics.ESTIMATE_COLUMNS)
        topics = [twin_topics.ESTIMATE_TOPIC]
        if names:  # nothing tracked: no /twin/parameters
            self._parameter_layout = twin_topics.layout(twin_topics.parameter_columns(names))
            topics.append(twin_topics.PARAMETERS_TOPIC)
        if self.spec.forecast_horizon_s > 0:  # no forecasts: no /twin/forecast
            self._forecast_points = max(1, math.ceil(self.spec.forecast_horizon_s / FORECAST_STEP_S - 1e-9) + 1)
            self._forecast_layout = twin_topics.layout(twin_topics.forecast_columns(self._forecast_points))
            topics.append(twin_topics.FORECAST_TOPIC)
        for topic in topics:
            self._channels[topic] = sink.register(topic, twin_topics.SCHEMA)

    def push(
        self,
        node: int,
        t_s: float,
        row: NDArray[np.float64],
        arrived_s: float,
        torques_n_m: Torques = (0.0, 0.0),
    ) -> None:
        """A node's sample: its instant (s on the twin's clock), its packet row
        (``acquire.packets.ROW_FIELDS``), when it came (s, the same clock as ``step``'s now)."""
        t_ns = nanoseconds(t_s)
        if (node, t_ns) in self.skip:
            return
        # the instant as the recording keeps it (whole ns): a replay of the recording gives the same numbers
        self.merger.push(node, seconds(t_ns), (row, torques_n_m), arrived_s)

    def step(self, now_s: float, *, final: bool = False, clock: Callable[[], float] | None = None) -> None:
        """Release what may go, take it into the twin, write and show what it produced;
        ``clock`` (s, the arrivals' clock) stamps when each estimate was ready (latency)."""
        released = self.merger.pop(now_s, final=final)
        if not released:
            return
        quat, gyro, accel = GROUP_SLICES["quat"], GROUP_SLICES["gyro"], GROUP_SLICES["accel"]
        for held in released:
            row, torques = held.item
            taken = self.session.take(held.node, held.t_s, row[quat], row[gyro], row[accel], torques)
            if taken and clock is not None:
                self.latency_s.append(clock() - held.arrived_s)
        if self.sink is not None:
            self._unwritten += released

    def collect(self) -> None:
        """Take what the twin produced since the last call (``tick`` calls it every
        ``PUBLISH_S``): an alarm's /diagnostics are the health status of this moment; the rest
        waits for ``publish``."""
        out = self.session.drain()
        if not (len(out.estimates) or out.forecasts or out.checks or out.alarms):
            return
        diagnostics = []
        for alarm in out.alarms:
            self.alarms.append(alarm)
            if self.sink is not None:
                diagnostics.append((alarm.t_s, self.statuses()))
        self._collected.append((out, diagnostics))

    def publish(self) -> None:
        """Write and show what was taken in since the last call, in one batch (``tick`` calls it
        every ``VIEW_S`` with views, before each flush and the diagnostics): the measured samples
        (one call per node), the twin's outputs (the estimates in one call)."""
        if self.sink is not None and self._unwritten:
            for node in (0, 1):
                mine = [h for h in self._unwritten if h.node == node]
                if mine:
                    t_ns = self.start_utc_ns + nanoseconds(np.array([h.t_s for h in mine]))
                    self.sink.add_samples(self.node_names[node], t_ns, np.array([h.item[0] for h in mine]))
            self._unwritten = []
        self.collect()
        collected, self._collected = self._collected, []
        if collected:
            self._publish(collected)

    def _publish(self, collected: list[tuple[TwinOutput, list[tuple[float, list[ros2.DiagnosticStatus]]]]]) -> None:
        outs = [out for out, _ in collected]
        parts = [out.estimates for out in outs if len(out.estimates)]
        est = Estimates.concatenate(parts) if len(parts) > 1 else (parts[0] if parts else Estimates.empty())
        sink = self.sink
        if sink is not None:
            base = self.start_utc_ns
            if len(est):
                logged = np.maximum.accumulate(np.concatenate([[self._estimate_logged_s], est.t_s]))[1:]
                self._estimate_logged_s = float(logged[-1])
                sink.add(
                    self._channels[twin_topics.ESTIMATE_TOPIC],
                    base + nanoseconds(logged),
                    twin_topics.encode(self._estimate_layout, twin_topics.estimate_values(est)),
                )
            for out, diagnostics in collected:
                for check in out.checks:
                    sink.add(
                        self._channels[twin_topics.PARAMETERS_TOPIC],
                        np.array([base + nanoseconds(check.t_s)]),
                        twin_topics.encode(self._parameter_layout, twin_topics.parameter_values(check)),
                    )
                for made, forecast in out.forecasts:
                    values = twin_topics.forecast_values(forecast, self._forecast_points)
                    sink.add(
                        self._channels[twin_topics.FORECAST_TOPIC],
                        np.array([base + nanoseconds(made)]),
                        twin_topics.encode(self._forecast_layout, values),
                    )
                for t_s, statuses in diagnostics:
                    self._diagnostics(t_s, statuses)
        for view in self.views:
            if len(est):
                view.add_estimates(est)
            for out in outs:
                for made, forecast in out.forecasts:
                    view.add_forecast(made, forecast)
                for check in out.checks:
                    view.add_parameters(check)
                for alarm in out.alarms:
                    view.add_alarm(alarm)

    def statuses(self) -> list[ros2.DiagnosticStatus]:
        """The health status: one per tracked parameter and one for the estimator."""
        session = self.session
        out = []
        found = session.estimator.parameters() if not math.isnan(session.started_s) else {}
        monitor = session.monitor
        g = monitor.history[-1][1] if monitor is not None and monitor.history else {}
        for name in session.estimator.track:
            value, sigma = found.get(name, (math.nan, math.nan))
            reference = monitor.reference.get(name, math.nan) if monitor and monitor.reference else math.nan
            z = g.get(name, math.nan)  # the monitor's own statistic (its references' spread included)
            alarm = monitor.alarmed.get(name) if monitor else None
            level = 2 if alarm else (1 if abs(z) > 2 else 0)
            if alarm:
                message = alarm.describe(self.start_utc_ns)
            elif name in NODE_PARAMETERS and not name.startswith("offset_m"):
                message = "a state of the measurement, not monitored"
            elif math.isnan(z):
                message = "waiting for the estimate and its reference"
            elif level:
                spec = self.spec
                message = f"{abs(z):.1f} sigmas from its reference (alarm beyond {spec.threshold:g})"
            else:
                message = "within 2 sigmas of its reference"
            unit = TRACKABLE[name][1]
            out.append(
                ros2.DiagnosticStatus(
                    level,
                    f"pendsim twin: {name}",
                    message,
                    WHAT[name],
                    (
                        ("value", f"{value:.6g}"),
                        ("sigma", f"{sigma:.3g}"),
                        ("reference", f"{reference:.6g}"),
                        ("g", f"{z:.2f}"),
                        ("unit", unit),
                    ),
                )
            )
        started = not math.isnan(session.started_s)
        misfit = session.misfit() if started else None
        out.append(
            ros2.DiagnosticStatus(
                0 if started and misfit is None else 1,
                "pendsim twin: estimator",
                ("tracking" if misfit is None else misfit) if started else session.waiting_text(),
                "estimator",
                (
                    ("t_s", f"{session.estimator.t_s:.3f}"),
                    ("samples_m1", str(session.samples[0])),
                    ("samples_m2", str(session.samples[1])),
                    ("late", str(len(self.merger.late))),
                ),
            )
        )
        return out

    def _diagnostics(self, t_s: float, statuses: list[ros2.DiagnosticStatus] | None = None) -> None:
        """The health status (``statuses``: taken earlier; None: now) at ``t_s`` to the file and
        the views."""
        statuses = self.statuses() if statuses is None else statuses
        if self.sink is not None:
            t_ns = self.start_utc_ns + nanoseconds(t_s)
            self.sink.add_diagnostics(t_ns, statuses)
        for view in self.views:
            view.add_diagnostics(t_s, statuses)

    def tick(self, now_s: float, t_s: float) -> bool:
        """Periodic work at ``now_s`` (the loop's clock) with the twin's time ``t_s``: diagnostics
        once a second, the views' batches, the file written up to what cannot change. True once
        a second (for a status line)."""
        second = False
        if now_s >= self._next_diag_s:
            self.publish()
            self._next_diag_s = now_s + DIAGNOSTICS_S
            self._diagnostics(max(t_s, 0.0))
            second = True
        if now_s >= self._next_collect_s:
            self._next_collect_s = now_s + PUBLISH_S
            if self.views and now_s >= self._next_view_s:
                self._next_view_s = now_s + VIEW_S
                self.publish()
                for view in self.views:
                    view.send()
            else:
                self.collect()
        if now_s >= self._next_flush_s and self.sink is not None:
            self.publish()
            self._next_flush_s = now_s + FLUSH_S
            released = self.merger.released_s
            if math.isfinite(released):
                self.sink.flush(self.start_utc_ns + nanoseconds(released - KEEP_S))
        return second

    def finish(self) -> None:
        """Everything waiting released and taken in, the last diagnostics, the views' last batch
        (their thread ended)."""
        self.step(math.inf, final=True)
        self.publish()
        self._diagnostics(max(self.session.estimator.t_s, 0.0))
        self.stop_views()

    def stop_views(self) -> None:
        """The views' last batch sent and their thread ended (also on an error: call it in a
        ``finally`` before the views are closed)."""
        if self.feeder is not None:
            self.feeder.stop()

    def latency_ms(self) -> tuple[float, float]:
        if not self.latency_s:
            return math.nan, math.nan
        p50, p99 = np.percentile(np.array(self.latency_s), [50, 99]) * 1e3
        return float(p50), float(p99)

    def result_metadata(self, summary: TwinSummary, stop_reason: str, duration_s: float) -> dict[str, str]:
        score = summary.forecast
        return {
            "stop_reason": stop_reason,
            "duration_s": f"{duration_s:.3f}",
            "started_s": repr(summary.started_s),
            "samples": json.dumps(list(summary.samples)),
            "nis_mean": json.dumps([_finite_or_none(v) for v in summary.nis_mean]),
            "whiteness_p": json.dumps([[_finite_or_none(v) for v in node] for node in summary.whiteness_p]),
            "accel_nis_mean": json.dumps([_finite_or_none(v) for v in summary.accel_nis_mean]),
            "accel_whiteness_p": json.dumps([[_finite_or_none(v) for v in node] for node in summary.accel_whiteness_p]),
            "forecast": json.dumps(
                {
                    "horizon_s": list(score.horizon_s),
                    "count": list(score.count),
                    "rms_error_rad": [_finite_or_none(v) for v in score.rms_error_rad],
                    "within_3_sigma": [_finite_or_none(v) for v in score.within_3_sigma],
                }
            ),
            "alarms": _strict_json(
                [dataclasses.asdict(a) | {"text": a.describe(self.start_utc_ns)} for a in summary.alarms]
            ),
            "parameters": _strict_json({k: list(v) for k, v in summary.parameters.items()}),
            "late": json.dumps([[n, nanoseconds(t)] for n, t in self.merger.late]),
            "latency_ms": json.dumps([_finite_or_none(v) for v in self.latency_ms()]),
            "learned": _strict_json([_learned(n) for n in self.session.learned()]),
            "events": json.dumps([[t, what] for t, what in self.session.events]),
        }


def _learned(learned: Learned) -> dict[str, object]:
    frame = learned.frame
    return {
        "fusion_phase_s": learned.fusion_phase_s,
        "phase_stretch_s": list(learned.phase_stretch_s) if learned.phase_stretch_s else None,
        "phase_drift_ppm": learned.phase_drift_ppm,
        "phase_moving_unfollowed": list(learned.phase_moving_unfollowed) if learned.phase_moving_unfollowed else None,
        "frame_t_s": learned.frame_t_s,
        "hinge_to_start_deg": learned.hinge_to_start_deg,
        "hinge_axis": None if frame is None else [float(v) for v in frame.hinge_axis],
        "reference_quat_wxyz": None if frame is None else [float(v) for v in frame.reference_quat_wxyz],
        "angle_offset_rad": None if frame is None else float(frame.angle_offset_rad),
    }


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _strict_json(value: object) -> str:
    """JSON that every parser reads: a float that is not finite (an alarm's evidence where none
    was weighed, a parameter not yet estimated) as null (Python's json writes NaN and Infinity,
    which JavaScript's JSON.parse, and so Foxglove, refuse)."""

    def finite(v: object) -> object:
        if isinstance(v, float):
            return _finite_or_none(v)
        if isinstance(v, dict):
            return {k: finite(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [finite(x) for x in v]
        return v

    return json.dumps(finite(value), allow_nan=False)


def open_sink(
    output: Path,
    *,
    replace: bool,
    spec: TwinSpec,
    source: str,
    groups: tuple[str, ...],
    node_names: tuple[str, str],
    start_utc_ns: int,
    extra_metadata: dict[str, dict[str, str]] | None = None,
) -> tuple[RecordingSink, Path]:
    """The recording's sink under a temporary name beside ``output``: (sink, its path)."""
    from pendsim_mj.rig.model import exact_mjcf  # start-up: MuJoCo, once the twin runs

    if not replace and (output.exists() or output.is_symlink()):
        raise OutputError(f"output {str(output)!r} exists; choose another name or pass {replace_hint()} to replace it")
    try:
        partial = temporary_sibling(output)
    except OSError as exc:
        raise OutputError(f"cannot write {str(output)!r}: {describe_os_error(exc)}") from None
    metadata = {twin_topics.TWIN_METADATA: spec.metadata(source)} | (extra_metadata or {})
    try:
        sink = RecordingSink(
            partial,
            nodes=node_names,
            groups=groups,
            params=spec.params,
            mjcf_xml=exact_mjcf(spec.params),
            metadata=metadata,
            start_time_ns=start_utc_ns,
            diagnostics=True,
        )
    except OutputError:
        partial.unlink(missing_ok=True)
        raise
    return sink, partial


def close_sink(
    pipeline: TwinPipeline, partial: Path, output: Path, *, replace: bool, stop_reason: str, duration_s: float
) -> int:
    """Write the result's metadata, close and publish the recording; the messages written."""
    sink = pipeline.sink
    assert sink is not None
    summary = pipeline.session.summary()
    sink.add_metadata(twin_topics.TWIN_RESULT_METADATA, pipeline.result_metadata(summary, stop_reason, duration_s))
    sink.close()
    messages = int(sink.messages)
    if pipeline.session.samples == (0, 0):
        partial.unlink(missing_ok=True)
        raise RecordingError("no node sample arrived: nothing was written")
    try:
        publish(partial, output, replace=replace)
    except OSError as exc:
        raise OutputError(
            f"cannot publish {str(output)!r}: {describe_os_error(exc)}; the recording is in {str(partial)!r}"
        ) from None
    return messages


__all__ = ["TwinPipeline", "TwinResult", "TwinSpec"]
