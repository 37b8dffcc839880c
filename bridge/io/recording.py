"""One MCAP file per run: what the IMUs measured, the joint states, the poses, and everything
needed to re-simulate the run from the file alone.

Topics (ROS 2 messages, CDR; log_time and header stamps in integer UTC ns from ``start_time_ns``,
recorded in ``pendsim/run``; the arrays read back count ns from that start):

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
  pivot axis; translation = the support's displacement in a run that moves it, plus M2's plane
  offset); ``/tf_static``: m1 -> imu_m1, m2 -> imu_m2 (the mounts), once.
- ``/drive`` (driven runs only): std_msgs/msg/Float64MultiArray at every simulation step, the
  inputs held over the step that starts at its log time (``pendsim_mj.rig.drives``): data =
  [torque_m1 N m, torque_m2 N m, support_x m/s^2, pivot_z m/s^2], one layout dimension whose
  label lists them (DRIVE_LABEL).
- ``/control`` (closed loops, ``pendsim control``): std_msgs/msg/Float64MultiArray at every
  control step: what the controller saw (angles, rates, each node's sample age) and its state
  (the torques it asked for and applied, its own quantities), the columns named with their units
  in the layout label; metadata ``pendsim/control`` (controller, design, limits, metrics).

Metadata records ``pendsim/run``, ``pendsim/rig_parameters``, ``pendsim/imu``, and for a driven
run ``pendsim/drive`` (each driven input's signal as JSON, the channel order, the sampling);
attachment ``pendulums.xml``: the exact MJCF the run used (parameters and drive actuators applied).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from pendsim_mj import __version__
from pendsim_mj.engines.dispatch import ENGINE_NAMES
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.rig.drives import NCHANNEL, Drive, recorded_drive
from pendsim_mj.rig.params import RigParams
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import Bno055, ImuNoise, ImuSamples
from pendsim_mj.sensors.imperfections import Imperfections
from pendsim_mj.units import NS_PER_S, seconds

from . import ros2
from .mcap.reader import ChannelData, McapFile, scan_mcap
from .mcap.writer import BulkMcapWriter
from .recording_layout import CONTROL_TOPIC, DRIVE_LAYOUT, JOINT_NAMES, SPATIAL_JOINT_NAMES, TF_LAYOUT

# ``X as X``: the layout's names a script uses with a recording, exported here too
from .recording_layout import DEFAULT_START_NS as DEFAULT_START_NS
from .recording_layout import DRIVE_TOPIC as DRIVE_TOPIC
from .recording_layout import MJCF_ATTACHMENT as MJCF_ATTACHMENT
from .recording_layout import NODES as NODES
from .recording_layout import RunInfo as RunInfo
from .recording_layout import imu_topic as imu_topic
from .recording_writer import RecordingWriter


def write_recording(
    path: str | Path,
    imu: ImuSamples,
    run: RunInfo,
    mjcf_xml: str,
    params: RigParams,
    *,
    traj: Trajectory | None = None,
    compression: str = "zstd",
    start_time_ns: int = DEFAULT_START_NS,
) -> Path:
    """Write a whole run held in memory to one MCAP file (``record`` streams instead).

    Args:
      path: output .mcap file.
      imu: the BNO055 samples of the run.
      run: initial conditions and settings.
      mjcf_xml: the MJCF used (attached verbatim).
      params: the rig parameters.
      traj: the simulated trajectory (single run); None for a static IMU-only recording, which
        has no /joint_states and /tf.
      compression: chunk compression, "zstd", "lz4" or "none".
      start_time_ns: UTC log time of t = 0, ns.
    """
    with BulkMcapWriter(path, compression=compression, library=f"pendsim {__version__}") as w:
        rw = RecordingWriter(
            w, params=params, config=imu.config, run=run, mjcf_xml=mjcf_xml, start_time_ns=start_time_ns,
            compression=compression, static=traj is None,
            spatial=traj is not None and traj.tilt_rate_rad_s is not None,
            drive=traj.drive if traj is not None and isinstance(traj.drive, Drive) else None,
        )  # fmt: skip
        rw.write_imu(imu)
        if traj is not None:
            rw.write_steps(traj, 0, last=True)
        rw.flush()
    return Path(path)


# --------------------------------------------------------------------------------------------
# Reading


@dataclasses.dataclass(frozen=True)
class ImuTopic:
    """One node's sensor_msgs/Imu messages as arrays (n messages); times in ns since the
    recording's start (``Recording.start_time_ns``)."""

    t_ns: np.ndarray  # (n,) log time
    stamp_ns: np.ndarray  # (n,) header stamp
    frame_id: str
    quat_wxyz: np.ndarray  # (n, 4)
    gyro_rad_s: np.ndarray  # (n, 3)
    accel_m_s2: np.ndarray  # (n, 3) with gravity (REP-145)
    orientation_covariance: np.ndarray  # (n, 3, 3) (a broadcast view when constant)
    gyro_covariance: np.ndarray  # (n, 3, 3)
    accel_covariance: np.ndarray  # (n, 3, 3)

    @property
    def t_s(self) -> np.ndarray:
        return seconds(self.t_ns)


