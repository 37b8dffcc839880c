"""The live twin in the Foxglove app: a WebSocket server (``foxglove-sdk``, the Foxglove WebSocket
protocol, subprotocol ``foxglove.sdk.v1``) on loopback, port 8765 by default (a
``twin_views.TwinView``).

Channels (each message's log time is its instant in UTC ns: the twin's start plus its time):

- ``/twin/estimate`` (JSON, one message per sample taken in): the node, its measured angle and
  rate, the estimate of that node's angle and rate with sigma and +- 3 sigma, the whole state;
- ``/twin/innovation`` (JSON, one per sample): the innovation with its predicted sigma and
  +- 3 sigma bounds, NIS and its 95 % limit;
- ``/twin/forecast`` (JSON, one per forecast): the instants and the predicted state with sigma;
- ``/twin/parameters`` (JSON, one per check): each tracked parameter's estimate, sigma, +- 3 sigma,
  reference and z-score;
- ``/twin/alarms`` (``foxglove.Log``, protobuf, level WARNING): one per alarm;
- ``/diagnostics`` (JSON in the shape of ROS's ``diagnostic_msgs/msg/DiagnosticArray``): the
  health statuses;
- ``/tf`` (``foxglove.FrameTransforms``, protobuf; with a model): each pendulum's frame (``m1``,
  ``m2``) in ``world``, posed from the latest estimate, once per ``send``.

Messages are only built for channels a client subscribes to. NaN (a reference before the baseline)
is sent as null: JSON has no NaN.
"""

from __future__ import annotations

import ipaddress
import json
import math
import time
from typing import Any

import foxglove
import mujoco
import numpy as np
from foxglove.channels import FrameTransformsChannel, LogChannel
from foxglove.messages import FrameTransform, FrameTransforms, Log, LogLevel, Quaternion, Timestamp, Vector3

from pendsim_mj.rig.model import BODIES
from pendsim_mj.sensors import rotations
from pendsim_mj.twin.outputs import STATE_NAMES, Estimates

from ..errors import ProcessError
from ..io.ros2 import DiagnosticStatus
from . import serve as serving
from .twin_views import FOXGLOVE_PORT, NIS_LIMIT_95, SIGMA_BAND, BufferedView, Pending

SERVER_NAME = "pendsim twin"
STOP_TIMEOUT_S = 2.0
"""How long ``close`` waits for the server to stop listening."""
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
_NUMBER = {"type": ["number", "null"]}
_NUMBERS = {"type": "array", "items": _NUMBER}


def _object(properties: dict[str, Any]) -> dict[str, Any]:
    return {"type": "object", "properties": properties}


_STATE = _object(dict.fromkeys(STATE_NAMES, _NUMBER))
SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    # topic: (schema name, JSON schema)
    "/twin/estimate": ("pendsim.TwinEstimate", _object({
        "t_s": _NUMBER, "node": {"type": "string"},
        **dict.fromkeys(("measured_angle_rad", "measured_rate_rad_s", "angle_rad", "angle_sigma_rad", "angle_upper_rad",
                         "angle_lower_rad", "rate_rad_s", "rate_sigma_rad_s", "rate_upper_rad_s", "rate_lower_rad_s"),
                        _NUMBER),
        "state": _STATE, "sigma": _STATE,
    })),
    "/twin/innovation": ("pendsim.TwinInnovation", _object({
        "t_s": _NUMBER, "node": {"type": "string"},
        **dict.fromkeys(("angle_rad", "angle_sigma_rad", "angle_upper_rad", "angle_lower_rad", "rate_rad_s",
                         "rate_sigma_rad_s", "rate_upper_rad_s", "rate_lower_rad_s", "nis", "nis_limit_95"), _NUMBER),
    })),
    "/twin/forecast": ("pendsim.TwinForecast", _object({
        "made_at_s": _NUMBER, "t_s": _NUMBERS,
        "mean": _object(dict.fromkeys(STATE_NAMES, _NUMBERS)), "sigma": _object(dict.fromkeys(STATE_NAMES, _NUMBERS)),
    })),
    "/twin/parameters": ("pendsim.TwinParameters", _object({
        "t_s": _NUMBER,
        "parameters": {"type": "array", "items": _object({
            "name": {"type": "string"},
            **dict.fromkeys(("value", "sigma", "upper", "lower", "reference", "z"), _NUMBER),
        })},
    })),
    "/diagnostics": (DIAGNOSTIC_ARRAY, _object({
        "header": _object({
            "stamp": _object({"sec": {"type": "integer"}, "nsec": {"type": "integer"}}), "frame_id": {"type": "string"},
        }),
        "status": {"type": "array", "items": _object({
            "level": {"type": "integer"}, "name": {"type": "string"}, "message": {"type": "string"},
            "hardware_id": {"type": "string"},
            "values": {"type": "array", "items": _object({"key": {"type": "string"}, "value": {"type": "string"}})},
        })},
    })),
}  # fmt: skip
"""The JSON channels: topic -> (schema name, JSON schema)."""


