"""Packet formats: the pendsim-v1 byte table, round trips of every format, and that nothing a node
sends makes a decoder raise anything but PacketError."""

import json
import math
import struct
import zlib

import numpy as np
import pytest

from pendsim_bridge.acquire.packets import (
    GROUP_SLICES,
    MALFORMED_REASONS,
    ROW_FIELDS,
    V1_SIZE,
    JsonCodec,
    PacketError,
    StreamFormat,
    Units,
    V1Codec,
    parse_columns,
    parse_fields,
    parse_units,
)
from pendsim_mj.errors import ParameterError


def _row(rng: np.random.Generator) -> np.ndarray:
    """A plausible sample on the BNO055's output grid (SI)."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    row = np.empty(len(ROW_FIELDS))
    row[GROUP_SLICES["quat"]] = np.rint(q * 2**14) / 2**14
    row[GROUP_SLICES["gyro"]] = np.rint(rng.normal(0, 3, 3) * 900) / 900
    for group in ("accel", "linear", "gravity"):
        row[GROUP_SLICES[group]] = np.rint(rng.normal(0, 10, 3) * 100) / 100
    row[GROUP_SLICES["calib"]] = rng.integers(0, 4, 4)
    return row


def test_pendsim_v1_packet_is_the_documented_byte_table():
    # docs/acquisition.md: offsets written out by hand here, not taken from the codec.
    data = bytearray(70)
    data[0:4] = b"PSIM"
    data[4] = 1  # version
    data[5] = 2  # node id (m2)
    data[6] = 0x02  # UNIT_SEL: m/s^2, rad/s
    data[8:12] = (123456).to_bytes(4, "little")  # sequence
    data[12:20] = (9_876_543_210).to_bytes(8, "little")  # device time, us
    data[20:26] = struct.pack("<3h", 12, -981, 5)  # ACC x, y, z: 100 LSB per m/s^2
    data[32:38] = struct.pack("<3h", 900, -450, 9)  # GYR: 900 LSB per rad/s
    data[44:52] = struct.pack("<4h", 16384, 0, 0, 0)  # QUA w, x, y, z: 2^14 LSB
    data[52:58] = struct.pack("<3h", 1, 2, 3)  # LIA
    data[58:64] = struct.pack("<3h", 0, 981, -4)  # GRV
    data[64] = 25  # TEMP
    data[65] = 0b11_10_01_00  # CALIB_STAT: sys 3, gyro 2, accel 1, mag 0
    data[66:70] = zlib.crc32(bytes(data[:66])).to_bytes(4, "little")
    packet = V1Codec(2).decode(bytes(data))
    assert packet.seq == 123456 and packet.device_time_us == 9_876_543_210
    row = dict(zip(ROW_FIELDS, packet.row, strict=True))
    assert (row["ax"], row["ay"], row["az"]) == pytest.approx((0.12, -9.81, 0.05))
    assert (row["gx"], row["gy"], row["gz"]) == pytest.approx((1.0, -0.5, 0.01))
    assert (row["qw"], row["qx"]) == (1.0, 0.0)
    assert (row["lax"], row["gvy"], row["gvz"]) == pytest.approx((0.01, 9.81, -0.04))
    assert (row["cal_sys"], row["cal_gyro"], row["cal_accel"], row["cal_mag"]) == (3, 2, 1, 0)
    assert V1_SIZE == 70


def test_one_pendsim_v1_packet_has_the_bytes_of_a_batch_of_one():
    """``V1Codec.encode`` (plain Python, for live senders) and ``encode_many`` (numpy, for batches)
    give the same bytes: random orientations and values from 1e-3 to 1e40 SI (clipped), NaN and
    infinities in the values, NaN orientations (sent as the identity), sequence numbers and times
    beyond their fields (wrapped)."""
    codec = V1Codec(2)
    rng = np.random.default_rng(7)
    n = 3000
    rows = rng.normal(0, 1, (n, len(ROW_FIELDS))) * rng.choice(
        [1e-3, 1.0, 10.0, 100.0, 1e4, 1e40], (n, len(ROW_FIELDS))
    )
    q = rng.normal(size=(n, 4))
    rows[:, :4] = q / np.linalg.norm(q, axis=1, keepdims=True)
    odd = rng.random((n, 16)) < 0.03
    rows[:, :16][odd] = rng.choice([np.nan, np.inf, -np.inf, -0.0], int(odd.sum()))
    calib = [ROW_FIELDS.index(name) for name in ("cal_sys", "cal_gyro", "cal_accel", "cal_mag")]
    rows[:, calib] = rng.integers(0, 4, (n, 4))
    seq, t_us = rng.integers(0, 2**40, n), rng.integers(0, 2**62, n)
    batch = codec.encode_many(seq, t_us, rows)
    assert [codec.encode(int(s), int(t), r) for s, t, r in zip(seq, t_us, rows, strict=True)] == batch


def test_pendsim_v1_unit_register_selects_mg_and_dps():
    codec = V1Codec(1)
    good = bytearray(codec.encode(0, 0, np.r_[1.0, 0, 0, 0, np.zeros(12), 3, 3, 3, 3]))
    good[6] = 0x01  # acceleration in mg, angular rate in dps
    good[20:22] = struct.pack("<h", 1000)  # ACC x: 1000 mg
    good[32:34] = struct.pack("<h", 16)  # GYR x: 16 LSB = 1 dps
    good[66:70] = zlib.crc32(bytes(good[:66])).to_bytes(4, "little")
    row = dict(zip(ROW_FIELDS, codec.decode(bytes(good)).row, strict=True))
    assert row["ax"] == pytest.approx(9.80665) and row["gx"] == pytest.approx(math.pi / 180)


def test_pendsim_v1_round_trip_is_exact_on_the_chip_grid():
    rng = np.random.default_rng(1)
    codec = V1Codec(1)
    for seq in range(200):
        row = _row(rng)
        packet = codec.decode(codec.encode(seq, 10**12 + seq * 12500, row))
        assert packet.seq == seq and packet.device_time_us == 10**12 + seq * 12500
        np.testing.assert_allclose(packet.row, row, rtol=0, atol=1e-12)


@pytest.mark.parametrize("fmt", ["csv", "json"])
def test_text_formats_round_trip_to_ten_digits(fmt):
    rng = np.random.default_rng(2)
    columns = ("seq", "t_us", *ROW_FIELDS)
    stream = StreamFormat(fmt, columns=columns, fields=tuple((c, f"imu/{c}") for c in columns), units=Units("g", "dps"))
    codec = stream.codec("m1", 1)
    for seq in range(100):
        row = _row(rng)
        packet = codec.decode(codec.encode(seq, 5_000_000 + seq, row))
        assert packet.seq == seq and packet.device_time_us == 5_000_000 + seq
        np.testing.assert_allclose(packet.row, row, rtol=1e-9, atol=1e-12)


def test_default_csv_line_is_what_an_adafruit_sketch_prints():
    codec = StreamFormat("csv").codec("m1", 1)  # t_ms,ax,ay,az,gx,gy,gz,qw,qx,qy,qz; accel m/s^2, gyro dps
    packet = codec.decode(b"1234.5,0.10,9.81,-0.20,57.29577951,0,-90,1,0,0,0\r\n")
    row = dict(zip(ROW_FIELDS, packet.row, strict=True))
    assert packet.seq is None and packet.device_time_us == 1_234_500
    assert row["ay"] == 9.81 and row["gx"] == pytest.approx(1.0) and row["gz"] == pytest.approx(-math.pi / 2)
    assert math.isnan(row["lax"]) and codec.groups == ("quat", "gyro", "accel")


def test_json_field_map_reads_nested_paths_and_list_indices():
    codec = JsonCodec(
        (("t_ms", "stamp"), ("gx", "w/0"), ("gy", "w/1"), ("gz", "w/2")), Units(gyro="rad/s"), "m2", 2
    )  # fmt: skip
    packet = codec.decode(json.dumps({"stamp": 12.5, "w": [0.1, 0.2, 0.3], "extra": "ignored"}).encode())
    assert packet.device_time_us == 12500 and packet.row[GROUP_SLICES["gyro"]] == (0.1, 0.2, 0.3)


def _with_crc(body: bytes) -> bytes:
    return body + zlib.crc32(body).to_bytes(4, "little")


def _codecs():
    return [
        V1Codec(1),
        StreamFormat("csv", columns=("node", "seq", "t_us", *ROW_FIELDS)).codec("m1", 1),
        StreamFormat("json").codec("m1", 1),
    ]


@pytest.mark.parametrize(
    ("codec_index", "mutate", "reason"),
    [
        (0, lambda b: b[:69], "truncated"),
        (0, lambda b: b + b"\x00", "oversized"),
        (0, lambda b: b"PSIX" + b[4:], "bad_header"),
        (0, lambda b: b[:4] + b"\x02" + b[5:], "bad_header"),
        (0, lambda b: b[:30] + bytes([b[30] ^ 1]) + b[31:], "crc"),
        (
            0,
            lambda b: b[:5] + b"\x02" + b[6:66] + zlib.crc32(b[:5] + b"\x02" + b[6:66]).to_bytes(4, "little"),
            "wrong_node",
        ),
        (1, lambda b: b.rsplit(b",", 1)[0], "truncated"),
        (1, lambda b: b.replace(b"\n", b",1\n"), "unparsable"),
        (1, lambda b: b" " * 1100 + b, "oversized"),
        (1, lambda b: b.replace(b"m1,", b"m2,", 1), "wrong_node"),
        (1, lambda b: b.rsplit(b",", 1)[0] + b",inf\n", "non_finite"),
        (1, lambda b: b"\xff\xfe" + b, "unparsable"),
        (1, lambda b: b + b"1,2,3\n", "unparsable"),
        (2, lambda b: b[:-5], "unparsable"),
        (2, lambda b: b"[1, 2]", "unparsable"),
        (2, lambda b: b.replace(b'"seq"', b'"sek"'), "truncated"),
        (2, lambda b: b.replace(b'"node":"m1"', b'"node":"m2"'), "wrong_node"),
        (2, lambda b: b.replace(b'"t_us":', b'"t_us":NaN,"x":'), "non_finite"),
        (2, lambda b: b.replace(b'"seq":', b'"seq":true,"x":'), "unparsable"),
        (2, lambda b: b.replace(b'"seq":', b'"seq":-3,"x":'), "out_of_range"),
        (2, lambda b: b[:-1] + b',"pad":"' + b"x" * 5000 + b'"}', "oversized"),
    ],
)
def test_each_kind_of_bad_packet_is_refused_with_its_reason(codec_index, mutate, reason):
    codec = _codecs()[codec_index]
    good = codec.encode(7, 1_000_000, _row(np.random.default_rng(3)))
    codec.decode(good)  # the unmutated packet is fine
    with pytest.raises(PacketError) as info:
        codec.decode(mutate(good))
    assert info.value.reason == reason and reason in MALFORMED_REASONS


def test_a_zero_quaternion_is_out_of_range_not_an_orientation():
    row = _row(np.random.default_rng(4))
    row[GROUP_SLICES["quat"]] = 0.0  # what a BNO055 reports before fusion starts
    with pytest.raises(PacketError, match="out_of_range"):
        V1Codec(1).decode(V1Codec(1).encode(0, 0, row))


def test_no_input_makes_a_decoder_raise_anything_but_packet_error():
    rng = np.random.default_rng(5)
    for codec in _codecs():
        good = codec.encode(1, 123, _row(rng))
        for _ in range(3000):
            kind = rng.integers(4)
            if kind == 0:
                data = rng.bytes(int(rng.integers(0, 200)))
            elif kind == 1:  # bit flips in a good packet
                buf = bytearray(good)
                for i in rng.integers(0, len(buf), int(rng.integers(1, 4))):
                    buf[i] ^= 1 << int(rng.integers(8))
                data = bytes(buf)
            elif kind == 2:  # cut anywhere
                data = good[: int(rng.integers(0, len(good)))]
            else:  # printable junk
                data = bytes(rng.choice(list(b"0123456789,.-+eEnaif{}[]:\"' \n"), int(rng.integers(0, 120))))
            try:
                packet = codec.decode(data)
            except PacketError as exc:
                assert exc.reason in MALFORMED_REASONS
            else:
                assert all(math.isfinite(v) for v in packet.row if not math.isnan(v))


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("t_ms,ax,ay", "the columns have ax, ay but not az"),
        ("t_ms,gx,gy,gz,t_us", "exactly one time column"),
        ("gx,gy,gz", "exactly one time column"),
        ("t_ms,gx,gy,gz,gx", "'gx' appears twice"),
        ("t_ms,accel_x,gy", "unknown name 'accel_x'"),
        ("t_ms,seq", "maps no sensor quantity"),
        ("t_ms,calib,cal_sys,gx,gy,gz", "not both"),
    ],
)
def test_bad_column_maps_name_the_problem(text, message):
    with pytest.raises(ParameterError, match=message):
        parse_columns(text)


def test_bad_unit_and_field_maps_name_the_problem():
    with pytest.raises(ParameterError, match="unknown gyro unit 'deg'; allowed: rad/s, dps"):
        parse_units("gyro=deg")
    with pytest.raises(ParameterError, match="expected accel=UNIT or gyro=UNIT"):
        parse_units("speed=m/s")
    with pytest.raises(ParameterError, match="expected NAME=PATH"):
        parse_fields("t_us=time,gx")
    assert parse_units("accel=mg") == Units("mg", "dps")
