"""pendsim import: a recorded run written to CSV, LabVIEW .lvm and TDMS files (by code here, in each
format's own conventions), imported back: values equal within the format's precision, and the
imported recording validates like the original."""

import math

import numpy as np
import pytest

from pendsim_bridge.cli import main
from pendsim_bridge.io.recording import read_recording
from pendsim_bridge.run.validate import validate

QUANTITIES = {  # name -> (recording field, component)
    **{f"q{a}": ("quat_wxyz", i) for i, a in enumerate("wxyz")},
    **{f"g{a}": ("gyro_rad_s", i) for i, a in enumerate("xyz")},
    **{f"a{a}": ("accel_m_s2", i) for i, a in enumerate("xyz")},
}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp("recorded") / "run.mcap"
    assert main(["record", "-o", str(path), "--duration-s", "6", "--hold-s", "2", "--seed", "4"]) == 0
    return path, read_recording(path)


def _columns(rec, *, gyro_scale=1.0):
    """The pendsim names and the (n, k) values of both nodes, time first."""
    names, values = ["t_s"], [rec.imu["m1"].t_ns * 1e-9]
    for node in ("m1", "m2"):
        imu = rec.imu[node]
        for name, (field, i) in QUANTITIES.items():
            names.append(f"{node}.{name}")
            values.append(getattr(imu, field)[:, i] * (gyro_scale if field == "gyro_rad_s" else 1.0))
        for name, store in (("la", rec.linear_accel_m_s2), ("gv", rec.gravity_m_s2)):
            for i, a in enumerate("xyz"):
                names.append(f"{node}.{name}{a}")
                values.append(store[node][1][:, i])
    return names, np.stack(values, axis=1)


def write_lvm(path, names, values, *, delta_x=None):
    """A LabVIEW measurement file (Writer_Version 2, tab separated, one X column), 6 decimals, the
    way LabVIEW's 'Write To Measurement File' writes it."""
    n, k = values.shape[0], len(names)
    tabs = lambda items: "\t".join(str(x) for x in items)  # noqa: E731
    head = [
        "LabVIEW Measurement\t", "Writer_Version\t2", "Reader_Version\t2", "Separator\tTab", "Decimal_Separator\t.",
        "Multi_Headings\tNo", "X_Columns\t" + ("No" if delta_x else "One"), "Time_Pref\tRelative",
        "Operator\tlab", "Date\t2025/03/14", "Time\t10:21:07.5", "***End_of_Header***\t", "\t",
        "Channels\t" + str(k) + "\t", "Samples\t" + tabs([n] * k), "Date\t" + tabs(["2025/03/14"] * k),
        "Time\t" + tabs(["10:21:07.5"] * k), "X_Dimension\t" + tabs(["Time"] * k),
        "X0\t" + tabs(["0.0000000000000000E+0"] * k), "Delta_X\t" + tabs([delta_x or 1.0] * k),
        "***End_of_Header***\t",
        ("" if delta_x else "X_Value\t") + tabs(names) + "\tComment",
    ]  # fmt: skip
    rows = ["\t".join(f"{v:.6f}" for v in row) for row in values]
    path.write_text("\r\n".join(head + rows) + "\r\n")


