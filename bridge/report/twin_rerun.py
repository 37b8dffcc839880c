"""The live twin in Rerun: measured against estimated motion with 3-sigma bands, innovations with
their predicted bands, NIS, the tracked parameters, the forecast, alarms and /diagnostics, and the
rig posed from the estimate (a ``twin_views.TwinView``).

Entities (timeline "time": seconds on the twin's clock), per node N (``m1``, ``m2``; node k's
swing angle is the state's phi_k):

- ``/twin/N/angle``, ``/twin/N/rate``: 4 series: measured, estimate, estimate +- 3 sigma (rad, rad/s);
- ``/twin/N/innovation/angle``, ``/twin/N/innovation/rate``: innovation, +- 3 predicted sigma;
- ``/twin/N/nis``: NIS and its 95 % limit (5.99);
- ``/twin/N/prediction/measured``, ``/twin/N/prediction/forecast``: the measured angle against what
  the forecasts predicted for it (each forecast's stretch until the next one was made, +- 3 sigma):
  predicted against measured;
- ``/twin/forecast/N``: the latest forecast, ahead of now (2D: x seconds ahead, y = -angle rad so
  that up is positive), replaced by each new one;
- ``/twin/parameters/P``: each tracked parameter, its +- 3 sigma and its reference; ``/twin/parameters/z``
  their z-scores;
- ``/twin/alarms`` (WARN), ``/twin/diagnostics`` (a status when its level or message changes): text logs;
- ``/rig/m1``, ``/rig/m2``: the bodies posed from the estimate, under the model's geometry.

Each ``send`` puts the estimates' streams in three Arrow record batches (``send_record_batch``:
per node its six plots, and the rig's two bodies; each column names its entity, Rerun's Sorbet
metadata): 14 ``send_columns`` calls cost 2.6 times as much in Rerun's Python layer (2.0 ms
against 0.75 ms per node and send); the view as a whole 4.0 % of a core against 2.5 % at 5 sends
a second (2026-11-28, paired runs). The parameters and text logs go with ``send_columns``, the
forecast as one ``log`` per forecast. Sinks, any together: an .rrd file, the desktop viewer,
Rerun's web viewer served on a bind address (``serve.start_live_server``: its own process
group, ended by ``close``).
"""

from __future__ import annotations

import functools
import subprocess
from pathlib import Path

import mujoco
import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

from pendsim_mj.rig.model import BODIES
from pendsim_mj.sensors import rotations
from pendsim_mj.twin.estimator import Forecast
from pendsim_mj.twin.outputs import Estimates

from ..errors import ProcessError
from ..io.outputs import publish, temporary_sibling
from . import serve as serving
from .rerun_view import log_rig_geometry
from .twin_views import NIS_LIMIT_95, SIGMA_BAND, BufferedView, Pending

APPLICATION_ID = "pendsim_twin"
TIMELINE = "time"
WINDOW_S = 20.0
"""The plots show the last WINDOW_S seconds before the time cursor."""
_BLUE, _ORANGE, _GREY, _GREEN, _RED = (30, 90, 230), (255, 140, 0), (150, 150, 150), (30, 150, 60), (210, 30, 30)
_STYLES: dict[str, tuple[list[tuple[int, int, int]], list[str], list[float]]] = {
    # series group: colours, names, widths (a Rerun entity of several scalars per row)
    "tracked": ([_BLUE, _ORANGE, _GREY, _GREY], ["measured", "estimate", "+3 sigma", "-3 sigma"], [3.0, 1.5, 1.0, 1.0]),
    "innovation": ([_RED, _GREY, _GREY], ["innovation", "+3 sigma", "-3 sigma"], [1.5, 1.0, 1.0]),
    "nis": ([_RED, _GREY], ["NIS", "95 % limit"], [1.5, 1.0]),
    "predicted": ([_GREEN, _GREY, _GREY], ["predicted", "+3 sigma", "-3 sigma"], [1.5, 1.0, 1.0]),
    "measured": ([_BLUE], ["measured"], [3.0]),
    "parameter": ([_ORANGE, _GREY, _GREY, _BLUE], ["estimate", "+3 sigma", "-3 sigma", "reference"], [1.5, 1, 1, 1.5]),
}
_PALETTE = [_ORANGE, _BLUE, _GREEN, _RED, _GREY, (130, 60, 180), (0, 0, 0)]  # the z-scores, one per parameter
_DIAGNOSTIC_LEVELS = {0: "INFO", 1: "WARN", 2: "ERROR", 3: "DEBUG"}  # OK, WARN, ERROR, STALE


