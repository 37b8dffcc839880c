"""The compiled check of a chunk's message index (bridge/io/mcap/chunk_kernel.py): on every file it gives
the numpy path's messages and problems, and it refuses every index that does not list exactly
the chunk's messages (the numpy path then takes the chunk)."""

import struct

import numpy as np
import pytest
from mcap_ros2.writer import Writer as Ros2Writer

from pendsim_bridge.cli import main
from pendsim_bridge.io import ros2
from pendsim_bridge.io.mcap import chunk_kernel
from pendsim_bridge.io.mcap import reader as mcap_reader
from pendsim_bridge.io.mcap.reader import scan_mcap
from pendsim_bridge.io.mcap.records import MESSAGE_FIELDS, RECORD_HEAD, message_index_record
from pendsim_bridge.io.mcap.writer import BulkMcapWriter
from pendsim_bridge.io.recording import read_recording

IMU_SCHEMA = "sensor_msgs/msg/Imu"


def _chunks(path, compiled, channels=None):
    """Every chunk's messages (offset, {channel: (log, publish, payloads)}) and the problems."""
    accepted.clear()
    mcap = scan_mcap(path)
    try:
        out = [
            (c.chunk.offset, {cid: (d.log_time_ns, d.publish_time_ns, d.payloads) for cid, d in c.channels.items()})
            for c in mcap.chunks(channels=channels, compiled=compiled)
        ]
        return out, list(mcap.problems)
    finally:
        mcap.close()


accepted: list[bool] = []  # per chunk parsed compiled: whether the kernel took it


@pytest.fixture(autouse=True)
def _count_accepted(monkeypatch):
    compiled = mcap_reader._messages_compiled

    def counting(*args, **kwargs):
        out = compiled(*args, **kwargs)
        accepted.append(out is not None)
        return out

    monkeypatch.setattr(mcap_reader, "_messages_compiled", counting)


def _assert_same(a, b):
    (chunks_a, problems_a), (chunks_b, problems_b) = a, b
    assert problems_a == problems_b
    assert [offset for offset, _ in chunks_a] == [offset for offset, _ in chunks_b]
    for (_, by_channel_a), (_, by_channel_b) in zip(chunks_a, chunks_b, strict=True):
        assert list(by_channel_a) == list(by_channel_b)
        for cid, fields in by_channel_a.items():
            for x, y in zip(fields, by_channel_b[cid], strict=True):
                if isinstance(x, np.ndarray):
                    assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y)
                else:
                    assert x == y


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("kernel") / "static.mcap"
    assert main(["record", "--static", "--duration-s", "60", "-o", str(path)]) == 0
    return path


def _foreign(path, *, backwards=False):
    """Two interleaved topics of different frame ids (sizes) by the mcap_ros2 writer, which puts
    Schema and Channel records inside its chunks; ``backwards``: log times falling in each chunk."""
    with open(path, "wb") as f:
        w = Ros2Writer(f, chunk_size=4000)
        imu = w.register_msgdef(IMU_SCHEMA, ros2.SCHEMAS[IMU_SCHEMA].decode())
        for i in range(200):
            for topic, frame in (("/imu/m1", "m1"), ("/a", "a_longer_frame")):
                msg = {"header": {"stamp": {"sec": i, "nanosec": 0}, "frame_id": frame}}
                msg["angular_velocity"] = {"x": float(i), "y": 0.0, "z": 0.0}
                t = (1000 - i if backwards else i) * 10**9
                w.write_message(topic, imu, msg, log_time=t, publish_time=t + 1)
        w.finish()
    return path


def _bulk(path, compression):
    """One topic of fixed-size messages and one of messages of two sizes, in small chunks."""
    with BulkMcapWriter(path, compression=compression, chunk_messages=37) as w:
        sid = w.register_schema("std_msgs/msg/UInt8MultiArray", "ros2msg", b"uint8[] data")
        fixed = w.register_channel("/fixed", sid, "cdr")
        varied = w.register_channel("/varied", sid, "cdr")
        t = np.arange(300, dtype=np.int64) * 1000
        w.write_messages(fixed, t, np.arange(300 * 12, dtype=np.uint8).reshape(300, 12))
        for k in range(300):  # two sizes in a chunk: numpy lists them as bytes
            w.write_messages(varied, t[k : k + 1] + 1, np.full((1, 8 if k % 2 else 16), k % 256, np.uint8))
    return path


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_compiled_and_numpy_paths_give_the_same_messages_of_a_bulk_file(tmp_path, compression):
    path = _bulk(tmp_path / "bulk.mcap", compression)
    _assert_same(_chunks(path, False), _chunks(path, True))
    assert len(accepted) == 17 and all(accepted)
    _assert_same(_chunks(path, False, channels={1}), _chunks(path, True, channels={1}))


@pytest.mark.parametrize("backwards", [False, True])
def test_compiled_and_numpy_paths_give_the_same_messages_of_another_writers_file(tmp_path, backwards):
    path = _foreign(tmp_path / "foreign.mcap", backwards=backwards)
    numpy_path = _chunks(path, False)
    assert len(numpy_path[0]) > 5 and not numpy_path[1]
    _assert_same(numpy_path, _chunks(path, True))
    # the first chunk defines the second channel between two messages: numpy walks its records
    assert len(accepted) == len(numpy_path[0]) and accepted[0] is False and all(accepted[1:])


