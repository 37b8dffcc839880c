"""MCAP write and read speed for a 6 h two-IMU recording (80 Hz x 2 nodes = 3.456 M Imu messages).

Run: python bench/bench_mcap.py [--hours 6] [--baseline-messages 100000]

Prints, in one run: messages per second written and read into numpy arrays, and bytes per
message, for zstd, lz4 and no compression; beside the plain mcap-ros2-support writer (one dict
per message) and decoder (one object per message) on a subset, as the baseline.
Target (issue 3): >= 100 000 messages/s written and >= 250 000 read.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

from pendsim_bridge.io import ros2
from pendsim_bridge.io.mcap.reader import read_mcap
from pendsim_bridge.io.mcap.writer import BulkMcapWriter
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import Bno055, ImuNoise, sample_imu

IMU = "sensor_msgs/msg/Imu"
BLOCK = 200_000


def realistic_samples(hours: float):
    """Both nodes' IMU values for `hours`: a 10 min simulated swing, repeated, with fresh noise
    and quantisation (so compression sees realistic data)."""
    traj = simulate(duration_s=600.0)
    ideal = sample_imu(traj, Bno055(noise=False))
    m = int(hours * 3600 * 80)
    reps = -(-m // len(ideal.t_s))
    rng = np.random.default_rng(0)
    noise = ImuNoise()
    gyro = np.tile(ideal.gyro_rad_s, (reps, 1, 1))[:m] + rng.normal(size=(m, 2, 3)) * noise.gyro_sigma_rad_s
    accel = np.tile(ideal.accel_m_s2, (reps, 1, 1))[:m] + rng.normal(size=(m, 2, 3)) * noise.accel_sigma_m_s2
    quat = np.tile(ideal.quat_wxyz, (reps, 1, 1))[:m]
    t_ns = np.arange(m, dtype=np.int64) * 12_500_000
    return t_ns, np.rint(gyro * 900) / 900, np.rint(accel * 100) / 100, np.rint(quat * 2**14) / 2**14


def encode_block(layout, t_ns, gyro, accel, quat):
    sec, nsec = ros2.split_time(t_ns)
    cov = np.zeros(9)
    return layout.encode(
        len(t_ns),
        sec=sec,
        nanosec=nsec,
        orientation=rotations.wxyz_to_xyzw(quat),
        orientation_covariance=cov,
        angular_velocity=gyro,
        angular_velocity_covariance=cov,
        linear_acceleration=accel,
        linear_acceleration_covariance=cov,
    )


def write_ours(path, data, compression):
    t_ns, gyro, accel, quat = data
    layouts = [ros2.imu_layout("imu_m1"), ros2.imu_layout("imu_m2")]
    with BulkMcapWriter(path, compression=compression) as w:
        sid = w.register_schema(IMU, "ros2msg", ros2.SCHEMAS[IMU])
        channels = [w.register_channel(f"/imu/m{k + 1}", sid, "cdr") for k in range(2)]
        for lo in range(0, len(t_ns), BLOCK):
            hi = lo + BLOCK
            for k in range(2):
                payload = encode_block(layouts[k], t_ns[lo:hi], gyro[lo:hi, k], accel[lo:hi, k], quat[lo:hi, k])
                w.write_messages(channels[k], t_ns[lo:hi], payload)
            w.flush()  # both channels given up to t_ns[hi]: write them out, interleaved


def read_ours(path):
    contents = read_mcap(path, strict=True)
    out = {}
    for k in range(2):
        d = ros2.imu_layout(f"imu_m{k + 1}").decode(contents.topic(f"/imu/m{k + 1}").payloads)
        out[k] = (d["angular_velocity"], d["linear_acceleration"], d["orientation"])
    return out


def baseline(path, data, n):
    t_ns, gyro, accel, quat = data
    start = time.perf_counter()
    with open(path, "wb") as f:
        w = Ros2Writer(f)
        schema = w.register_msgdef(IMU, ros2.SCHEMAS[IMU].decode())
        for i in range(n // 2):
            for k in range(2):
                x, y, z, qw = quat[i, k, 1], quat[i, k, 2], quat[i, k, 3], quat[i, k, 0]
                msg = {
                    "header": {
                        "stamp": {"sec": int(t_ns[i] // 10**9), "nanosec": int(t_ns[i] % 10**9)},
                        "frame_id": f"imu_m{k + 1}",
                    },
                    "orientation": {"x": x, "y": y, "z": z, "w": qw},
                    "angular_velocity": dict(zip("xyz", gyro[i, k].tolist(), strict=True)),
                    "linear_acceleration": dict(zip("xyz", accel[i, k].tolist(), strict=True)),
                }
                w.write_message(f"/imu/m{k + 1}", schema, msg, log_time=int(t_ns[i]), publish_time=int(t_ns[i]))
        w.finish()
    write_s = time.perf_counter() - start
    start = time.perf_counter()
    count = 0
    with open(path, "rb") as f:
        for _ in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            count += 1
    read_s = time.perf_counter() - start
    return count / write_s, count / read_s, os.path.getsize(path) / count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=6.0)
    parser.add_argument("--baseline-messages", type=int, default=100_000)
    args = parser.parse_args()
    data = realistic_samples(args.hours)
    n = 2 * len(data[0])
    print(f"{args.hours:g} h, 2 IMUs at 80 Hz: {n:,} sensor_msgs/Imu messages (324 bytes of CDR each)")
    with tempfile.TemporaryDirectory() as tmp:
        base_w, base_r, base_b = baseline(Path(tmp) / "baseline.mcap", data, args.baseline_messages)
        print(f"{'writer':26} {'write msg/s':>12} {'read msg/s':>12} {'bytes/msg':>10} {'write x':>8} {'read x':>8}")
        print(f"{'mcap-ros2-support (subset)':26} {base_w:12,.0f} {base_r:12,.0f} {base_b:10.1f} {1:8.1f} {1:8.1f}")
        for compression in ("zstd", "lz4", "none"):
            path = Path(tmp) / f"{compression}.mcap"
            start = time.perf_counter()
            write_ours(path, data, compression)
            write_rate = n / (time.perf_counter() - start)
            start = time.perf_counter()
            arrays = read_ours(path)
            read_rate = n / (time.perf_counter() - start)
            assert np.array_equal(arrays[1][0], data[1][:, 1])  # read back exactly
            size = path.stat().st_size / n
            print(
                f"{'pendsim bulk, ' + compression:26} {write_rate:12,.0f} {read_rate:12,.0f} {size:10.1f} "
                f"{write_rate / base_w:8.1f} {read_rate / base_r:8.1f}"
            )
            path.unlink()


if __name__ == "__main__":
    main()
