"""The bulk MCAP writer and the recovering reader: validity for other readers, crash safety,
truncation, corruption and garbage."""

import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.writer import Writer as Ros2Writer

from pendsim_bridge.io import ros2
from pendsim_bridge.io.mcap.reader import read_mcap, scan_mcap
from pendsim_bridge.io.mcap.tools import recover
from pendsim_bridge.io.mcap.writer import BulkMcapWriter
from pendsim_mj.errors import RecordingError

IMU_SCHEMA = "sensor_msgs/msg/Imu"


def _imu_payloads(n, start=0):
    layout = ros2.imu_layout("imu_m1")
    t_ns = (np.arange(start, start + n) * 12_500_000).astype(np.int64)
    sec, nsec = ros2.split_time(t_ns)
    gyro = np.stack([np.arange(start, start + n, dtype=float), np.zeros(n), np.ones(n)], axis=1)
    zeros9 = np.zeros(9)
    payloads = layout.encode(
        n,
        sec=sec,
        nanosec=nsec,
        orientation=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
        orientation_covariance=zeros9,
        angular_velocity=gyro,
        angular_velocity_covariance=zeros9,
        linear_acceleration=np.tile([0.0, 9.81, 0.0], (n, 1)),
        linear_acceleration_covariance=zeros9,
    )
    return t_ns, payloads


def _write(path, n=1000, chunk=100, compression="zstd"):
    t_ns, payloads = _imu_payloads(n)
    with BulkMcapWriter(path, compression=compression, chunk_messages=chunk) as w:
        sid = w.register_schema(IMU_SCHEMA, "ros2msg", ros2.SCHEMAS[IMU_SCHEMA])
        cid = w.register_channel("/imu/m1", sid, "cdr")
        w.add_metadata("pendsim/run", {"engine": "mujoco"})
        w.add_attachment("pendulums.xml", "application/xml", b"<mujoco/>")
        w.write_messages(cid, t_ns, payloads)
    return t_ns, payloads


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_the_official_mcap_reader_validates_and_reads_every_message(tmp_path, compression):
    path = tmp_path / "a.mcap"
    t_ns, payloads = _write(path, compression=compression)
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary.statistics.message_count == 1000 and summary.statistics.chunk_count == 10
        messages = list(reader.iter_messages())
        assert [m.log_time for _, _, m in messages] == t_ns.tolist()
        assert messages[7][2].data == payloads[7].tobytes()
        assert next(reader.iter_metadata()).metadata["engine"] == "mujoco"
        assert next(reader.iter_attachments()).data == b"<mujoco/>"


def test_our_reader_reads_a_file_written_by_mcap_ros2_with_interleaved_channels(tmp_path):
    path = tmp_path / "foreign.mcap"
    with open(path, "wb") as f:
        w = Ros2Writer(f)
        imu = w.register_msgdef(IMU_SCHEMA, ros2.SCHEMAS[IMU_SCHEMA].decode())
        for i in range(50):
            for topic, frame in (("/a", "frame_a"), ("/b", "long_frame_b")):
                msg = {"header": {"stamp": {"sec": i, "nanosec": 0}, "frame_id": frame}}
                msg["angular_velocity"] = {"x": float(i), "y": 0.0, "z": 0.0}
                w.write_message(topic, imu, msg, log_time=i * 10**9, publish_time=i * 10**9)
        w.finish()
    contents = read_mcap(path, strict=True)
    assert contents.topics() == {"/a": 50, "/b": 50}
    b = contents.topic("/b")
    decoded = ros2.imu_layout("long_frame_b").decode(b.payloads)
    np.testing.assert_array_equal(decoded["angular_velocity"][:, 0], np.arange(50.0))
    np.testing.assert_array_equal(b.log_time_ns, np.arange(50) * 10**9)


