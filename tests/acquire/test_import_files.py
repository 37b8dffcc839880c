"""pendsim import on files as other programs leave them: TDMS in either byte order (written here
by a writer that follows NI's description of the format, independent of npTDMS and of pendsim, and
by npTDMS itself), TDMS and LabVIEW files cut short, unfinished or damaged, and values out of range."""

import math
import struct
from pathlib import Path

import numpy as np
import pytest

from pendsim_bridge.acquire.lab_files import read_tdms
from pendsim_bridge.cli import main
from pendsim_bridge.io.recording import read_recording

TOC_META, TOC_NEW_OBJECTS, TOC_RAW, TOC_BIG_ENDIAN = 1 << 1, 1 << 2, 1 << 3, 1 << 6
TDS_DOUBLE, TDS_STRING = 10, 0x20


def tdms_segment(channels: dict[str, dict[str, np.ndarray]], *, big_endian: bool, properties=None) -> bytes:
    """One TDMS 2.0 segment (NI, "TDMS File Format Internal Structure"): the 28-byte lead-in ("TDSm",
    the table of contents, always little-endian, then version 4713, the next segment's offset and
    the raw data's offset in the segment's byte order), the objects (root, groups, channels with
    their raw data index and properties) and the raw data, channel after channel, float64."""
    order = ">" if big_endian else "<"

    def text(value: str) -> bytes:
        raw = value.encode()
        return struct.pack(order + "I", len(raw)) + raw

    def props(items: dict) -> bytes:
        out = struct.pack(order + "I", len(items))
        for key, value in items.items():
            out += text(key)
            if isinstance(value, str):
                out += struct.pack(order + "I", TDS_STRING) + text(value)
            else:
                out += struct.pack(order + "Id", TDS_DOUBLE, float(value))
        return out

    objects = [("/", None, properties or {})]
    for group, columns in channels.items():
        objects.append((f"/'{group}'", None, {}))
        objects += [(f"/'{group}'/'{name}'", data, {"wf_increment": 1 / 80}) for name, data in columns.items()]
    meta, raw = struct.pack(order + "I", len(objects)), b""
    for path, data, items in objects:
        meta += text(path)
        if data is None:
            meta += struct.pack(order + "I", 0xFFFFFFFF)  # no raw data
        else:
            meta += struct.pack(order + "IIIQ", 20, TDS_DOUBLE, 1, len(data))  # index length, type, dimension, count
            raw += np.asarray(data, dtype=order + "f8").tobytes()
        meta += props(items)
    toc = TOC_META | TOC_NEW_OBJECTS | TOC_RAW | (TOC_BIG_ENDIAN if big_endian else 0)
    lead = b"TDSm" + struct.pack("<i", toc) + struct.pack(order + "iQQ", 4713, len(meta) + len(raw), len(meta))
    return lead + meta + raw


def _node_at_rest(n: int = 400) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(11)
    return {
        **{f"g{a}": rng.normal(0.0, 0.002, n) for a in "xyz"},
        **{f"a{a}": rng.normal(g, 0.02, n) for a, g in zip("xyz", (0.0, 0.0, 9.81), strict=True)},
    }


COLUMNS = "m1.gx,m1.gy,m1.gz,m1.ax,m1.ay,m1.az"
GYRO_RAD_S = ["--units", "gyro=rad/s"]


def _import(tmp_path, name: str, *extra: str) -> int:
    return main(["import", str(tmp_path / name), "-o", str(tmp_path / "out.mcap"), "--columns", COLUMNS, *extra])


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("pendsim: error: ")
    return err[0]


