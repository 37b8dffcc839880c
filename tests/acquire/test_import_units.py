"""pendsim import checks the units of a lab file against the data's own physics: the gyro's
integral against the quaternions' rotation (or the gravity vector's), gravity's magnitude. The
files are made here by an independent generator (a damped pendulum swinging about a hinge at an
arbitrary mounting, orientations by scipy, not pendsim's sensor model), written as hand-made CSV
in the units a lab logs."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pendsim_bridge.cli import main
from pendsim_bridge.io.recording import read_recording

G = 9.80665
RATE_HZ = 80.0


def swinging_node(
    amplitude_deg: float = 29.0, seconds: float = 20.0, *, seed: int = 0, radius_m: float = 0.33
) -> dict[str, np.ndarray]:
    """One node on a pendulum released from ``amplitude_deg`` (0.9 Hz, decaying): times (s), the
    gyro (rad/s, sensor frame), the orientation (w, x, y, z; the fused value 5 ms older than
    the gyro's, as a BNO055's), the specific force (m/s2, with gravity) and the gravity vector."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    w0, decay = 2 * math.pi * 0.9, 0.03
    amplitude = math.radians(amplitude_deg)

    def phi(t):
        return amplitude * np.exp(-decay * t) * np.cos(w0 * t)

    def rate(t):
        return amplitude * np.exp(-decay * t) * (-decay * np.cos(w0 * t) - w0 * np.sin(w0 * t))

    def accel(t):
        return amplitude * np.exp(-decay * t) * ((decay**2 - w0**2) * np.cos(w0 * t) + 2 * decay * w0 * np.sin(w0 * t))

    hinge = np.array([0.0, 1.0, 0.0])  # world: z up, the hinge horizontal
    mount = Rotation.from_euler("zyx", rng.uniform(-180, 180, 3), degrees=True)  # sensor -> pendulum, glued anyhow
    swing = Rotation.from_rotvec(phi(t)[:, None] * hinge)
    sensor = swing * mount  # sensor -> world
    gyro = mount.inv().apply(np.outer(rate(t), hinge))  # the pendulum's rate in the sensor's frame
    lagged = Rotation.from_rotvec(phi(t - 0.005)[:, None] * hinge) * mount
    xyzw = lagged.as_quat()
    where = swing.apply(np.array([0.0, 0.0, -radius_m]))  # the sensor, radius_m below the hinge at rest
    omega = np.outer(rate(t), hinge)
    alpha = np.outer(accel(t), hinge)
    a_world = np.cross(alpha, where) + np.cross(omega, np.cross(omega, where))
    force = sensor.inv().apply(a_world + np.array([0.0, 0.0, G]))
    gravity = sensor.inv().apply(np.tile([0.0, 0.0, G], (len(t), 1)))
    return {
        "t": t,
        "gyro": gyro + rng.normal(0.0, 0.002, gyro.shape),
        "quat": np.column_stack([xyzw[:, 3], xyzw[:, :3]]),
        "accel": force + rng.normal(0.0, 0.015, force.shape),
        "gravity": gravity,
    }


def write_csv(path, node, *, gyro_scale=1.0, accel_scale=1.0, columns=("gyro", "quat", "accel"), decimals=6):
    """One node's columns as a sketch prints them: t_ms, then each quantity (scaled to the file's
    units, ``decimals`` places; quaternions with 7)."""
    names = {"gyro": "gx,gy,gz", "quat": "qw,qx,qy,qz", "accel": "ax,ay,az", "gravity": "gvx,gvy,gvz"}
    scale = {"gyro": gyro_scale, "quat": 1.0, "accel": accel_scale, "gravity": accel_scale}
    blocks = [[f"{v:.3f}" for v in node["t"] * 1e3]]
    for c in columns:
        places = 7 if c == "quat" else decimals
        blocks.append([",".join(f"{v:.{places}f}" for v in row) for row in node[c] * scale[c]])
    rows = [",".join(parts) for parts in zip(*blocks, strict=True)]
    path.write_text("t_ms," + ",".join(names[c] for c in columns) + "\n" + "\n".join(rows) + "\n")


def _import(tmp_path, *args) -> int:
    return main(["import", str(tmp_path / "node.csv"), "-o", str(tmp_path / "node.mcap"), "--node", "m1", *args])


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("pendsim: error: ")
    return err[0]


TRUST = " (or --trust-units to import with the units given)"


def test_a_rad_s_gyro_read_as_deg_s_is_named_with_its_fix_not_imported_as_no_motion(tmp_path, capsys):
    write_csv(tmp_path / "node.csv", swinging_node())  # the quaternions swing +-29 deg
    assert _import(tmp_path) == 2  # default gyro=dps
    line = _error(capsys)
    assert "the units do not fit the data: m1: the gyro, read as gyro=dps, turns 0.017" in line
    assert line.endswith("the values are in rad/s: give --units accel=m/s2,gyro=rad/s" + TRUST)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["node.csv"]
    assert _import(tmp_path, "--units", "gyro=rad/s") == 0
    check = read_recording(tmp_path / "node.mcap").metadata["pendsim/import"]["units_check"]
    ratio = float(check.split("gyro/orientation ")[1].split()[0])
    assert ratio == pytest.approx(1.0, abs=0.01)  # the gyro and the lagged quaternions agree within 1 %