def test_compiled_and_numpy_paths_give_the_same_recording(recording):
    _assert_same(_chunks(recording, False), _chunks(recording, True))
    assert len(accepted) > 3 and all(accepted)
    plain = read_recording(recording)
    fast = read_recording(recording, compiled=True)
    for node in plain.imu:
        for field in ("t_ns", "stamp_ns", "quat_wxyz", "gyro_rad_s", "accel_m_s2"):
            np.testing.assert_array_equal(getattr(plain.imu[node], field), getattr(fast.imu[node], field))


def test_a_message_index_that_lies_gives_the_numpy_paths_problem_or_messages(recording, tmp_path):
    """Message indexes carry no CRC: one entry's offset and another's log time are changed."""
    damaged = tmp_path / "damaged.mcap"
    data = bytearray(recording.read_bytes())
    mcap = scan_mcap(recording)
    ref = mcap.chunk_refs[1]
    (offset_a, _), (offset_b, _) = list(ref.index.values())[:2]
    mcap.close()
    entries_a = offset_a + RECORD_HEAD.size + 6
    entries_b = offset_b + RECORD_HEAD.size + 6
    struct.pack_into("<Q", data, entries_a + 16 + 8, struct.unpack_from("<Q", data, entries_a + 16 + 8)[0] + 1)
    struct.pack_into("<Q", data, entries_b, struct.unpack_from("<Q", data, entries_b)[0] + 7)
    damaged.write_bytes(bytes(data))
    _assert_same(_chunks(damaged, False), _chunks(damaged, True))
    assert accepted[1] is False and sum(accepted) == len(accepted) - 1


def _chunk(messages):
    """An uncompressed chunk of Message records (channel, log time, data) and its index: the
    chunk's bytes, the file bytes of the MessageIndex records, the spans and the offsets."""
    raw, offsets = b"", []
    for channel, log_ns, data in messages:
        offsets.append(len(raw))
        body = MESSAGE_FIELDS.pack(channel, 0, log_ns, log_ns + 5) + data
        raw += RECORD_HEAD.pack(0x05, len(body)) + body
    return raw, offsets


def _index(entries_by_channel):
    """File bytes of MessageIndex records {channel: [(log time, offset), ...]} and their spans."""
    file, spans = b"", []
    for channel, entries in entries_by_channel.items():
        spans.append((channel, len(file) + RECORD_HEAD.size + 6, len(entries)))
        log = np.array([e[0] for e in entries], np.uint64)
        offsets = np.array([e[1] for e in entries], np.uint64)
        file += message_index_record(channel, log, offsets)
    return np.frombuffer(file, np.uint8), np.array(spans, np.int64).reshape(-1, 3)


def _run(raw, file, spans, wanted=(1,)):
    slot, row_of = np.full((2, 1 << 16), -1, np.int64)
    slot[list(wanted)] = np.arange(len(wanted))
    row_of[spans[:, 0]] = np.arange(len(spans))
    found = np.zeros((4, len(wanted), 8), np.int64)
    counts = np.zeros(len(wanted), np.int64)
    first = chunk_kernel.index_messages(np.frombuffer(raw, np.uint8), file, spans, slot, row_of, *found, counts)
    return first, found, counts


MESSAGES = [(1, 100, b"abcd"), (2, 150, b"xy"), (1, 200, b"efgh")]


def test_an_index_that_lists_every_message_once_gives_the_wanted_channels_messages():
    raw, at = _chunk(MESSAGES)
    file, spans = _index({1: [(100, at[0]), (200, at[2])], 2: [(150, at[1])]})
    first, found, counts = _run(raw, file, spans)
    assert first == 0 and counts.tolist() == [2]
    offsets, log, publish, sizes = (f[0, :2].tolist() for f in found)
    assert offsets == [at[0], at[2]] and log == [100, 200] and publish == [105, 205] and sizes == [4, 4]


@pytest.mark.parametrize(
    "entries",
    [
        {1: [(100, 0), (201, 2)], 2: [(150, 1)]},  # a log time the message does not carry
        {1: [(100, 0)], 2: [(150, 1)]},  # a message the index does not list
        {1: [(100, 0), (100, 0), (200, 2)], 2: [(150, 1)]},  # a message listed twice
        {1: [(200, 2), (100, 0)], 2: [(150, 1)]},  # entries in another order than the chunk's
        {1: [(100, 0), (200, 2)], 3: [(150, 1)]},  # a message listed under another channel
        {1: [(100, 0), (200, 2)], 2: [(150, 1)], 4: [(150, 1)]},  # one message in two records
    ],
    ids=["log time", "missing", "twice", "order", "channel", "two records"],
)
def test_an_index_that_does_not_list_exactly_the_chunks_messages_is_refused(entries):
    raw, at = _chunk(MESSAGES)
    file, spans = _index({c: [(t, at[i]) for t, i in e] for c, e in entries.items()})
    assert _run(raw, file, spans)[0] == -1


def test_records_that_do_not_tile_the_chunk_are_refused():
    raw, at = _chunk(MESSAGES)
    file, spans = _index({1: [(100, at[0]), (200, at[2])], 2: [(150, at[1])]})
    assert _run(raw + b"\x05", file, spans)[0] == -1  # a byte after the last message
    assert _run(raw[:-1], file, spans)[0] == -1  # the last message runs past the end
    other = bytearray(raw)
    other[at[1]] = 0x06  # the second record is not a Message
    assert _run(bytes(other), file, spans)[0] == -1


def test_leading_records_before_the_first_message_are_left_to_the_caller():
    raw, at = _chunk(MESSAGES)
    head = b"\x04" + struct.pack("<Q", 3) + b"abc"  # any 12 bytes before the first message
    file, spans = _index({1: [(100, at[0] + 12), (200, at[2] + 12)], 2: [(150, at[1] + 12)]})
    assert _run(head + raw, file, spans)[0] == 12
