"""Streaming record: block by block equals one pass, for both engines, the spatial model, a hold
and a static test; Ctrl-C and SIGTERM stop a real recording process within 0.5 s and leave a
complete file of what was recorded."""

import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from pendsim_bridge.io.mcap.reader import read_mcap
from pendsim_bridge.io.recording import read_recording
from pendsim_bridge.run.record import RecordSpec, record
from pendsim_mj.engines import dispatch as engines
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, ImuNoise, ImuSampler, sample_imu

T0 = 1_750_000_000_000_000_000
NOISY = Bno055(
    seed=11,
    noise_model=ImuNoise(
        gyro_bias_walk_rad_s_per_sqrt_s=(1e-4, 2e-4, 3e-4),
        accel_bias_instability_m_s2=(1e-3, 1e-3, 2e-3),
    ),
)


@pytest.mark.parametrize(
    ("engine", "spatial", "config"),
    [
        ("mujoco", False, NOISY),
        ("reference", False, NOISY),
        ("mujoco", True, Bno055(seed=4)),
        ("mujoco", False, Bno055(fusion_timing=False, seed=5)),
    ],
)
def test_blocked_sampling_equals_one_pass_over_the_whole_run(engine, spatial, config):
    phi0, omega0, duration, dt, hold = (0.5, -0.2), (0.0, 0.3), 7.0, 0.01, 0.6
    one = sample_imu(engines.run(engine, DEFAULT_PARAMS, phi0, omega0, duration, dt, spatial=spatial), config,
                     hold_s=hold)  # fmt: skip
    sampler = ImuSampler(config, DEFAULT_PARAMS, end_t_s=round(duration / dt) * dt, hold_s=hold)
    parts = []
    blocks = engines.run_blocks(engine, DEFAULT_PARAMS, phi0, omega0, duration, dt, block_steps=37, spatial=spatial)
    for first, traj in blocks:
        parts.append(sampler.block(traj, first_row=first, last=first + len(traj.t_s) - 1 == round(duration / dt)))
    for name in ("t_s", "fused_t_s", "gyro_rad_s", "accel_m_s2", "linear_accel_m_s2", "gravity_m_s2", "quat_wxyz"):
        blocked = np.concatenate([getattr(p, name) for p in parts])
        assert blocked.shape == getattr(one, name).shape, name
        np.testing.assert_allclose(blocked, getattr(one, name), rtol=0, atol=1e-12, err_msg=name)


@pytest.mark.parametrize(
    "spec",
    [
        RecordSpec(duration_s=6.0, hold_s=1.0, imu=NOISY),
        RecordSpec(duration_s=6.0, engine="reference", imu=Bno055(noise=False)),
        RecordSpec(duration_s=4.0, model="spatial", hold_s=0.5),
        RecordSpec(duration_s=5.0, model="static", imu=NOISY),
    ],
    ids=["mujoco-hold-noise", "reference", "spatial", "static"],
)
def test_a_recording_made_in_small_blocks_equals_one_made_in_one_block(tmp_path, spec):
    small, whole = tmp_path / "small.mcap", tmp_path / "whole.mcap"
    record(spec, small, start_time_ns=T0, block_s=0.37)
    record(spec, whole, start_time_ns=T0, block_s=1e6)
    a, b = read_recording(small), read_recording(whole)
    for node in ("m1", "m2"):
        for field in ("t_ns", "gyro_rad_s", "accel_m_s2", "quat_wxyz"):
            np.testing.assert_allclose(getattr(a.imu[node], field), getattr(b.imu[node], field), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(a.calibration[node][0], b.calibration[node][0])
    if spec.model != "static":
        np.testing.assert_allclose(a.joint_states.position_rad, b.joint_states.position_rad, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(a.joint_states.t_ns, b.joint_states.t_ns)
    assert read_mcap(small, strict=True).chunks > read_mcap(whole, strict=True).chunks  # flushed as it went


def _start_recording(tmp_path, *extra: str) -> tuple[subprocess.Popen, object]:
    out = tmp_path / "long.mcap"
    cmd = [sys.executable, "-m", "pendsim_bridge.cli", "record", "-o", str(out), "--duration-s", "36000", *extra]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # wait until some blocks are on disk (the hidden partial file)
        partial = [p for p in tmp_path.iterdir() if p.name.startswith(".long.mcap.")]
        if partial and partial[0].stat().st_size > 500_000:
            return proc, out
        time.sleep(0.05)
    proc.kill()
    raise AssertionError("the recording did not start writing within 60 s")


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupted_record_stops_within_half_a_second_and_keeps_what_it_recorded(tmp_path, signum):
    proc, out = _start_recording(tmp_path)
    sent = time.monotonic()
    proc.send_signal(signum)
    try:
        line = proc.stderr.readline()  # printed once the file is complete and published
        reacted = time.monotonic() - sent
        proc.wait(timeout=20)  # then the interpreter tears down (about 1 s with every command imported)
    finally:
        proc.kill()
    err = [line.strip(), *proc.stderr.read().strip().splitlines()]
    assert proc.returncode == 130, err
    assert reacted < 0.5, f"took {reacted:.2f} s to stop and publish"
    assert len(err) == 1 and err[0].startswith("pendsim: interrupted after") and "long.mcap holds the first" in err[0]
    rec = read_recording(out)  # a complete, verified file
    stopped = rec.metadata["pendsim/interrupted"]
    recorded = float(stopped["recorded_s"])
    assert float(stopped["requested_s"]) == 36000.0 and 0 < recorded < 36000
    assert rec.imu["m1"].t_s[-1] == pytest.approx(recorded, abs=1e-9)
    assert [p.name for p in tmp_path.iterdir()] == ["long.mcap"]  # no partial file left behind


@pytest.mark.parametrize("engine", ["mujoco", "reference"])
def test_a_driven_run_in_blocks_equals_one_run(engine):
    from pendsim_mj.rig.drives import Drive, Sine

    drive = Drive(torque_m1=Sine(0.002, 0.8), support_x=Sine(0.3, 1.1))
    one = engines.run(engine, DEFAULT_PARAMS, (0.3, 0.0), (0.0, 0.0), 5.0, 0.01, drive=drive)
    for first, block in engines.run_blocks(
        engine, DEFAULT_PARAMS, (0.3, 0.0), (0.0, 0.0), 5.0, 0.01, block_steps=83, drive=drive
    ):
        rows = slice(first, first + len(block.t_s))
        for name in ("phi_rad", "omega_rad_s", "imu_accel_m_s2", "support_m", "drive_input"):
            np.testing.assert_allclose(getattr(block, name), getattr(one, name)[rows], rtol=0, atol=1e-12, err_msg=name)
