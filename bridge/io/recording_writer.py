"""Write a recording block by block: the topics, metadata and attachment of a recording
(``recording``'s docstring; the names in ``recording_layout``), through one streaming
``BulkMcapWriter``.

ROS conventions kept (checked by tests with the mcap library, ``rosbags`` and Foxglove's
TypeScript readers):

- log times and header stamps are UTC nanoseconds from a real start (``start_time_ns``,
  recorded in ``pendsim/run`` as ``start_time_ns`` and ``start_time_utc``);
- ``/tf`` and ``/joint_states`` from the first message, the hold included (the pendulums held
  at their initial angles, at rest);
- ``/tf_static`` is transient-local (channel metadata ``offered_qos_profiles`` as rosbag2 writes
  it) and, in a static recording, also holds ``world -> m1`` and ``world -> m2`` (a ``world`` root);
- ``/joint_states`` lists every joint of the model (spatial: both hinges and both tilts);
- orientation quaternions are unit quaternions (normalised after the chip's quantisation);
- chunks interleave the topics in log-time order (the writer's flush after each block).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pendsim_mj import __version__
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.rig.drives import NCHANNEL, Drive
from pendsim_mj.rig.params import RigParams
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import Bno055, ImuSamples
from pendsim_mj.units import nanoseconds, split_ns

from . import ros2
from .mcap.writer import BulkMcapWriter
from .recording_layout import (
    CONTROL_METADATA,
    CONTROL_TOPIC,
    DRIVE_LABEL,
    DRIVE_LAYOUT,
    DRIVE_TOPIC,
    JOINT_NAMES,
    MJCF_ATTACHMENT,
    NODES,
    SITE_QUAT_WXYZ,
    SPATIAL_JOINT_NAMES,
    STATIC_TF_LAYOUT,
    STATIC_WORLD_TF_LAYOUT,
    TF_LAYOUT,
    ControlTopic,
    RunInfo,
    control_layout,
    imu_topic,
)

# rosbag2's QoS profile for a latched topic (Humble's YAML): reliable, transient-local.
TRANSIENT_LOCAL_QOS = (
    "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 1\n"
    "  deadline:\n    sec: 2147483647\n    nsec: 4294967295\n"
    "  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n"
    "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n"
    "  avoid_ros_namespace_conventions: false\n"
)


def utc_text(t_ns: int) -> str:
    """ISO 8601 UTC text of a time in ns since the Unix epoch."""
    sec, ns = split_ns(t_ns)
    moment = datetime.datetime.fromtimestamp(sec, tz=datetime.UTC)
    return moment.strftime("%Y-%m-%dT%H:%M:%S") + f".{ns:09d}Z"


def _ns(t_s: np.ndarray, start_time_ns: int) -> NDArray[np.int64]:
    return start_time_ns + nanoseconds(np.asarray(t_s))


def _unit(quat: NDArray[np.float64]) -> NDArray[np.float64]:
    return quat / np.linalg.norm(quat, axis=-1, keepdims=True)


def _diag(values: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.diag(values).ravel()


class RecordingWriter:
    """Writes one run's topics in blocks, in log-time order.

    Usage: ``rw = RecordingWriter(w, ...)``; then per block ``rw.write_imu(samples)`` and
    ``rw.write_steps(traj_block, first_row, last)`` (in any order), then ``rw.flush()``.

    Args:
      w: the open writer.
      params, config, run: the rig, the node model and how the run was made.
      mjcf_xml: the MJCF used (attached verbatim).
      start_time_ns: UTC log time of the recording's t = 0, ns.
      compression: recorded in the metadata.
      static: a static noise test (IMU topics and a static world -> m1, m2; no /tf, /joint_states).
      spatial: the spatial variant (/joint_states lists the tilt joints too).
      drive: the run's drive (``/drive`` topic and ``pendsim/drive`` metadata), or None.
      control: a closed loop's ``/control`` topic and ``pendsim/control`` metadata, or None
        (written whole at the start; the writer's flushes put it in log-time order).
    """

    def __init__(
        self,
        w: BulkMcapWriter,
        *,
        params: RigParams,
        config: Bno055,
        run: RunInfo,
        mjcf_xml: str,
        start_time_ns: int,
        compression: str = "zstd",
        static: bool = False,
        spatial: bool = False,
        drive: Drive | None = None,
        control: ControlTopic | None = None,
    ) -> None:
        self.w, self.params, self.config, self.run = w, params, config, run
        self.drive = drive
        self.start_time_ns = int(start_time_ns)
        self.static, self.spatial = static, spatial
        cov = config.covariance_diagonals()
        self._cov = {key: [_diag(cov[key][k]) for k in range(2)] for key in cov}
        self._imu = [ros2.imu_layout(f"imu_{n}") for n in NODES]
        self._vec = [ros2.vector3_stamped_layout(f"imu_{n}") for n in NODES]
        self._calib = ros2.uint8_multiarray_layout(4)
        self.joint_names = JOINT_NAMES + (SPATIAL_JOINT_NAMES if spatial else ())
        self._joint = ros2.joint_state_layout(self.joint_names)
        self._last_calibration: NDArray[np.uint8] | None = None
        self._release_row = round(run.release_time_s / run.dt_s) if not static else 0
        self._hold_written = False
        write_metadata(w, params, config, run, compression, self.start_time_ns)
        if drive is not None:
            w.add_metadata("pendsim/drive", drive_metadata(drive))
        w.add_attachment(MJCF_ATTACHMENT, "application/xml", mjcf_xml.encode(), self.start_time_ns)
        sid = {name: w.register_schema(name, "ros2msg", text) for name, text in ros2.SCHEMAS.items()}
        self.ch: dict[str, int] = {}
        for n in NODES:
            self.ch[f"imu_{n}"] = w.register_channel(imu_topic(n), sid["sensor_msgs/msg/Imu"], "cdr")
            vec = sid["geometry_msgs/msg/Vector3Stamped"]
            self.ch[f"lin_{n}"] = w.register_channel(f"/imu/{n}/linear_acceleration", vec, "cdr")
            self.ch[f"grav_{n}"] = w.register_channel(f"/imu/{n}/gravity", vec, "cdr")
            self.ch[f"cal_{n}"] = w.register_channel(
                f"/imu/{n}/calibration", sid["std_msgs/msg/UInt8MultiArray"], "cdr"
            )
        if not static:
            self.ch["joint"] = w.register_channel("/joint_states", sid["sensor_msgs/msg/JointState"], "cdr")
            self.ch["tf"] = w.register_channel("/tf", sid["tf2_msgs/msg/TFMessage"], "cdr")
            if drive is not None:
                self.ch["drive"] = w.register_channel(DRIVE_TOPIC, sid["std_msgs/msg/Float64MultiArray"], "cdr")
        self.ch["tf_static"] = w.register_channel(
            "/tf_static", sid["tf2_msgs/msg/TFMessage"], "cdr", {"offered_qos_profiles": TRANSIENT_LOCAL_QOS}
        )
        w.write_messages(self.ch["tf_static"], [self.start_time_ns], self._static_tf())
        if control is not None and not static:
            self._write_control(control, sid["std_msgs/msg/Float64MultiArray"])

    def _write_control(self, control: ControlTopic, schema_id: int) -> None:
        w = self.w
        w.add_metadata(CONTROL_METADATA, control.metadata)
        channel = w.register_channel(CONTROL_TOPIC, schema_id, "cdr")
        values = np.asarray(control.values, dtype=float)
        t_ns = _ns(np.asarray(control.t_s, dtype=float) + self.run.release_time_s, self.start_time_ns)
        n, k = values.shape
        size = np.full(n, k)
        payload = control_layout(control.names).encode(n, size=size, stride=size, data_offset=np.zeros(n), data=values)
        w.write_messages(channel, t_ns, payload)

    # -- IMU topics ----------------------------------------------------------------------------
    def write_imu(self, imu: ImuSamples) -> None:
        """A block of samples (consecutive with the previous block's). Header stamps are each
        node's clock, log times when the recorder got each packet; lost packets are left out."""
        if not len(imu.t_s):
            return
        rows = self._calibration_rows(imu)
        for k, n in enumerate(NODES):
            stamp, log, received = imu.node_times(k)
            si = np.flatnonzero(received)
            stamp_ns, log_ns = _ns(stamp[si], self.start_time_ns), _ns(log[si], self.start_time_ns)
            sec, nsec = ros2.split_time(stamp_ns)
            payload = self._imu[k].encode(
                len(si),
                sec=sec,
                nanosec=nsec,
                orientation=rotations.wxyz_to_xyzw(_unit(imu.quat_wxyz[si, k])),
                orientation_covariance=self._cov["orientation"][k],
                angular_velocity=imu.gyro_rad_s[si, k],
                angular_velocity_covariance=self._cov["gyro"][k],
                linear_acceleration=imu.accel_m_s2[si, k],
                linear_acceleration_covariance=self._cov["accel"][k],
            )
            self.w.write_messages(self.ch[f"imu_{n}"], log_ns, payload)
            for key, values in (("lin", imu.linear_accel_m_s2), ("grav", imu.gravity_m_s2)):
                vec = self._vec[k].encode(len(si), sec=sec, nanosec=nsec, vector=values[si, k])
                self.w.write_messages(self.ch[f"{key}_{n}"], log_ns, vec)
            ci = si[np.isin(si, rows)]
            cal = self._calib.encode(len(ci), data_offset=np.zeros(len(ci)), data=imu.calibration[ci, k])
            self.w.write_messages(self.ch[f"cal_{n}"], _ns(log[ci], self.start_time_ns), cal)
        self._last_calibration = imu.calibration[-1].copy()

    def _calibration_rows(self, imu: ImuSamples) -> NDArray[np.int64]:
        """Rows at which calibration is published: every second and whenever it changes."""
        rate = round(self.config.sample_rate_hz)
        k = np.rint(imu.t_s * self.config.sample_rate_hz).astype(np.int64)  # absolute sample numbers
        previous = imu.calibration[:1] if self._last_calibration is None else self._last_calibration[None]
        changed = np.any(imu.calibration != np.concatenate([previous, imu.calibration[:-1]]), axis=(1, 2))
        return np.flatnonzero((k % rate == 0) | changed)

    # -- joint states and poses ----------------------------------------------------------------
    def write_steps(self, traj: Trajectory, first_row: int, last: bool) -> None:
        """/joint_states and /tf for rows first_row .. of a run block (the shared boundary row
        belongs to the next block unless ``last``); the hold's rows come before the first."""
        if self.static:
            return
        if not self._hold_written:
            self._hold_written = True
            if self._release_row:
                self._write_hold(traj)
        stop = len(traj.t_s) if last else len(traj.t_s) - 1
        if stop <= 0:
            return
        t_ns = _ns(traj.t_s[:stop] + self.run.release_time_s, self.start_time_ns)
        tilt = traj.tilt_rad[:stop]
        rate = traj.tilt_rate_rad_s[:stop] if traj.tilt_rate_rad_s is not None else np.zeros_like(tilt)
        self._write_joints(
            t_ns, traj.phi_rad[:stop], traj.omega_rad_s[:stop], traj.spring_moment_n_m[:stop], tilt, rate
        )
        self._write_tf(t_ns, traj.body_quat_wxyz()[:stop], traj.support_m[:stop])
        if "drive" in self.ch:
            size = np.full(stop, NCHANNEL)
            values = DRIVE_LAYOUT.encode(
                stop, size=size, stride=size, data_offset=np.zeros(stop), data=traj.drive_input[:stop]
            )
            self.w.write_messages(self.ch["drive"], t_ns, values)

    def _write_hold(self, traj: Trajectory) -> None:
        """The held pendulums before the release: initial angles, at rest, one row per step."""
        n = self._release_row
        t_ns = _ns(np.arange(n) * self.run.dt_s, self.start_time_ns)
        phi = np.broadcast_to(traj.phi_rad[0], (n, 2))
        held = dataclasses.replace(
            traj, phi_rad=traj.phi_rad[:1], tilt_rad=np.zeros((1, 2)), omega_rad_s=np.zeros((1, 2))
        )
        zeros = np.zeros((n, 2))
        self._write_joints(t_ns, phi, zeros, np.broadcast_to(traj.spring_moment_n_m[0], (n, 2)), zeros, zeros)
        self._write_tf(t_ns, np.broadcast_to(held.body_quat_wxyz()[0], (n, 2, 4)), np.zeros((n, 2)))

    def _write_joints(self, t_ns, phi, omega, moment, tilt, tilt_rate) -> None:
        sec, nsec = ros2.split_time(t_ns)
        if self.spatial:  # hinges, then tilts; the tilt moment is not modelled: NaN (unknown)
            phi, omega = np.hstack([phi, tilt]), np.hstack([omega, tilt_rate])
            moment = np.hstack([moment, np.full((len(t_ns), 2), np.nan)])
        joint = self._joint.encode(len(t_ns), sec=sec, nanosec=nsec, position=phi, velocity=omega, effort=moment)
        self.w.write_messages(self.ch["joint"], t_ns, joint)

    def _write_tf(
        self, t_ns: NDArray[np.int64], body_quat_wxyz: NDArray[np.float64], support_m: NDArray[np.float64]
    ) -> None:
        """world -> m1, m2: the pivots (moved with the support: world x and z) and the swings."""
        sec, nsec = ros2.split_time(t_ns)
        xyzw = rotations.wxyz_to_xyzw(_unit(body_quat_wxyz))
        support = np.zeros((len(t_ns), 3))
        support[:, 0], support[:, 2] = support_m[:, 0], support_m[:, 1]
        offsets = self._body_offsets()
        values = {}
        for k in range(2):
            values.update(
                {
                    f"t{k}_sec": sec,
                    f"t{k}_nanosec": nsec,
                    f"t{k}_translation": support + offsets[k],
                    f"t{k}_rotation": xyzw[:, k],
                }
            )
        self.w.write_messages(self.ch["tf"], t_ns, TF_LAYOUT.encode(len(t_ns), **values))

    def _body_offsets(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Pivot of each pendulum in the world: M2 sits plane_offset_m behind M1."""
        return np.zeros(3), np.array([0.0, self.params.plane_offset_m, 0.0])

    def _static_tf(self) -> NDArray[np.uint8]:
        return static_tf_message(self.params, self.config, self.start_time_ns, static=self.static)

    def flush(self, upto_s: float | None = None) -> None:
        """Write out what was given: everything, or what lies before ``upto_s`` (recording time;
        later messages wait for the next block, whose first may come slightly earlier than
        the last of this one: node clocks and fusion timing)."""
        self.w.flush(None if upto_s is None else int(_ns(np.array([upto_s]), self.start_time_ns)[0]))


def static_tf_message(params: RigParams, config: Bno055, t_ns: int, *, static: bool = False) -> NDArray[np.uint8]:
    """/tf_static: m1 -> imu_m1 and m2 -> imu_m2 (the nodes' mounts: disk centres, the spec's axes,
    the config's mount offset and rotation); for a static recording also world -> m1 and
    world -> m2 at rest."""
    sec, nsec = ros2.split_time(np.array([t_ns]))
    site_rotation = rotations.to_matrix(SITE_QUAT_WXYZ)
    values: dict[str, NDArray] = {}
    first = 0
    if static:
        for k, offset in enumerate((np.zeros(3), np.array([0.0, params.plane_offset_m, 0.0]))):
            values.update(
                {
                    f"t{k}_sec": sec,
                    f"t{k}_nanosec": nsec,
                    f"t{k}_translation": offset[None],
                    f"t{k}_rotation": np.array([[0.0, 0.0, 0.0, 1.0]]),
                }
            )
        first = 2
    for k, radius in enumerate((params.om1_m, params.om2_m)):
        offset = site_rotation @ np.asarray(config.mount_offset_m[k])
        quat = rotations.multiply(SITE_QUAT_WXYZ, np.asarray(config.mount_quat_wxyz[k]))
        values[f"t{first + k}_sec"] = sec
        values[f"t{first + k}_nanosec"] = nsec
        values[f"t{first + k}_translation"] = (np.array([0.0, 0.0, -radius]) + offset)[None]
        values[f"t{first + k}_rotation"] = rotations.wxyz_to_xyzw(_unit(quat))[None]
    layout = STATIC_WORLD_TF_LAYOUT if static else STATIC_TF_LAYOUT
    return layout.encode(1, **values)


def write_metadata(
    w: BulkMcapWriter, params: RigParams, config: Bno055, run: RunInfo, compression: str, start_time_ns: int
) -> None:
    """``pendsim/run``, ``pendsim/rig_parameters`` and ``pendsim/imu``."""
    import mujoco  # start-up: only its version is recorded, when a recording is written

    w.add_metadata(
        "pendsim/run",
        {
            "engine": run.engine,
            "model": run.model,
            "phi0_rad": json.dumps(list(run.phi0_rad)),
            "omega0_rad_s": json.dumps(list(run.omega0_rad_s)),
            "duration_s": repr(run.duration_s),
            "dt_s": repr(run.dt_s),
            "release_time_s": repr(run.release_time_s),
            "b1_n_m_s": repr(params.b1_n_m_s),
            "b2_n_m_s": repr(params.b2_n_m_s),
            "noise": str(config.noise).lower(),
            "seed": str(config.seed),
            "start_time_ns": str(start_time_ns),
            "start_time_utc": utc_text(start_time_ns),
            "compression": compression,
            "pendsim_version": __version__,
            "mujoco_version": mujoco.__version__,
        },
    )
    w.add_metadata("pendsim/rig_parameters", {k: repr(v) for k, v in params.as_dict().items()})
    w.add_metadata("pendsim/imu", imu_metadata(config))


def imu_metadata(config: Bno055) -> dict[str, str]:
    """Every field of the node model as JSON text; nested models (noise, imperfections) under
    ``<field>.<name>``."""
    out = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            for g in dataclasses.fields(value):
                out[f"{f.name}.{g.name}"] = json.dumps(_plain(getattr(value, g.name)))
        else:
            out[f.name] = json.dumps(_plain(value))
    return out


def _plain(value: Any) -> Any:
    """Tuples (nested) as lists, for JSON."""
    return [_plain(v) for v in value] if isinstance(value, tuple) else value


def drive_metadata(drive: Drive) -> dict[str, str]:
    """``pendsim/drive``: each driven input's signal as JSON, the channel order, the sampling."""
    out = {target: json.dumps(fields) for target, fields in drive.describe().items()}
    out["channels"] = DRIVE_LABEL
    out["sampling"] = "each input held over a simulation step at its value at the step's midpoint"
    return out
