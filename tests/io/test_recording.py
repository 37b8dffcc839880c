"""A recorded run read back: values, conventions, metadata, re-simulation from the file alone,
and interop with mcap_ros2 and Rerun's own MCAP loader."""

import collections
import math
import shutil
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mujoco import rollout

from pendsim_bridge.io.recording import RunInfo, read_recording, write_recording
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.rig.model import exact_mjcf
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import Bno055, sample_imu

DURATION_S = 20.0
PHI0 = (math.radians(30), 0.0)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    params = DEFAULT_PARAMS.with_overrides(b2_n_m_s=0.0004)
    traj = simulate(params, PHI0, (0.0, 0.0), DURATION_S)
    imu = sample_imu(traj, Bno055(seed=5))
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    run = RunInfo("mujoco", PHI0, (0.0, 0.0), DURATION_S, 0.01)
    write_recording(path, imu, run, exact_mjcf(params), params, traj=traj)
    return path, traj, imu, params


def test_every_topic_reads_back_exactly(recorded):
    path, traj, imu, _ = recorded
    rec = read_recording(path)
    assert rec.complete
    for k, node in enumerate(("m1", "m2")):
        topic = rec.imu[node]
        np.testing.assert_array_equal(topic.gyro_rad_s, imu.gyro_rad_s[:, k])
        np.testing.assert_array_equal(topic.accel_m_s2, imu.accel_m_s2[:, k])
        unit = imu.quat_wxyz[:, k] / np.linalg.norm(imu.quat_wxyz[:, k], axis=-1, keepdims=True)
        np.testing.assert_array_equal(topic.quat_wxyz, unit)  # the chip's quaternion, normalised
        np.testing.assert_array_equal(rec.linear_accel_m_s2[node][1], imu.linear_accel_m_s2[:, k])
        np.testing.assert_array_equal(rec.gravity_m_s2[node][1], imu.gravity_m_s2[:, k])
        assert topic.frame_id == f"imu_{node}"
    np.testing.assert_array_equal(rec.joint_states.position_rad, traj.phi_rad)
    np.testing.assert_array_equal(rec.joint_states.velocity_rad_s, traj.omega_rad_s)
    np.testing.assert_array_equal(rec.joint_states.effort_n_m, traj.spring_moment_n_m)


@pytest.mark.parametrize("fields", [("gyro_rad_s", "accel_m_s2"), ("stamp_ns", "quat_wxyz", "gyro_covariance")])
def test_chosen_imu_fields_read_the_same_values_and_leave_the_others_empty(recorded, fields):
    path, _, imu, _ = recorded
    full = read_recording(path)
    part = read_recording(path, imu_fields=fields)
    names = ("stamp_ns", "quat_wxyz", "gyro_rad_s", "accel_m_s2", "orientation_covariance", "gyro_covariance")
    for node in ("m1", "m2"):
        np.testing.assert_array_equal(part.imu[node].t_ns, full.imu[node].t_ns)  # log times always
        assert len(part.imu[node].t_ns) == len(imu.t_s)
        for name in names:
            got, want = getattr(part.imu[node], name), getattr(full.imu[node], name)
            if name in fields:
                np.testing.assert_array_equal(got, want)
            else:
                assert got.shape == (0, *want.shape[1:])
    np.testing.assert_array_equal(part.joint_states.position_rad, full.joint_states.position_rad)  # other topics whole


def test_timestamps_are_integer_nanoseconds_on_the_sample_grid(recorded):
    path, traj, imu, _ = recorded
    rec = read_recording(path)
    for node in ("m1", "m2"):
        assert rec.imu[node].t_ns.dtype == np.int64
        np.testing.assert_array_equal(rec.imu[node].t_ns, np.arange(len(imu.t_s)) * 12_500_000)
        np.testing.assert_array_equal(rec.imu[node].stamp_ns, rec.imu[node].t_ns)
    np.testing.assert_array_equal(rec.joint_states.t_ns, np.arange(len(traj.t_s)) * 10_000_000)
    assert np.all(np.diff(rec.calibration["m1"][0]) == 1_000_000_000)  # 1 Hz, no change in level


