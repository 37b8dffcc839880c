"""The packets a sensor node sends, in three formats, each with an encoder and a strict decoder.

Every decoded packet becomes a ``Packet``: the sequence number (None when the format has none),
the device time in microseconds, and one row of ``ROW_FIELDS`` in SI units (NaN where the
format carries nothing). Anything else a node (or anyone) sends raises ``PacketError`` with one
of ``MALFORMED_REASONS``; no input makes a decoder raise anything else. A CRC says only that
the bytes arrived as sent, not that a node sent them: every field is range-checked (device time
within ``MAX_DEVICE_TIME_US``, sequence numbers, node id, header bytes, and every value finite and
within what a BNO055 can report, ``ACCEL_LIMIT_M_S2`` and ``GYRO_LIMIT_RAD_S``). Whether a packet
fits its node's timeline is ``timeline``'s question.

- ``pendsim-v1``: a 70-byte binary packet (docs/acquisition.md has the byte table): magic
  ``PSIM``, version 1, node id, the chip's UNIT_SEL register, sequence number (uint32), device
  time (uint64 microseconds), the BNO055's registers 0x08-0x35 verbatim (one I2C burst read:
  accelerometer, magnetometer, gyroscope, Euler, quaternion, linear acceleration, gravity,
  temperature, CALIB_STAT) and a CRC-32 (zlib's, IEEE 802.3) of everything before it.
- ``csv``: one text line per datagram, comma-separated, in the order of a declared column map
  (``--columns t_ms,ax,ay,az,gx,gy,gz,qw,qx,qy,qz``) and units (``--units accel=m/s2,gyro=dps``),
  as typical Arduino/Adafruit BNO055 sketches print them.
- ``json``: one object per datagram; a field map names where each quantity sits (``gyro/x``:
  key ``x`` of object ``gyro``; a number indexes a list), the PlotJuggler convention.
"""

from __future__ import annotations

import dataclasses
import json
import math
import operator
import struct
import zlib
from typing import Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.errors import ParameterError
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import (
    ACCEL_FULL_SCALE_M_S2,
    ACCEL_LSB_M_S2,
    GYRO_FULL_SCALE_RAD_S,
    GYRO_LSB_RAD_S,
    QUAT_LSB,
    STANDARD_GRAVITY_M_S2,
)

FORMATS = ("pendsim-v1", "csv", "json")

# One decoded sample, SI units: orientation (w, x, y, z), angular velocity (rad/s), acceleration
# with gravity, linear acceleration, gravity (m/s^2, sensor axes), calibration levels 0-3.
GROUPS: dict[str, tuple[str, ...]] = {
    "quat": ("qw", "qx", "qy", "qz"),
    "gyro": ("gx", "gy", "gz"),
    "accel": ("ax", "ay", "az"),
    "linear": ("lax", "lay", "laz"),
    "gravity": ("gvx", "gvy", "gvz"),
    "calib": ("cal_sys", "cal_gyro", "cal_accel", "cal_mag"),
}
ROW_FIELDS: tuple[str, ...] = tuple(name for names in GROUPS.values() for name in names)
ROW_INDEX = {name: i for i, name in enumerate(ROW_FIELDS)}
GROUP_SLICES = {
    group: slice(ROW_INDEX[names[0]], ROW_INDEX[names[-1]] + 1) for group, names in GROUPS.items()
}  # fmt: skip
TIME_COLUMNS = {"t_s": 1e6, "t_ms": 1e3, "t_us": 1.0}  # name -> microseconds per unit
EXTRA_COLUMNS = ("seq", "node", "calib", "_")  # "calib": the CALIB_STAT byte; "_": skip the column
COLUMN_NAMES = (*TIME_COLUMNS, *ROW_FIELDS, *EXTRA_COLUMNS)
MALFORMED_REASONS = (
    "truncated", "oversized", "bad_header", "crc", "wrong_node", "non_finite", "out_of_range", "bad_time",
    "unparsable",
)  # fmt: skip

