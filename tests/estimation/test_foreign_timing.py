"""Recordings whose values are taken at their stamps (another sensor, a simulation, a resampled log),
not a BNO055's held 100 Hz fused values: validate must not shift them onto fusion ticks. The truth
is independent of the alignment: the IMU sites' radii read from the MJCF, and the simulated angle."""

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from pendsim_bridge.cli import main
from pendsim_mj import DEFAULT_PARAMS
from pendsim_mj.engines.simulation import simulate

MJCF = Path(__file__).resolve().parents[2] / "models" / "pendulums.xml"
NODES = ("m1", "m2")


def _site_radius_m(name: str) -> float:
    site = next(s for s in ET.parse(MJCF).iter("site") if s.get("name") == name)
    return float(np.linalg.norm([float(v) for v in site.get("pos", "0 0 0").split()]))


def _write_stamped_csv(path: Path, seed: int):
    """A two-node CSV like a lab's logger writes: each sample's values at its own stamp (80 Hz,
    microseconds), BNO055-sized noise, 30 deg release without a hold."""
    tr = simulate(DEFAULT_PARAMS, phi0_rad=(math.pi / 6, 0.0), omega0_rad_s=(0.0, 0.0), duration_s=20.0, dt_s=0.0025)
    rows = np.arange(0, tr.phi_rad.shape[0], 5)  # every 12.5 ms
    rng = np.random.default_rng(seed)
    columns = [np.round(rows * 2500 + 1_000_000).astype(np.int64).astype(float)]
    names = ["t_us"]
    for k, node in enumerate(NODES):
        accel = tr.imu_accel_m_s2[rows, k] + rng.normal(0, 0.012, (len(rows), 3))
        gyro_dps = np.degrees(tr.imu_gyro_rad_s[rows, k] + rng.normal(0, 0.0015, (len(rows), 3)))
        for axis, values in enumerate((*accel.T, *gyro_dps.T, *tr.imu_quat_wxyz[rows, k].T)):
            columns.append(values)
            names.append(f"{node}.{['ax', 'ay', 'az', 'gx', 'gy', 'gz', 'qw', 'qx', 'qy', 'qz'][axis]}")
    table = np.stack(columns, axis=1)
    lines = [",".join(names)] + [",".join(f"{v:.6g}" if j else f"{v:.0f}" for j, v in enumerate(r)) for r in table]
    path.write_text("\n".join(lines) + "\n")
    return tr


@pytest.mark.parametrize("seed", [1, 2])
def test_values_taken_at_their_stamps_validate_without_a_fusion_shift(tmp_path, seed):
    csv = tmp_path / "lab.csv"
    truth = _write_stamped_csv(csv, seed)
    names = csv.read_text().splitlines()[0]
    assert main(["import", str(csv), "-o", str(tmp_path / "lab.mcap"), "--columns", names]) == 0
    out = tmp_path / "v"
    assert main(["validate", str(tmp_path / "lab.mcap"), "-o", str(out), "--damping", "recorded"]) == 0
    report = json.loads((out / "report.json").read_text())
    for node in NODES:
        got = report["nodes"][node]
        assert got["fusion_phase_s"] is None, got  # no held fused values found in these data
        assert not got["mirrored_axes"]
        assert got["radius_m"] == pytest.approx(_site_radius_m(f"imu_{node}"), abs=0.003)
    # the start the model is given is the simulated one (30 deg at rest), within the noise
    start = report["release"]
    assert math.degrees(start["estimated_angle_rad"][0]) == pytest.approx(30.0, abs=0.2), start
    assert truth.phi_rad[0, 0] == pytest.approx(math.pi / 6)


def test_a_bno055_recording_still_gets_its_fusion_timing(tmp_path):
    """The other side of the decision: the sensor model's held fused values are recognised."""
    path = tmp_path / "run.mcap"
    assert main(["record", "-o", str(path), "--duration-s", "20", "--seed", "3"]) == 0
    out = tmp_path / "v"
    assert main(["validate", str(path), "-o", str(out), "--damping", "recorded"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert all(report["nodes"][n]["fusion_phase_s"] is not None for n in NODES)