def test_imu_messages_follow_rep_145_and_carry_the_noise_covariance(tmp_path):
    traj = simulate(DEFAULT_PARAMS, (0.0, 0.0), (0.0, 0.0), 2.0)
    config = Bno055(seed=1)
    path = write_recording(
        tmp_path / "rest.mcap",
        sample_imu(traj, config),
        RunInfo("mujoco", (0, 0), (0, 0), 2.0, 0.01),
        "<mujoco/>",
        DEFAULT_PARAMS,
        traj=traj,
    )
    rec = read_recording(path)
    imu = rec.imu["m1"]
    # at rest linear_acceleration is specific force: +g up, which is sensor +y
    np.testing.assert_allclose(imu.accel_m_s2.mean(axis=0), [0, DEFAULT_PARAMS.g_m_s2, 0], atol=0.01)
    np.testing.assert_allclose(np.diagonal(imu.accel_covariance[0]), np.square(config.noise_model.accel_sigma_m_s2))
    np.testing.assert_allclose(np.diagonal(imu.gyro_covariance[0]), np.square(config.noise_model.gyro_sigma_rad_s))
    assert np.count_nonzero(imu.accel_covariance[0] - np.diag(np.diagonal(imu.accel_covariance[0]))) == 0


def test_metadata_describes_the_run_completely(recorded):
    path, _, imu, params = recorded
    rec = read_recording(path)
    assert rec.params() == params
    assert rec.imu_config() == imu.config
    run = rec.run_info()
    assert run.phi0_rad == PHI0 and run.duration_s == DURATION_S and run.engine == "mujoco"
    meta = rec.metadata["pendsim/run"]
    assert meta["seed"] == "5" and meta["noise"] == "true" and meta["b2_n_m_s"] == repr(0.0004)
    assert meta["pendsim_version"] and meta["mujoco_version"] == mujoco.__version__


def test_the_run_can_be_resimulated_from_the_file_alone(recorded):
    path, _, _, _ = recorded
    rec = read_recording(path)
    model = mujoco.MjModel.from_xml_string(rec.mjcf_xml)  # the attachment, nothing else
    run = rec.run_info()
    data = mujoco.MjData(model)
    data.qpos[:] = run.phi0_rad
    data.qvel[:] = run.omega0_rad_s
    state = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    nstep = round(run.duration_s / model.opt.timestep)
    states, _ = rollout.rollout(model, data, state[None], nstep=nstep)
    phi = np.concatenate([[run.phi0_rad], states[0, :, 1:3]])
    np.testing.assert_allclose(phi, rec.joint_states.position_rad, atol=1e-12)
    # and the tf poses are those angles about the pivot axis (world -y)
    _, quat = rec.tf_rotation_wxyz
    x_axis = rotations.to_matrix(quat)[..., :, 0]  # body x axis in world: (cos phi, 0, sin phi)
    np.testing.assert_allclose(np.arctan2(x_axis[..., 2], x_axis[..., 0]), rec.joint_states.position_rad, atol=1e-12)


def test_mcap_ros2_reader_decodes_the_same_values(recorded):
    path, traj, imu, _ = recorded
    counts = collections.Counter()
    gyro, position, static = [], [], None
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()], validate_crcs=True)
        for _, channel, _, msg in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            if channel.topic == "/imu/m1":
                gyro.append([msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z])
            elif channel.topic == "/joint_states":
                position.append(list(msg.position))
            elif channel.topic == "/tf_static":
                static = msg
    assert counts["/imu/m1"] == counts["/imu/m2"] == len(imu.t_s) == 1601
    assert counts["/joint_states"] == counts["/tf"] == len(traj.t_s)
    np.testing.assert_array_equal(gyro, imu.gyro_rad_s[:, 0])
    np.testing.assert_array_equal(position, traj.phi_rad)
    assert [t.child_frame_id for t in static.transforms] == ["imu_m1", "imu_m2"]
    assert static.transforms[0].transform.translation.z == -DEFAULT_PARAMS.om1_m


def _rerun_cli() -> str:
    found = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
    return found


def test_rerun_loads_the_recording_with_imu_and_joint_state_entities(recorded, tmp_path):
    path, traj, imu, _ = recorded
    rrd = tmp_path / "run.rrd"
    env = {"HOME": str(tmp_path), "PATH": "/usr/bin:/bin"}
    cmd = [_rerun_cli(), "mcap", "convert", str(path), "-o", str(rrd), "--application-id", "pendsim"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr
    import rerun as rr

    rows = collections.Counter()
    for chunk in rr.chunk.RrdReader(str(rrd)).stream():
        if not chunk.is_static:
            rows[str(chunk.entity_path)] += chunk.num_rows
    assert rows["/imu/m1"] >= len(imu.t_s) and rows["/imu/m2"] >= len(imu.t_s)
    for field in ("position", "velocity", "effort"):
        assert rows[f"/joint_states/{field}"] == len(traj.t_s)
