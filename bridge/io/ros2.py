"""ROS 2 messages with a fixed CDR layout, encoded and decoded in bulk with numpy.

A message whose strings and sequence lengths are the same in every instance (a given
``frame_id``, two joint names, two transforms) has one byte layout. ``FixedCdr`` computes it once
from a field list, following CDR (XCDR1, little endian) alignment: each primitive sits at a
multiple of its size, counted from the end of the 4-byte encapsulation header. Encoding fills a
numpy structured array from a template; decoding is a view. ``tests/io/test_ros2.py`` checks the
bytes against ``mcap_ros2``'s own encoder and decoder.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from pendsim_mj.units import NS_PER_S, split_ns

ENCAPSULATION_CDR_LE = b"\x00\x01\x00\x00"
_PRIMITIVES = {"int32": ("<i4", 4), "uint32": ("<u4", 4), "float64": ("<f8", 8), "uint8": ("u1", 1)}


@dataclasses.dataclass(frozen=True)
class Field:
    """One item of a fixed layout.

    kind: "int32", "uint32", "float64", "uint8" (a variable field named ``name``, ``count``
    values), "string" (constant text ``value``) or "length" (a constant uint32 ``value``: the
    element count that precedes a sequence).
    """

    kind: str
    name: str = ""
    count: int = 1
    value: str | int = ""


class FixedCdr:
    """Bulk codec for one message type with a constant layout.

    Attributes:
      size: bytes per message, including the encapsulation header.
      dtype: structured dtype of one message; variable fields by name.
    """

    def __init__(self, fields: list[Field]) -> None:
        template = bytearray(ENCAPSULATION_CDR_LE)
        names: list[str] = []
        formats: list[str | tuple[str, tuple[int]]] = []
        offsets: list[int] = []
        for f in fields:
            if f.kind == "string":
                _align(template, 4)
                text = str(f.value).encode() + b"\x00"
                template += np.uint32(len(text)).tobytes() + text
            elif f.kind == "length":
                _align(template, 4)
                template += np.uint32(int(f.value)).tobytes()
            elif f.kind in _PRIMITIVES:
                fmt, size = _PRIMITIVES[f.kind]
                _align(template, size)
                names.append(f.name)
                formats.append((fmt, (f.count,)) if f.count > 1 else fmt)
                offsets.append(len(template))
                template += bytes(size * f.count)
            else:
                raise ValueError(f"unknown field kind {f.kind!r}")
        self.size = len(template)
        self.template = np.frombuffer(bytes(template), dtype=np.uint8)
        self.dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": self.size})
        variable = np.zeros(self.size, bool)
        for layout, off in zip(formats, offsets, strict=True):
            variable[off : off + np.dtype(layout).itemsize] = True
        edges = np.flatnonzero(np.diff(np.concatenate([[True], variable, [True]]).astype(int)))
        self._constant_runs = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]

    def encode(self, n: int, **values: np.ndarray) -> np.ndarray:
        """n messages as an (n, size) uint8 array; ``values`` give every variable field, (n, ...)."""
        out = np.empty((n, self.size), dtype=np.uint8)
        out[:] = self.template
        view = out.view(self.dtype).reshape(n)
        missing = set(self.dtype.names or ()) - set(values)
        if missing:
            raise ValueError(f"missing fields: {', '.join(sorted(missing))}")
        for name, value in values.items():
            view[name] = value
        return out

    def decode(self, payload: np.ndarray) -> np.ndarray:
        """(n, size) uint8 payloads to an (n,) structured array (checked against the template)."""
        if payload.ndim != 2 or payload.shape[1] != self.size:
            raise ValueError(f"expected payloads of {self.size} bytes, got shape {payload.shape}")
        if len(payload):
            for lo, hi in self._constant_runs:  # contiguous slices: no large temporaries
                if not np.array_equal(
                    payload[:, lo:hi], np.broadcast_to(self.template[lo:hi], (len(payload), hi - lo))
                ):
                    raise ValueError("payload does not match the fixed layout (different frame ids, names or lengths)")
        return np.ascontiguousarray(payload).view(self.dtype).reshape(len(payload))


def _align(buf: bytearray, size: int) -> None:
    pad = (-(len(buf) - 4)) % size
    buf += bytes(pad)


def _header(prefix: str, frame_id: str) -> list[Field]:
    return [Field("int32", f"{prefix}sec"), Field("uint32", f"{prefix}nanosec"), Field("string", value=frame_id)]


def imu_layout(frame_id: str) -> FixedCdr:
    """sensor_msgs/msg/Imu with a constant frame_id."""
    return FixedCdr(
        [
            *_header("", frame_id),
            Field("float64", "orientation", 4),  # x, y, z, w
            Field("float64", "orientation_covariance", 9),
            Field("float64", "angular_velocity", 3),
            Field("float64", "angular_velocity_covariance", 9),
            Field("float64", "linear_acceleration", 3),
            Field("float64", "linear_acceleration_covariance", 9),
        ]
    )


def joint_state_layout(joint_names: tuple[str, ...], frame_id: str = "") -> FixedCdr:
    """sensor_msgs/msg/JointState with constant joint names (position, velocity, effort each n)."""
    n = len(joint_names)
    fields = [*_header("", frame_id), Field("length", value=n)]
    fields += [Field("string", value=name) for name in joint_names]
    for name in ("position", "velocity", "effort"):
        fields += [Field("length", value=n), Field("float64", name, n)]
    return FixedCdr(fields)


def tf_layout(frames: tuple[tuple[str, str], ...]) -> FixedCdr:
    """tf2_msgs/msg/TFMessage with one transform per (parent, child) pair; fields suffixed
    by the transform's index: t0_sec, t0_translation, t0_rotation (x, y, z, w), t1_..."""
    fields = [Field("length", value=len(frames))]
    for i, (parent, child) in enumerate(frames):
        fields += [
            *_header(f"t{i}_", parent),
            Field("string", value=child),
            Field("float64", f"t{i}_translation", 3),
            Field("float64", f"t{i}_rotation", 4),
        ]
    return FixedCdr(fields)