@dataclasses.dataclass(frozen=True)
class JointStates:
    """/joint_states as arrays: n messages of the two hinges (ns since the recording's start)."""

    t_ns: np.ndarray
    position_rad: np.ndarray  # (n, 2)
    velocity_rad_s: np.ndarray  # (n, 2)
    effort_n_m: np.ndarray  # (n, 2)

    @property
    def t_s(self) -> np.ndarray:
        return seconds(self.t_ns)


Series = tuple[NDArray[np.int64], NDArray[Any]]  # (t_ns since the start, values)


@dataclasses.dataclass(frozen=True)
class Recording:
    """A recording read back: arrays per topic (times in ns since ``start_time_ns``), metadata,
    the MJCF, and what was wrong with the file (non-strict reads)."""

    path: Path
    imu: dict[str, ImuTopic]
    linear_accel_m_s2: dict[str, Series]  # node -> (t_ns, (n, 3))
    gravity_m_s2: dict[str, Series]
    calibration: dict[str, Series]  # node -> (t_ns, (n, 4) uint8)
    joint_states: JointStates | None
    tf_rotation_wxyz: Series | None  # (t_ns, (n, 2, 4)) world -> m1, m2
    metadata: dict[str, dict[str, str]]
    mjcf_xml: str | None
    start_time_ns: int  # UTC log time of the recording's t = 0
    problems: tuple[str, ...] = ()
    unverified: tuple[str, ...] = ()
    drive_input: Series | None = None  # (t_ns, (n, 4)) the /drive topic of a driven run

    @property
    def complete(self) -> bool:
        return not self.problems

    @property
    def drive_input_s(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """The /drive topic as (t_s (n,) on the recording's clock, held inputs (n, 4)); None for a
        free run (or a topic of fewer than two steps)."""
        if self.drive_input is None or len(self.drive_input[0]) < 2:
            return None
        t_ns, held = self.drive_input
        return np.asarray(seconds(t_ns), dtype=np.float64), np.asarray(held, dtype=np.float64)

    def without_imu(self) -> Recording:
        """This recording without its IMU topics (the rest as it is): a caller that has taken
        the samples it needs out of them lets go of the others (a 6 h run: 16 bytes of log time
        and stamp per sample and node)."""
        return dataclasses.replace(self, imu={})

    def drive_from(self, start_s: float, *, until_s: float | None = None) -> Drive | None:
        """The recording's drive from ``start_s`` (s on its clock: the release) on, drive time 0
        there (``pendsim_mj.rig.drives.recorded_drive``: covering [0, until_s] since the start); None
        for a free run."""
        inputs = self.drive_input_s
        return None if inputs is None else recorded_drive(*inputs, start_s, until_s=until_s)

    def params(self) -> RigParams:
        """The rig parameters recorded in the metadata (RecordingError if they are not valid)."""
        return stated_rig(self.path, self._metadata("pendsim/rig_parameters"))

    def run_info(self) -> RunInfo:
        """How the run was made (RecordingError if the metadata are not valid)."""
        raw = self._metadata("pendsim/run")
        where = "pendsim/run"
        engine = raw.get("engine", "")
        allowed = (*ENGINE_NAMES, "static")  # every engine ``record`` runs, and a static noise test
        if engine not in allowed:
            raise RecordingError(f"{self.path}: metadata {where}: engine = {engine!r}; allowed: {', '.join(allowed)}")
        model = raw.get("model", "planar")
        if model not in ("planar", "spatial", "static"):
            raise RecordingError(f"{self.path}: metadata {where}: model = {model!r}; allowed: planar, spatial, static")
        duration = _finite(self.path, where, "duration_s", raw.get("duration_s"), low=0.0, high=1e7)
        dt = _finite(self.path, where, "dt_s", raw.get("dt_s"), low=0.0, high=10.0)
        release = _finite(self.path, where, "release_time_s", raw.get("release_time_s", "0"), low=0.0, high=1e7)
        if dt <= 0 or duration <= 0:
            raise RecordingError(f"{self.path}: metadata {where}: duration_s and dt_s must be > 0")
        return RunInfo(
            engine=engine,
            phi0_rad=_pair(self.path, where, "phi0_rad", raw.get("phi0_rad"), 2 * math.pi),
            omega0_rad_s=_pair(self.path, where, "omega0_rad_s", raw.get("omega0_rad_s"), 1e3),
            duration_s=duration,
            dt_s=dt,
            model=model,
            release_time_s=release,
        )

    def imu_config(self) -> Bno055:
        """The node model recorded in the metadata (RecordingError if it is not valid)."""
        raw = self._metadata("pendsim/imu")
        try:
            nested: dict[str, dict[str, Any]] = {"noise_model": {}, "imperfections": {}}
            kwargs: dict[str, Any] = {}
            for k, v in raw.items():
                head, dot, name = k.partition(".")
                value = _tuple(json.loads(v, parse_constant=_no_constant))
                if dot and head in nested:
                    nested[head][name] = value
                elif dot:
                    raise ParameterError(f"unknown entry {k!r}")
                else:
                    kwargs[k] = value
            noise = ImuNoise(**nested["noise_model"])
            imperfections = Imperfections(**nested["imperfections"])
            for name in ("sample_rate_hz", "fusion_rate_hz", "accel_range_m_s2"):
                if name in kwargs and not (_number(kwargs[name]) and 0 < kwargs[name] <= 1e6):
                    raise ParameterError(f"{name} = {kwargs[name]!r} is not a number in (0, 1e6]")
            for name in ("fusion_timing", "noise"):
                if name in kwargs and not isinstance(kwargs[name], bool):
                    raise ParameterError(f"{name} = {kwargs[name]!r} is not true or false")
            if "seed" in kwargs and not (isinstance(kwargs["seed"], int) and 0 <= kwargs["seed"] < 2**63):
                raise ParameterError(f"seed = {kwargs['seed']!r} is not an integer in [0, 2^63)")
            return Bno055(noise_model=noise, imperfections=imperfections, **kwargs)
        except (ValueError, TypeError, ParameterError) as exc:  # JSONDecodeError is a ValueError
            message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise RecordingError(f"{self.path}: metadata pendsim/imu is not valid: {message}") from None

    def _metadata(self, name: str) -> dict[str, str]:
        raw = self.metadata.get(name)
        if raw is None:
            raise RecordingError(f"{self.path}: no {name} metadata (not a pendsim recording?)")
        return raw


def _no_constant(text: str) -> float:
    raise ValueError(f"{text} is not a finite number")


def _number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _tuple(value: Any) -> Any:
    if isinstance(value, list):
        return tuple(_tuple(v) for v in value)
    return value


def rig_stated_in(path: Path) -> tuple[RigParams | None, str]:
    """The rig a recording's metadata state (None: none, e.g. another tool's file) and its damage in
    one line ("" where its structure is whole), from the file's structure alone (no chunk inflated)."""
    mcap = scan_mcap(path)
    try:
        raw = mcap.metadata.get("pendsim/rig_parameters")
        damaged = mcap.error_text() if mcap.problems else ""
    finally:
        mcap.close()
    return (None if raw is None else stated_rig(path, raw)), damaged


def stated_rig(path: Path, raw: dict[str, str]) -> RigParams:
    """The rig a recording states (its ``pendsim/rig_parameters`` metadata, ``raw``), on top of
    the paper's for what it leaves out (RecordingError naming the file if a value is not valid)."""
    values = {k: _finite(path, "pendsim/rig_parameters", k, v) for k, v in raw.items()}
    try:
        return RigParams().with_mapping(values)
    except ParameterError as exc:
        raise RecordingError(f"{path}: metadata pendsim/rig_parameters: {exc}") from None


def _finite(path: Path, where: str, key: str, text: str | None, *, low: float = -1e300, high: float = 1e300) -> float:
    """A metadata value that must be a finite number in [low, high]; RecordingError naming it."""
    try:
        value = float(text) if text is not None else math.nan
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and low <= value <= high):
        raise RecordingError(
            f"{path}: metadata {where}: {key} = {text!r} is not a finite number in [{low:g}, {high:g}]"
        )
    return value