def test_csv_with_pendsim_names_round_trips_exactly_and_validates_like_the_original(recorded, tmp_path, capsys):
    original, rec = recorded
    names, values = _columns(rec)
    lines = [",".join(names)] + [",".join(repr(float(v)) for v in row) for row in values]
    (tmp_path / "lab.csv").write_text("# exported from the lab\n" + "\n".join(lines) + "\n")
    out = tmp_path / "imported.mcap"
    assert main(["import", str(tmp_path / "lab.csv"), "-o", str(out), "--units", "gyro=rad/s"]) == 0
    assert "wrote" in capsys.readouterr().out
    imported = read_recording(out)
    for node in ("m1", "m2"):
        np.testing.assert_array_equal(imported.imu[node].t_ns, rec.imu[node].t_ns)
        for field in ("quat_wxyz", "gyro_rad_s", "accel_m_s2"):
            np.testing.assert_array_equal(getattr(imported.imu[node], field), getattr(rec.imu[node], field))
        np.testing.assert_array_equal(imported.gravity_m_s2[node][1], rec.gravity_m_s2[node][1])
    meta = imported.metadata["pendsim/import"]
    assert meta["source_name"] == "lab.csv" and meta["format"] == "csv" and len(meta["source_sha256"]) == 64
    assert meta["source_file"] == str((tmp_path / "lab.csv").resolve())
    a = validate(original, damping="recorded").case("mujoco", "estimated", "whole").comparisons["phi1"]
    b = validate(out, damping="recorded").case("mujoco", "estimated", "whole").comparisons["phi1"]
    assert b.f_measured_hz == pytest.approx(a.f_measured_hz, rel=1e-4)  # release found a few ms apart: see docs
    assert a.delta_f < 0.005 and b.delta_f < 0.005
    assert b.max_abs < 0.02


def test_labview_lvm_file_round_trips_to_its_six_decimals(recorded, tmp_path):
    original, rec = recorded
    names, values = _columns(rec, gyro_scale=180 / math.pi)  # the lab logged the gyro in deg/s
    lab_names = [f"Ch{i}" for i in range(len(names) - 1)]
    write_lvm(tmp_path / "run.lvm", lab_names, values)
    columns = ",".join(names[:1] + names[1:])  # the X column is the time: t_s
    out = tmp_path / "imported.mcap"
    assert main(["import", str(tmp_path / "run.lvm"), "-o", str(out), "--columns", columns]) == 0
    assert not list(tmp_path.glob("*.pkl"))  # lvm-read's pickle cache is never written beside the file
    imported = read_recording(out)
    for node in ("m1", "m2"):
        np.testing.assert_allclose(imported.imu[node].t_ns, rec.imu[node].t_ns, atol=1000)  # 1 us
        np.testing.assert_allclose(imported.imu[node].accel_m_s2, rec.imu[node].accel_m_s2, atol=5e-7)
        np.testing.assert_allclose(imported.imu[node].gyro_rad_s, rec.imu[node].gyro_rad_s, atol=5e-7 * math.pi / 180)
    meta = imported.metadata["pendsim/import"]
    assert meta["format"] == "lvm" and meta["lvm_date"] == "2025/03/14"
    a = validate(original, damping="recorded").case("mujoco", "estimated", "whole").comparisons["phi1"]
    b = validate(out, damping="recorded").case("mujoco", "estimated", "whole").comparisons["phi1"]
    assert b.f_measured_hz == pytest.approx(a.f_measured_hz, rel=1e-5) and b.delta_f < 0.005


def test_tdms_file_with_waveform_timing_round_trips_exactly(recorded, tmp_path):
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    _, rec = recorded
    names, values = _columns(rec)
    objects = [RootObject(properties={"name": "pendulum run", "operator": "lab"})]
    columns = []
    for node, group in (("m1", "Front IMU"), ("m2", "Rear IMU")):
        objects.append(GroupObject(group))
        for j, name in enumerate(names):
            if name.startswith(node + "."):
                props = {"wf_increment": 1 / 80, "wf_start_offset": 0.0, "unit_string": "SI"}
                objects.append(ChannelObject(group, name.split(".")[1].upper(), values[:, j], properties=props))
                columns.append(name)
    with TdmsWriter(str(tmp_path / "run.tdms")) as writer:
        writer.write_segment(objects)
    out = tmp_path / "imported.mcap"
    args = ["import", str(tmp_path / "run.tdms"), "-o", str(out), "--columns", ",".join(columns)]
    args += ["--units", "gyro=rad/s"]
    assert main(args) == 0
    imported = read_recording(out)
    for node in ("m1", "m2"):
        np.testing.assert_allclose(imported.imu[node].t_ns, rec.imu[node].t_ns, atol=1)
        np.testing.assert_array_equal(imported.imu[node].gyro_rad_s, rec.imu[node].gyro_rad_s)
        np.testing.assert_array_equal(imported.linear_accel_m_s2[node][1], rec.linear_accel_m_s2[node][1])
    assert "file's timing" in imported.metadata["pendsim/import"]["time"]
    assert imported.metadata["pendsim/import"]["tdms_name"] == "pendulum run"