def test_truncation_anywhere_recovers_every_complete_chunk_and_never_crashes(tmp_path):
    path = tmp_path / "full.mcap"
    _write(path, n=1000, chunk=100)
    data = path.read_bytes()
    with open(path, "rb") as f:
        chunk_ends = sorted(
            ci.chunk_start_offset + ci.chunk_length for ci in make_reader(f).get_summary().chunk_indexes
        )
    cut_path = tmp_path / "cut.mcap"
    for cut in [*range(8, 400, 37), *range(400, len(data), max(1, len(data) // 97))]:
        cut_path.write_bytes(data[:cut])
        if cut < 8:
            continue
        contents = read_mcap(cut_path)
        expected = 100 * sum(end <= cut for end in chunk_ends)
        assert contents.message_count == expected, cut
        if cut < len(data):
            nothing = "no complete chunk of messages, nothing to recover"
            said = rf"{expected} messages in \d+ chunks? intact" if expected else nothing
            with pytest.raises(RecordingError, match=rf"cut.mcap: .*{said}"):
                read_mcap(cut_path, strict=True)


def test_a_corrupted_chunk_is_reported_and_the_others_are_kept(tmp_path):
    path = tmp_path / "bad.mcap"
    _write(path, n=1000, chunk=100)
    with open(path, "rb") as f:
        third = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)[2]
    data = bytearray(path.read_bytes())
    data[third.chunk_start_offset + third.chunk_length - 20] ^= 0xFF  # inside the compressed data
    path.write_bytes(bytes(data))
    contents = read_mcap(path)
    assert contents.message_count == 900
    assert any(p.startswith(f"chunk at byte {third.chunk_start_offset}: ") for p in contents.problems)
    with pytest.raises(RecordingError, match=r"bad\.mcap: .*900 messages in 9 chunks intact"):
        read_mcap(path, strict=True)


def test_a_chunk_only_the_data_section_crc_finds_damaged_is_not_counted_as_intact(tmp_path):
    """The DataEnd CRC fails first (no chunk is inflated to find it); the readable part the error
    names leaves the damaged chunk out, as ``recover`` does."""
    path = tmp_path / "a.mcap"
    _write(path)
    mcap = scan_mcap(path)
    ref = mcap.chunk_refs[2]
    mcap.close()
    data = bytearray(path.read_bytes())
    data[ref.data_start + ref.data_size // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(RecordingError) as caught:
        read_mcap(path, strict=True)
    message = str(caught.value)
    assert "fails the DataEnd CRC" in message
    assert "900 messages in 9 chunks intact" in message


@pytest.mark.parametrize("content", [b"", b"PK\x03\x04 not an mcap at all" * 20, os.urandom(4096)])
def test_garbage_is_an_error_that_names_the_file(tmp_path, content):
    path = tmp_path / "junk.mcap"
    path.write_bytes(content)
    with pytest.raises(RecordingError, match=r"junk.mcap: not an MCAP file"):
        read_mcap(path)


def test_a_missing_file_is_an_error_that_names_it(tmp_path):
    with pytest.raises(RecordingError, match=r"nope.mcap: cannot open"):
        read_mcap(tmp_path / "nope.mcap")


def test_a_writer_killed_with_sigkill_leaves_every_flushed_chunk_readable(tmp_path):
    path = tmp_path / "killed.mcap"
    script = textwrap.dedent(
        f"""
        import sys, time
        sys.path.insert(0, {str(os.path.dirname(__file__))!r})
        from test_mcap_io import _imu_payloads, IMU_SCHEMA
        from pendsim_bridge.io import ros2
        from pendsim_bridge.io.mcap.writer import BulkMcapWriter
        w = BulkMcapWriter({str(path)!r}, chunk_messages=100)
        sid = w.register_schema(IMU_SCHEMA, "ros2msg", ros2.SCHEMAS[IMU_SCHEMA])
        cid = w.register_channel("/imu/m1", sid, "cdr")
        for k in range(10_000):
            t_ns, payloads = _imu_payloads(100, start=100 * k)
            w.write_messages(cid, t_ns, payloads)
            w.flush()
            print(k + 1, flush=True)  # chunks written and flushed so far
            time.sleep(0.02)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        written = 0
        while written < 8:
            line = proc.stdout.readline()
            assert line, "the writer died before writing 8 chunks"
            written = int(line)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
    assert proc.returncode == -signal.SIGKILL
    contents = read_mcap(path)
    assert not contents.complete
    imu = contents.topic("/imu/m1")
    assert len(imu) >= 100 * written  # every chunk reported flushed before the kill
    gyro_x = ros2.imu_layout("imu_m1").decode(imu.payloads)["angular_velocity"][:, 0]
    np.testing.assert_array_equal(gyro_x, np.arange(len(imu), dtype=float))  # in order, none lost


def test_recover_writes_a_complete_file_with_everything_readable(tmp_path):
    path = tmp_path / "full.mcap"
    _, payloads = _write(path, n=1000, chunk=100)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: int(path.stat().st_size * 0.6)])
    broken = read_mcap(cut)
    fixed = tmp_path / "fixed.mcap"
    recover(cut, fixed)
    again = read_mcap(fixed, strict=True)
    assert again.complete and again.message_count == broken.message_count > 0
    np.testing.assert_array_equal(again.topic("/imu/m1").payloads, payloads[: broken.message_count])
    assert again.metadata == {"pendsim/run": {"engine": "mujoco"}}  # its CRC entry checked and removed
    assert again.attachments["pendulums.xml"].data == b"<mujoco/>"
    with open(fixed, "rb") as f:
        assert make_reader(f, validate_crcs=True).get_summary().statistics.message_count == broken.message_count


def test_a_file_cut_inside_its_first_chunk_has_nothing_to_recover_and_nothing_is_written(tmp_path, capsys):
    from pendsim_bridge.cli import main

    whole, cut = tmp_path / "whole.mcap", tmp_path / "cut.mcap"
    assert main(["record", "--duration-s", "20", "-o", str(whole)]) == 0
    cut.write_bytes(whole.read_bytes()[:20_000])  # header, metadata, then part of the first chunk
    capsys.readouterr()
    assert main(["validate", str(cut)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("no complete chunk of messages, nothing to recover") and "pendsim recover" not in err, err
    assert main(["recover", str(cut), str(tmp_path / "fixed.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no message to recover" in err[0], err
    assert not (tmp_path / "fixed.mcap").exists()


def test_a_file_that_is_not_mcap_is_named_before_an_existing_output(tmp_path, capsys, monkeypatch):
    from pendsim_bridge.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "run.rrd").write_bytes(b"RRF2" + b"\0" * 100)
    (tmp_path / "run_validation").mkdir()
    (tmp_path / "run_validation" / "report.json").write_text("{}")
    for argv in (["validate", "run.rrd"], ["identify", "run.rrd"], ["view", "run.rrd"], ["allan", "run.rrd"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].endswith("run.rrd: not an MCAP file (no MCAP magic at the start)"), err


def test_a_file_written_without_chunks_is_named_as_such_not_as_damaged(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "unchunked.mcap"
    with open(path, "wb") as f:
        w = Writer(f, use_chunking=False)
        w.start()
        schema = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", ros2.SCHEMAS[IMU_SCHEMA])
        channel = w.register_channel("/imu/m1", "cdr", schema)
        w.add_message(channel, log_time=1, data=_imu_payloads(1)[1][0].tobytes(), publish_time=1)
        w.finish()
    with pytest.raises(RecordingError) as caught:
        read_mcap(path, strict=True)
    message = str(caught.value)
    assert "a message outside chunks (pendsim reads chunked files only)" in message
    assert message.endswith("write it with chunks (every MCAP writer's default layout)")
    assert "recover" not in message and "damaged" not in message