def _pair(path: Path, where: str, key: str, text: str | None, bound: float) -> tuple[float, float]:
    try:
        value = json.loads(text, parse_constant=_no_constant) if text is not None else None
    except ValueError:
        value = None
    if not (isinstance(value, list) and len(value) == 2 and all(_number(v) and abs(v) <= bound for v in value)):
        raise RecordingError(f"{path}: metadata {where}: {key} = {text!r} is not two finite numbers within +-{bound:g}")
    return float(value[0]), float(value[1])


# The schema each known topic must carry.
EXPECTED_SCHEMAS = {
    **{imu_topic(n): "sensor_msgs/msg/Imu" for n in NODES},
    **{
        f"/imu/{n}/{key}": "geometry_msgs/msg/Vector3Stamped"
        for n in NODES
        for key in ("linear_acceleration", "gravity")
    },
    **{f"/imu/{n}/calibration": "std_msgs/msg/UInt8MultiArray" for n in NODES},
    "/joint_states": "sensor_msgs/msg/JointState",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    DRIVE_TOPIC: "std_msgs/msg/Float64MultiArray",
    CONTROL_TOPIC: "std_msgs/msg/Float64MultiArray",
}


def read_recording(
    path: str | Path,
    *,
    strict: bool = True,
    topics: Collection[str] | None = None,
    progress: Callable[[int], None] | None = None,
    sensor_float32: bool = False,
    imu_fields: Collection[str] | None = None,
    compiled: bool = False,
) -> Recording:
    """Read a recording into numpy arrays per topic, chunk by chunk: each chunk's messages are
    decoded straight into per-field arrays (payloads are never all held at once).

    Args:
      path: the .mcap file.
      strict: raise RecordingError (naming the file, the damaged region and how much is
        readable) if the file is truncated, damaged or inconsistent; with False, return what
        could be read (and the problems).
      topics: read only these topics (others are skipped without inflating their chunks).
      progress: called with bytes read, for a progress bar.
      sensor_float32: keep the IMU's orientation, angular velocity and acceleration as float32
        (half the memory of a long recording; the BNO055 outputs 16-bit integers, which float32
        holds to 1e-7 of their value, far below one LSB); stamps and log times stay int64.
      imu_fields: decode only these ``ImuTopic`` fields of the IMU topics (e.g. ``("gyro_rad_s",
        "accel_m_s2")`` for an Allan analysis; log times always); the others come back with no
        rows. None: all of them. Every message is still checked as before.
      compiled: check the chunks' message indexes with the compiled kernel (``McapFile.chunks``:
        the same result, each chunk parsed in a quarter of the time, after numba's 0.3-0.5 s
        first call).

    Raises:
      RecordingError: a damaged file (strict), or a known topic with an unexpected schema.
    """
    path = Path(path)
    mcap = scan_mcap(path)
    try:
        if strict and mcap.problems:
            raise RecordingError(mcap.error_text())
        wanted_topics = set(EXPECTED_SCHEMAS) - {"/tf_static"} if topics is None else set(topics)
        decoders = _topic_decoders(path, mcap, wanted_topics, sensor_float32, imu_fields)
        for chunk in mcap.chunks(channels=set(decoders), progress=progress, compiled=compiled):
            for cid, data in chunk.channels.items():
                if cid in decoders:
                    decoders[cid].add(data)
            if strict and mcap.problems:
                raise RecordingError(mcap.error_text())
        start = _start_time_ns(path, mcap)
        by_topic = {d.topic: d for d in decoders.values()}
        attachment = mcap.attachments.get(MJCF_ATTACHMENT)
        rec = _assemble(path, by_topic, start, mcap, attachment.data if attachment is not None else None)
        _check_metadata(rec)
        return rec
    finally:
        mcap.close()