def test_a_one_node_csv_without_header_imports_with_a_column_map(tmp_path):
    rows = [f"{k * 12.5},{0.01 * k},0,0,1,0,0,0" for k in range(200)]
    (tmp_path / "m2.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "m2.mcap"
    columns = "t_ms,gz,gx,gy,qw,qx,qy,qz"
    args = ["import", str(tmp_path / "m2.csv"), "-o", str(out), "--node", "m2", "--columns", columns]
    assert main(args) == 0
    rec = read_recording(out)
    assert list(rec.imu) == ["m2"] and len(rec.imu["m2"].t_ns) == 200
    assert rec.imu["m2"].gyro_rad_s[10, 2] == pytest.approx(math.radians(0.1))  # default gyro unit: dps
    assert rec.imu["m2"].t_ns[1] == 12_500_000 and rec.imu["m2"].accel_covariance[0, 0, 0] == -1  # not provided


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("pendsim: error: ")
    return err[0]


@pytest.mark.parametrize(
    ("content", "args", "message"),
    [
        ("t_s,m1.gx,m1.gy\n0,1,2\n", [], "lab.csv: m1: the columns have gx, gy but not gz (a quantity needs all"),
        (
            "t_s,m1.gx,m1.gy,m1.gZ\n0,1,2,3\n",
            [],
            "lab.csv: column 4 'm1.gZ' is not a pendsim name (did you mean 'm1.gz'?)",
        ),
        ("t_s,AccX\n0,1\n", [], "column 2 'AccX' is not a pendsim name (t_s, m1.gx, ...); give --columns"),
        ("t_s,gx,gy,gz\n0,1,2,3\n", [], "say which node (m1.gx or m2.gx), or give --node"),
        (
            "a,b,c,d\n0,1,2,3\n",
            ["--columns", "t_s,m1.gx,m1.gy"],
            "lab.csv (--columns): the column map has 3 entries, the file 4",
        ),
        ("t_s,m1.gx,m1.gy,m1.gz\n0,1,2,3\n1,x,2,3\n", [], "line 3, column 2 ('m1.gx'): 'x' is not a number"),
        ("t_s,m1.gx,m1.gy,m1.gz,\n0,1,2,3,\n1,,2,3,\n2,1,2,3,\n", [], "line 3, column 2 ('m1.gx'): '' is not a number"),
        ("t_s,m1.gx,m1.gy,m1.gz\n0,1,2,3\n1,1,2\n2,1,2,3\n", [], "line 3 has 3 fields, the header 4"),
        ("boot ok\nt_s,m1.gx,m1.gy,m1.gz\n1,2,3\n", [], "no complete data line"),
        ("t_s,m1.gx,m1.gy,m1.gz\n0,1,2,3\n", ["--start-utc", "2026-11-25T10:00"], "has no time zone: end it in Z"),
        ("t_s,m1.gx,m1.gy,m1.gz\n0,1,2,3\n", ["--start-utc", "noon"], "is not an ISO 8601 time"),
        (
            "t_s,m1.gx,m1.gy,m1.gz\n1,1,2,3\n0,1,2,3\n",
            [],
            "time does not increase at line 3: t = 1.000000 s, then 0.000000 s (1 s back)",
        ),
        (
            "t_s,m1.gx,m1.gy,m1.gz\n1712345678.1,1,2,3\n1712345678.123456,1,2,3\n1712345678.1,1,2,3\n",
            [],
            "time does not increase at line 4: t = 1712345678.123456 s, then 1712345678.100000 s (23.456 ms back)",
        ),
        (
            "t_ms,m1.gx,m1.gy,m1.gz\n1000,1,2,3\n1012.5,1,2,3\n1012.499,1,2,3\n",
            [],
            "time does not increase at line 4: t = 1.0125000 s, then 1.0124990 s (1 us back)",
        ),
        ("t_s,m1.gx,m1.gy,m1.gz\n0,nan,2,3\n1,1,2,3\n", [], "line 2, column 'm1.gx': not a finite number"),
        ("m1.gx,m1.gy,m1.gz\n0,1,2\n", [], "no time column"),
        ("t_s,m1.gx,m1.gy,m1.gz\n0,1,2,3\n", ["--units", "gyro=rpm"], "unknown gyro unit 'rpm'"),
        ("t_s,m1.qw,m1.qx,m1.qy,m1.qz\n0,0,0,0,0\n", [], "line 2: the quaternion has norm 0, not 1"),
        (  # file lines, not data rows: the comment, the blank line and the header count
            "# lab run\n\nt_s,m1.gx,m1.gy,m1.gz\n0,1,2,3\n1,1,2,3\n1,1,2,3\n",
            [],
            "time does not increase at line 6: t = 1.000000 s, then 1.000000 s (the same time twice)",
        ),
    ],
)
def test_bad_lab_files_are_one_line_exit_2_and_write_nothing(tmp_path, capsys, content, args, message):
    (tmp_path / "lab.csv").write_text(content)
    assert main(["import", str(tmp_path / "lab.csv"), "-o", str(tmp_path / "out.mcap"), *args]) == 2
    assert message in _error(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lab.csv"]


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("junk.lvm", "not a labview file\n", "not a LabVIEW measurement file"),
        ("table.lvm", "t,a,b\n1,2,3\n", "as LabVIEW writes them: a 'LabVIEW Measurement' header whose Separator"),
        ("junk.tdms", "TDSm garbage" * 10, "not a TDMS file"),
        ("junk.dat", "1,2,3\n", "cannot tell the format from the extension '.dat'"),
        ("empty.csv", "", "no data lines"),
    ],
)
def test_files_that_are_not_what_they_claim_are_refused(tmp_path, capsys, name, content, message):
    (tmp_path / name).write_text(content)
    assert main(["import", str(tmp_path / name), "-o", str(tmp_path / "out.mcap")]) == 2
    assert message in _error(capsys)
    assert not (tmp_path / "out.mcap").exists()