def test_a_deg_s_gyro_read_as_rad_s_is_named_not_taken_for_a_sensor_on_the_hinge_axis(tmp_path, capsys):
    write_csv(tmp_path / "node.csv", swinging_node(), gyro_scale=180 / math.pi)
    assert _import(tmp_path, "--units", "gyro=rad/s") == 2
    line = _error(capsys)
    assert "m1: the gyro, read as gyro=rad/s, turns 57.3 times as far as the quaternions" in line
    assert line.endswith("the values are in deg/s: give --units accel=m/s2,gyro=dps" + TRUST)
    assert _import(tmp_path) == 0


def test_the_bno055s_raw_counts_are_named_with_their_mode(tmp_path, capsys):
    node = swinging_node(seed=1)
    node["gyro"] = np.rint(node["gyro"] * 16 * 180 / math.pi) / (16 * 180 / math.pi)  # the chip's dps grid
    node["accel"] = np.rint(node["accel"] * 100) / 100
    write_csv(tmp_path / "node.csv", node, gyro_scale=16 * 180 / math.pi, accel_scale=100, decimals=0)
    assert _import(tmp_path) == 2
    line = _error(capsys)
    assert "m1: the gyro, read as gyro=dps, turns 16 times as far as the quaternions" in line
    assert (
        "the values are in the BNO055's raw counts in its dps mode (16 per deg/s) (or the BNO055's raw counts " in line
    )
    # swinging, never at rest: the median specific force is 1.04 g, nearer 1000 mg than 100 per m/s2
    assert (
        "m1: gravity, read as accel=m/s2, measures 1018 m/s2 by the accelerometer (median over 20.0 s, not at " in line
    )
    assert "accel=raw-m/s2: too close to tell apart" in line
    assert line.endswith("give --units accel=mg,gyro=raw-dps" + TRUST)
    assert _import(tmp_path, "--units", "accel=raw-m/s2,gyro=raw-dps") == 0
    imu = read_recording(tmp_path / "node.mcap").imu["m1"]
    np.testing.assert_allclose(imu.gyro_rad_s, node["gyro"], atol=1e-12)


def test_without_quaternions_the_gravity_vector_checks_the_gyro(tmp_path, capsys):
    write_csv(tmp_path / "node.csv", swinging_node(seed=2), columns=("gyro", "gravity"))
    assert _import(tmp_path) == 2
    line = _error(capsys)
    assert "m1: the gyro, read as gyro=dps, turns 0.017" in line and "times as far as the gravity vector" in line
    assert line.endswith("the values are in rad/s: give --units accel=m/s2,gyro=rad/s" + TRUST)


def test_a_gyro_with_nothing_to_check_it_against_is_noted_and_imported(tmp_path, capsys):
    write_csv(tmp_path / "node.csv", swinging_node(seed=3), columns=("gyro", "accel"))
    assert _import(tmp_path, "--units", "gyro=rad/s") == 0
    notes = capsys.readouterr().err
    assert "note: m1: the gyro's unit cannot be checked: no quaternion or gravity columns to compare it with" in notes
    write_csv(tmp_path / "node.csv", swinging_node(amplitude_deg=0.0, seed=4))  # at rest: nothing turns
    assert _import(tmp_path, "--units", "gyro=rad/s", "--force") == 0
    assert "note: m1: the gyro's unit cannot be checked: its orientation turns too little" in capsys.readouterr().err


def test_trust_units_imports_as_given_with_a_warning_and_the_finding_in_the_metadata(tmp_path, capsys):
    write_csv(tmp_path / "node.csv", swinging_node())
    assert _import(tmp_path, "--units", "gyro=dps", "--trust-units") == 0
    err = capsys.readouterr().err
    warning = next(line for line in err.splitlines() if line.startswith("warning: "))
    assert "the gyro, read as gyro=dps, turns 0.017" in warning
    assert warning.endswith("imported as given (--trust-units; give --units accel=m/s2,gyro=rad/s)")
    meta = read_recording(tmp_path / "node.mcap").metadata["pendsim/import"]
    assert "turns 0.017" in meta["units_trusted_over"] and meta["units"] == "accel=m/s2,gyro=dps"


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ("1e300,0,0,0", "line 3: the time 1e+297 s is out of range (allowed: within +-4e+09 s, Unix time up to the "
         "year 2096); is the time column's unit right (t_s, t_ms, t_us)?"),
        ("12.5,1e300,0,0", "line 3, column 'gx': 1.74533e+298 rad/s (read as gyro=dps) is beyond what a BNO055 can "
         "report (2048 dps = 35.7 rad/s)"),
        ("12.5,2100,0,0", "line 3, column 'gx': 36.6519 rad/s (read as gyro=dps) is beyond what a BNO055 can report "
         "(2048 dps = 35.7 rad/s); in raw-dps or raw-rad/s every value would be within it: check --units"),
    ],
)  # fmt: skip
def test_values_beyond_what_the_chip_reports_are_named_not_crashing(tmp_path, capsys, row, message):
    (tmp_path / "node.csv").write_text("t_ms,gx,gy,gz\n0,0,0,0\n" + row + "\n25,0,0,0\n")
    assert _import(tmp_path, "--units", "gyro=dps", "--trust-units") == 2
    assert message in _error(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["node.csv"]