# SI per unit. "raw-...": the BNO055's register counts in that UNIT_SEL mode (its mg mode's are mg).
ACCEL_UNITS = {"m/s2": 1.0, "g": STANDARD_GRAVITY_M_S2, "mg": STANDARD_GRAVITY_M_S2 / 1000.0}
ACCEL_UNITS["raw-m/s2"] = ACCEL_LSB_M_S2
GYRO_UNITS = {"rad/s": 1.0, "dps": math.pi / 180.0, "raw-dps": math.pi / 180.0 / 16.0, "raw-rad/s": GYRO_LSB_RAD_S}
DEFAULT_CSV_COLUMNS = ("t_ms", "ax", "ay", "az", "gx", "gy", "gz", "qw", "qx", "qy", "qz")
DEFAULT_JSON_FIELDS: tuple[tuple[str, str], ...] = (
    ("node", "node"),
    ("seq", "seq"),
    ("t_us", "t_us"),
    *((f"q{a}", f"quat/{a}") for a in "wxyz"),
    *((f"g{a}", f"gyro/{a}") for a in "xyz"),
    *((f"a{a}", f"accel/{a}") for a in "xyz"),
    *((f"la{a}", f"linear_accel/{a}") for a in "xyz"),
    *((f"gv{a}", f"gravity/{a}") for a in "xyz"),
    ("cal_sys", "calib/sys"), ("cal_gyro", "calib/gyro"), ("cal_accel", "calib/accel"), ("cal_mag", "calib/mag"),
)  # fmt: skip
MAX_TEXT_BYTES = 1024  # a CSV line
MAX_JSON_BYTES = 4096  # a JSON object
QUAT_NORM_RANGE = (0.9, 1.1)  # a quaternion further from unit length is not an orientation
# Device time, us: below 2^52 (142 years of a clock counting from boot, or Unix time in us until
# 2112), where a float64 holds it exactly and, in seconds, to better than 1 us; the clock fit
# needs no more. Larger values (a uint64 field can hold up to 2^64 - 1) are refused as bad_time.
MAX_DEVICE_TIME_US = 2**52
MAX_TEXT_SEQ = 2**53  # a text packet's sequence number: an integer a float64 holds exactly
# Per axis, the largest value a BNO055 can report (its largest ranges: 16 g, 2000 dps) plus 1 %
# for values rounded when printed; beyond that a reading is no BNO055's ("out_of_range").
RANGE_MARGIN = 1.01
ACCEL_LIMIT_M_S2 = ACCEL_FULL_SCALE_M_S2 * RANGE_MARGIN  # acceleration, linear acceleration, gravity
GYRO_LIMIT_RAD_S = GYRO_FULL_SCALE_RAD_S * RANGE_MARGIN


class Packet(NamedTuple):
    """One decoded sample: sequence number (None if the format has none), device time (us) and
    ``ROW_FIELDS`` in SI units (NaN where the format carries nothing)."""

    seq: int | None
    device_time_us: int
    row: tuple[float, ...]