def _millis_csv(path, rows: int = 401, boot_ms: int = 123_456) -> np.ndarray:
    """One node's CSV as an Arduino sketch prints it with millis(): times from the node's boot."""
    t_ms = boot_ms + 12.5 * np.arange(rows)
    path.write_text("t_ms,gx,gy,gz\n" + "".join(f"{t},{0.01 * k:g},0,0\n" for k, t in enumerate(t_ms)))
    return t_ms


def _tf_static_and_imu_log_times(path):
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        times = [(channel.topic, message.log_time) for _, channel, message in make_reader(f).iter_messages()]
    return [t for topic, t in times if topic == "/tf_static"], [t for topic, t in times if topic == "/imu/m1"]


def test_boot_relative_times_keep_their_duration_and_start_utc_places_them(tmp_path, capsys):
    import datetime

    t_ms = _millis_csv(tmp_path / "node.csv")
    span_s = (t_ms[-1] - t_ms[0]) / 1e3
    relative, placed = tmp_path / "relative.mcap", tmp_path / "placed.mcap"
    assert main(["import", str(tmp_path / "node.csv"), "-o", str(relative), "--node", "m1"]) == 0
    err = capsys.readouterr().err
    assert "note: the times are not UTC (the first is 123.456 s)" in err
    assert "note: one node (m1): inspect and allan read the recording; validate, identify and view need both" in err
    tf, imu = _tf_static_and_imu_log_times(relative)
    assert tf == [imu[0]] and imu[0] == 123_456_000_000  # /tf_static with the first sample, not at 0
    assert main(["inspect", str(relative)]) == 0
    out = capsys.readouterr().out
    assert f"duration {span_s:.3f} s" in out and "log times are not UTC" in out

    args = ["import", str(tmp_path / "node.csv"), "-o", str(placed), "--node", "m1"]
    assert main([*args, "--start-utc", "2026-11-25T11:00:00+01:00"]) == 0
    assert "not UTC" not in capsys.readouterr().err
    start_ns = int(datetime.datetime(2026, 11, 25, 10, tzinfo=datetime.UTC).timestamp()) * 10**9
    tf, imu = _tf_static_and_imu_log_times(placed)
    assert tf == [start_ns] and imu[0] == start_ns
    np.testing.assert_array_equal(np.array(imu) - start_ns, np.rint((t_ms - t_ms[0]) * 1e6).astype(np.int64))
    rec = read_recording(placed)
    assert rec.metadata["pendsim/import"]["time_base"] == "utc: the first sample at 2026-11-25T10:00:00.000000Z"
    assert main(["inspect", str(placed)]) == 0
    out = capsys.readouterr().out
    assert f"duration {span_s:.3f} s" in out and "starts 2026-11-25T10:00:00.000000Z (log times are UTC)" in out