def vector3_stamped_layout(frame_id: str) -> FixedCdr:
    """geometry_msgs/msg/Vector3Stamped with a constant frame_id."""
    return FixedCdr([*_header("", frame_id), Field("float64", "vector", 3)])


def uint8_multiarray_layout(count: int) -> FixedCdr:
    """std_msgs/msg/UInt8MultiArray with no layout dimensions and ``count`` data bytes."""
    return FixedCdr(
        [
            Field("length", value=0),
            Field("uint32", "data_offset"),
            Field("length", value=count),
            Field("uint8", "data", count),
        ]
    )


def float64_multiarray_layout(label: str, count: int) -> FixedCdr:
    """std_msgs/msg/Float64MultiArray with one layout dimension (``label``, size and stride
    ``count``) and ``count`` values."""
    return FixedCdr(
        [
            Field("length", value=1),
            Field("string", value=label),
            Field("uint32", "size"),
            Field("uint32", "stride"),
            Field("uint32", "data_offset"),
            Field("length", value=count),
            Field("float64", "data", count),
        ]
    )


def frame_id_of(payload: np.ndarray) -> str:
    """The header.frame_id of a CDR message that starts with a std_msgs/Header."""
    length = int(payload[12:16].view("<u4")[0])
    return bytes(payload[16 : 16 + length - 1]).decode()


def decoder_for(schema: Any) -> Callable[[bytes], Any]:
    """A per-message decoder for a ros2msg schema record (``mcap_ros2``'s public DecoderFactory).

    Raises:
      ValueError: the schema is not a ROS 2 message definition mcap_ros2 can parse.
    """
    from mcap_ros2.decoder import DecoderFactory  # start-up: only for messages of a foreign layout

    try:
        decoder = DecoderFactory().decoder_for("cdr", schema)
    except Exception as exc:  # McapROS2DecodeError and parse errors of the definition text
        raise ValueError(f"schema {schema.name!r} cannot be parsed ({type(exc).__name__})") from None
    if decoder is None:
        raise ValueError(f"schema {schema.name!r} ({schema.encoding}) is not a ROS 2 message definition")
    return decoder


