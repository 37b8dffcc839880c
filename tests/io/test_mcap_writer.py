"""The streaming MCAP writer: channels interleaved in log-time order in every chunk, read in file
order by the official streaming reader; time-based flushing; write errors as OutputError."""

import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from pendsim_bridge.errors import OutputError
from pendsim_bridge.io.mcap.reader import read_mcap
from pendsim_bridge.io.mcap.writer import BulkMcapWriter


def _rows(n: int, size: int, first: int) -> np.ndarray:
    """n payloads of ``size`` bytes whose first 8 bytes count from ``first`` (to check order)."""
    out = np.zeros((n, size), np.uint8)
    out[:, :8] = np.arange(first, first + n, dtype="<u8").view(np.uint8).reshape(n, 8)
    return out


def _channels(w: BulkMcapWriter) -> tuple[int, int, int]:
    sid = w.register_schema("raw", "", b"")
    return tuple(w.register_channel(t, sid, "raw") for t in ("/fast", "/slow", "/once"))  # type: ignore[return-value]


def _write_blocks(w: BulkMcapWriter, blocks: int, *, flush: bool) -> None:
    """Per block of 1 s: /fast at 100 Hz (40-byte messages), /slow at 10 Hz (200 bytes), each
    given as a whole block, channel after channel (as record does)."""
    fast, slow, once = _channels(w)
    w.write_messages(once, [0], _rows(1, 16, 0))
    for b in range(blocks):
        t0 = b * 1_000_000_000
        w.write_messages(fast, t0 + np.arange(100) * 10_000_000, _rows(100, 40, 100 * b))
        w.write_messages(slow, t0 + 5_000_000 + np.arange(10) * 100_000_000, _rows(10, 200, 10 * b))
        if flush:
            w.flush()


def test_chunks_interleave_channels_in_log_time_order_for_a_streaming_reader(tmp_path):
    path = tmp_path / "mixed.mcap"
    with BulkMcapWriter(path, chunk_messages=64) as w:
        _write_blocks(w, 5, flush=True)
    with open(path, "rb") as f:
        records = list(StreamReader(f, validate_crcs=True).records)
    messages = [r for r in records if type(r).__name__ == "Message"]
    times = [m.log_time for m in messages]
    assert len(messages) == 1 + 5 * 110
    assert times == sorted(times)  # file order is log-time order, across channels and chunks
    chunk_channels = []
    with open(path, "rb") as f:
        for r in StreamReader(f, emit_chunks=True).records:
            if type(r).__name__ == "MessageIndex":
                chunk_channels.append(r.channel_id)
    assert len(set(chunk_channels)) == 3 and chunk_channels.count(1) > 1  # channels share chunks
    with open(path, "rb") as f:  # the seeking reader agrees, and every CRC checks
        summary = make_reader(f, validate_crcs=True).get_summary()
    assert summary.statistics.channel_message_counts == {1: 500, 2: 50, 3: 1}
    contents = read_mcap(path, strict=True)
    fast = contents.topic("/fast").payloads
    assert np.array_equal(fast[:, :8].copy().view("<u8").ravel(), np.arange(500))  # each channel in order


def test_a_message_older_than_what_was_written_is_refused(tmp_path):
    with BulkMcapWriter(tmp_path / "a.mcap") as w:
        fast, slow, _ = _channels(w)
        w.write_messages(fast, [10, 20], _rows(2, 8, 0))
        w.flush()
        with pytest.raises(ValueError, match="comes after messages up to 20 ns were written"):
            w.write_messages(slow, [15], _rows(1, 8, 0))


def test_a_live_writer_writes_a_chunk_per_interval_of_log_time(tmp_path):
    path = tmp_path / "live.mcap"
    wall = [0.0]
    with BulkMcapWriter(path, reorder_window_ns=50_000_000, flush_interval_s=1.0, clock=lambda: wall[0]) as w:
        fast, _, _ = _channels(w)
        for k in range(1000):  # 10 s at 100 Hz, one message per call
            w.write_messages(fast, [k * 10_000_000], _rows(1, 40, k))
        size_before_finish = os.path.getsize(path)
        chunks_before_finish = len(w._chunk_indexes)
    assert 9 <= chunks_before_finish <= 11  # one per second of log time
    assert size_before_finish > 0
    with open(path, "rb") as f:
        assert make_reader(f, validate_crcs=True).get_summary().statistics.message_count == 1000


def test_a_live_writer_writes_a_chunk_per_interval_of_wall_time(tmp_path):
    wall = [0.0]
    with BulkMcapWriter(tmp_path / "w.mcap", reorder_window_ns=0, flush_interval_s=1.0, clock=lambda: wall[0]) as w:
        fast, _, _ = _channels(w)
        for k in range(10):  # slow log time (1 ms per message) but 0.5 s of wall time each
            wall[0] += 0.5
            w.write_messages(fast, [k * 1_000_000], _rows(1, 40, k))
        assert len(w._chunk_indexes) == 5


def test_a_killed_live_writer_loses_at_most_the_last_interval(tmp_path):
    path = tmp_path / "killed.mcap"
    script = textwrap.dedent(
        f"""
        import time
        import numpy as np
        from pendsim_bridge.io.mcap.writer import BulkMcapWriter
        w = BulkMcapWriter({str(path)!r}, reorder_window_ns=0, flush_interval_s=0.2)
        sid = w.register_schema("raw", "", b"")
        cid = w.register_channel("/live", sid, "raw")
        t0 = time.monotonic()
        k = 0
        while True:
            now = time.monotonic() - t0
            w.write_messages(cid, [int(now * 1e9)], np.full((1, 8), k % 256, np.uint8))
            k += 1
            if k == 50:
                print("running", flush=True)
            time.sleep(0.005)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "running"
        import time

        time.sleep(1.5)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
    contents = read_mcap(path)
    assert not contents.complete
    t = contents.topic("/live").log_time_ns
    assert t[-1] / 1e9 > 1.0  # everything but the last 0.2 s (and scheduling slack) is there


def test_a_full_disk_is_an_output_error_naming_the_file(tmp_path):
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full on this system")
    with pytest.raises(OutputError, match=r"cannot write '/dev/full': no space left on the device"):
        BulkMcapWriter("/dev/full")  # the header is flushed at once


def test_an_unwritable_path_is_an_output_error(tmp_path):
    with pytest.raises(OutputError, match=r"no-such-folder/a.mcap': the folder does not exist"):
        BulkMcapWriter(tmp_path / "no-such-folder" / "a.mcap")


def test_metadata_carry_their_own_crc_and_a_flipped_value_is_caught(tmp_path):
    path = tmp_path / "m.mcap"
    w = BulkMcapWriter(path)
    w.add_metadata("pendsim/rig_parameters", {"b1_n_m_s": "0.00123"})
    w.flush()
    w.close_unfinished()  # no DataEnd: only the record's own CRC can vouch for it
    assert read_mcap(path).metadata == {"pendsim/rig_parameters": {"b1_n_m_s": "0.00123"}}
    data = path.read_bytes().replace(b"0.00123", b"0.00923")
    path.write_bytes(data)
    contents = read_mcap(path)
    assert "pendsim/rig_parameters" not in contents.metadata
    assert any("metadata 'pendsim/rig_parameters' fails its CRC" in p for p in contents.problems)