def _check_metadata(rec: Recording) -> None:
    """Every pendsim metadata record the file has must hold valid values (RecordingError)."""
    checks: dict[str, Callable[[], object]] = {
        "pendsim/rig_parameters": rec.params,
        "pendsim/run": rec.run_info,
        "pendsim/imu": rec.imu_config,
    }
    for name, check in checks.items():
        if name in rec.metadata:
            check()


def _start_time_ns(path: Path, mcap: McapFile) -> int:
    """The recording's t = 0: ``pendsim/run`` start_time_ns, else its first message."""
    text = mcap.metadata.get("pendsim/run", {}).get("start_time_ns")
    if text is not None:
        if not (text.isdigit() and int(text) < 2**63):
            raise RecordingError(f"{path}: metadata pendsim/run: start_time_ns = {text!r} is not a time in ns")
        return int(text)
    return min((r.start_ns for r in mcap.chunk_refs), default=0)


def _topic_decoders(
    path: Path,
    mcap: McapFile,
    topics: set[str],
    sensor_float32: bool = False,
    imu_fields: Collection[str] | None = None,
) -> dict[int, _TopicDecoder]:
    """A decoder per channel of the wanted known topics, after checking its schema."""
    out: dict[int, _TopicDecoder] = {}
    for cid, channel in mcap.channels.items():
        expected = EXPECTED_SCHEMAS.get(channel.topic)
        if expected is None or channel.topic not in topics:
            continue
        schema = mcap.schemas.get(channel.schema_id)
        name = schema.name if schema is not None else "(no schema)"
        if (
            schema is None
            or schema.name != expected
            or schema.encoding != "ros2msg"
            or channel.message_encoding != "cdr"
        ):
            encoding = f"{schema.encoding if schema else '?'}/{channel.message_encoding}"
            raise RecordingError(
                f"{path}: topic {channel.topic} carries schema {name!r} ({encoding}); pendsim expects {expected} "
                "(ros2msg/cdr)"
            )
        count = sum(r.index_count(cid) for r in mcap.chunk_refs)
        out[cid] = _TopicDecoder(path, channel.topic, schema, count, sensor_float32)
        if imu_fields is not None and schema.name == "sensor_msgs/msg/Imu":
            unknown = set(imu_fields) - set(_TopicDecoder.IMU_FIELDS)
            if unknown:
                raise ValueError(f"imu_fields: no ImuTopic field {sorted(unknown)}; {sorted(_TopicDecoder.IMU_FIELDS)}")
            out[cid].keep = {_TopicDecoder.IMU_FIELDS[f] for f in imu_fields}
    return out