_SCALARS = ("rerun.archetypes.Scalars", "Scalars:scalars", "rerun.components.Scalar")
_QUATERNION = ("rerun.archetypes.Transform3D", "Transform3D:quaternion", "rerun.components.RotationQuat")
_TRANSLATION = ("rerun.archetypes.Transform3D", "Transform3D:translation", "rerun.components.Translation3D")


class _Columns:
    """One Arrow record batch of several entities' components at the same instants (Rerun's
    Sorbet metadata on each field: its entity, archetype, component; the time column the index):
    what ``send_columns`` would send for each entity, in one ``send_record_batch``."""

    def __init__(self, times: rr.TimeColumn) -> None:
        metadata = {b"rerun:index_name": TIMELINE.encode(), b"rerun:kind": b"index"}
        index = pa.field(TIMELINE, pa.duration("ns"), metadata=metadata)
        self.fields, self.arrays = [index], [times.as_arrow_array()]

    def add(self, entity: str, kind: tuple[str, str, str], values: np.ndarray, item: pa.DataType) -> None:
        """values (n, k): one row of k numbers per instant, as a list of one ``item`` (a float64
        scalar per number; or a fixed-size list of k float32: a quaternion, a translation)."""
        n, k = values.shape
        if item == pa.float64():  # k scalars per row
            flat, step = pa.array(np.ascontiguousarray(values, dtype=np.float64).ravel()), k
        else:  # one fixed-size list of k per row
            flat, step = pa.FixedSizeListArray.from_arrays(pa.array(values.astype(np.float32).ravel()), k), 1
        column = pa.ListArray.from_arrays(pa.array(np.arange(0, n * step + 1, step, dtype=np.int32)), flat)
        self.fields.append(_field(entity, kind, column.type))
        self.arrays.append(column)

    def send(self, rec: rr.RecordingStream) -> None:
        rr.send_record_batch(pa.RecordBatch.from_arrays(self.arrays, schema=pa.schema(self.fields)), recording=rec)


@functools.cache
def _field(entity: str, kind: tuple[str, str, str], column_type: pa.DataType) -> pa.Field:
    """An entity's component column (``_Columns``): made once per stream."""
    archetype, component, component_type = kind
    metadata = {b"rerun:kind": b"data", b"rerun:entity_path": entity.encode(), b"rerun:archetype": archetype.encode(),
                b"rerun:component": component.encode(), b"rerun:component_type": component_type.encode()}  # fmt: skip
    return pa.field(f"{entity}:{component}", column_type, metadata=metadata)


def _window() -> rrb.VisibleTimeRange:
    return rrb.VisibleTimeRange(
        TIMELINE, start=rrb.TimeRangeBoundary.cursor_relative(seconds=-WINDOW_S), end=rrb.TimeRangeBoundary.infinite()
    )