def test_boot_lines_trailing_commas_and_a_cut_last_line_are_left_out_with_a_note(tmp_path, capsys):
    t_ms = 1000 + 12.5 * np.arange(50)
    gyro_dps = 0.5 * np.arange(50)
    boot = "ets Jul 29 2019 12:21:46\nrst:0x1 (POWERON_RESET),boot:0x13\nBNO055 found\n"
    body = "".join(f"{t:g},{g:g},0,0,\n" for t, g in zip(t_ms, gyro_dps, strict=True))
    (tmp_path / "serial.csv").write_text(boot + "t_ms,gx,gy,gz,\n" + body + "1625,0.5,0.")  # the logger stopped
    out = tmp_path / "serial.mcap"
    assert main(["import", str(tmp_path / "serial.csv"), "-o", str(out), "--node", "m1"]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if line.startswith("note: ")]
    assert notes[:3] == [
        "note: skipped lines 1-3 before the header: not data",
        "note: 51 line(s) end in ',': the empty field after it is not a column",
        "note: dropped the last line 55: cut short (3 of 4 fields)",
    ]
    imu = read_recording(out).imu["m1"]
    assert len(imu.t_ns) == 50
    np.testing.assert_allclose(imu.gyro_rad_s[:, 0], np.radians(gyro_dps), rtol=1e-15)
    np.testing.assert_array_equal(imu.t_ns - imu.t_ns[0], np.rint((t_ms - t_ms[0]) * 1e6).astype(np.int64))


def test_lvm_errors_name_no_option_import_lacks(tmp_path, capsys):
    (tmp_path / "table.csv").write_text("t,a,b\n1,2,3\n")
    assert main(["import", str(tmp_path / "table.csv"), "--format", "lvm", "-o", str(tmp_path / "out.mcap")]) == 2
    line = _error(capsys)
    assert "not a LabVIEW measurement file" in line and "a plain table is --format csv" in line
    assert "pass the separator" not in line