class _Column:
    """One decoded field, growing chunk by chunk into a preallocated array; a field whose value
    never changes (covariances) is kept once and returned as a broadcast view."""

    def __init__(self, capacity: int) -> None:
        self.capacity = max(capacity, 1)
        self.data: NDArray[Any] | None = None
        self.constant: NDArray[Any] | None = None
        self.n = 0

    def add(self, values: NDArray[Any], *, may_be_constant: bool = False) -> None:
        m = len(values)
        if not m:
            return
        if may_be_constant and self.data is None:
            first = values[0]
            same = self.n == 0 if self.constant is None else np.array_equal(first, self.constant)
            if same and np.all(values == first):
                self.constant = np.array(first)
                self.n += m
                return
        if self.data is None:
            self.data = np.empty((max(self.capacity, self.n + m), *values.shape[1:]), values.dtype)
            if self.constant is not None:
                self.data[: self.n] = self.constant
                self.constant = None
        elif self.n + m > len(self.data):  # more than the index said (a chunk without index)
            grown = np.empty((max(2 * len(self.data), self.n + m), *values.shape[1:]), values.dtype)
            grown[: self.n] = self.data[: self.n]
            self.data = grown
        self.data[self.n : self.n + m] = values
        self.n += m

    def result(self, shape: tuple[int, ...], dtype: Any = np.float64) -> NDArray[Any]:
        if self.constant is not None:
            return np.broadcast_to(self.constant.reshape(shape), (self.n, *shape))
        if self.data is None:
            return np.zeros((0, *shape), dtype)
        return self.data[: self.n].reshape(self.n, *shape)