class PacketError(Exception):
    """A datagram that is not a valid packet of the expected node; ``reason`` is one of
    ``MALFORMED_REASONS``."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


class Codec(Protocol):
    """Encoder and decoder of one format for one node."""

    format: str
    groups: tuple[str, ...]  # which GROUPS its packets carry
    has_seq: bool
    seq_modulus: int | None  # sequence numbers wrap at this value (None: they do not)

    def decode(self, data: bytes) -> Packet: ...

    def encode(self, seq: int, device_time_us: int, row: np.ndarray) -> bytes: ...

    def encode_many(
        self, seq: NDArray[np.int64], device_time_us: NDArray[np.int64], rows: NDArray[np.float64]
    ) -> list[bytes]: ...


# -- units and column maps --------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Units:
    """Units of text packets: ``accel`` (acceleration, linear acceleration, gravity) one of
    ``ACCEL_UNITS``; ``gyro`` one of ``GYRO_UNITS``. Quaternions are unit quaternions."""

    accel: str = "m/s2"
    gyro: str = "dps"

    def __post_init__(self) -> None:
        if self.accel not in ACCEL_UNITS:
            raise ParameterError(f"unknown accel unit {self.accel!r}; allowed: {', '.join(ACCEL_UNITS)}")
        if self.gyro not in GYRO_UNITS:
            raise ParameterError(f"unknown gyro unit {self.gyro!r}; allowed: {', '.join(GYRO_UNITS)}")

    def scales(self) -> np.ndarray:
        """Per ROW_FIELDS: SI value per unit of the packet."""
        scale = np.ones(len(ROW_FIELDS))
        for group in ("accel", "linear", "gravity"):
            scale[GROUP_SLICES[group]] = ACCEL_UNITS[self.accel]
        scale[GROUP_SLICES["gyro"]] = GYRO_UNITS[self.gyro]
        return scale

    def describe(self) -> str:
        return f"accel={self.accel},gyro={self.gyro}"


def parse_units(text: str) -> Units:
    """``accel=m/s2,gyro=dps`` (either or both) to Units."""
    values: dict[str, str] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key not in ("accel", "gyro"):
            raise ParameterError(f"bad units entry {item!r}: expected accel=UNIT or gyro=UNIT")
        if key in values:
            raise ParameterError(f"units: {key} given twice")
        values[key] = value.strip()
    return Units(**values)


def groups_of(names: tuple[str, ...] | list[str]) -> tuple[str, ...]:
    """The complete GROUPS among ``names`` (a CALIB_STAT ``calib`` column counts as calibration).

    Raises:
      ParameterError: a group is named in part (e.g. gx and gy without gz).
    """
    present = set(names)
    found = []
    for group, members in GROUPS.items():
        have = [m for m in members if m in present]
        if group == "calib" and "calib" in present:
            if have:
                raise ParameterError("give calibration as the CALIB_STAT byte 'calib' or as cal_sys, ..., not both")
            found.append(group)
        elif len(have) == len(members):
            found.append(group)
        elif have:
            missing = [m for m in members if m not in present]
            raise ParameterError(
                f"the columns have {', '.join(have)} but not {', '.join(missing)} (a quantity needs all of its columns)"
            )
    return tuple(found)


def check_columns(columns: tuple[str, ...] | list[str], *, what: str = "column map") -> tuple[str, ...]:
    """A column map: known names, each once (but '_'), exactly one time column, complete groups."""
    names = tuple(c.strip() for c in columns)
    unknown = [c for c in names if c not in COLUMN_NAMES]
    if unknown:
        raise ParameterError(f"{what}: unknown name {unknown[0]!r}; allowed: {', '.join(COLUMN_NAMES)}")
    repeated = sorted({c for c in names if c != "_" and names.count(c) > 1})
    if repeated:
        raise ParameterError(f"{what}: {repeated[0]!r} appears twice")
    times = [c for c in names if c in TIME_COLUMNS]
    if len(times) != 1:
        raise ParameterError(f"{what}: needs exactly one time column (t_s, t_ms or t_us), got {len(times)}")
    if not groups_of(names):
        raise ParameterError(f"{what}: maps no sensor quantity (e.g. gx,gy,gz or ax,ay,az)")
    return names


def parse_columns(text: str) -> tuple[str, ...]:
    """``t_ms,ax,ay,az,...`` to a checked column map."""
    return check_columns([c for c in text.split(",")])


def parse_fields(text: str) -> tuple[tuple[str, str], ...]:
    """``t_us=time,gx=imu/gyro/x,...`` (NAME=PATH, comma-separated) to a checked field map."""
    pairs = []
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, path = item.partition("=")
        if not sep or not path.strip():
            raise ParameterError(f"bad field map entry {item!r}: expected NAME=PATH, e.g. gx=gyro/x")
        pairs.append((name.strip(), path.strip()))
    check_columns([n for n, _ in pairs], what="field map")
    return tuple(pairs)


def calib_levels(calib_stat: int) -> tuple[int, int, int, int]:
    """The BNO055 CALIB_STAT register (0x35) to (system, gyro, accel, mag) levels 0-3."""
    return (calib_stat >> 6) & 3, (calib_stat >> 4) & 3, (calib_stat >> 2) & 3, calib_stat & 3


def calib_stat(levels: np.ndarray) -> int:
    """(system, gyro, accel, mag) levels 0-3 to the CALIB_STAT byte."""
    s, g, a, m = (int(v) & 3 for v in levels)
    return (s << 6) | (g << 4) | (a << 2) | m


def _check_row(row: list[float], groups: tuple[str, ...]) -> None:
    if not all(math.isfinite(row[ROW_INDEX[name]]) for group in groups for name in GROUPS[group]):
        raise PacketError("non_finite", "a value is NaN or infinite")
    if "quat" in groups:
        norm = math.sqrt(sum(row[i] * row[i] for i in range(4)))
        if not QUAT_NORM_RANGE[0] <= norm <= QUAT_NORM_RANGE[1]:
            raise PacketError("out_of_range", f"quaternion norm {norm:.3g} is not 1")
    if "calib" in groups and not all(row[ROW_INDEX[n]] in (0.0, 1.0, 2.0, 3.0) for n in GROUPS["calib"]):
        raise PacketError("out_of_range", "calibration levels must be 0-3")
    for group in groups:
        limit = _LIMITS.get(group)
        if limit is not None and not all(abs(row[ROW_INDEX[n]]) <= limit for n in GROUPS[group]):
            raise PacketError("out_of_range", f"{group} beyond what a BNO055 reports (|value| <= {limit:.4g} SI)")


_LIMITS = {"gyro": GYRO_LIMIT_RAD_S, "accel": ACCEL_LIMIT_M_S2, "linear": ACCEL_LIMIT_M_S2, "gravity": ACCEL_LIMIT_M_S2}


# -- pendsim-v1 -------------------------------------------------------------------------------

V1_MAGIC = b"PSIM"
V1_VERSION = 1
# Header: magic, version, node id, UNIT_SEL, reserved, sequence (uint32), device time (uint64 us).
_V1_HEAD = struct.Struct("<4sBBBBIQ")
# The BNO055's registers 0x08-0x35: ACC, MAG, GYR (x, y, z), EUL (heading, roll, pitch), QUA (w, x,
# y, z), LIA, GRV (x, y, z) as int16 LSB first; TEMP (int8); CALIB_STAT (uint8). 46 bytes.
_V1_REGISTERS = struct.Struct("<3h3h3h3h4h3h3hbB")
_V1_CRC = struct.Struct("<I")
V1_SIZE = _V1_HEAD.size + _V1_REGISTERS.size + _V1_CRC.size  # 70
_V1_PACKET = struct.Struct("<4sBBBBIQ3h3h3h3h4h3h3hbBI")  # the three above in one
# From _V1_PACKET's fields: QUA w x y z, GYR x y z, ACC x y z, LIA x y z, GRV x y z (ROW_FIELDS order).
_V1_PICK = operator.itemgetter(19, 20, 21, 22, 13, 14, 15, 7, 8, 9, 23, 24, 25, 26, 27, 28)
_QUAT_NORM2_LSB = ((QUAT_NORM_RANGE[0] / QUAT_LSB) ** 2, (QUAT_NORM_RANGE[1] / QUAT_LSB) ** 2)
_CALIB_LEVELS = [tuple(float(v) for v in calib_levels(c)) for c in range(256)]
UNIT_SEL_ACCEL_MG = 0x01  # UNIT_SEL bit 0: acceleration in mg (else m/s^2, 100 LSB per m/s^2)
UNIT_SEL_GYRO_RPS = 0x02  # UNIT_SEL bit 1: angular rate in rad/s, 900 LSB (else dps, 16 LSB)
V1_UNIT_SEL = UNIT_SEL_GYRO_RPS  # what the emulator sends: the grid pendsim's BNO055 model uses
# UNIT_SEL bits the datasheet leaves reserved (3, 5, 6); bits 2 (Euler unit), 4 (temperature unit)
# and 7 (Euler orientation convention) change nothing pendsim reads.
UNIT_SEL_RESERVED = 0x68


def _v1_scales(unit_sel: int) -> tuple[float, ...]:
    """SI per LSB of the 16 registers _V1_PICK takes, for a UNIT_SEL value."""
    accel = STANDARD_GRAVITY_M_S2 / 1000.0 if unit_sel & UNIT_SEL_ACCEL_MG else ACCEL_LSB_M_S2
    gyro = GYRO_LSB_RAD_S if unit_sel & UNIT_SEL_GYRO_RPS else math.radians(1.0 / 16.0)
    return (QUAT_LSB,) * 4 + (gyro,) * 3 + (accel,) * 9


_V1_SCALES = [_v1_scales(u) for u in range(4)]
# The largest |register| (LSB) of the gyro and of the nine acceleration registers, per UNIT_SEL & 3.
_V1_GYRO_MAX_LSB = [GYRO_LIMIT_RAD_S / s[4] for s in _V1_SCALES]
_V1_ACCEL_MAX_LSB = [ACCEL_LIMIT_M_S2 / s[7] for s in _V1_SCALES]
EULER_LSB_DEG = 1.0 / 16.0  # BNO055: 1 deg = 16 LSB (UNIT_SEL bit 2 clear)
MAG_LSB_UT = 1.0 / 16.0  # BNO055: 1 uT = 16 LSB
EARTH_FIELD_UT = np.array([0.0, 22.0, -42.0])  # a mid-latitude field in the fusion frame (z up), uT
INT16 = (-32768, 32767)


def _i16(value: float) -> int:
    """One value as ``_int16`` stores it: NaN 0, rounded half to even, clipped to int16."""
    if value != value:
        return 0
    if not math.isfinite(value):
        return INT16[1] if value > 0 else INT16[0]
    return min(max(round(value), INT16[0]), INT16[1])


def _int16(values: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(np.nan_to_num(values)), *INT16).astype(np.int16)


# The packet as a numpy record (packed, little endian): the same bytes as _V1_HEAD, _V1_REGISTERS, _V1_CRC.
_V1_DTYPE = np.dtype(
    [
        ("magic", "S4"), ("version", "u1"), ("node", "u1"), ("unit_sel", "u1"), ("reserved", "u1"),
        ("seq", "<u4"), ("t_us", "<u8"), ("acc", "<i2", 3), ("mag", "<i2", 3), ("gyr", "<i2", 3),
        ("eul", "<i2", 3), ("qua", "<i2", 4), ("lia", "<i2", 3), ("grv", "<i2", 3), ("temp", "i1"),
        ("calib", "u1"), ("crc", "<u4"),
    ]
)  # fmt: skip


class V1Codec:
    """pendsim-v1 for one node (``node_id`` 1 for m1, 2 for m2)."""

    format = "pendsim-v1"
    groups = tuple(GROUPS)
    has_seq = True
    seq_modulus: int | None = 2**32
    max_bytes = V1_SIZE

    def __init__(self, node_id: int) -> None:
        self.node_id = node_id

    def decode(self, data: bytes) -> Packet:
        if len(data) != V1_SIZE:
            reason = "truncated" if len(data) < V1_SIZE else "oversized"
            raise PacketError(reason, f"{len(data)} bytes, pendsim-v1 has {V1_SIZE}")
        v = _V1_PACKET.unpack(data)
        if v[0] != V1_MAGIC or v[1] != V1_VERSION:
            raise PacketError("bad_header", f"magic {v[0]!r} version {v[1]}")
        if zlib.crc32(memoryview(data)[: V1_SIZE - 4]) != v[-1]:
            raise PacketError("crc", "CRC-32 does not match")
        if v[2] != self.node_id:
            raise PacketError("wrong_node", f"node id {v[2]} on the port of node {self.node_id}")
        if v[3] & UNIT_SEL_RESERVED or v[4]:
            raise PacketError("bad_header", f"UNIT_SEL {v[3]:#04x} or reserved byte {v[4]} has reserved bits set")
        if v[6] >= MAX_DEVICE_TIME_US:
            raise PacketError("bad_time", f"device time {v[6]} us, at most {MAX_DEVICE_TIME_US - 1}")
        registers = _V1_PICK(v)  # quaternion, gyro, accel, linear, gravity: int16 LSB
        norm2 = registers[0] ** 2 + registers[1] ** 2 + registers[2] ** 2 + registers[3] ** 2
        if not _QUAT_NORM2_LSB[0] <= norm2 <= _QUAT_NORM2_LSB[1]:
            raise PacketError("out_of_range", f"quaternion norm {math.sqrt(norm2) * QUAT_LSB:.3g} is not 1")
        units = v[3] & 3
        gyro_lsb = max(abs(registers[4]), abs(registers[5]), abs(registers[6]))
        accel_lsb = max(max(registers[7:]), -min(registers[7:]))
        if gyro_lsb > _V1_GYRO_MAX_LSB[units] or accel_lsb > _V1_ACCEL_MAX_LSB[units]:
            raise PacketError("out_of_range", "a gyro or acceleration register beyond what a BNO055 reports")
        row = (*map(operator.mul, registers, _V1_SCALES[units]), *_CALIB_LEVELS[v[-2]])
        return Packet(v[5], v[6], row)

    def encode(self, seq: int, device_time_us: int, row: np.ndarray, *, node_id: int | None = None) -> bytes:
        """A packet as a node fills it: the bytes of ``encode_many`` for one row (tested on random
        and extreme rows), computed in plain Python, about 30 times faster than a batch of one
        (what a live sender such as the emulated rig with motors needs)."""
        v = [float(x) for x in np.asarray(row, dtype=float)]
        w, x, y, z = v[0:4] if all(math.isfinite(q) for q in v[0:4]) else (1.0, 0.0, 0.0, 0.0)
        euler = (
            math.degrees(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))),
            math.degrees(math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))),
            math.degrees(math.asin(min(max(2 * (w * y - z * x), -1.0), 1.0))),
        )
        # rotate_into_frame: R^T e, R's rows as rotations.to_matrix builds them
        r = (
            (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
        )
        e = EARTH_FIELD_UT
        mag = [(r[0][i] * e[0] + r[1][i] * e[1] + r[2][i] * e[2]) / MAG_LSB_UT for i in range(3)]
        calib = 0
        for level in v[ROW_INDEX["cal_sys"] : ROW_INDEX["cal_mag"] + 1]:
            calib = (calib << 2) | ((int(level) if math.isfinite(level) else 0) & 3)
        registers = (
            *(_i16(a / ACCEL_LSB_M_S2) for a in v[GROUP_SLICES["accel"]]),
            *(_i16(m) for m in mag),
            *(_i16(g / GYRO_LSB_RAD_S) for g in v[GROUP_SLICES["gyro"]]),
            *(_i16(d / EULER_LSB_DEG) for d in euler),
            *(_i16(q / QUAT_LSB) for q in (w, x, y, z)),
            *(_i16(a / ACCEL_LSB_M_S2) for a in v[GROUP_SLICES["linear"]]),
            *(_i16(a / ACCEL_LSB_M_S2) for a in v[GROUP_SLICES["gravity"]]),
        )
        head = _V1_PACKET.pack(
            V1_MAGIC, V1_VERSION, self.node_id if node_id is None else node_id, V1_UNIT_SEL, 0, seq % 2**32,
            device_time_us % 2**64, *registers, 25, calib, 0,
        )  # fmt: skip
        return head[:-4] + _V1_CRC.pack(zlib.crc32(memoryview(head)[:-4]))

    def encode_many(
        self,
        seq: NDArray[np.int64],
        device_time_us: NDArray[np.int64],
        rows: NDArray[np.float64],
        *,
        node_id: int | None = None,
    ) -> list[bytes]:
        """Packets as a node fills them (UNIT_SEL: m/s^2 and rad/s), (n,) sequence numbers and device
        times, (n, len(ROW_FIELDS)) rows. Magnetometer and Euler registers are filled from the
        orientation (a constant field; heading, roll, pitch), temperature 25 C; pendsim reads neither."""
        rows = np.asarray(rows, dtype=float)
        n = len(rows)
        quat = rows[:, GROUP_SLICES["quat"]].copy()
        quat[~np.all(np.isfinite(quat), axis=1)] = (1.0, 0.0, 0.0, 0.0)
        w, x, y, z = quat.T
        euler = np.degrees(
            np.stack(
                [
                    np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)),
                    np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)),
                    np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0)),
                ],
                axis=1,
            )
        )
        packets = np.zeros(n, dtype=_V1_DTYPE)
        packets["magic"] = V1_MAGIC
        packets["version"] = V1_VERSION
        packets["node"] = self.node_id if node_id is None else node_id
        packets["unit_sel"] = V1_UNIT_SEL
        packets["seq"] = np.asarray(seq) % 2**32
        packets["t_us"] = np.asarray(device_time_us).astype(np.uint64)
        packets["acc"] = _int16(rows[:, GROUP_SLICES["accel"]] / ACCEL_LSB_M_S2)
        packets["mag"] = _int16(rotations.rotate_into_frame(quat, EARTH_FIELD_UT) / MAG_LSB_UT)
        packets["gyr"] = _int16(rows[:, GROUP_SLICES["gyro"]] / GYRO_LSB_RAD_S)
        packets["eul"] = _int16(euler / EULER_LSB_DEG)
        packets["qua"] = _int16(quat / QUAT_LSB)
        packets["lia"] = _int16(rows[:, GROUP_SLICES["linear"]] / ACCEL_LSB_M_S2)
        packets["grv"] = _int16(rows[:, GROUP_SLICES["gravity"]] / ACCEL_LSB_M_S2)
        packets["temp"] = 25
        levels = np.nan_to_num(rows[:, GROUP_SLICES["calib"]], nan=0.0).astype(np.uint8) & 3
        packets["calib"] = (levels[:, 0] << 6) | (levels[:, 1] << 4) | (levels[:, 2] << 2) | levels[:, 3]
        raw = packets.view(np.uint8).reshape(n, V1_SIZE)
        packets["crc"] = [zlib.crc32(raw[i, : V1_SIZE - 4].tobytes()) for i in range(n)]
        return [bytes(row) for row in raw]


# -- text formats -----------------------------------------------------------------------------


def _node_matches(value: Any, name: str, node_id: int) -> bool:
    if isinstance(value, str):
        return value.strip() in (name, str(node_id))
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return value == node_id
    return False


class _TextCodec:
    """What the CSV and JSON codecs share: names to row positions, units, time, checks."""

    has_seq: bool
    seq_modulus: int | None = None

    def __init__(self, names: tuple[str, ...], units: Units, node: str, node_id: int) -> None:
        self.names = names
        self.units = units
        self.node = node
        self.node_id = node_id
        self.groups = groups_of(names)
        self.has_seq = "seq" in names
        self.time_name = next(n for n in names if n in TIME_COLUMNS)
        self._scales = units.scales()

    def _packet(self, values: dict[str, Any]) -> Packet:
        """Packet from name -> raw value (numbers, or a string for ``node``)."""
        if "node" in values and not _node_matches(values["node"], self.node, self.node_id):
            raise PacketError("wrong_node", f"node {values['node']!r} on the port of {self.node}")
        numbers: dict[str, float] = {}
        for name, value in values.items():
            if name == "node":
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise PacketError("unparsable", f"{name} is not a number")
            try:
                numbers[name] = float(value)
            except OverflowError:  # an integer of hundreds of digits (JSON allows it)
                reason = "bad_time" if name == self.time_name else "out_of_range"
                raise PacketError(reason, f"{name} has {len(str(value))} digits") from None
        if not all(math.isfinite(v) for v in numbers.values()):
            raise PacketError("non_finite", "a value is NaN or infinite")
        t = numbers[self.time_name] * TIME_COLUMNS[self.time_name]
        if not 0 <= t < MAX_DEVICE_TIME_US:
            raise PacketError("bad_time", f"device time {t:g} us, allowed 0 to 2^52")
        seq = None
        if self.has_seq:
            s = numbers["seq"]
            if not 0 <= s < MAX_TEXT_SEQ or s != int(s):
                raise PacketError("out_of_range", f"sequence number {s:g}, allowed an integer 0 to 2^53")
            seq = int(s)
        row = [math.nan] * len(ROW_FIELDS)
        for name, value in numbers.items():
            i = ROW_INDEX.get(name)
            if i is not None:
                row[i] = value * self._scales[i]
        if "calib" in numbers:
            c = numbers["calib"]
            if c != int(c) or not 0 <= c <= 255:
                raise PacketError("out_of_range", f"CALIB_STAT {c:g}")
            row[GROUP_SLICES["calib"]] = [float(v) for v in calib_levels(int(c))]
        _check_row(row, self.groups)
        return Packet(seq, round(t), tuple(row))

    def encode(self, seq: int, device_time_us: int, row: np.ndarray) -> bytes:
        raise NotImplementedError

    def encode_many(
        self, seq: NDArray[np.int64], device_time_us: NDArray[np.int64], rows: NDArray[np.float64]
    ) -> list[bytes]:
        """n packets, one per row."""
        return [self.encode(int(s), int(t), r) for s, t, r in zip(seq, device_time_us, rows, strict=True)]

    def _values_for(self, seq: int, device_time_us: int, row: np.ndarray) -> dict[str, Any]:
        """name -> value in the packet's units, for the encoders."""
        values: dict[str, Any] = {}
        for name in self.names:
            if name == "_":
                continue
            if name in TIME_COLUMNS:
                values[name] = device_time_us / TIME_COLUMNS[name]
            elif name == "seq":
                values[name] = seq
            elif name == "node":
                values[name] = self.node
            elif name == "calib":
                values[name] = calib_stat(row[GROUP_SLICES["calib"]])
            elif name in GROUPS["calib"]:
                values[name] = int(row[ROW_INDEX[name]])
            else:
                values[name] = float(row[ROW_INDEX[name]] / self._scales[ROW_INDEX[name]])
        return values


