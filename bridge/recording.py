"""One MCAP file per run: what the IMUs measured, the joint states, the poses, and everything
needed to re-simulate the run from the file alone.

Topics (ROS 2 messages, CDR; log_time and header stamps in integer ns from ``start_time_ns``):

- ``/imu/m1``, ``/imu/m2``: sensor_msgs/msg/Imu at 80 Hz, frame ``imu_m1``/``imu_m2``:
  orientation (x, y, z, w), angular_velocity, linear_acceleration with gravity (REP-145), and
  covariance diagonals from the noise model.
- ``/imu/mN/linear_acceleration``, ``/imu/mN/gravity``: geometry_msgs/msg/Vector3Stamped, the
  BNO055's gravity-free acceleration and gravity vector (not part of sensor_msgs/Imu).
- ``/imu/mN/calibration``: std_msgs/msg/UInt8MultiArray [system, gyro, accel, mag], 0-3, at 1 Hz
  and whenever it changes.
- ``/joint_states``: sensor_msgs/msg/JointState at every simulation step: hinge_phi1/2 position
  (rad), velocity (rad/s), effort = spring moment on each pendulum (N m).
- ``/tf``: tf2_msgs/msg/TFMessage at every step, world -> m1 and world -> m2 (rotation about the
  pivot axis); ``/tf_static``: m1 -> imu_m1, m2 -> imu_m2 (the mounts), once.

Metadata records ``pendsim/run``, ``pendsim/rig_parameters``, ``pendsim/imu``; attachment
``pendulums.xml``: the exact MJCF the run used (parameters applied).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Collection
from pathlib import Path

import numpy as np

from bridge import ros2
from bridge.mcap_reader import ChannelData, McapContents, read_mcap
from bridge.mcap_writer import BulkMcapWriter
from pendsim_mj import __version__, rotations
from pendsim_mj.errors import RecordingError
from pendsim_mj.params import RigParams
from pendsim_mj.sensors import Bno055, ImuNoise, ImuSamples
from pendsim_mj.trajectory import Trajectory

NODES = ("m1", "m2")
JOINT_NAMES = ("hinge_phi1", "hinge_phi2")
WORLD_FRAME = "world"
MJCF_ATTACHMENT = "pendulums.xml"
# The IMU site's axes in its body at rest (models/pendulums.xml: xyaxes="1 0 0 0 0 1").
SITE_QUAT_WXYZ = np.array([math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])
TF_LAYOUT = ros2.tf_layout(((WORLD_FRAME, "m1"), (WORLD_FRAME, "m2")))
STATIC_TF_LAYOUT = ros2.tf_layout((("m1", "imu_m1"), ("m2", "imu_m2")))


def imu_topic(node: str) -> str:
    return f"/imu/{node}"


@dataclasses.dataclass(frozen=True)
class RunInfo:
    """How a run was made: enough, with the MJCF, to re-simulate it."""

    engine: str
    phi0_rad: tuple[float, float]
    omega0_rad_s: tuple[float, float]
    duration_s: float
    dt_s: float
    model: str = "planar"
    release_time_s: float = 0.0  # when the pendulums were let go, on the recording's clock


def _ns(t_s: np.ndarray, start_time_ns: int) -> np.ndarray:
    return start_time_ns + np.rint(np.asarray(t_s) * 1e9).astype(np.int64)


def write_recording(
    path: str | Path,
    imu: ImuSamples,
    run: RunInfo,
    mjcf_xml: str,
    params: RigParams,
    *,
    traj: Trajectory | None = None,
    compression: str = "zstd",
    block_s: float = 30.0,
    start_time_ns: int = 0,
    progress: Callable[[float], None] | None = None,
) -> Path:
    """Write a run to one MCAP file, block by block (each block's chunks flushed as written).

    Args:
      path: output .mcap file.
      imu: the BNO055 samples of the run.
      run: initial conditions and settings.
      mjcf_xml: the MJCF used (attached verbatim).
      params: the rig parameters.
      traj: the simulated trajectory (single run); None for a static IMU-only recording, which
        has no /joint_states and /tf.
      compression: chunk compression, "zstd", "lz4" or "none".
      block_s: simulated seconds per block: a chunk per topic per block.
      start_time_ns: log time of t = 0.
      progress: called with the simulated seconds written after each block.
    """
    config = imu.config
    cov = config.covariance_diagonals()
    layouts = {
        "imu": [ros2.imu_layout(f"imu_{n}") for n in NODES],
        "vec": [ros2.vector3_stamped_layout(f"imu_{n}") for n in NODES],
        "calib": ros2.uint8_multiarray_layout(4),
        "joint": ros2.joint_state_layout(JOINT_NAMES),
        "tf": TF_LAYOUT,
    }
    imu_ns = _ns(imu.t_s, start_time_ns)
    if traj is not None:
        step_ns = _ns(traj.t_s + run.release_time_s, start_time_ns)
        body_quat_xyzw = rotations.wxyz_to_xyzw(traj.body_quat_wxyz())

    with BulkMcapWriter(path, compression=compression, library=f"pendsim {__version__}") as w:
        _write_metadata(w, params, config, run, compression, start_time_ns)
        w.add_attachment(MJCF_ATTACHMENT, "application/xml", mjcf_xml.encode(), start_time_ns)
        sid = {name: w.register_schema(name, "ros2msg", text) for name, text in ros2.SCHEMAS.items()}
        ch = {}
        for n in NODES:
            ch[f"imu_{n}"] = w.register_channel(imu_topic(n), sid["sensor_msgs/msg/Imu"], "cdr")
            ch[f"lin_{n}"] = w.register_channel(
                f"/imu/{n}/linear_acceleration", sid["geometry_msgs/msg/Vector3Stamped"], "cdr"
            )
            ch[f"grav_{n}"] = w.register_channel(f"/imu/{n}/gravity", sid["geometry_msgs/msg/Vector3Stamped"], "cdr")
            ch[f"cal_{n}"] = w.register_channel(f"/imu/{n}/calibration", sid["std_msgs/msg/UInt8MultiArray"], "cdr")
        if traj is not None:
            ch["joint"] = w.register_channel("/joint_states", sid["sensor_msgs/msg/JointState"], "cdr")
            ch["tf"] = w.register_channel("/tf", sid["tf2_msgs/msg/TFMessage"], "cdr")
        ch["tf_static"] = w.register_channel("/tf_static", sid["tf2_msgs/msg/TFMessage"], "cdr")
        w.write_messages(ch["tf_static"], imu_ns[:1], _static_tf(params, config, int(imu_ns[0])))

        calib_rows = _calibration_rows(imu)
        duration = float(imu.t_s[-1])
        nblocks = max(1, math.ceil(duration / block_s + 1e-12))
        for b in range(nblocks):
            lo, hi = b * block_s, (b + 1) * block_s if b < nblocks - 1 else math.inf
            si = np.flatnonzero((imu.t_s >= lo - 1e-12) & (imu.t_s < hi - 1e-12))
            for k, n in enumerate(NODES):
                sec, nsec = ros2.split_time(imu_ns[si])
                payload = layouts["imu"][k].encode(
                    len(si),
                    sec=sec,
                    nanosec=nsec,
                    orientation=rotations.wxyz_to_xyzw(imu.quat_wxyz[si, k]),
                    orientation_covariance=_diag(cov["orientation"][k]),
                    angular_velocity=imu.gyro_rad_s[si, k],
                    angular_velocity_covariance=_diag(cov["gyro"][k]),
                    linear_acceleration=imu.accel_m_s2[si, k],
                    linear_acceleration_covariance=_diag(cov["accel"][k]),
                )
                w.write_messages(ch[f"imu_{n}"], imu_ns[si], payload)
                for key, values in (("lin", imu.linear_accel_m_s2), ("grav", imu.gravity_m_s2)):
                    vec = layouts["vec"][k].encode(len(si), sec=sec, nanosec=nsec, vector=values[si, k])
                    w.write_messages(ch[f"{key}_{n}"], imu_ns[si], vec)
                ci = si[np.isin(si, calib_rows)]
                cal = layouts["calib"].encode(len(ci), data_offset=np.zeros(len(ci)), data=imu.calibration[ci, k])
                w.write_messages(ch[f"cal_{n}"], imu_ns[ci], cal)
            if traj is not None:
                _write_joint_block(w, ch, layouts, traj, step_ns, body_quat_xyzw, run.release_time_s, lo, hi)
            if progress is not None:
                progress(min(hi, duration) - lo)
    return Path(path)


def _write_joint_block(w, ch, layouts, traj, step_ns, body_quat_xyzw, release_time_s, lo, hi) -> None:
    """/joint_states and /tf for the steps in [lo, hi) s."""
    params = traj.params[0] if isinstance(traj.params, tuple) else traj.params
    body_offsets = (np.zeros(3), np.array([0.0, params.plane_offset_m, 0.0]))  # M2 sits behind M1
    step_t = traj.t_s + release_time_s  # on the recording's clock
    ti = np.flatnonzero((step_t >= lo - 1e-12) & (step_t < hi - 1e-12))
    sec, nsec = ros2.split_time(step_ns[ti])
    joint = layouts["joint"].encode(
        len(ti),
        sec=sec,
        nanosec=nsec,
        position=traj.phi_rad[ti],
        velocity=traj.omega_rad_s[ti],
        effort=traj.spring_moment_n_m[ti],
    )
    w.write_messages(ch["joint"], step_ns[ti], joint)
    tf_values = {}
    for k in range(2):
        tf_values.update(
            {
                f"t{k}_sec": sec,
                f"t{k}_nanosec": nsec,
                f"t{k}_translation": np.broadcast_to(body_offsets[k], (len(ti), 3)),
                f"t{k}_rotation": body_quat_xyzw[ti, k],
            }
        )
    w.write_messages(ch["tf"], step_ns[ti], layouts["tf"].encode(len(ti), **tf_values))


def _diag(values: np.ndarray) -> np.ndarray:
    return np.diag(values).ravel()


def _calibration_rows(imu: ImuSamples) -> np.ndarray:
    """Sample indices at which calibration is published: every second and on any change."""
    rate = round(imu.config.sample_rate_hz)
    k = np.arange(len(imu.t_s))
    changed = np.zeros(len(k), bool)
    changed[1:] = np.any(imu.calibration[1:] != imu.calibration[:-1], axis=(1, 2))
    return k[(k % rate == 0) | changed]


def _static_tf(params: RigParams, config: Bno055, t_ns: int) -> np.ndarray:
    """/tf_static: m1 -> imu_m1 and m2 -> imu_m2, the mount position and axes in the body."""
    sec, nsec = ros2.split_time(np.array([t_ns]))
    site_rotation = rotations.to_matrix(SITE_QUAT_WXYZ)
    values = {}
    for k, radius in enumerate((params.om1_m, params.om2_m)):
        offset = site_rotation @ np.asarray(config.mount_offset_m[k])
        quat = rotations.multiply(SITE_QUAT_WXYZ, np.asarray(config.mount_quat_wxyz[k]))
        values[f"t{k}_sec"] = sec
        values[f"t{k}_nanosec"] = nsec
        values[f"t{k}_translation"] = (np.array([0.0, 0.0, -radius]) + offset)[None]
        values[f"t{k}_rotation"] = rotations.wxyz_to_xyzw(quat)[None]
    return STATIC_TF_LAYOUT.encode(1, **values)


def _write_metadata(
    w: BulkMcapWriter, params: RigParams, config: Bno055, run: RunInfo, compression: str, t0: int
) -> None:
    import mujoco

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
            "start_time_ns": str(t0),
            "compression": compression,
            "pendsim_version": __version__,
            "mujoco_version": mujoco.__version__,
        },
    )
    w.add_metadata("pendsim/rig_parameters", {k: repr(v) for k, v in params.as_dict().items()})
    w.add_metadata("pendsim/imu", _imu_metadata(config))


def _imu_metadata(config: Bno055) -> dict[str, str]:
    out = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if f.name == "noise_model":
            for g in dataclasses.fields(value):
                out[f"noise_model.{g.name}"] = json.dumps(list(getattr(value, g.name)))
        else:
            out[f.name] = json.dumps(
                value if not isinstance(value, tuple) else [list(v) if isinstance(v, tuple) else v for v in value]
            )
    return out


# --------------------------------------------------------------------------------------------
# Reading


@dataclasses.dataclass(frozen=True)
class ImuTopic:
    """One node's sensor_msgs/Imu messages as arrays (n messages)."""

    t_ns: np.ndarray  # (n,) log time
    stamp_ns: np.ndarray  # (n,) header stamp
    frame_id: str
    quat_wxyz: np.ndarray  # (n, 4)
    gyro_rad_s: np.ndarray  # (n, 3)
    accel_m_s2: np.ndarray  # (n, 3) with gravity (REP-145)
    orientation_covariance: np.ndarray  # (n, 3, 3)
    gyro_covariance: np.ndarray  # (n, 3, 3)
    accel_covariance: np.ndarray  # (n, 3, 3)

    @property
    def t_s(self) -> np.ndarray:
        return self.t_ns * 1e-9


@dataclasses.dataclass(frozen=True)
class JointStates:
    """/joint_states as arrays: n messages of the two hinges."""

    t_ns: np.ndarray
    position_rad: np.ndarray  # (n, 2)
    velocity_rad_s: np.ndarray  # (n, 2)
    effort_n_m: np.ndarray  # (n, 2)

    @property
    def t_s(self) -> np.ndarray:
        return self.t_ns * 1e-9


@dataclasses.dataclass(frozen=True)
class Recording:
    """A recording read back: arrays per topic, metadata, the MJCF, and what was recovered."""

    path: Path
    imu: dict[str, ImuTopic]
    linear_accel_m_s2: dict[str, tuple[np.ndarray, np.ndarray]]  # node -> (t_ns, (n, 3))
    gravity_m_s2: dict[str, tuple[np.ndarray, np.ndarray]]
    calibration: dict[str, tuple[np.ndarray, np.ndarray]]  # node -> (t_ns, (n, 4) uint8)
    joint_states: JointStates | None
    tf_rotation_wxyz: tuple[np.ndarray, np.ndarray] | None  # (t_ns, (n, 2, 4)) world -> m1, m2
    metadata: dict[str, dict[str, str]]
    mjcf_xml: str | None
    contents: McapContents

    @property
    def complete(self) -> bool:
        return self.contents.complete

    def params(self) -> RigParams:
        """The rig parameters recorded in the metadata."""
        raw = self.metadata.get("pendsim/rig_parameters")
        if raw is None:
            raise RecordingError(f"{self.path}: no pendsim/rig_parameters metadata (not a pendsim recording?)")
        return RigParams().with_mapping({k: float(v) for k, v in raw.items()})

    def run_info(self) -> RunInfo:
        raw = self.metadata.get("pendsim/run")
        if raw is None:
            raise RecordingError(f"{self.path}: no pendsim/run metadata (not a pendsim recording?)")
        return RunInfo(
            engine=raw["engine"],
            phi0_rad=tuple(json.loads(raw["phi0_rad"])),
            omega0_rad_s=tuple(json.loads(raw["omega0_rad_s"])),
            duration_s=float(raw["duration_s"]),
            dt_s=float(raw["dt_s"]),
            model=raw.get("model", "planar"),
            release_time_s=float(raw.get("release_time_s", "0")),
        )

    def imu_config(self) -> Bno055:
        raw = self.metadata.get("pendsim/imu")
        if raw is None:
            raise RecordingError(f"{self.path}: no pendsim/imu metadata (not a pendsim recording?)")
        noise = ImuNoise(
            **{k.split(".", 1)[1]: tuple(json.loads(v)) for k, v in raw.items() if k.startswith("noise_model.")}
        )
        kwargs = {}
        for k, v in raw.items():
            if k.startswith("noise_model."):
                continue
            value = json.loads(v)
            kwargs[k] = (
                tuple(tuple(x) if isinstance(x, list) else x for x in value) if isinstance(value, list) else value
            )
        return Bno055(noise_model=noise, **kwargs)


def _decode(data: ChannelData, schema_name: str, layout: ros2.FixedCdr | None) -> np.ndarray | list:
    """Bulk decode with the fixed layout when it fits, else per message with mcap_ros2."""
    if layout is not None and isinstance(data.payloads, np.ndarray):
        try:
            return layout.decode(data.payloads)
        except ValueError:
            pass
    from mcap_ros2._dynamic import generate_dynamic

    decoder = generate_dynamic(schema_name, ros2.SCHEMAS[schema_name].decode())[schema_name]
    rows = data.payloads if isinstance(data.payloads, list) else [p.tobytes() for p in data.payloads]
    return [decoder(bytes(r)) for r in rows]


def read_recording(
    path: str | Path,
    *,
    strict: bool = True,
    topics: Collection[str] | None = None,
    progress: Callable[[int], None] | None = None,
) -> Recording:
    """Read a recording into numpy arrays per topic.

    Args:
      path: the .mcap file.
      strict: raise RecordingError (naming the file and how much was recovered) if the file is
        truncated or damaged; with False, return what could be read.
      topics: read only these topics (others are skipped without decompressing).
      progress: called with bytes read, for a progress bar.
    """
    contents = read_mcap(path, strict=strict, topics=topics, progress=progress)
    present = {t for t, count in contents.topics().items() if count}
    imu, lin, grav, cal = {}, {}, {}, {}
    topics = present
    for n in NODES:
        if imu_topic(n) in topics:
            imu[n] = _read_imu(contents.topic(imu_topic(n)))
        for key, store in (("linear_acceleration", lin), ("gravity", grav)):
            topic = f"/imu/{n}/{key}"
            if topic in topics:
                d = contents.topic(topic)
                dec = _decode(d, "geometry_msgs/msg/Vector3Stamped", ros2.vector3_stamped_layout(f"imu_{n}"))
                vec = (
                    dec["vector"]
                    if isinstance(dec, np.ndarray)
                    else np.array([[m.vector.x, m.vector.y, m.vector.z] for m in dec])
                )
                store[n] = (d.log_time_ns, vec.reshape(-1, 3))
        topic = f"/imu/{n}/calibration"
        if topic in topics:
            d = contents.topic(topic)
            dec = _decode(d, "std_msgs/msg/UInt8MultiArray", ros2.uint8_multiarray_layout(4))
            levels = dec["data"] if isinstance(dec, np.ndarray) else np.array([list(m.data) for m in dec], np.uint8)
            cal[n] = (d.log_time_ns, levels.reshape(-1, 4))
    joints = None
    if "/joint_states" in topics:
        d = contents.topic("/joint_states")
        dec = _decode(d, "sensor_msgs/msg/JointState", ros2.joint_state_layout(JOINT_NAMES))
        if isinstance(dec, np.ndarray):
            pos, vel, eff = dec["position"], dec["velocity"], dec["effort"]
        else:
            pos, vel, eff = (np.array([getattr(m, f) for m in dec]) for f in ("position", "velocity", "effort"))
        joints = JointStates(d.log_time_ns, pos.reshape(-1, 2), vel.reshape(-1, 2), eff.reshape(-1, 2))
    tf = None
    if "/tf" in topics:
        d = contents.topic("/tf")
        dec = _decode(d, "tf2_msgs/msg/TFMessage", TF_LAYOUT)
        if isinstance(dec, np.ndarray):
            xyzw = np.stack([dec["t0_rotation"], dec["t1_rotation"]], axis=1)
            tf = (d.log_time_ns, rotations.xyzw_to_wxyz(xyzw))
    attachment = contents.attachments.get(MJCF_ATTACHMENT)
    return Recording(
        path=Path(path),
        imu=imu,
        linear_accel_m_s2=lin,
        gravity_m_s2=grav,
        calibration=cal,
        joint_states=joints,
        tf_rotation_wxyz=tf,
        metadata=contents.metadata,
        mjcf_xml=attachment.data.decode() if attachment is not None else None,
        contents=contents,
    )


def _read_imu(d: ChannelData) -> ImuTopic:
    frame = ros2.frame_id_of(d.payloads[0]) if isinstance(d.payloads, np.ndarray) and len(d) else ""
    dec = _decode(d, "sensor_msgs/msg/Imu", ros2.imu_layout(frame) if frame else None)
    if isinstance(dec, np.ndarray):
        stamp = dec["sec"].astype(np.int64) * 1_000_000_000 + dec["nanosec"]
        quat = rotations.xyzw_to_wxyz(dec["orientation"])
        gyro, accel = dec["angular_velocity"], dec["linear_acceleration"]
        covs = [
            dec[f].reshape(-1, 3, 3)
            for f in ("orientation_covariance", "angular_velocity_covariance", "linear_acceleration_covariance")
        ]
    else:
        stamp = np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in dec], np.int64)
        quat = np.array([[m.orientation.w, m.orientation.x, m.orientation.y, m.orientation.z] for m in dec])
        gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in dec])
        accel = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in dec])
        covs = [
            np.array([getattr(m, f) for m in dec]).reshape(-1, 3, 3)
            for f in ("orientation_covariance", "angular_velocity_covariance", "linear_acceleration_covariance")
        ]
        frame = dec[0].header.frame_id if dec else ""
    return ImuTopic(d.log_time_ns, stamp, frame, quat, gyro, accel, *covs)
