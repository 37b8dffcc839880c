"""Rerun views read back with Rerun's own reader: entity paths, rows per timeline, values; bad
files fail fast (serving: test_serve.py)."""

import collections
import itertools
import math
import time

import numpy as np
import pytest
import rerun as rr
from mcap.reader import make_reader

from pendsim_bridge.cli import main
from pendsim_bridge.io.measured import align_recording, recorded_params
from pendsim_bridge.io.recording import read_recording


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


def _times_with(path, entity, *components):
    """Per component, the sorted instants (s) at which ``entity`` has a value of it."""
    found = {c: [] for c in components}
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        if str(chunk.entity_path) == entity and not chunk.is_static:
            batch = chunk.to_record_batch()
            for c in components:
                if c in batch.schema.names:
                    found[c].append(batch.column("time").cast("int64").to_numpy())
    return [np.sort(np.concatenate(found[c])) for c in components]


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
    assert steps == rows["/rig/m2"] == rows["/plots/phi1/model"] > 1900
    # the springs' strips as the run is logged, their colours once the run's tension range is known
    strips, colours = _times_with(rrd, "/rig/springs", "LineStrips3D:strips", "LineStrips3D:colors")
    assert len(strips) == steps and np.array_equal(strips, colours)
    # the measured series, one row per IMU sample after the release
    rec = read_recording(recording)
    run = align_recording(rec, recorded_params(rec))
    for q in ("phi1", "omega1", "omega2", "tangential_m1", "normal_m1"):
        assert rows[f"/plots/{q}/measured"] == len(run.series(q)[0]), q
    t, phi1 = values["/plots/phi1/measured"]
    order = np.argsort(t)
    np.testing.assert_allclose(phi1[order], run.series("phi1")[1], atol=1e-9)
    np.testing.assert_allclose(t[order], run.series("phi1")[0], atol=1e-9)
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
            indexes = make_reader(f).get_summary().chunk_indexes
            chunk = indexes[(len(data) % 7 + 3) % len(indexes)]
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


def test_the_view_gathers_a_model_run_from_its_blocks_as_from_the_whole_run(monkeypatch):
    from pendsim_bridge.report import rerun_view
    from pendsim_mj.engines.simulation import simulate, simulate_blocks
    from pendsim_mj.estimation.validation import resample

    logged, springs = [], []
    monkeypatch.setattr(rerun_view, "log_trajectory", lambda block, model, springs: logged.append(block.t_s))
    monkeypatch.setattr(rerun_view, "log_springs", lambda model, t_s, *args: springs.append(t_s))
    whole = simulate(duration_s=2.0)
    at = np.sort(np.random.default_rng(0).uniform(0.0, 2.0, 500))  # measured instants, anywhere
    phi1_at = rerun_view._ModelAtInstants(at)
    kept, moving = rerun_view._log_blocks(simulate_blocks(duration_s=2.0, block_steps=30), None, phi1_at)
    assert np.array_equal(np.concatenate(logged), whole.t_s) and np.array_equal(np.concatenate(springs), whole.t_s)
    assert np.array_equal(kept["t_s"], whole.t_s) and not moving
    for name, values in (
        ("phi_rad", whole.phi_rad),
        ("omega_rad_s", whole.omega_rad_s),
        ("force_n", whole.spring_force_n),
    ):
        assert np.array_equal(kept[name], values.astype(np.float32)), name
    # phi1 at the instants, block by block: one cubic spline through the whole run
    np.testing.assert_allclose(phi1_at.finish(), resample(whole.t_s, whole.phi_rad[:, 0], at), rtol=0, atol=1e-13)


def _log_windows(count: int, rows: int = 50_000) -> None:
    rng = np.random.default_rng(0)
    for k in range(count):
        times = rr.TimeColumn("time", duration=np.arange(k * rows, (k + 1) * rows) * 0.01)
        rr.send_columns("/plots/x", indexes=[times], columns=rr.Scalars.columns(scalars=rng.normal(size=rows)))


def _unpublished_bytes(folder, published):
    return sum(f.stat().st_size for f in folder.iterdir() if f.is_file() and f != published)