def _text(value: Any) -> str:
    if isinstance(value, float):
        return format(value, ".10g")
    return str(value)


class CsvCodec(_TextCodec):
    """One comma-separated line per datagram, columns as ``names`` (``_`` skips a column)."""

    format = "csv"
    max_bytes = MAX_TEXT_BYTES

    def decode(self, data: bytes) -> Packet:
        if len(data) > MAX_TEXT_BYTES:
            raise PacketError("oversized", f"{len(data)} bytes, a CSV line has at most {MAX_TEXT_BYTES}")
        try:
            text = data.decode("ascii").strip()
        except UnicodeDecodeError:
            raise PacketError("unparsable", "not ASCII text") from None
        if "\n" in text or "\r" in text:
            raise PacketError("unparsable", "more than one line")
        parts = text.split(",")
        if len(parts) != len(self.names):
            reason = "truncated" if len(parts) < len(self.names) else "unparsable"
            raise PacketError(reason, f"{len(parts)} fields, the column map has {len(self.names)}")
        values: dict[str, Any] = {}
        for name, part in zip(self.names, parts, strict=True):
            if name == "_":
                continue
            if name == "node":
                values[name] = part
                continue
            try:
                values[name] = float(part)
            except ValueError:
                raise PacketError("unparsable", f"{name}: not a number") from None
        return self._packet(values)

    def encode(self, seq: int, device_time_us: int, row: np.ndarray) -> bytes:
        values = self._values_for(seq, device_time_us, np.asarray(row, dtype=float))
        return (",".join(_text(values.get(name, "")) for name in self.names) + "\n").encode()


