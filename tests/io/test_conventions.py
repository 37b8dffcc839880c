"""ROS and Foxglove conventions of a recording, checked by three independent readers: the mcap
library, ``rosbags`` (rosbag2's reader in Python) and Foxglove's own TypeScript libraries under
node (``@mcap/core`` + ``@foxglove/rosmsg2-serialization``, installed from npm into a cache
folder by the fixture below)."""

import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability
from rosbags.typesys import Stores, get_typestore

from pendsim_bridge.io.recording import read_recording
from pendsim_bridge.run.record import RecordSpec, record
from pendsim_bridge.run.replay import replay_to_mcap

T0 = 1_767_225_600_123_456_789  # 2026-01-01T00:00:00.123456789Z, injected: no wall clock in the checks
NPM_PACKAGES = (
    "@mcap/core@2.2.2",
    "@mcap/support@1.1.0",
    "@foxglove/rosmsg@5.0.5",
    "@foxglove/rosmsg2-serialization@3.1.0",
)
FOXGLOVE_SCRIPT = Path(__file__).parent / "interop" / "foxglove_read.mjs"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("conventions")
    out = {
        "planar": folder / "planar.mcap",
        "spatial": folder / "spatial.mcap",
        "static": folder / "static.mcap",
        "cut": folder / "cut.mcap",
    }
    record(RecordSpec(duration_s=4.0, hold_s=1.0), out["planar"], start_time_ns=T0, block_s=1.5)
    record(RecordSpec(duration_s=3.0, model="spatial", hold_s=0.5), out["spatial"], start_time_ns=T0)
    record(RecordSpec(duration_s=3.0, model="static"), out["static"], start_time_ns=T0)
    replay_to_mcap(out["planar"], out["cut"], start_s=2.5, end_s=4.0)
    return out


@pytest.fixture(scope="module")
def foxglove(files):
    """node + Foxglove's readers; the npm packages go to a cache folder (installed once)."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("node and npm are not installed (CI and the dev machines have them)")
    cache = Path(os.environ.get("PENDSIM_NODE_CACHE", Path.home() / ".cache" / "pendsim-node-interop"))
    modules = cache / "node_modules"
    if not (modules / "@foxglove" / "rosmsg2-serialization").is_dir():
        cache.mkdir(parents=True, exist_ok=True)
        cmd = [npm, "install", "--no-audit", "--no-fund", "--prefix", str(cache), *NPM_PACKAGES]
        subprocess.run(cmd, check=True, capture_output=True, timeout=600)

    def read(path: Path) -> dict:
        done = subprocess.run(
            [node, str(FOXGLOVE_SCRIPT), str(path)], capture_output=True, text=True, timeout=120,
            env={**os.environ, "NODE_PATH": str(modules)},
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        return json.loads(done.stdout)

    return read


def test_log_times_start_at_a_real_utc_time_recorded_in_the_metadata(files):
    meta = read_recording(files["planar"]).metadata["pendsim/run"]
    assert meta["start_time_ns"] == str(T0) and meta["start_time_utc"] == "2026-01-01T00:00:00.123456789Z"
    with open(files["planar"], "rb") as f:
        stats = make_reader(f, validate_crcs=True).get_summary().statistics
    assert stats.message_start_time == T0


def test_the_default_start_is_now(tmp_path):
    before = time.time_ns()
    result = record(RecordSpec(duration_s=0.5, model="static"), tmp_path / "now.mcap")
    assert before <= result.start_time_ns <= time.time_ns()


def test_a_streaming_reader_never_sees_log_time_go_backwards(files):
    for path in files.values():
        with open(path, "rb") as f:
            times = [m.log_time for _, _, m in NonSeekingReader(f, validate_crcs=True).iter_messages()]
        assert len(times) > 100 and times == sorted(times), path.name


def test_tf_and_joint_states_start_with_the_first_message_hold_included(files):
    rec = read_recording(files["planar"])
    assert rec.joint_states.t_ns[0] == rec.tf_rotation_wxyz[0][0] == rec.imu["m1"].t_ns[0] == 0
    held = rec.joint_states.t_ns < 1_000_000_000  # the 1 s hold: initial angles, at rest
    assert held.sum() == 100
    initial = np.broadcast_to([np.radians(30), 0.0], (100, 2))
    np.testing.assert_allclose(rec.joint_states.position_rad[held], initial, atol=1e-15)
    assert not np.any(rec.joint_states.velocity_rad_s[held])


def test_rosbags_reads_every_message_and_tf_static_is_transient_local(files):
    store = get_typestore(Stores.ROS2_HUMBLE)
    for name, path in files.items():
        with AnyReader([path], default_typestore=store) as reader:
            count = 0
            for connection, _, raw in reader.messages():
                reader.deserialize(raw, connection.msgtype)
                count += 1
            assert count == sum(c.msgcount for c in reader.connections) > 0
            static = next(c for c in reader.connections if c.topic == "/tf_static")
            assert static.ext.offered_qos_profiles[0].durability == QosDurability.TRANSIENT_LOCAL, name
            if name == "spatial":
                joints = next(c for c in reader.connections if c.topic == "/joint_states")
                msg = reader.deserialize(next(reader.messages([joints]))[2], joints.msgtype)
                assert list(msg.name) == ["hinge_phi1", "hinge_phi2", "tilt_m1", "tilt_m2"]


def test_foxglove_reads_every_file_with_the_conventions(files, foxglove):
    planar = foxglove(files["planar"])
    assert planar["backwards"] == 0 and planar["indexedCount"] == sum(planar["topics"].values())
    assert planar["maxQuatNormError"] < 1e-6  # unit quaternions after the chip's quantisation
    assert int(planar["first"]["/tf"]) == int(planar["first"]["/joint_states"]) == T0  # hold included
    assert planar["tfStatic"] == [["m1", "imu_m1"], ["m2", "imu_m2"]]
    assert "durability: 1" in planar["channelMetadata"]["/tf_static"]["offered_qos_profiles"]
    assert planar["jointNames"] == ["hinge_phi1", "hinge_phi2"]
    assert foxglove(files["spatial"])["jointNames"] == ["hinge_phi1", "hinge_phi2", "tilt_m1", "tilt_m2"]
    static = foxglove(files["static"])
    assert static["tfStatic"][:2] == [["world", "m1"], ["world", "m2"]]  # a world root
    assert "/tf" not in static["topics"] and static["backwards"] == 0


def test_a_cut_keeps_tf_static_at_its_start(files, foxglove):
    cut = foxglove(files["cut"])
    assert cut["topics"]["/tf_static"] == 1
    assert int(cut["first"]["/tf_static"]) == int(cut["first"]["/imu/m1"]) == T0 + 2_500_000_000
    assert cut["tfStatic"] == [["m1", "imu_m1"], ["m2", "imu_m2"]] and cut["backwards"] == 0