def test_the_rrd_is_written_to_disk_while_it_is_logged_and_opens_in_rerun(tmp_path):
    # the proxy for memory flat with duration: the bytes reach the disk while logging goes on,
    # under a temporary name (the file itself appears only when the block ends)
    import subprocess
    import sys
    from pathlib import Path

    from pendsim_bridge.report.rerun_view import rrd_output

    out = tmp_path / "stream.rrd"
    on_disk = []
    with rrd_output(out, series=None):
        for _ in range(8):
            _log_windows(1)
            rr.get_global_data_recording().flush(timeout_sec=10)
            deadline = time.monotonic() + 10
            while _unpublished_bytes(tmp_path, out) <= (on_disk[-1] if on_disk else 0) and time.monotonic() < deadline:
                time.sleep(0.01)
            on_disk.append(_unpublished_bytes(tmp_path, out))
        assert not out.exists()
    assert all(b > a for a, b in itertools.pairwise(on_disk)), on_disk  # grew with every window
    assert on_disk[-1] > 0.8 * out.stat().st_size and list(tmp_path.iterdir()) == [out]
    rows, _, values = _read_rrd(out)
    assert rows["/plots/x"] == 8 * 50_000 and len(values["/plots/x"][0]) == 8 * 50_000
    rerun = Path(sys.executable).with_name("rerun")  # the real Rerun CLI checks every chunk
    verified = subprocess.run([str(rerun), "rrd", "verify", str(out)], capture_output=True, text=True, timeout=120)
    assert verified.returncode == 0, verified.stderr


def test_without_named_pipes_the_rrd_is_written_at_the_end(tmp_path, monkeypatch):
    from pendsim_bridge.report.rerun_view import rrd_output

    monkeypatch.delattr("os.mkfifo")  # as on Windows
    out = tmp_path / "buffered.rrd"
    with rrd_output(out, series=None):
        _log_windows(2)
    rows, _, _ = _read_rrd(out)
    assert rows["/plots/x"] == 2 * 50_000 and list(tmp_path.iterdir()) == [out]


def test_a_failure_while_logging_leaves_no_file_and_ends_the_copy(tmp_path):
    import threading

    from pendsim_bridge.report.rerun_view import rrd_output

    out = tmp_path / "failed.rrd"
    with pytest.raises(RuntimeError, match="stop"), rrd_output(out, series=None):
        _log_windows(1)
        raise RuntimeError("stop")
    assert list(tmp_path.iterdir()) == [] and not any(t.name == "rrd-copy" for t in threading.enumerate())


@pytest.mark.parametrize("n", [24_000, 24_004])  # the last window full, or too short and joined
def test_the_phi1_error_in_windows_equals_one_whole_run_comparison(n):
    from pendsim_bridge.report.rerun_view import error_in_windows
    from pendsim_mj.estimation.validation import compare

    rng = np.random.default_rng(1)
    t = np.delete(np.arange(n + 40) * 0.0125, np.arange(10_000, 10_040))  # a 0.5 s gap
    measured = 0.5 * np.cos(2 * np.pi * 0.86 * t) * np.exp(-t / 200) + 1e-3 * rng.normal(size=len(t))
    computed = 0.5 * np.cos(2 * np.pi * 0.861 * t) * np.exp(-t / 190)
    whole = compare(t, measured, computed, max_gap_s=0.1)
    parts = list(error_in_windows(t, measured, computed, max_gap_s=0.1, window=1000))
    assert len(parts) == 24 and all(len(p[0]) >= 8 for p in parts)
    t_w, delta, iae, ise = (np.concatenate([p[k] for p in parts]) for k in range(4))
    assert np.array_equal(t_w, whole.t_s) and np.array_equal(delta, whole.delta)  # every instant once
    np.testing.assert_allclose(iae, whole.iae_curve, rtol=0, atol=1e-9 * whole.iae)
    np.testing.assert_allclose(ise, whole.ise_curve, rtol=0, atol=1e-9 * whole.ise)


def test_view_takes_o_like_every_command_and_still_takes_save(recording, tmp_path):
    for flag in ("-o", "--output", "--save"):
        rrd = tmp_path / f"{flag.strip('-')}.rrd"
        assert main(["view", str(recording), flag, str(rrd)]) == 0
        assert rrd.stat().st_size > 0
