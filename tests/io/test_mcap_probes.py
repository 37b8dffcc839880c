"""Damaged and hostile files, made by code: a bit flipped in every region, truncation at every
record boundary, damaged lengths, decompression bombs, wrong schemas, bad metadata values,
garbage after the end, special files. Each is an error (exit 2, one line, no traceback) and
never read as valid; ``recover`` keeps every intact chunk and carries nothing unverified."""

import io
import os
import struct
import subprocess
import sys
import textwrap
import time
import zlib

import numpy as np
import pytest
import zstandard

from pendsim_bridge.cli import main
from pendsim_bridge.io import ros2
from pendsim_bridge.io.mcap.reader import read_mcap
from pendsim_bridge.io.mcap.tools import recover
from pendsim_bridge.io.mcap.writer import BulkMcapWriter
from pendsim_bridge.run.record import RecordSpec, record
from pendsim_mj.errors import RecordingError

T0 = 1_750_000_000_000_000_000  # a fixed UTC start: the tests do not read the wall clock


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    path = tmp_path_factory.mktemp("probe") / "good.mcap"
    record(RecordSpec(duration_s=3.0, hold_s=0.5), path, start_time_ns=T0, block_s=1.0)
    return path


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, end) of every record, walked by hand (independently of pendsim's reader)."""
    out, at = [], 8
    while at + 9 <= len(data) - 8:
        opcode, length = struct.unpack_from("<BQ", data, at)
        out.append((at, opcode, at + 9 + length))
        at += 9 + length
    return out


def _chunk_messages(data: bytes) -> list[tuple[int, int]]:
    """(end of the chunk record, messages in it) per chunk, counted by hand."""
    out = []
    for at, opcode, end in _records(data):
        if opcode == 0x06:
            body = data[at + 9 : end]
            usize, clen = struct.unpack_from("<Q", body, 16)[0], struct.unpack_from("<I", body, 28)[0]
            compression = body[32 : 32 + clen].decode()
            (dlen,) = struct.unpack_from("<Q", body, 32 + clen)
            raw = body[40 + clen : 40 + clen + dlen]
            raw = zstandard.ZstdDecompressor().decompress(raw, max_output_size=usize) if compression else raw
            count, k = 0, 0
            while k < len(raw):
                op, length = struct.unpack_from("<BQ", raw, k)
                count += op == 0x05
                k += 9 + length
            out.append((end, count))
    return out


def _cli_error(capsys, argv: list[str]) -> str:
    code = main(argv)
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2, (argv, captured.out[-300:], captured.err[-500:])
    assert len(lines) == 1 and lines[0].startswith("pendsim: error: "), lines
    assert "Traceback" not in captured.err
    return lines[0]


def test_the_probe_recording_is_valid_and_chunked(good):
    contents = read_mcap(good, strict=True)
    assert contents.complete and not contents.problems and not contents.unverified
    assert len(_chunk_messages(good.read_bytes())) >= 3


def test_a_bit_flipped_in_any_record_is_an_error_naming_the_region(good, tmp_path, capsys):
    data = good.read_bytes()
    bad = tmp_path / "flip.mcap"
    seen = set()
    for at, opcode, end in _records(data):
        if (opcode, end - at > 200) in seen and opcode not in (0x0C, 0x09):
            continue  # one record of each kind and size class (all metadata and attachments)
        seen.add((opcode, end - at > 200))
        for where in (at + 9 + (end - at - 9) // 2, end - 1):
            flipped = bytearray(data)
            flipped[where] ^= 0x10
            bad.write_bytes(bytes(flipped))
            line = _cli_error(capsys, ["inspect", str(bad)])
            assert "flip.mcap" in line, (opcode, where, line)
            with pytest.raises(RecordingError):
                read_mcap(bad, strict=True)
    for where in (3, len(data) - 3):  # the magic at either end
        flipped = bytearray(data)
        flipped[where] ^= 0x01
        bad.write_bytes(bytes(flipped))
        _cli_error(capsys, ["inspect", str(bad)])


def test_a_flipped_rig_parameter_makes_validate_and_identify_fail_not_mislead(good, tmp_path, capsys):
    data = good.read_bytes()
    i = data.index(b"b1_n_m_s")
    j = data.index(b"0.", i)  # the value's first digits: 0.00... -> 0.09...
    bad = bytearray(data)
    bad[j + 3] = ord("9") if bad[j + 3] != ord("9") else ord("8")
    path = tmp_path / "b1.mcap"
    path.write_bytes(bytes(bad))
    for command in ("validate", "identify"):
        line = _cli_error(capsys, [command, str(path)])
        assert "pendsim/rig_parameters" in line or "pendsim/run" in line or "data section" in line


def test_a_summary_channel_that_differs_from_the_data_section_is_an_error(good, tmp_path, capsys):
    data = bytearray(good.read_bytes())
    # The summary's copy of /imu/m1 renamed /imu/m3, and the summary CRC set to 0 ("not computed").
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]
    k = data.index(b"/imu/m1", summary_start)
    data[k + 6] = ord("3")
    struct.pack_into("<I", data, len(data) - 8 - 4, 0)
    path = tmp_path / "summary.mcap"
    path.write_bytes(bytes(data))
    line = _cli_error(capsys, ["allan", str(path)])
    assert "summary: Channel" in line and "differs from the data section" in line


def test_truncation_at_every_record_boundary_recovers_every_complete_chunk(good, tmp_path, capsys):
    data = good.read_bytes()
    chunks = _chunk_messages(data)
    cut = tmp_path / "cut.mcap"
    for at, _, _ in _records(data)[1:]:
        cut.write_bytes(data[:at])
        contents = read_mcap(cut)
        assert contents.message_count == sum(n for end, n in chunks if end <= at), at
        assert not contents.complete
        _cli_error(capsys, ["inspect", str(cut)])


def test_recover_resynchronises_after_a_damaged_length_and_keeps_every_intact_chunk(good, tmp_path):
    data = bytearray(good.read_bytes())
    chunks = [(at, end) for at, opcode, end in _records(bytes(data)) if opcode == 0x06]
    counts = [n for _, n in _chunk_messages(bytes(data))]
    middle = len(chunks) // 2
    for damage in (2**40, chunks[middle][1] - chunks[middle][0] + 5):  # past the end; plausible but wrong
        broken = bytearray(data)
        struct.pack_into("<Q", broken, chunks[middle][0] + 1, damage)
        src, fixed = tmp_path / f"len{damage}.mcap", tmp_path / f"fixed{damage}.mcap"
        src.write_bytes(bytes(broken))
        contents = recover(src, fixed)
        assert contents.message_count == sum(counts) - counts[middle]  # all but the damaged chunk
        again = read_mcap(fixed, strict=True)
        assert again.complete and again.message_count == contents.message_count
        assert again.metadata == read_mcap(good).metadata  # covered by their own CRCs


def test_recover_leaves_out_unverified_metadata_unless_asked(tmp_path, capsys):
    path = tmp_path / "foreign.mcap"
    w = BulkMcapWriter(path)
    w.add_metadata("pendsim/run", {"engine": "mujoco"})
    sid = w.register_schema("raw", "", b"")
    cid = w.register_channel("/x", sid, "raw")
    w.write_messages(cid, [1, 2, 3], np.zeros((3, 4), np.uint8))
    w.flush()
    w.close_unfinished()
    data = bytearray(path.read_bytes())  # strip the metadata's own CRC: nothing covers it now
    k = data.index(b"pendsim.crc32")
    data[k : k + 13] = b"othertool.key"
    path.write_bytes(bytes(data))
    fixed, forced = tmp_path / "fixed.mcap", tmp_path / "forced.mcap"
    assert main(["recover", str(path), str(fixed)]) == 0
    out = capsys.readouterr().out
    assert "unverified, left out" in out and "metadata pendsim/run at byte" in out
    assert read_mcap(fixed, strict=True).metadata == {}
    assert main(["recover", str(path), str(forced), "--keep-unverified"]) == 0
    kept = read_mcap(forced, strict=True).metadata
    assert kept["pendsim/run"]["engine"] == "mujoco" and "metadata pendsim/run" in kept["pendsim/unverified"]["0"]
    assert read_mcap(forced).message_count == 3


def _bomb(path, *, declared: int) -> None:
    """A file whose one chunk is 16 KB of zstd that inflates to 512 MB of zeros."""
    cctx = zstandard.ZstdCompressor(level=19)
    stream = io.BytesIO()
    with cctx.stream_writer(stream, closefd=False) as writer:
        zeros = bytes(1 << 20)
        for _ in range(512):
            writer.write(zeros)
    payload = stream.getvalue()
    assert len(payload) < 32_000
    w = BulkMcapWriter(path, compression="none")
    w.close_unfinished()
    body = struct.pack("<QQQI", 0, 0, declared, 0) + struct.pack("<I", 4) + b"zstd"
    body += struct.pack("<Q", len(payload)) + payload
    with open(path, "ab") as f:
        f.write(struct.pack("<BQ", 0x06, len(body)) + body)


@pytest.mark.parametrize("declared", [512 << 20, 4096])  # the truth (a ratio of 32 000), or a lie
def test_a_decompression_bomb_is_refused_quickly_with_bounded_memory(tmp_path, declared):
    path = tmp_path / "bomb.mcap"
    _bomb(path, declared=declared)
    script = textwrap.dedent(
        f"""
        import time
        from pendsim_bridge.io.mcap.reader import read_mcap
        start = time.perf_counter()
        contents = read_mcap({str(path)!r})
        took = time.perf_counter() - start
        peak_kb = int(open('/proc/self/status').read().split('VmHWM:')[1].split()[0])
        print(took, peak_kb, contents.message_count, contents.problems)
        """
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    took, rss_kb, count, problems = out.stdout.split(" ", 3)
    assert float(took) < 1.0 and int(rss_kb) < 400_000 and int(count) == 0, out.stdout
    assert any(phrase in problems for phrase in ("decompression bomb", "(limit", "not the declared", "more than"))


def _write_topic(path, source, topic: str, schema_name: str, schema: bytes, payloads: np.ndarray) -> None:
    """A file with ``source``'s metadata and one topic of the given schema and payloads."""
    with BulkMcapWriter(path) as w:
        for name, values in read_mcap(source).metadata.items():
            w.add_metadata(name, values)
        sid = w.register_schema(schema_name, "ros2msg", schema)
        cid = w.register_channel(topic, sid, "cdr")
        w.write_messages(cid, T0 + np.arange(len(payloads)) * 12_500_000, payloads)


def test_a_known_topic_with_another_schema_is_an_error_naming_both(good, tmp_path, capsys):
    path = tmp_path / "schema.mcap"
    _write_topic(path, good, "/imu/m1", "std_msgs/msg/String", b"string data\n", np.zeros((100, 12), np.uint8))
    line = _cli_error(capsys, ["allan", str(path)])
    assert "topic /imu/m1 carries schema 'std_msgs/msg/String'" in line and "sensor_msgs/msg/Imu" in line


def test_a_known_topic_whose_messages_do_not_decode_is_an_error_not_a_struct_error(good, tmp_path, capsys):
    path = tmp_path / "garbled.mcap"
    imu = "sensor_msgs/msg/Imu"
    _write_topic(path, good, "/imu/m1", imu, ros2.SCHEMAS[imu], np.full((100, 40), 7, np.uint8))
    line = _cli_error(capsys, ["allan", str(path)])
    assert "topic /imu/m1: a message does not decode as sensor_msgs/msg/Imu" in line
    line = _cli_error(capsys, ["replay", str(path), "--quiet", "--rerun", str(tmp_path / "r.rrd")])
    assert "topic /imu/m1: a message at log time" in line and "does not decode as sensor_msgs/msg/Imu" in line


@pytest.mark.parametrize(
    ("record_name", "key", "value"),
    [
        ("pendsim/rig_parameters", "c1_n_m", "abc"),
        ("pendsim/rig_parameters", "c1_n_m", "nan"),
        ("pendsim/rig_parameters", "c1_n_m", "-5"),
        ("pendsim/rig_parameters", "m1_kg", "1e300"),
        ("pendsim/imu", "sample_rate_hz", '"abc"'),
        ("pendsim/imu", "sample_rate_hz", "NaN"),
        ("pendsim/imu", "seed", "-1"),
        ("pendsim/imu", "noise_model.gyro_sigma_rad_s", "[1, 2]"),
        ("pendsim/run", "duration_s", "nan"),
        ("pendsim/run", "phi0_rad", "[1e308, 0]"),
        ("pendsim/run", "engine", "warp"),
    ],
)
def test_bad_metadata_values_are_one_line_errors(good, tmp_path, capsys, record_name, key, value):
    contents = read_mcap(good, strict=True)
    path = tmp_path / "meta.mcap"
    with BulkMcapWriter(path) as w:
        for name, values in contents.metadata.items():
            w.add_metadata(name, {**values, key: value} if name == record_name else values)
        w.add_attachment("pendulums.xml", "application/xml", contents.attachments["pendulums.xml"].data)
        ids = {sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in contents.schemas.items()}
        for cid, ch in contents.channels.items():
            new = w.register_channel(ch.topic, ids[ch.schema_id], ch.message_encoding, ch.metadata)
            d = contents.messages[cid]
            w.write_messages(new, d.log_time_ns, d.payloads)
    command = "allan" if record_name == "pendsim/imu" else "identify"
    line = _cli_error(capsys, [command, str(path)])
    assert record_name in line and "meta.mcap" in line


def test_garbage_after_the_end_and_concatenated_files_are_reported(good, tmp_path, capsys):
    data = good.read_bytes()
    for name, extra, phrase in (
        ("tail.mcap", os.urandom(100), "100 bytes of garbage after the end"),
        ("twice.mcap", data, "a second MCAP file is concatenated"),
    ):
        path = tmp_path / name
        path.write_bytes(data + extra)
        assert phrase in _cli_error(capsys, ["inspect", str(path)])


def test_fifos_and_folders_are_refused_without_blocking(tmp_path, capsys):
    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    start = time.perf_counter()
    assert "pipe.mcap" in _cli_error(capsys, ["inspect", str(fifo)])
    assert "is a folder; give a file" in _cli_error(capsys, ["inspect", str(tmp_path)])
    with pytest.raises(RecordingError, match="not a regular file"):
        read_mcap(fifo)
    assert time.perf_counter() - start < 5


def test_chunk_crc_is_checked_even_when_the_data_section_crc_is_absent(good, tmp_path):
    data = bytearray(good.read_bytes())
    at = next(a for a, opcode, _ in _records(bytes(data)) if opcode == 0x0F)  # DataEnd
    struct.pack_into("<I", data, at + 9, 0)  # "no data-section CRC"
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]
    crc = zlib.crc32(bytes(data[summary_start : len(data) - 8 - 4]))
    struct.pack_into("<I", data, len(data) - 8 - 4, crc)
    chunk_at, _, chunk_end = next(r for r in _records(bytes(data)) if r[1] == 0x06)
    data[chunk_end - 10] ^= 0x40
    path = tmp_path / "nocrc.mcap"
    path.write_bytes(bytes(data))
    contents = read_mcap(path)
    assert any(p.startswith(f"chunk at byte {chunk_at}:") for p in contents.problems)