class _TopicDecoder:
    """Decodes one topic's chunks into columns: in bulk with the fixed CDR layout when the
    messages have it, else message by message with the file's own schema (mcap_ros2)."""

    FIELDS: ClassVar[dict[str, tuple[str, ...]]] = {
        "sensor_msgs/msg/Imu": ("sec", "nanosec", "orientation", "angular_velocity", "linear_acceleration",
                                "orientation_covariance", "angular_velocity_covariance",
                                "linear_acceleration_covariance"),
        "geometry_msgs/msg/Vector3Stamped": ("vector",),
        "std_msgs/msg/UInt8MultiArray": ("data",),
        "sensor_msgs/msg/JointState": ("position", "velocity", "effort"),
        "tf2_msgs/msg/TFMessage": ("t0_rotation", "t1_rotation"),
        "std_msgs/msg/Float64MultiArray": ("data",),
    }  # fmt: skip
    CONSTANT = frozenset({"orientation_covariance", "angular_velocity_covariance", "linear_acceleration_covariance"})

    SENSOR = frozenset({"orientation", "angular_velocity", "linear_acceleration"})
    IMU_FIELDS: ClassVar[dict[str, str]] = {
        "stamp_ns": "sec",
        "quat_wxyz": "orientation",
        "gyro_rad_s": "angular_velocity",
        "accel_m_s2": "linear_acceleration",
        "orientation_covariance": "orientation_covariance",
        "gyro_covariance": "angular_velocity_covariance",
        "accel_covariance": "linear_acceleration_covariance",
    }
    """``ImuTopic`` fields by the message field they come from (``read_recording``'s imu_fields)."""

    def __init__(self, path: Path, topic: str, schema: Any, count: int, sensor_float32: bool = False) -> None:
        self.path, self.topic, self.schema = path, topic, schema
        self.sensor_float32 = sensor_float32 and schema.name == "sensor_msgs/msg/Imu"
        names = [name for name in self.FIELDS[schema.name] if name not in ("sec", "nanosec")]
        if "sec" in self.FIELDS[schema.name]:
            names.append("stamp")
        self.columns = {name: _Column(count) for name in ("log", *names)}
        self.layout: ros2.FixedCdr | None = None
        self.frame_id = ""
        self._decoder: Callable[[bytes], Any] | None = None
        self.keep: set[str] | None = None  # the fields decoded into columns (None: all)

    def add(self, data: ChannelData) -> None:
        if not len(data):
            return
        fields = self._bulk(data.payloads) if isinstance(data.payloads, np.ndarray) else None
        if fields is None:
            fields = self._one_by_one(data.payloads)
        self.columns["log"].add(data.log_time_ns)
        if self.keep is not None:
            fields = {k: v for k, v in fields.items() if k in self.keep or (k == "nanosec" and "sec" in self.keep)}
        if "sec" in fields:  # the header stamp in ns, chunk by chunk (no whole-run temporaries)
            fields["stamp"] = fields.pop("sec").astype(np.int64) * NS_PER_S + fields.pop("nanosec")
        if "orientation" in fields:
            fields["orientation"] = rotations.xyzw_to_wxyz(fields["orientation"])
        for name, values in fields.items():
            if self.sensor_float32 and name in self.SENSOR:
                values = values.astype(np.float32)
            self.columns[name].add(values, may_be_constant=name in self.CONSTANT)

    def _layout_for(self, payloads: NDArray[np.uint8]) -> ros2.FixedCdr | None:
        name = self.schema.name
        if name in ("sensor_msgs/msg/Imu", "geometry_msgs/msg/Vector3Stamped"):
            if payloads.shape[1] < 20:
                return None
            try:
                frame = ros2.frame_id_of(payloads[0])
            except (UnicodeDecodeError, ValueError):
                return None
            self.frame_id = frame
            return ros2.imu_layout(frame) if name == "sensor_msgs/msg/Imu" else ros2.vector3_stamped_layout(frame)
        if name == "std_msgs/msg/UInt8MultiArray":
            return ros2.uint8_multiarray_layout(4)
        if name == "std_msgs/msg/Float64MultiArray":
            return DRIVE_LAYOUT
        if name == "sensor_msgs/msg/JointState":
            for names in (JOINT_NAMES, JOINT_NAMES + SPATIAL_JOINT_NAMES):
                layout = ros2.joint_state_layout(names)
                if layout.size == payloads.shape[1]:
                    return layout
            return None
        return TF_LAYOUT

    def _bulk(self, payloads: NDArray[np.uint8]) -> dict[str, NDArray[Any]] | None:
        if self.schema.data != ros2.SCHEMAS[self.schema.name]:
            return None  # another definition of the type: decode with it
        if self.layout is None or self.layout.size != payloads.shape[1]:
            self.layout = self._layout_for(payloads)
        if self.layout is None:
            return None
        try:
            dec = self.layout.decode(payloads)
        except ValueError:
            return None
        # views of the chunk's payloads: the columns copy them once, into their arrays
        out = {name: dec[name] for name in self.FIELDS[self.schema.name] if name in (dec.dtype.names or ())}
        if self.schema.name == "sensor_msgs/msg/JointState":  # the hinges (first two joints)
            out = {k: v.reshape(len(dec), -1)[:, :2] for k, v in out.items()}
        return out

    def _one_by_one(self, payloads: NDArray[np.uint8] | list[bytes]) -> dict[str, NDArray[Any]]:
        """Per message with the file's own schema (slow; for messages without our fixed layout)."""
        rows = [bytes(p) for p in payloads]
        try:
            if self._decoder is None:
                self._decoder = ros2.decoder_for(self.schema)
            messages = [self._decoder(r) for r in rows]
            return self._extract(messages)
        except Exception as exc:  # struct.error, AttributeError, IndexError, ...: not this type
            raise RecordingError(
                f"{self.path}: topic {self.topic}: a message does not decode as {self.schema.name} "
                f"({type(exc).__name__})"
            ) from None

    def _extract(self, messages: list[Any]) -> dict[str, NDArray[Any]]:
        name = self.schema.name
        if name == "sensor_msgs/msg/Imu":
            self.frame_id = messages[0].header.frame_id
            xyz = ("x", "y", "z")
            return {
                "sec": np.array([m.header.stamp.sec for m in messages], np.int64),
                "nanosec": np.array([m.header.stamp.nanosec for m in messages], np.int64),
                "orientation": np.array([[m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w]
                                         for m in messages]),
                "angular_velocity": np.array([[getattr(m.angular_velocity, a) for a in xyz] for m in messages]),
                "linear_acceleration": np.array([[getattr(m.linear_acceleration, a) for a in xyz] for m in messages]),
                **{f: np.array([list(getattr(m, f)) for m in messages], float) for f in self.CONSTANT},
            }  # fmt: skip
        if name == "geometry_msgs/msg/Vector3Stamped":
            return {"vector": np.array([[m.vector.x, m.vector.y, m.vector.z] for m in messages])}
        if name == "std_msgs/msg/UInt8MultiArray":
            return {"data": np.array([list(m.data)[:4] for m in messages], np.uint8).reshape(-1, 4)}
        if name == "std_msgs/msg/Float64MultiArray":
            return {"data": np.array([list(m.data)[:NCHANNEL] for m in messages], float).reshape(-1, NCHANNEL)}
        if name == "sensor_msgs/msg/JointState":
            order = [list(messages[0].name).index(j) for j in JOINT_NAMES]
            return {f: np.array([[list(getattr(m, f))[i] for i in order] for m in messages]) for f in
                    ("position", "velocity", "effort")}  # fmt: skip
        out = {}
        for k, child in enumerate(("m1", "m2")):
            rot = []
            for m in messages:
                t = next(t for t in m.transforms if t.child_frame_id == child)
                rot.append([t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
                            t.transform.rotation.w])  # fmt: skip
            out[f"t{k}_rotation"] = np.array(rot)
        return out


