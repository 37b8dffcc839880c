"""The one adapter between samples that arrive over time and the MCAP file: the layout of
``pendsim record`` (``bridge/io/recording.py``) for data that were measured, not simulated.

Topics: ``/imu/m1``, ``/imu/m2`` (sensor_msgs/msg/Imu: orientation, angular velocity,
acceleration with gravity; a quantity the packets do not carry has covariance element 0 = -1,
the REP-145 "not provided"; the others' covariances are 0, "unknown"), ``/imu/mN/linear_acceleration``
and ``/imu/mN/gravity`` (geometry_msgs/msg/Vector3Stamped) and ``/imu/mN/calibration``
(std_msgs/msg/UInt8MultiArray, at 1 Hz and on change) when the packets carry them, ``/tf_static``
(the mounts), and optionally ``/diagnostics`` (diagnostic_msgs/msg/DiagnosticArray). Metadata
records as given, the rig parameters, and the MJCF as the attachment ``pendulums.xml``.

Samples are buffered and written at ``flush()`` as chunks that interleave every channel in log-time
order (``mcap_writer.BulkMcapWriter``), each handed to the OS at once, so a process killed after a
flush leaves those samples recoverable (``pendsim recover``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pendsim_mj import __version__
from pendsim_mj.rig.params import RigParams
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import Bno055
from pendsim_mj.units import NS_PER_S

from ..errors import OutputError
from ..io import ros2
from ..io.mcap.writer import BulkMcapWriter
from ..io.outputs import output_error
from ..io.recording_layout import MJCF_ATTACHMENT, imu_topic
from ..io.recording_writer import TRANSIENT_LOCAL_QOS, static_tf_message
from .packets import GROUP_SLICES

DIAGNOSTICS_TOPIC = "/diagnostics"
NOT_PROVIDED = -1.0  # REP-145: covariance element 0 = -1 means the quantity is not provided


class RecordingSink:
    """An MCAP recording written as samples arrive.

    Args:
      path: the file to write (created or truncated).
      nodes: node names ("m1", "m2" or one of them).
      groups: which ``packets.GROUPS`` the samples carry (others are not written).
      params: the rig parameters (metadata and the mounts in /tf_static).
      mjcf_xml: the MJCF to attach.
      metadata: name -> entries, written first.
      start_time_ns: log time of /tf_static and the attachment.
      diagnostics: register /diagnostics.
      compression: chunk compression ("zstd", "lz4", "none").

    Raises:
      OutputError: the file cannot be written (full disk, permissions, ...).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        nodes: tuple[str, ...],
        groups: tuple[str, ...],
        params: RigParams,
        mjcf_xml: str,
        metadata: dict[str, dict[str, str]],
        start_time_ns: int,
        diagnostics: bool = False,
        compression: str = "zstd",
    ) -> None:
        self.path = Path(path)
        self.groups = groups
        self.messages = 0  # every message given (all topics; what the file holds once flushed)
        self.samples = 0  # node samples taken (each is one message per topic of its groups)
        self.dropped = 0  # messages of other topics given older than what the file held (``add``)
        self.written_upto_ns = -1  # every message up to this log time is in the file
        self._imu_layout = {n: ros2.imu_layout(f"imu_{n}") for n in nodes}
        self._vec_layout = {n: ros2.vector3_stamped_layout(f"imu_{n}") for n in nodes}
        self._calib_layout = ros2.uint8_multiarray_layout(4)
        self._last_calib: dict[str, tuple[int, ...]] = {}
        self._last_calib_second: dict[str, int] = {}
        self._buffer: dict[int, list[tuple[NDArray[np.int64], NDArray[np.uint8]]]] = {}
        self._covariance = {
            name: np.array([0.0 if group in groups else NOT_PROVIDED] + [0.0] * 8)
            for name, group in (("orientation", "quat"), ("gyro", "gyro"), ("accel", "accel"))
        }
        with self._errors():
            w = self._writer = BulkMcapWriter(self.path, compression=compression, library=f"pendsim {__version__}")
            for name, values in metadata.items():
                w.add_metadata(name, values)
            w.add_metadata("pendsim/rig_parameters", {k: repr(v) for k, v in params.as_dict().items()})
            w.add_attachment(MJCF_ATTACHMENT, "application/xml", mjcf_xml.encode(), start_time_ns)
            sid = {name: w.register_schema(name, "ros2msg", text) for name, text in ros2.SCHEMAS.items()}
            self._schemas = sid
            vec, cal = sid["geometry_msgs/msg/Vector3Stamped"], sid["std_msgs/msg/UInt8MultiArray"]
            self._channels: dict[str, int] = {}
            for n in nodes:
                self._channels[f"imu_{n}"] = w.register_channel(imu_topic(n), sid["sensor_msgs/msg/Imu"], "cdr")
                if "linear" in groups:
                    self._channels[f"linear_{n}"] = w.register_channel(f"/imu/{n}/linear_acceleration", vec, "cdr")
                if "gravity" in groups:
                    self._channels[f"gravity_{n}"] = w.register_channel(f"/imu/{n}/gravity", vec, "cdr")
                if "calib" in groups:
                    self._channels[f"calib_{n}"] = w.register_channel(f"/imu/{n}/calibration", cal, "cdr")
            tf_static = w.register_channel(
                "/tf_static", sid["tf2_msgs/msg/TFMessage"], "cdr", {"offered_qos_profiles": TRANSIENT_LOCAL_QOS}
            )
            if diagnostics:
                self._channels["diagnostics"] = w.register_channel(
                    DIAGNOSTICS_TOPIC, sid["diagnostic_msgs/msg/DiagnosticArray"], "cdr"
                )
        # Through the buffer like every message, so that written_upto_ns knows when it is written.
        self._add(tf_static, np.array([start_time_ns], np.int64), static_tf_message(params, Bno055(), start_time_ns))

    def _errors(self) -> contextlib.AbstractContextManager[None]:
        return _os_errors(self.path)

    def _add(self, channel: int, t_ns: NDArray[np.int64], payloads: NDArray[np.uint8]) -> None:
        if len(t_ns):
            self._buffer.setdefault(channel, []).append((t_ns, payloads))
            self.messages += len(t_ns)

    def register(self, topic: str, schema: str) -> int:
        """Another topic of a ``ros2.SCHEMAS`` message type (CDR); its channel id for ``add``."""
        with self._errors():
            return self._writer.register_channel(topic, self._schemas[schema], "cdr")

    def add(self, channel: int, t_ns: NDArray[np.int64], payloads: NDArray[np.uint8]) -> None:
        """n messages (payloads (n, size)) of a registered topic at log times t_ns (n,), buffered
        until ``flush``; those older than what the file holds are dropped (the count is returned
        by ``flush``'s caller's bookkeeping: ``dropped``)."""
        t_ns = np.asarray(t_ns, dtype=np.int64)
        taken = t_ns >= self.written_upto_ns
        self.dropped += int(np.sum(~taken))
        self._add(channel, t_ns[taken], payloads[taken])

    def add_samples(
        self, node: str, t_ns: NDArray[np.int64], rows: NDArray[np.float64], stamp_ns: NDArray[np.int64] | None = None
    ) -> NDArray[np.bool_]:
        """n samples of one node: log times (n,) ns, non-decreasing, (n, len(ROW_FIELDS)) rows and
        the header stamps (n,) ns (None: the log times).

        Returns (n,) which were taken: those older than what the file already holds
        (``written_upto_ns``) are dropped, since an MCAP file's chunks are written in log-time
        order (the caller counts them late)."""
        t_ns = np.asarray(t_ns, dtype=np.int64)
        stamp_ns = t_ns if stamp_ns is None else np.asarray(stamp_ns, dtype=np.int64)
        taken = t_ns >= self.written_upto_ns
        if not np.all(taken):
            t_ns, rows, stamp_ns = t_ns[taken], rows[taken], stamp_ns[taken]
        n = len(t_ns)
        if not n:
            return taken
        sec, nanosec = ros2.split_time(stamp_ns)
        groups = self.groups
        quat = rows[:, GROUP_SLICES["quat"]] if "quat" in groups else np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        zeros = np.zeros((n, 3))
        imu = self._imu_layout[node].encode(
            n,
            sec=sec,
            nanosec=nanosec,
            orientation=rotations.wxyz_to_xyzw(quat),
            orientation_covariance=self._covariance["orientation"],
            angular_velocity=rows[:, GROUP_SLICES["gyro"]] if "gyro" in groups else zeros,
            angular_velocity_covariance=self._covariance["gyro"],
            linear_acceleration=rows[:, GROUP_SLICES["accel"]] if "accel" in groups else zeros,
            linear_acceleration_covariance=self._covariance["accel"],
        )
        self._add(self._channels[f"imu_{node}"], t_ns, imu)
        for group in ("linear", "gravity"):
            if group in groups:
                vec = self._vec_layout[node].encode(n, sec=sec, nanosec=nanosec, vector=rows[:, GROUP_SLICES[group]])
                self._add(self._channels[f"{group}_{node}"], t_ns, vec)
        if "calib" in groups:
            self._add_calibration(node, t_ns, rows[:, GROUP_SLICES["calib"]].astype(np.uint8))
        self.samples += n
        return taken

    def _add_calibration(self, node: str, t_ns: NDArray[np.int64], levels: NDArray[np.uint8]) -> None:
        """Calibration at 1 Hz (the first sample of each second) and whenever it changes."""
        keep = []
        for i, (t, row) in enumerate(zip(t_ns, levels, strict=True)):
            value, second = tuple(int(v) for v in row), int(t) // NS_PER_S
            if value != self._last_calib.get(node) or second != self._last_calib_second.get(node):
                keep.append(i)
                self._last_calib[node], self._last_calib_second[node] = value, second
        if keep:
            chosen = levels[keep]
            payload = self._calib_layout.encode(len(keep), data_offset=np.zeros(len(keep)), data=chosen)
            self._add(self._channels[f"calib_{node}"], t_ns[keep], payload)

    def add_diagnostics(self, t_ns: int, statuses: list[ros2.DiagnosticStatus]) -> None:
        """One /diagnostics message (at ``t_ns``, or when the file already holds later messages, at
        the latest of them)."""
        t_ns = max(t_ns, self.written_upto_ns)
        payload = np.frombuffer(ros2.encode_diagnostic_array(t_ns, statuses), np.uint8)[None]
        self._add(self._channels["diagnostics"], np.array([t_ns], np.int64), payload)

    def flush(self, upto_ns: int | None = None) -> None:
        """Write every message given so far with log time <= ``upto_ns`` (all of them for None) and
        hand it to the OS. The caller promises that no message given later is older than
        ``upto_ns``; ``written_upto_ns`` is the latest log time written."""
        with self._errors():
            kept: dict[int, list[tuple[NDArray[np.int64], NDArray[np.uint8]]]] = {}
            for channel, parts in self._buffer.items():
                if len({p.shape[1] for _, p in parts}) == 1:  # one size: one call, one chunk
                    parts = [(np.concatenate([t for t, _ in parts]), np.concatenate([p for _, p in parts]))]
                for t, p in parts:
                    now = np.ones(len(t), bool) if upto_ns is None else t <= upto_ns
                    if np.any(now):
                        self._writer.write_messages(channel, t[now], p[now])
                        self.written_upto_ns = max(self.written_upto_ns, int(t[now][-1]))
                    if not np.all(now):
                        kept.setdefault(channel, []).append((t[~now], p[~now]))
            self._writer.flush()  # one chunk (or more), channels interleaved in log-time order
            self._buffer = kept

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        with self._errors():
            self._writer.add_metadata(name, values)

    def close(self) -> None:
        """Write what is left, the summary and the footer."""
        self.flush()
        with self._errors():
            self._writer.finish()


@contextlib.contextmanager
def _os_errors(path: Path) -> Iterator[None]:
    """Turn an OSError while writing into an OutputError naming the file."""
    try:
        yield
    except OSError as exc:
        raise output_error(path, exc) from None


__all__ = ["DIAGNOSTICS_TOPIC", "OutputError", "RecordingSink"]