def _num(x: float) -> float | None:
    """A float for JSON: NaN and infinities as null."""
    return float(x) if math.isfinite(x) else None


def _nums(values: np.ndarray) -> list[float | None]:
    return [_num(x) for x in np.asarray(values, dtype=float).tolist()]


def _stamp(utc_ns: int) -> dict[str, int]:
    return {"sec": utc_ns // 1_000_000_000, "nsec": utc_ns % 1_000_000_000}


def _dumps(message: dict[str, Any]) -> bytes:
    return json.dumps(message, allow_nan=False, separators=(",", ":")).encode()


class TwinFoxgloveView(BufferedView):
    """The live twin served to the Foxglove app (module docstring); a ``twin_views.TwinView``.

    Args:
      start_utc_ns: the twin's start, UTC ns (the messages' log times count from it).
      nodes: the node names, in the estimator's order (``Estimates.node`` indexes them).
      mjcf_xml: the rig's model: its pendulums' pivots for ``/tf`` (None: no ``/tf``).
      bind: the IP address to listen on (loopback by default: this machine only).
      port: the TCP port (0: any free one; ``port`` tells which).

    Raises:
      ProcessError: a bad address, a port in use, or a server that could not start.
    """

    def __init__(
        self,
        start_utc_ns: int,
        nodes: tuple[str, ...],
        *,
        mjcf_xml: str | None = None,
        bind: str = "127.0.0.1",
        port: int = FOXGLOVE_PORT,
    ) -> None:
        super().__init__(start_utc_ns, nodes)
        try:
            address = ipaddress.ip_address(bind)
        except ValueError:
            raise ProcessError(f"the Foxglove server's address must be an IP address, got {bind!r}") from None
        if not 0 <= port <= 65535:
            raise ProcessError(f"the Foxglove server's port must be in [0, 65535], got {port}")
        self.bind = str(address)
        self._pivots_m: list[np.ndarray] = []
        if mjcf_xml is not None:
            model = mujoco.MjModel.from_xml_string(mjcf_xml)
            self._pivots_m = [np.array(model.body(b).pos, dtype=float) for b in BODIES]
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(
                name=SERVER_NAME,
                host=bind,
                port=port,
                context=self.context,
                capabilities=[foxglove.Capability.Time],
            )
        except RuntimeError as exc:
            if "in use" in str(exc):
                raise ProcessError(
                    f"port {port} on {bind} is in use (another Foxglove server?): choose another port for the "
                    "Foxglove view (--foxglove PORT)"
                ) from None
            raise ProcessError(f"the Foxglove server cannot listen on {bind} port {port}: {exc}") from None
        try:
            self._open_channels(address.version)
        except BaseException:
            self.server.stop()
            # the SDK closes its listening socket on its own thread, after stop returns
            deadline = time.monotonic() + STOP_TIMEOUT_S
            while serving.listening_here(self.port) and time.monotonic() < deadline:
                time.sleep(0.005)
            raise

    def _open_channels(self, ip_version: int) -> None:
        self.port = self.server.port
        host = f"[{self.bind}]" if ip_version == 6 else self.bind
        self.url = f"ws://{host}:{self.port}"
        self.channels = {
            topic: foxglove.Channel(
                topic,
                schema=foxglove.Schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode()),
                message_encoding="json",
                context=self.context,
            )
            for topic, (name, schema) in SCHEMAS.items()
        }
        self.alarms = LogChannel("/twin/alarms", context=self.context)
        self.tf = FrameTransformsChannel("/tf", context=self.context) if self._pivots_m else None
        self._latest: tuple[float, np.ndarray] | None = None

    def send(self) -> None:
        """Publish everything added since the last call."""
        if self.closed or not self.pending:
            return
        batch = self.pending.take()
        self.sends += 1
        if batch.estimates:
            self._send_estimates(Estimates.concatenate(batch.estimates))
        self._send_others(batch)
        if self._latest is not None:
            self.server.broadcast_time(self.utc_ns(self._latest[0]))

    def _send_estimates(self, est: Estimates) -> None:
        self._latest = (float(est.t_s[-1]), est.state[-1].copy())
        t_ns = self.utc_ns_array(est.t_s).tolist()
        estimate, innovation = self.channels["/twin/estimate"], self.channels["/twin/innovation"]
        k = est.node
        rows = np.arange(len(est))
        if estimate.has_sinks():
            angle, rate = est.state[rows, k], est.state[rows, 2 + k]
            angle_s, rate_s = est.sigma[rows, k], est.sigma[rows, 2 + k]
            columns = zip(
                est.t_s.tolist(), k.tolist(), est.measured.tolist(), angle.tolist(), angle_s.tolist(), rate.tolist(),
                rate_s.tolist(), est.state.tolist(), est.sigma.tolist(), t_ns, strict=True,
            )  # fmt: skip
            for t, node, (m_angle, m_rate), a, a_s, r, r_s, state, sigma, ns in columns:
                message = {
                    "t_s": t, "node": self.nodes[node], "measured_angle_rad": _num(m_angle),
                    "measured_rate_rad_s": _num(m_rate), "angle_rad": _num(a), "angle_sigma_rad": _num(a_s),
                    "angle_upper_rad": _num(a + SIGMA_BAND * a_s), "angle_lower_rad": _num(a - SIGMA_BAND * a_s),
                    "rate_rad_s": _num(r), "rate_sigma_rad_s": _num(r_s),
                    "rate_upper_rad_s": _num(r + SIGMA_BAND * r_s), "rate_lower_rad_s": _num(r - SIGMA_BAND * r_s),
                    "state": dict(zip(STATE_NAMES, map(_num, state), strict=True)),
                    "sigma": dict(zip(STATE_NAMES, map(_num, sigma), strict=True)),
                }  # fmt: skip
                estimate.log(_dumps(message), log_time=ns)
        if innovation.has_sinks():
            columns = zip(
                est.t_s.tolist(), k.tolist(), est.innovation.tolist(), est.innovation_sigma.tolist(), est.nis.tolist(),
                t_ns, strict=True,
            )  # fmt: skip
            for t, node, (v_a, v_r), (s_a, s_r), nis, ns in columns:
                message = {
                    "t_s": t, "node": self.nodes[node],
                    "angle_rad": _num(v_a), "angle_sigma_rad": _num(s_a), "angle_upper_rad": _num(SIGMA_BAND * s_a),
                    "angle_lower_rad": _num(-SIGMA_BAND * s_a), "rate_rad_s": _num(v_r), "rate_sigma_rad_s": _num(s_r),
                    "rate_upper_rad_s": _num(SIGMA_BAND * s_r), "rate_lower_rad_s": _num(-SIGMA_BAND * s_r),
                    "nis": _num(nis), "nis_limit_95": NIS_LIMIT_95,
                }  # fmt: skip
                innovation.log(_dumps(message), log_time=ns)
        if self.tf is not None and self.tf.has_sinks():
            quat = rotations.wxyz_to_xyzw(rotations.pendulum_quat_wxyz(self._latest[1][:2]))  # (2, 4)
            stamp = Timestamp(*divmod(self.utc_ns(self._latest[0]), 1_000_000_000))
            transforms = [
                FrameTransform(
                    timestamp=stamp, parent_frame_id="world", child_frame_id=body,
                    translation=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                    rotation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
                )
                for body, p, q in zip(BODIES, self._pivots_m, quat, strict=True)
            ]  # fmt: skip
            self.tf.log(FrameTransforms(transforms=transforms), log_time=self.utc_ns(self._latest[0]))

    def _send_others(self, batch: Pending) -> None:
        forecast = self.channels["/twin/forecast"]
        for made_at_s, f in batch.forecasts:
            if forecast.has_sinks():
                message = {
                    "made_at_s": made_at_s, "t_s": _nums(f.t_s),
                    "mean": {name: _nums(f.mean[:, i]) for i, name in enumerate(STATE_NAMES)},
                    "sigma": {name: _nums(f.sigma[:, i]) for i, name in enumerate(STATE_NAMES)},
                }  # fmt: skip
                forecast.log(_dumps(message), log_time=self.utc_ns(made_at_s))
        parameters = self.channels["/twin/parameters"]
        for check in batch.parameters:
            if parameters.has_sinks():
                rows = zip(check.names, check.value, check.sigma, check.reference, check.z, strict=True)
                items = [
                    {"name": name, "value": _num(v), "sigma": _num(s), "upper": _num(v + SIGMA_BAND * s),
                     "lower": _num(v - SIGMA_BAND * s), "reference": _num(ref), "z": _num(z)}
                    for name, v, s, ref, z in rows
                ]  # fmt: skip
                parameters.log(_dumps({"t_s": check.t_s, "parameters": items}), log_time=self.utc_ns(check.t_s))
        for alarm in batch.alarms:
            ns = self.utc_ns(alarm.t_s)
            log = Log(
                timestamp=Timestamp(*divmod(ns, 1_000_000_000)), level=LogLevel.Warning,
                message=alarm.describe(self.start_utc_ns), name="pendsim.twin", file=alarm.parameter,
            )  # fmt: skip
            self.alarms.log(log, log_time=ns)
        diagnostics = self.channels["/diagnostics"]
        for t_s, statuses in batch.diagnostics:
            if diagnostics.has_sinks():
                ns = self.utc_ns(t_s)
                diagnostics.log(_dumps(diagnostic_array(ns, statuses)), log_time=ns)

    def close(self) -> None:
        """Publish what is left, unadvertise the channels and stop the server. Idempotent."""
        if self.closed:
            return
        try:
            self.send()
        finally:
            self.closed = True
            for channel in self.channels.values():
                channel.close()
            self.alarms.close()
            if self.tf is not None:
                self.tf.close()
            self.server.stop()
            # the SDK closes its listening socket on its own thread, after stop returns
            deadline = time.monotonic() + STOP_TIMEOUT_S
            while serving.listening_here(self.port) and time.monotonic() < deadline:
                time.sleep(0.005)


def diagnostic_array(stamp_utc_ns: int, statuses: list[DiagnosticStatus]) -> dict[str, Any]:
    """A ``diagnostic_msgs/msg/DiagnosticArray`` as JSON (the ROS message's fields)."""
    return {
        "header": {"stamp": _stamp(stamp_utc_ns), "frame_id": ""},
        "status": [
            {
                "level": s.level,
                "name": s.name,
                "message": s.message,
                "hardware_id": s.hardware_id,
                "values": [{"key": key, "value": value} for key, value in s.values],
            }
            for s in statuses
        ],
    }
