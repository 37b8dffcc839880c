"""Rerun views read back with Rerun's own reader: entity paths, rows per timeline, values; bad
files fail fast; --serve listens on loopback only."""

import collections
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from mcap.reader import make_reader

from bridge.cli import main
from bridge.recording import read_recording
from bridge.validate import align, recorded_params


def _read_rrd(path):
    rows, static, values = collections.Counter(), collections.Counter(), {}
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        entity = str(chunk.entity_path)
        (static if chunk.is_static else rows)[entity] += chunk.num_rows
        if not chunk.is_static and entity.startswith("/plots/"):
            batch = chunk.to_record_batch()
            t = batch.column("time").cast("int64").to_numpy() * 1e-9
            v = np.array([x[0] for x in batch.column("Scalars:scalars").to_pylist()])
            previous = values.get(entity, (np.zeros(0), np.zeros(0)))
            values[entity] = (np.concatenate([previous[0], t]), np.concatenate([previous[1], v]))
    return rows, static, values


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("view") / "run.mcap"
    assert main(["record", "-o", str(path), "--duration-s", "20", "--hold-s", "1"]) == 0
    return path


def test_view_writes_the_rig_and_measured_against_model_series(recording, tmp_path):
    rrd = tmp_path / "run.rrd"
    assert main(["view", str(recording), "--save", str(rrd)]) == 0
    rows, static, values = _read_rrd(rrd)
    # the rig from the model's geometry, posed at every 10 ms step of the model run
    for entity in ("/rig/frame/geoms", "/rig/m1/geoms", "/rig/m2/geoms", "/rig/m1/points", "/rig/m1/imu_m1"):
        assert static[entity] == 1, entity
    steps = rows["/rig/m1"]
    assert steps == rows["/rig/m2"] == rows["/rig/springs"] == rows["/plots/phi1/model"] > 1900
    # the measured series, one row per IMU sample after the release
    rec = read_recording(recording)
    run = align(rec, recorded_params(rec))
    for q in ("phi1", "omega1", "omega2", "tangential_m1", "normal_m1"):
        assert rows[f"/plots/{q}/measured"] == len(run.t_s), q
    t, phi1 = values["/plots/phi1/measured"]
    order = np.argsort(t)
    np.testing.assert_allclose(phi1[order], run.series["phi1"], atol=1e-9)
    np.testing.assert_allclose(t[order], run.t_s, atol=1e-9)
    for name in ("delta", "iae", "ise"):
        assert rows[f"/plots/error_phi1/{name}"] > 1500
    assert static["/phase/m1/measured"] == static["/phase/m1/model"] == 1


def test_simulate_rerun_logs_the_run_through_the_same_path(tmp_path, capsys):
    rrd = tmp_path / "sim.rrd"
    assert main(["simulate", "--duration-s", "3", "--rerun", str(rrd)]) == 0
    rows, static, values = _read_rrd(rrd)
    assert rows["/rig/m1"] == rows["/rig/springs"] == rows["/plots/phi1/model"] == 301
    t, phi1 = values["/plots/phi1/model"]
    assert phi1[np.argmin(t)] == pytest.approx(math.radians(30), abs=1e-12)
    assert static["/rig/m2/geoms"] == 1


@pytest.mark.parametrize("damage", ["truncate", "corrupt", "garbage"])
def test_view_refuses_damaged_files_quickly_with_one_line(recording, tmp_path, capsys, damage):
    data = bytearray(recording.read_bytes())
    bad = tmp_path / "bad.mcap"
    if damage == "truncate":
        bad.write_bytes(bytes(data[: len(data) // 2]))
    elif damage == "corrupt":  # a flipped byte inside a chunk's compressed data
        with open(recording, "rb") as f:
            chunk = make_reader(f).get_summary().chunk_indexes[len(data) % 7 + 3]
        data[chunk.chunk_start_offset + chunk.chunk_length - 30] ^= 0xFF
        bad.write_bytes(bytes(data))
    else:
        bad.write_bytes(b"\x00" * 5000)
    start = time.perf_counter()
    assert main(["view", str(bad), "--save", str(tmp_path / "bad.rrd")]) == 2
    assert time.perf_counter() - start < 30
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.mcap" in err[0]
    assert not (tmp_path / "bad.rrd").exists()


def _listening(port: int) -> list[str]:
    """Local addresses listening on a TCP port, from /proc/net/tcp (IPv4)."""
    found = []
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        address, hex_port = local.split(":")
        if state == "0A" and int(hex_port, 16) == port:
            found.append(".".join(str(int(address[i : i + 2], 16)) for i in (6, 4, 2, 0)))
    return found


def test_serve_listens_on_loopback_only(recording, tmp_path):
    port = 19300
    exe = str(Path(sys.executable).with_name("pendsim"))
    command = [exe, "view", str(recording), "--save", str(tmp_path / "s.rrd"), "--serve", "--port", str(port)]
    proc = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env={"HOME": str(tmp_path), "PATH": "/usr/bin:/bin"}
    )
    try:
        deadline = time.time() + 60
        while time.time() < deadline and not (_listening(port) and _listening(port + 1)):
            time.sleep(0.2)
        assert _listening(port) == ["127.0.0.1"] and _listening(port + 1) == ["127.0.0.1"]
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def test_demo_runs_the_whole_chain_and_says_where_everything_is(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "-o", str(out), "--duration-s", "20"]) == 0
    text = capsys.readouterr().out
    names = {p.name for p in out.iterdir()}
    assert {"run.mcap", "report.json", "run.rrd"} <= names
    assert len([n for n in names if n.startswith("fig") and n.endswith(".png")]) == 7
    assert f"Rerun         {out / 'run.rrd'}" in text and "report" in text
    assert read_recording(out / "run.mcap").complete
    rows, static, _ = _read_rrd(out / "run.rrd")
    assert rows["/rig/m1"] > 1900 and static["/rig/m1/geoms"] == 1


def test_demo_refuses_a_file_as_its_folder(tmp_path, capsys):
    target = tmp_path / "taken"
    target.write_text("x")
    assert main(["demo", "-o", str(target)]) == 2
    assert "is a file" in capsys.readouterr().err