def test_a_big_endian_tdms_file_imports_like_the_little_endian_one_npTDMS_writes(tmp_path):
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsFile, TdmsWriter

    node = _node_at_rest()
    big = tmp_path / "big.tdms"
    big.write_bytes(tdms_segment({"IMU": node}, big_endian=True, properties={"name": "big-endian run"}))
    read = TdmsFile.read(str(big))  # npTDMS reads the hand-written file as written
    assert read.properties["name"] == "big-endian run"
    np.testing.assert_array_equal(read["IMU"]["gy"][:], node["gy"])
    with TdmsWriter(str(tmp_path / "little.tdms")) as writer:
        writer.write_segment(
            [RootObject(), GroupObject("IMU")]
            + [ChannelObject("IMU", k, v, properties={"wf_increment": 1 / 80}) for k, v in node.items()]
        )
    for name in ("big.tdms", "little.tdms"):
        out = tmp_path / f"{name}.mcap"
        args = ["import", str(tmp_path / name), "-o", str(out), "--columns", COLUMNS, *GYRO_RAD_S]
        assert main(args) == 0
        imu = read_recording(out).imu["m1"]
        np.testing.assert_array_equal(imu.gyro_rad_s, np.stack([node[f"g{a}"] for a in "xyz"], axis=1))
        np.testing.assert_array_equal(imu.accel_m_s2, np.stack([node[f"a{a}"] for a in "xyz"], axis=1))
        np.testing.assert_array_equal(imu.t_ns, np.rint(np.arange(400) * 12.5e6).astype(np.int64))
    assert read_recording(tmp_path / "big.tdms.mcap").metadata["pendsim/import"]["tdms_name"] == "big-endian run"


def test_npTDMS_own_big_endian_example_file_reads_as_npTDMS_reads_it():
    from importlib.resources import files

    from nptdms import TdmsFile

    example = Path(str(files("nptdms") / "test" / "data" / "big_endian.tdms"))
    if not example.exists():
        pytest.skip("this npTDMS install carries no test data")
    table = read_tdms(example)
    theirs = TdmsFile.read(str(example))["Measured Data"]
    assert table.names == ("Measured Data/Amplitude sweep", "Measured Data/Phase sweep")
    np.testing.assert_array_equal(table.values[:, 1], theirs["Phase sweep"][:])
    np.testing.assert_allclose(table.values[:5, 1], [0.0, 0.0634176, 0.1265799, 0.1892325, 0.2511234], atol=1e-7)
    assert table.timing == (0.001, 0.0)