class JsonCodec(_TextCodec):
    """One JSON object per datagram; ``fields`` maps each name to a path (``gyro/x``)."""

    format = "json"
    max_bytes = MAX_JSON_BYTES

    def __init__(self, fields: tuple[tuple[str, str], ...], units: Units, node: str, node_id: int) -> None:
        super().__init__(tuple(n for n, _ in fields), units, node, node_id)
        self.paths = {name: tuple(path.split("/")) for name, path in fields if name != "_"}

    def decode(self, data: bytes) -> Packet:
        if len(data) > MAX_JSON_BYTES:
            raise PacketError("oversized", f"{len(data)} bytes, a JSON packet has at most {MAX_JSON_BYTES}")
        try:
            obj = json.loads(data)
        except (ValueError, RecursionError):  # UnicodeDecodeError and JSONDecodeError are ValueErrors
            raise PacketError("unparsable", "not a JSON document") from None
        if not isinstance(obj, dict):
            raise PacketError("unparsable", "not a JSON object")
        values = {}
        for name, path in self.paths.items():
            node: Any = obj
            for key in path:
                if isinstance(node, dict) and key in node:
                    node = node[key]
                elif isinstance(node, list) and key.isdigit() and int(key) < len(node):
                    node = node[int(key)]
                else:
                    raise PacketError("truncated", f"no {'/'.join(path)!r} in the object")
            values[name] = node
        return self._packet(values)

    def encode(self, seq: int, device_time_us: int, row: np.ndarray) -> bytes:
        values = self._values_for(seq, device_time_us, np.asarray(row, dtype=float))
        obj: dict[str, Any] = {}
        for name, path in self.paths.items():
            node = obj
            for key in path[:-1]:
                node = node.setdefault(key, {})
            node[path[-1]] = values[name]
        return json.dumps(obj, separators=(",", ":")).encode()