def _assemble(
    path: Path, topics: dict[str, _TopicDecoder], start: int, mcap: McapFile, mjcf: bytes | None
) -> Recording:
    def log(d: _TopicDecoder) -> NDArray[np.int64]:
        return since_start(d.columns["log"].result((), np.int64))

    def since_start(t_ns: NDArray[np.int64]) -> NDArray[np.int64]:
        """Times since the start, in place (the decoder's own array: no second copy)."""
        if t_ns.flags.writeable:
            t_ns -= start
            return t_ns
        return t_ns - start

    imu: dict[str, ImuTopic] = {}
    lin: dict[str, Series] = {}
    grav: dict[str, Series] = {}
    cal: dict[str, Series] = {}
    for n in NODES:
        d = topics.get(imu_topic(n))
        if d is not None and d.columns["log"].n:
            c = d.columns
            imu[n] = ImuTopic(
                log(d), since_start(c["stamp"].result((), np.int64)), d.frame_id, c["orientation"].result((4,)),
                c["angular_velocity"].result((3,)), c["linear_acceleration"].result((3,)),
                c["orientation_covariance"].result((3, 3)), c["angular_velocity_covariance"].result((3, 3)),
                c["linear_acceleration_covariance"].result((3, 3)),
            )  # fmt: skip
        for key, store in (("linear_acceleration", lin), ("gravity", grav)):
            d = topics.get(f"/imu/{n}/{key}")
            if d is not None and d.columns["log"].n:
                store[n] = (log(d), d.columns["vector"].result((3,)))
        d = topics.get(f"/imu/{n}/calibration")
        if d is not None and d.columns["log"].n:
            cal[n] = (log(d), d.columns["data"].result((4,), np.uint8))
    joints = None
    d = topics.get("/joint_states")
    if d is not None and d.columns["log"].n:
        c = d.columns
        joints = JointStates(log(d), c["position"].result((2,)), c["velocity"].result((2,)), c["effort"].result((2,)))
    tf = None
    d = topics.get("/tf")
    if d is not None and d.columns["log"].n:
        xyzw = np.stack([d.columns["t0_rotation"].result((4,)), d.columns["t1_rotation"].result((4,))], axis=1)
        tf = (log(d), rotations.xyzw_to_wxyz(xyzw))
    drive_input = None
    d = topics.get(DRIVE_TOPIC)
    if d is not None and d.columns["log"].n:
        drive_input = (log(d), d.columns["data"].result((NCHANNEL,)))
    # not UTF-8 (a foreign or hostile file): replaced characters; the MJCF guard then judges the text
    mjcf_xml = mjcf.decode("utf-8", errors="replace") if mjcf is not None else None
    return Recording(
        path=path,
        imu=imu,
        linear_accel_m_s2=lin,
        gravity_m_s2=grav,
        calibration=cal,
        joint_states=joints,
        tf_rotation_wxyz=tf,
        metadata=mcap.metadata,
        mjcf_xml=mjcf_xml,
        start_time_ns=start,
        problems=tuple(mcap.problems),
        unverified=tuple(str(u) for u in mcap.unverified),
        drive_input=drive_input,
    )