def blueprint(nodes: tuple[str, ...], parameters: tuple[str, ...] = ()) -> rrb.Blueprint:
    """The rig, the latest forecast and the text logs on the left; per node a tab per plot, then
    NIS and the parameters on the right."""

    def plot(origin: str, name: str) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(origin=origin, name=name, time_ranges=_window())

    per_node = [
        rrb.Tabs(
            plot(f"/twin/{n}/angle", f"{n}: angle (rad), measured vs estimate +- 3 sigma"),
            plot(f"/twin/{n}/prediction", f"{n}: angle (rad), measured vs predicted +- 3 sigma"),
            plot(f"/twin/{n}/rate", f"{n}: rate (rad/s), measured vs estimate +- 3 sigma"),
            plot(f"/twin/{n}/innovation/angle", f"{n}: angle innovation (rad) +- 3 sigma"),
            plot(f"/twin/{n}/innovation/rate", f"{n}: rate innovation (rad/s) +- 3 sigma"),
        )
        for n in nodes
    ]
    health = [
        plot("/twin/parameters/z", "tracked parameters: z-score"),
        *(plot(f"/twin/parameters/{p}", f"{p}: estimate +- 3 sigma, reference") for p in parameters),
    ]
    nis = rrb.TimeSeriesView(
        origin="/twin", contents=[f"/twin/{n}/nis" for n in nodes], name="NIS (chi^2, 2 dof)", time_ranges=_window()
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(origin="/rig", name="rig (estimate)"),
                rrb.Spatial2DView(origin="/twin/forecast", name="forecast: angle (rad, up) vs seconds ahead"),
                rrb.TextLogView(origin="/twin", contents=["/twin/alarms", "/twin/diagnostics"], name="alarms, health"),
                row_shares=[3, 2, 2],
            ),
            rrb.Vertical(*per_node, rrb.Horizontal(nis, rrb.Tabs(*health))),
            column_shares=[2, 3],
        ),
        collapse_panels=True,
    )