@dataclasses.dataclass(frozen=True)
class StreamFormat:
    """What the nodes send: ``format`` (one of FORMATS), and for text formats the CSV column map,
    the JSON field map and the units."""

    format: str = "pendsim-v1"
    columns: tuple[str, ...] = DEFAULT_CSV_COLUMNS
    fields: tuple[tuple[str, str], ...] = DEFAULT_JSON_FIELDS
    units: Units = Units()

    def __post_init__(self) -> None:
        if self.format not in FORMATS:
            raise ParameterError(f"unknown format {self.format!r}; allowed: {', '.join(FORMATS)}")
        check_columns(self.columns)
        check_columns([n for n, _ in self.fields], what="field map")

    def codec(self, node: str, node_id: int) -> V1Codec | CsvCodec | JsonCodec:
        """The codec of one node (``node_id``: 1 for the first node, 2 for the second)."""
        if self.format == "pendsim-v1":
            return V1Codec(node_id)
        if self.format == "csv":
            return CsvCodec(self.columns, self.units, node, node_id)
        return JsonCodec(self.fields, self.units, node, node_id)

    def groups(self) -> tuple[str, ...]:
        """The GROUPS the packets carry."""
        return self.codec("m1", 1).groups

    def describe(self) -> dict[str, str]:
        """For the recording's metadata."""
        out = {"format": self.format}
        if self.format == "csv":
            out["columns"] = ",".join(self.columns)
        if self.format == "json":
            out["fields"] = ",".join(f"{n}={p}" for n, p in self.fields)
        if self.format != "pendsim-v1":
            out["units"] = self.units.describe()
        return out