def test_a_bad_value_in_an_lvm_file_is_named_by_its_file_line(tmp_path, capsys):
    values = np.array([[0.0, 1.0, 2.0, 3.0], [0.0125, 1.0, 2.0, 3.0], [0.025, 1.0, math.nan, 3.0]])
    write_lvm(tmp_path / "run.lvm", ["Ch0", "Ch1", "Ch2"], values)
    lines = (tmp_path / "run.lvm").read_text().splitlines()
    expected = next(i for i, line in enumerate(lines, start=1) if line.startswith("0.025000"))
    args = ["import", str(tmp_path / "run.lvm"), "-o", str(tmp_path / "out.mcap"), "--columns", "t_s,m1.gx,m1.gy,m1.gz"]
    assert main(args) == 2
    assert f"line {expected}, column 'Ch1': not a finite number" in _error(capsys)


def _arduino_csv(path, rows: int, *, accel_m_s2=(0.0, 0.0, 9.81), drop=()) -> np.ndarray:
    """One node at rest logged at 80 Hz by a sketch stamping millis(): t_ms = floor(12.5 k), steps
    of 12 and 13 ms; ``drop`` lists lost samples (numbers k)."""
    rng = np.random.default_rng(7)
    k = np.setdiff1d(np.arange(rows), np.asarray(drop, dtype=int))
    t_ms = np.floor(123_456 + 12.5 * k).astype(np.int64)
    gyro = rng.normal(0.0, 0.05, (len(k), 3))
    accel = np.asarray(accel_m_s2) + rng.normal(0.0, 0.01, (len(k), 3))
    body = "".join(
        f"{t},{g[0]:.5f},{g[1]:.5f},{g[2]:.5f},{a[0]:.5f},{a[1]:.5f},{a[2]:.5f}\n"
        for t, g, a in zip(t_ms, gyro, accel, strict=True)
    )
    path.write_text("t_ms,gx,gy,gz,ax,ay,az\n" + body)
    return t_ms


def test_millis_stamps_at_80_hz_give_80_hz_not_the_median_step(tmp_path, capsys):
    from pendsim_mj.estimation.timing import DEFAULT_MAX_GAP_S, coverage, nominal_rate_hz

    t_ms = _arduino_csv(tmp_path / "node.csv", 2000)  # an even count: 1000 steps of 12 ms, 999 of 13 ms
    steps = np.diff(t_ms)
    assert np.count_nonzero(steps == 12) == np.count_nonzero(steps == 13) + 1  # the median is 12 ms: 83.3 Hz
    out = tmp_path / "node.mcap"
    assert main(["import", str(tmp_path / "node.csv"), "-o", str(out), "--node", "m1"]) == 0
    capsys.readouterr()
    rec = read_recording(out)
    written = rec.metadata["pendsim/imu"]["sample_rate_hz"]
    assert float(written) == pytest.approx(80.0, abs=1e-3) and len(written) <= len("80.000001")
    t_s = rec.imu["m1"].t_ns * 1e-9
    assert nominal_rate_hz(t_s) == pytest.approx(80.0, abs=1e-3)
    assert coverage(t_s, DEFAULT_MAX_GAP_S, nominal_rate_hz(t_s)).lost_fraction == 0.0  # validate's share lost
    assert main(["allan", str(out), "--json"]) == 0
    import json

    assert json.loads(capsys.readouterr().out)["rate_hz"] == pytest.approx(80.0, abs=1e-3)


def test_lost_samples_are_gaps_not_a_slower_rate(tmp_path):
    from pendsim_mj.estimation.timing import DEFAULT_MAX_GAP_S, coverage, nominal_rate_hz

    t_ms = _arduino_csv(tmp_path / "node.csv", 2000, drop=range(500, 540))  # 40 samples lost in one burst
    t_s = t_ms * 1e-3
    assert nominal_rate_hz(t_s) == pytest.approx(80.0, abs=1e-3)
    assert coverage(t_s, DEFAULT_MAX_GAP_S, nominal_rate_hz(t_s)).lost_fraction == pytest.approx(40 / 2000, abs=1e-3)