def split_time(t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Integer nanoseconds to builtin_interfaces/Time (sec int32, nanosec uint32)."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    return (t_ns // NS_PER_S).astype(np.int32), (t_ns % NS_PER_S).astype(np.uint32)


# ROS 2 message definitions (ros2msg, dependencies after a line of 80 '='), as the MCAP ros2
# profile stores them; Foxglove, Rerun and mcap_ros2 parse these.
_SEP = "=" * 80
_TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec"
_HEADER = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id"
_QUATERNION = "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w"
_VECTOR3 = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z"


def _schema(main: str, *deps: str) -> bytes:
    return "\n".join([main, *[f"{_SEP}\n{d}" for d in deps]]).encode() + b"\n"


SCHEMAS: dict[str, bytes] = {
    "sensor_msgs/msg/Imu": _schema(
        "std_msgs/Header header\n"
        "geometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\n"
        "geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n"
        "geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance",
        _HEADER,
        _TIME,
        _QUATERNION,
        _VECTOR3,
    ),
    "sensor_msgs/msg/JointState": _schema(
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort",
        _HEADER,
        _TIME,
    ),
    "tf2_msgs/msg/TFMessage": _schema(
        "geometry_msgs/TransformStamped[] transforms",
        "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n"
        "geometry_msgs/Transform transform",
        _HEADER,
        _TIME,
        "MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation",
        _VECTOR3,
        _QUATERNION,
    ),
    "geometry_msgs/msg/Vector3Stamped": _schema(
        "std_msgs/Header header\ngeometry_msgs/Vector3 vector", _HEADER, _TIME, _VECTOR3
    ),
    "std_msgs/msg/UInt8MultiArray": _schema(
        "std_msgs/MultiArrayLayout layout\nuint8[] data",
        "MSG: std_msgs/MultiArrayLayout\nstd_msgs/MultiArrayDimension[] dim\nuint32 data_offset",
        "MSG: std_msgs/MultiArrayDimension\nstring label\nuint32 size\nuint32 stride",
    ),
    "std_msgs/msg/Float64MultiArray": _schema(
        "std_msgs/MultiArrayLayout layout\nfloat64[] data",
        "MSG: std_msgs/MultiArrayLayout\nstd_msgs/MultiArrayDimension[] dim\nuint32 data_offset",
        "MSG: std_msgs/MultiArrayDimension\nstring label\nuint32 size\nuint32 stride",
    ),
    "diagnostic_msgs/msg/DiagnosticArray": _schema(
        "std_msgs/Header header\ndiagnostic_msgs/DiagnosticStatus[] status",
        _HEADER,
        _TIME,
        "MSG: diagnostic_msgs/DiagnosticStatus\nbyte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\n"
        "string name\nstring message\nstring hardware_id\ndiagnostic_msgs/KeyValue[] values",
        "MSG: diagnostic_msgs/KeyValue\nstring key\nstring value",
    ),
}


@dataclasses.dataclass(frozen=True)
class DiagnosticStatus:
    """One diagnostic_msgs/DiagnosticStatus: ``level`` 0 OK, 1 WARN, 2 ERROR, 3 STALE."""

    level: int
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...]


class _CdrText:
    """A little-endian CDR (XCDR1) body built field by field, aligned from the body's start (after
    the 4-byte encapsulation header): what messages with strings and sequences need."""

    def __init__(self) -> None:
        self.body = bytearray()

    def _align(self, n: int) -> None:
        self.body += bytes(-len(self.body) % n)

    def u32(self, value: int) -> None:
        self._align(4)
        self.body += int(value).to_bytes(4, "little")

    def i32(self, value: int) -> None:
        self._align(4)
        self.body += int(value).to_bytes(4, "little", signed=True)

    def u8(self, value: int) -> None:
        self.body.append(int(value) & 0xFF)

    def string(self, text: str) -> None:
        raw = text.encode("utf-8") + b"\0"
        self.u32(len(raw))
        self.body += raw

    def message(self) -> bytes:
        return b"\x00\x01\x00\x00" + bytes(self.body)


def encode_diagnostic_array(t_ns: int, statuses: list[DiagnosticStatus]) -> bytes:
    """A diagnostic_msgs/msg/DiagnosticArray, CDR-encoded here (strings of any length; decoded in
    the tests by mcap_ros2's DecoderFactory and by rosbags)."""
    sec, nanosec = split_ns(t_ns)
    cdr = _CdrText()
    cdr.i32(sec)
    cdr.u32(nanosec)
    cdr.string("")  # header.frame_id
    cdr.u32(len(statuses))
    for status in statuses:
        cdr.u8(status.level)
        cdr.string(status.name)
        cdr.string(status.message)
        cdr.string(status.hardware_id)
        cdr.u32(len(status.values))
        for key, value in status.values:
            cdr.string(key)
            cdr.string(value)
    return cdr.message()