def _two_segments(tmp_path) -> bytes:
    """Two complete big-endian segments of 400 samples each."""
    first = tdms_segment({"IMU": _node_at_rest()}, big_endian=True)
    return first + tdms_segment({"IMU": _node_at_rest()}, big_endian=True)


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda b, one: b[: len(b) - 100], "truncated TDMS file: segment 2 at byte {one} claims {rest} bytes after its "
         "lead-in; the file ends 100 bytes short (1 complete segment before it)"),
        (lambda b, one: b[: one + 20], "truncated TDMS file: segment 2 at byte {one} ends after 20 of its lead-in's "
         "28 bytes (1 complete segment before it)"),
        (lambda b, one: b[:100], "truncated TDMS file: segment 1 at byte 0 claims {rest} bytes after its lead-in; the "
         "file ends {short} bytes short"),
        (lambda b, one: b[:one] + b[one: one + 12] + b"\xff" * 8 + b[one + 20:], "unfinished TDMS file: segment 2 at "
         "byte {one} was never closed (its length is unset: the writer stopped while writing it)"),
        (lambda b, one: b + b"\r\n", "damaged TDMS file: segment 3 at byte {end} has no 'TDSm' lead-in (2 complete "
         "segments before it)"),
        (lambda b, one: b[:8] + struct.pack(">i", 4714) + b[12:], "not a TDMS file: segment 1 at byte 0 has version "
         "4714 (TDMS 1.0 is 4712, 2.0 is 4713, big-endian here)"),
        (lambda b, one: b"", "an empty file, not a TDMS file"),
    ],
)  # fmt: skip
def test_a_tdms_file_cut_short_unfinished_or_damaged_is_refused_in_one_line(tmp_path, capsys, damage, message):
    whole = _two_segments(tmp_path)
    one = len(whole) // 2
    (tmp_path / "run.tdms").write_bytes(damage(whole, one))
    assert _import(tmp_path, "run.tdms", *GYRO_RAD_S) == 2
    expected = message.format(one=one, rest=one - 28, short=one - 100, end=len(whole))
    assert expected in _error(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.tdms"]


def test_a_tdms_segment_whose_data_do_not_fill_its_channels_is_refused_not_cropped(tmp_path, capsys):
    segment = bytearray(tdms_segment({"IMU": _node_at_rest()}, big_endian=True))
    at = segment.index(b"'az'") + 4  # the last channel's raw data index claims one value more than is there
    assert struct.unpack(">IIIQ", segment[at : at + 20]) == (20, TDS_DOUBLE, 1, 400)
    segment[at : at + 20] = struct.pack(">IIIQ", 20, TDS_DOUBLE, 1, 401)
    (tmp_path / "run.tdms").write_bytes(bytes(segment))
    assert _import(tmp_path, "run.tdms", *GYRO_RAD_S) == 2
    line = _error(capsys)
    assert "damaged TDMS file: its data do not match what its metadata declares (npTDMS: 'Data size 19200" in line
    assert "attempt" not in line and "[nptdms" not in capsys.readouterr().err


@pytest.mark.parametrize("step", [0.0, -0.0125, math.inf, 1e300])
def test_tdms_waveform_timing_out_of_range_is_refused(tmp_path, capsys, step):
    from nptdms import ChannelObject, TdmsWriter

    node = _node_at_rest()
    with TdmsWriter(str(tmp_path / "run.tdms")) as writer:
        writer.write_segment([ChannelObject("IMU", k, v, properties={"wf_increment": step}) for k, v in node.items()])
    code = _import(tmp_path, "run.tdms", *GYRO_RAD_S)
    if step == 0.0:  # no timing at all: the file needs a time column or --rate-hz
        assert code == 2 and "no time column" in _error(capsys)
        return
    assert code == 2
    assert f"channel IMU/gx: waveform timing wf_increment = {step!r} s" in _error(capsys)


def _lvm(tmp_path, rows: int = 200) -> bytes:
    """A LabVIEW measurement file (Writer_Version 2, tab separated, one X column, CRLF line ends,
    six decimals) as LabVIEW's 'Write To Measurement File' writes it."""
    t = np.arange(rows) / 80
    head = [
        "LabVIEW Measurement\t", "Writer_Version\t2", "Reader_Version\t2", "Separator\tTab", "Decimal_Separator\t.",
        "Multi_Headings\tNo", "X_Columns\tOne", "Time_Pref\tRelative", "Operator\tlab", "Date\t2025/03/14",
        "Time\t10:21:07.5", "***End_of_Header***\t", "\t", "Channels\t3\t", f"Samples\t{rows}\t{rows}\t{rows}",
        "Date\t2025/03/14\t2025/03/14\t2025/03/14", "Time\t10:21:07.5\t10:21:07.5\t10:21:07.5",
        "X_Dimension\tTime\tTime\tTime", "X0\t0.0000000000000000E+0\t0.0000000000000000E+0\t0.0000000000000000E+0",
        "Delta_X\t1.000000\t1.000000\t1.000000", "***End_of_Header***\t", "X_Value\tCh0\tCh1\tCh2\tComment",
    ]  # fmt: skip
    rows_text = [f"{x:.6f}\t{np.sin(x):.6f}\t{np.cos(x):.6f}\t0.000000" for x in t]
    return ("\r\n".join(head + rows_text) + "\r\n").encode()


@pytest.mark.parametrize(
    ("cut", "message"),
    [
        (lambda b: b[:-12], "truncated LVM file: its last line (222) has no line end, as LabVIEW writes every line"),
        (lambda b: b[:600], "truncated LVM file: its last line (25) has no line end"),
        (lambda b: b[: b.index(b"\r\n1.250000\t") + 2], "truncated LVM file: the header declares 200 samples per "
         "channel, the file holds 100 rows (cut short, or rows removed by hand)"),
    ],
)  # fmt: skip
def test_an_lvm_file_cut_short_is_refused_in_one_line(tmp_path, capsys, cut, message):
    (tmp_path / "run.lvm").write_bytes(cut(_lvm(tmp_path)))
    args = ["import", str(tmp_path / "run.lvm"), "-o", str(tmp_path / "out.mcap"), "--columns", "t_s,m1.gx,m1.gy,m1.gz"]
    assert main(args) == 2
    assert message in _error(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.lvm"]