def test_a_file_without_quaternions_is_noted_as_unfit_for_validate(tmp_path, capsys):
    _arduino_csv(tmp_path / "node.csv", 200)
    assert main(["import", str(tmp_path / "node.csv"), "-o", str(tmp_path / "n.mcap"), "--node", "m1"]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if line.startswith("note: ")]
    assert (
        "note: no orientation (quaternion columns qw,qx,qy,qz): validate, identify and view need it; "
        "inspect and allan read the recording"
    ) in notes
    assert not any("far from g" in n for n in notes)  # m/s2 read as m/s2: no unit note


@pytest.mark.parametrize(
    ("accel_m_s2", "units", "measured", "fix"),
    [
        ((0.0, 0.0, 9.81), "accel=g", "read as accel=g, measures 96.2 m/s2", "the values are in m/s2: give --units "
         "accel=m/s2,gyro=dps"),
        ((0.0, 0.0, 1.0), "accel=m/s2", "read as accel=m/s2, measures 1 m/s2", "the values are in g: give --units "
         "accel=g,gyro=dps"),
        ((0.0, 0.0, 1000.0), "accel=m/s2", "read as accel=m/s2, measures 1000 m/s2", "the values are in mg (also the "
         "BNO055's raw counts in its mg mode) (or the BNO055's raw counts in its m/s2 mode (100 per m/s2), "
         "accel=raw-m/s2: too close to tell apart): give --units accel=mg,gyro=dps"),
    ],
)  # fmt: skip
def test_an_acceleration_far_from_g_is_a_unit_mix_up_named_with_its_fix(
    tmp_path, capsys, accel_m_s2, units, measured, fix
):
    _arduino_csv(tmp_path / "node.csv", 200, accel_m_s2=accel_m_s2)
    args = ["import", str(tmp_path / "node.csv"), "-o", str(tmp_path / "n.mcap"), "--node", "m1", "--units", units]
    assert main(args) == 2
    line = _error(capsys)
    assert f"the units do not fit the data: m1: gravity, {measured}" in line and "by the accelerometer" in line
    assert line.endswith(f"{fix} (or --trust-units to import with the units given)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["node.csv"]
    if accel_m_s2[2] > 327.67:  # beyond what the chip can report: refused even so
        assert main([*args, "--trust-units"]) == 2
        line = _error(capsys)
        assert (
            "(read as accel=m/s2) is beyond what a BNO055 can report (327.67 m/s2 = 33.4 g); in mg or raw-m/s2" in line
        )
        return
    assert main([*args, "--trust-units"]) == 0  # the user insists: a warning, and the metadata says so
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning: ")]
    assert (
        len(warnings) == 1
        and measured in warnings[0]
        and "imported as given (--trust-units; give --units" in warnings[0]
    )
    meta = read_recording(tmp_path / "n.mcap").metadata["pendsim/import"]
    assert measured in meta["units_trusted_over"] and meta["units"] == units + ",gyro=dps"


@pytest.mark.parametrize("name", ["lab.csv", "run.LVM", "run.tdms"])
def test_a_lab_file_given_as_a_recording_points_to_import(tmp_path, capsys, name):
    (tmp_path / name).write_text("t_s,m1.gx,m1.gy,m1.gz\n0,1,2,3\n")
    assert main(["validate", str(tmp_path / name)]) == 2
    assert f"not an MCAP file (no MCAP magic at the start); a {name.split('.')[1].upper()} lab file becomes" in (
        line := _error(capsys)
    )
    assert f"'pendsim import {tmp_path / name} -o run.mcap'" in line
    from pendsim_bridge.io.recording import read_recording as read

    with pytest.raises(Exception, match="pendsim import"):
        read(tmp_path / name)


def test_other_non_mcap_inputs_get_no_import_hint(tmp_path, capsys):
    (tmp_path / "notes.mcap").write_text("hello, not a recording\n")
    assert main(["inspect", str(tmp_path / "notes.mcap")]) == 2
    assert "pendsim import" not in _error(capsys)