class TwinRerunView(BufferedView):
    """The live twin in Rerun (module docstring); a ``twin_views.TwinView``.

    Args:
      start_utc_ns: the twin's start, UTC ns (kept as the recording's start; the timeline counts
        seconds from it).
      nodes: the node names, in the estimator's order (``Estimates.node`` indexes them).
      mjcf_xml: the rig's model, for the 3D geometry.
      rrd: save everything to this .rrd file (written under a temporary name, published by ``close``).
      spawn: open the desktop viewer.
      serve: (bind address, web port) to serve the web viewer on (gRPC port = web port + 1).

    Raises:
      ProcessError: the web viewer could not be served (a port in use, ...).
    """

    def __init__(
        self,
        start_utc_ns: int,
        nodes: tuple[str, ...],
        mjcf_xml: str,
        *,
        rrd: Path | None = None,
        spawn: bool = False,
        serve: tuple[str, int] | None = None,
    ) -> None:
        super().__init__(start_utc_ns, nodes)
        self.url: str | None = None
        self._server: subprocess.Popen[bytes] | None = None
        self._rrd = rrd
        self._rrd_partial = temporary_sibling(rrd) if rrd is not None else None
        self._forecast: tuple[float, Forecast] | None = None  # the latest, its stretch not yet logged
        self._last_t_s = -np.inf
        self._parameters: tuple[str, ...] = ()
        self._diagnostics: dict[str, tuple[int, str]] = {}
        self._model = mujoco.MjModel.from_xml_string(mjcf_xml)
        self.rec = rr.RecordingStream(APPLICATION_ID)
        sinks: list[rr.FileSink | rr.GrpcSink] = []
        if self._rrd_partial is not None:
            sinks.append(rr.FileSink(str(self._rrd_partial)))
        if spawn:
            rr.spawn(connect=False, recording=self.rec)
            sinks.append(rr.GrpcSink())
        if serve is not None:
            bind, port = serve
            try:
                self._server = serving.start_live_server(bind, port)
            except ProcessError:
                if self._rrd_partial is not None:
                    self._rrd_partial.unlink(missing_ok=True)
                raise
            sinks.append(rr.GrpcSink(serving.live_grpc_url(bind, port)))
            self.url = serving.viewer_url(bind, port, port + 1)
        try:
            self.rec.set_sinks(*sinks, default_blueprint=blueprint(nodes))
            self.rec.send_recording_start_time_nanos(self.start_utc_ns)
            self._log_static()
        except BaseException:
            self.close(publish_rrd=False)
            raise

    def _log_static(self) -> None:
        previous = rr.set_thread_local_data_recording(self.rec)
        try:
            log_rig_geometry(self._model)
        finally:
            rr.set_thread_local_data_recording(previous)
        for n in self.nodes:
            for entity, style in (
                (f"/twin/{n}/angle", "tracked"), (f"/twin/{n}/rate", "tracked"),
                (f"/twin/{n}/innovation/angle", "innovation"), (f"/twin/{n}/innovation/rate", "innovation"),
                (f"/twin/{n}/nis", "nis"), (f"/twin/{n}/prediction/forecast", "predicted"),
                (f"/twin/{n}/prediction/measured", "measured"),
            ):  # fmt: skip
                self._style(entity, style)

    def _style(self, entity: str, style: str) -> None:
        colours, names, widths = _STYLES[style]
        self.rec.log(entity, rr.SeriesLines(colors=colours, names=names, widths=widths), static=True)

    def _columns(self, entity: str, t_s: np.ndarray | rr.TimeColumn, values: np.ndarray) -> None:
        """Scalars (n, k) at instants (n,) s (or their time column, built once for several entities)."""
        times = t_s if isinstance(t_s, rr.TimeColumn) else rr.TimeColumn(TIMELINE, duration=t_s)
        self.rec.send_columns(entity, indexes=[times], columns=rr.Scalars.columns(scalars=values))

    def send(self) -> None:
        """Log everything added since the last call, one ``send_columns`` per stream."""
        if self.closed or not self.pending:
            return
        batch = self.pending.take()
        self.sends += 1
        if batch.estimates:
            self._send_estimates(batch)
        for made_at_s, forecast in batch.forecasts:
            self._send_forecast(made_at_s, forecast)
        if batch.parameters:
            self._send_parameters(batch)
        self._send_texts(batch)

    def _send_estimates(self, batch: Pending) -> None:
        est = Estimates.concatenate(batch.estimates)
        self._last_t_s = max(self._last_t_s, float(est.t_s[-1]))
        for k, n in enumerate(self.nodes):
            rows = est.node == k
            if not rows.any():
                continue
            plots = _Columns(rr.TimeColumn(TIMELINE, duration=est.t_s[rows]))  # the node's six entities
            measured, state, sigma = est.measured[rows], est.state[rows], est.sigma[rows]
            for j, quantity in enumerate(("angle", "rate")):
                x, s = state[:, 2 * j + k], SIGMA_BAND * sigma[:, 2 * j + k]
                tracked = np.stack([measured[:, j], x, x + s, x - s], axis=1)
                plots.add(f"/twin/{n}/{quantity}", _SCALARS, tracked, pa.float64())
                v, s = est.innovation[rows, j], SIGMA_BAND * est.innovation_sigma[rows, j]
                plots.add(f"/twin/{n}/innovation/{quantity}", _SCALARS, np.stack([v, s, -s], axis=1), pa.float64())
            nis = est.nis[rows]
            limit = np.full_like(nis, NIS_LIMIT_95)
            plots.add(f"/twin/{n}/nis", _SCALARS, np.stack([nis, limit], axis=1), pa.float64())
            plots.add(f"/twin/{n}/prediction/measured", _SCALARS, measured[:, :1], pa.float64())
            plots.send(self.rec)
        quat = rotations.wxyz_to_xyzw(rotations.pendulum_quat_wxyz(est.state[:, :2]))  # (n, 2, 4)
        rig = _Columns(rr.TimeColumn(TIMELINE, duration=est.t_s))
        for k, body in enumerate(BODIES):
            rig.add(f"/rig/{body}", _QUATERNION, quat[:, k], pa.float32())
            translation = np.repeat(self._model.body(body).pos[None], len(est), axis=0)
            rig.add(f"/rig/{body}", _TRANSLATION, translation, pa.float32())
        rig.send(self.rec)

    def _send_predicted(self, until_s: float) -> None:
        """The stretch of the latest forecast before ``until_s`` (the next forecast's instant)."""
        if self._forecast is None:
            return
        _, forecast = self._forecast
        keep = forecast.t_s < until_s
        if not keep.any():
            return
        t = forecast.t_s[keep]
        for k, n in enumerate(self.nodes):
            x, s = forecast.mean[keep, k], SIGMA_BAND * forecast.sigma[keep, k]
            self._columns(f"/twin/{n}/prediction/forecast", t, np.stack([x, x + s, x - s], axis=1))

    def _send_forecast(self, made_at_s: float, forecast: Forecast) -> None:
        self._send_predicted(made_at_s)
        self._forecast = (made_at_s, forecast)
        self.rec.set_time(TIMELINE, duration=made_at_s)
        ahead = forecast.t_s - made_at_s
        for k, n in enumerate(self.nodes):
            x, s = forecast.mean[:, k], SIGMA_BAND * forecast.sigma[:, k]
            strips = [np.stack([ahead, -y], axis=1) for y in (x, x + s, x - s)]
            self.rec.log(
                f"/twin/forecast/{n}",
                rr.LineStrips2D(
                    strips, colors=[_GREEN, _GREY, _GREY], labels=[f"{n} predicted", "+3 sigma", "-3 sigma"]
                ),
            )

    def _send_parameters(self, batch: Pending) -> None:
        names = batch.parameters[0].names
        if names != self._parameters:  # the first check (or another set): their plots
            self._parameters = names
            for p in names:
                self._style(f"/twin/parameters/{p}", "parameter")
            self.rec.log(
                "/twin/parameters/z",
                rr.SeriesLines(names=list(names), colors=_PALETTE[: len(names)]),
                static=True,
            )  # fmt: skip
            rr.send_blueprint(blueprint(self.nodes, names), recording=self.rec)
        checks = [c for c in batch.parameters if c.names == names]
        t = np.array([c.t_s for c in checks])
        value, sigma = np.array([c.value for c in checks]), SIGMA_BAND * np.array([c.sigma for c in checks])
        reference = np.array([c.reference for c in checks])
        for i, p in enumerate(names):
            v, s = value[:, i], sigma[:, i]
            self._columns(f"/twin/parameters/{p}", t, np.stack([v, v + s, v - s, reference[:, i]], axis=1))
        self._columns("/twin/parameters/z", t, np.array([c.z for c in checks]))

    def _send_texts(self, batch: Pending) -> None:
        if batch.alarms:
            self.rec.send_columns(
                "/twin/alarms",
                indexes=[rr.TimeColumn(TIMELINE, duration=[a.t_s for a in batch.alarms])],
                columns=rr.TextLog.columns(
                    text=[a.describe(self.start_utc_ns) for a in batch.alarms], level=["WARN"] * len(batch.alarms)
                ),
            )
        rows: list[tuple[float, str, str]] = []
        for t_s, statuses in batch.diagnostics:
            for status in statuses:
                if self._diagnostics.get(status.name) != (status.level, status.message):
                    self._diagnostics[status.name] = (status.level, status.message)
                    level = _DIAGNOSTIC_LEVELS.get(status.level, "WARN")
                    rows.append((t_s, f"{status.name}: {status.message}", level))
        if rows:
            self.rec.send_columns(
                "/twin/diagnostics",
                indexes=[rr.TimeColumn(TIMELINE, duration=[r[0] for r in rows])],
                columns=rr.TextLog.columns(text=[r[1] for r in rows], level=[r[2] for r in rows]),
            )

    def close(self, *, publish_rrd: bool = True) -> None:
        """Send what is left (and the last forecast's stretch up to the last sample), publish the
        .rrd file (unless ``publish_rrd`` is false: a failed run), end the web viewer. Idempotent."""
        if self.closed:
            return
        try:
            self.send()
            self._send_predicted(np.nextafter(self._last_t_s, np.inf))
            self.closed = True
            self.rec.flush()
            self.rec.disconnect()
            if publish_rrd and self._rrd is not None and self._rrd_partial is not None:
                publish(self._rrd_partial, self._rrd, replace=True)
        finally:
            self.closed = True
            if self._rrd_partial is not None:
                self._rrd_partial.unlink(missing_ok=True)
            if self._server is not None:
                serving.stop_group(self._server)
                self._server = None
