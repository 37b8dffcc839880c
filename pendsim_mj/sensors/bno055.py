"""A simulated BNO055 node on each pendulum (spec RIG.md section 6; FIELD-NOTES: BNO055).

What the real node does, and how it is modelled:

- **Sampling**: the ESP32 node reads the chip at 80 Hz; samples carry timestamps k/80 s on the
  node's clock.
- **Fusion timing** (``fusion_timing=True``, default): in NDOF mode the chip fuses at 100 Hz, and
  the node reads the latest fused value, so each sample is 0-10 ms old and about one fused value
  in five is never read. By default the fusion ticks fall on the release and the 10 ms
  simulation grid, so the values are the trajectory's own rows, exactly; with a fusion phase or
  clock drift (``imperfections``) they fall between steps and are interpolated as below.
- **Ideal timing** (``fusion_timing=False``): values at the sample instants themselves. The state
  (phi, omega) is interpolated inside each step with a quintic Hermite polynomial through phi,
  omega and alpha at both ends, and MuJoCo's sensors are evaluated at those states
  (``simulation.evaluate_states``); tests bound the error against a run with a finer step.
- **Mount**: default at the disk centre with the spec's axes (x tangential, y toward the pivot,
  z along the pivot axis). An offset d (sensor axes, m) moves it by rigid-body kinematics,
  a' = a + alpha x d + omega x (omega x d); a mount rotation q_m turns the axes (v' = R_m^T v).
- **Outputs**: angular velocity; acceleration with gravity (specific force, +g on y at rest);
  gravity vector; linear acceleration = acceleration - gravity; orientation quaternion (w, x, y,
  z, the chip's order; the chip's Euler output is unreliable at large tilt, so none is given);
  calibration status (system, gyro, accel, mag, 0-3 each).
- **Noise** (seeded ``np.random.default_rng``): white noise per axis whose total standard
  deviation after quantisation equals the configured sigma (the spec's sigmas are measured on the
  chip's quantised output: drawn with sqrt(sigma^2 - LSB^2/12)); optional constant bias, bias
  random walk K (Allan deviation K sqrt(tau/3)) and bias instability B (flicker noise of one-sided
  PSD B^2/(pi f), whose Allan deviation is flat at sqrt(2 ln 2 / pi) B = 0.664 B); clipping at
  the fusion modes' +-4 g accelerometer range; quantisation to the
  output resolution (1 m/s^2 = 100 LSB, 1 rad/s = 900 LSB, quaternion 1 = 2^14 LSB).
  ``noise=False`` gives the ideal signal (no noise, clipping or quantisation).
- **Imperfections** of real nodes (heading, axis remap, fusion error and phase, packet loss,
  clocks, hand wobble; all off by default): ``pendsim_mj.sensors.imperfections``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import RigParams
from pendsim_mj.sensors import imperfections as imp
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.imperfections import Imperfections

STANDARD_GRAVITY_M_S2 = 9.80665  # the "g" of the chip's range setting
ACCEL_LSB_M_S2 = 0.01  # BNO055 datasheet: 1 m/s^2 = 100 LSB (acceleration, linear, gravity)
SAMPLE_RATE_HZ = 80.0  # the rig's ESP32 nodes read the chip at 80 Hz (paper; spec RIG.md section 6)
FUSION_RATE_HZ = 100.0  # NDOF mode: fused output at 100 Hz (BNO055 datasheet; FIELD-NOTES: BNO055)
GYRO_LSB_RAD_S = 1.0 / 900.0  # BNO055 datasheet: 1 rad/s = 900 LSB
QUAT_LSB = 2.0**-14  # BNO055 datasheet: quaternion 1 = 2^14 LSB
# The swing angle read from a quantised quaternion (rotation about one axis: two components, w and
# that axis's, each rounded to an LSB, variance LSB^2/12; the angle is 2 atan2(q_axis, q_w)):
# sigma = 2 sqrt(2 LSB^2/12) = LSB sqrt(2/3) = 5.0e-5 rad (measured on the sensor model: 4.97e-5).
SWING_ANGLE_SIGMA_RAD = QUAT_LSB * math.sqrt(2.0 / 3.0)
# The largest readings the chip can give in any mode (datasheet: accelerometer ranges +-2/4/8/16 g,
# gyroscope +-125/250/500/1000/2000 dps; the fusion modes use 4 g and 2000 dps). Acceleration,
# linear acceleration and the gravity vector share the accelerometer's scale.
ACCEL_FULL_SCALE_M_S2 = 16 * STANDARD_GRAVITY_M_S2
GYRO_FULL_SCALE_RAD_S = math.radians(2000.0)
CALIBRATION_FIELDS = ("system", "gyro", "accel", "mag")

Vec3 = tuple[float, float, float]


MIN_MOTION_RAD_S = 0.05  # a node whose gyro stays below this does not move (40x the gyro noise sigma)


@dataclasses.dataclass(frozen=True)
class ImuNoise:
    """Noise of one BNO055 (the same for both nodes), per sensor axis x, y, z.

    Defaults: the paper's 6 h static Allan-deviation test at 80 Hz (one-sample standard
    deviation), spec RIG.md section 6. Bias and bias random walk default to zero.
    """

    accel_sigma_m_s2: Vec3 = (0.0109, 0.0117, 0.01633)
    gyro_sigma_rad_s: Vec3 = (0.00116, 0.00213, 0.00127)
    accel_bias_m_s2: Vec3 = (0.0, 0.0, 0.0)
    gyro_bias_rad_s: Vec3 = (0.0, 0.0, 0.0)
    accel_bias_walk_m_s2_per_sqrt_s: Vec3 = (0.0, 0.0, 0.0)
    gyro_bias_walk_rad_s_per_sqrt_s: Vec3 = (0.0, 0.0, 0.0)
    accel_bias_instability_m_s2: Vec3 = (0.0, 0.0, 0.0)
    gyro_bias_instability_rad_s: Vec3 = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if len(value) != 3 or not all(math.isfinite(v) for v in value):
                raise ParameterError(f"{f.name} must be three finite numbers (x, y, z), got {value!r}")
            if "bias_m" not in f.name and "bias_rad" not in f.name and any(v < 0 for v in value):
                raise ParameterError(f"{f.name} must be >= 0, got {value!r}")


@dataclasses.dataclass(frozen=True)
class Bno055:
    """Configuration of the two simulated BNO055 nodes (index 0: M1, 1: M2)."""

    sample_rate_hz: float = SAMPLE_RATE_HZ
    fusion_rate_hz: float = FUSION_RATE_HZ
    fusion_timing: bool = True
    noise: bool = True
    noise_model: ImuNoise = ImuNoise()
    accel_range_m_s2: float = 4 * STANDARD_GRAVITY_M_S2
    mount_offset_m: tuple[Vec3, Vec3] = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    mount_quat_wxyz: tuple[tuple[float, float, float, float], ...] = ((1.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
    calibration: tuple[int, int, int, int] = (3, 3, 3, 3)
    seed: int = 0
    imperfections: Imperfections = dataclasses.field(default_factory=Imperfections)

    def __post_init__(self) -> None:
        for name in ("sample_rate_hz", "fusion_rate_hz", "accel_range_m_s2"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ParameterError(f"{name} must be a finite number > 0, got {value!r}")
        if len(self.calibration) != 4 or any(c not in (0, 1, 2, 3) for c in self.calibration):
            raise ParameterError(
                f"calibration must be four levels 0-3 (system, gyro, accel, mag), got {self.calibration!r}"
            )
        if np.shape(self.mount_offset_m) != (2, 3) or not np.all(np.isfinite(self.mount_offset_m)):
            raise ParameterError(f"mount_offset_m must be two finite (x, y, z) vectors, got {self.mount_offset_m!r}")
        q = np.asarray(self.mount_quat_wxyz, dtype=float)
        if q.shape != (2, 4) or not np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9):
            raise ParameterError(
                f"mount_quat_wxyz must be two unit quaternions (w, x, y, z), got {self.mount_quat_wxyz!r}"
            )

    def covariance_diagonals(self) -> dict[str, np.ndarray]:
        """Variances per axis (2 nodes, 3 axes) for the ROS Imu covariance fields.

        acceleration: sigma^2 (m/s^2)^2; angular velocity: sigma^2 (rad/s)^2; orientation:
        the quaternion quantisation as a small angle, (2 LSB)^2 / 12 rad^2 (no fusion error is
        modelled). All zero for an ideal (noise=False) node.
        """
        if not self.noise:
            zero = np.zeros((2, 3))
            return {"accel": zero, "gyro": zero, "orientation": zero}
        n = self.noise_model
        return {
            "accel": np.tile(np.square(n.accel_sigma_m_s2), (2, 1)),
            "gyro": np.tile(np.square(n.gyro_sigma_rad_s), (2, 1)),
            "orientation": np.full((2, 3), (2 * QUAT_LSB) ** 2 / 12),
        }


@dataclasses.dataclass(frozen=True)
class ImuSamples:
    """Both nodes' samples; m samples at t_s = k / sample_rate_hz. Sensor axes, SI units.

    Attributes:
      t_s: (m,) sample instants k / sample_rate_hz on the nodes' clocks, s (the true instants too
        when the clocks are perfect).
      fused_t_s: (m,) true instant of the value each of M1's samples carries (= t_s without fusion
        timing or clock imperfections).
      gyro_rad_s: (m, 2, 3) angular velocity.
      accel_m_s2: (m, 2, 3) acceleration including gravity (specific force).
      linear_accel_m_s2: (m, 2, 3) acceleration with gravity removed.
      gravity_m_s2: (m, 2, 3) gravity vector (reads +g upward, like the accelerometer at rest).
      quat_wxyz: (m, 2, 4) orientation of the sensor frame in the world frame.
      calibration: (m, 2, 4) uint8 status 0-3 of (system, gyro, accel, mag).
      config: the Bno055 configuration that made them.
      value_t_s: (m, 2) true instant of the value each node's sample carries, s (None: fused_t_s).
      stamp_s: (m, 2) header stamp of each sample: its node's clock, s (None: t_s).
      log_t_s: (m, 2) when the recorder logged it: the true instant plus transport latency, s
        (None: t_s).
      received: (m, 2) False where the packet was lost (None: all arrived).
    """

    t_s: np.ndarray
    fused_t_s: np.ndarray
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    linear_accel_m_s2: np.ndarray
    gravity_m_s2: np.ndarray
    quat_wxyz: np.ndarray
    calibration: np.ndarray
    config: Bno055
    value_t_s: np.ndarray | None = None
    stamp_s: np.ndarray | None = None
    log_t_s: np.ndarray | None = None
    received: np.ndarray | None = None

    def node_times(self, node: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """Header stamps (node clock), log times (recorder clock), both s, and the arrival mask of
        one node's samples, each (m,)."""
        stamp = self.t_s if self.stamp_s is None else self.stamp_s[:, node]
        log = self.t_s if self.log_t_s is None else self.log_t_s[:, node]
        received = np.ones(len(self.t_s), bool) if self.received is None else self.received[:, node]
        return stamp, log, received

    @property
    def tangential_m_s2(self) -> np.ndarray:
        """(m, 2) accelerometer x: r phi'' + g sin phi (what the sensor reads, gravity included)."""
        return self.accel_m_s2[..., 0]

    @property
    def normal_m_s2(self) -> np.ndarray:
        """(m, 2) accelerometer y, toward the pivot: r phi'^2 + g cos phi (gravity included)."""
        return self.accel_m_s2[..., 1]

    @property
    def tangential_linear_m_s2(self) -> np.ndarray:
        """(m, 2) linear acceleration x: the kinematic r phi''."""
        return self.linear_accel_m_s2[..., 0]

    @property
    def normal_linear_m_s2(self) -> np.ndarray:
        """(m, 2) linear acceleration y: the kinematic r phi'^2."""
        return self.linear_accel_m_s2[..., 1]


def fused_instants(t_s: NDArray[np.float64], fusion_rate_hz: float | None) -> NDArray[np.float64]:
    """The instant (s) of the value a node reports at each sample time ``t_s`` (s): the latest
    fusion instant at or before it (the chip fuses at ``fusion_rate_hz``), or ``t_s`` itself
    for a node without fusion timing (None)."""
    t = np.asarray(t_s, dtype=float)
    if not fusion_rate_hz:
        return t
    return np.floor(t * fusion_rate_hz + 1e-9) / fusion_rate_hz


def node_instants(
    config: Bno055, m: int, hold_s: float, *, first: int = 0
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """When each node samples, and the instant of the value it carries.

    Sample k is taken at k / sample_rate_hz on each node's clock, which runs ``clock_drift_ppm``
    fast; the chip's fusion ticks fall on that clock at the release plus the fusion phase plus
    whole fusion periods, and a sample carries the latest fused value.

    Args:
      config: the node model.
      m: number of samples.
      hold_s: when the release happens, s after the recording's start.
      first: the number of the first sample (samples first .. first + m - 1; each is computed
        on its own, so any range gives the values of the whole run).

    Returns:
      The nodes' clock times k / rate (m,), the true sample instants (m, 2) and the true instants
      of the values (m, 2), all s from the recording's start.
    """
    imperfect = config.imperfections
    clock_t = np.arange(first, first + m) / config.sample_rate_hz
    sample_t = np.empty((m, 2))
    value_t = np.empty((m, 2))
    for n in range(2):
        rate = 1.0 + imperfect.clock_drift_ppm[n] * 1e-6
        sample_t[:, n] = clock_t / rate
        if config.fusion_timing:
            first_tick = hold_s + imperfect.fusion_phase_s[n]
            value_clock = first_tick + fused_instants(clock_t - first_tick, config.fusion_rate_hz)
            value_t[:, n] = value_clock / rate
        else:
            value_t[:, n] = sample_t[:, n]
    return clock_t, sample_t, value_t


def _hermite_states(traj: Trajectory, t_s: np.ndarray, first_row: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """phi, omega (m, 2) at arbitrary instants: quintic Hermite through (phi, omega, alpha).
    ``traj`` may be a block of a run whose first row is the run's row ``first_row``."""
    h = traj.dt_s
    i = np.clip(np.floor(t_s / h + 1e-9).astype(int), first_row, first_row + len(traj.t_s) - 2) - first_row
    s = ((t_s - traj.t_s[i]) / h)[:, None]
    p0, p1 = traj.phi_rad[i], traj.phi_rad[i + 1]
    v0, v1 = traj.omega_rad_s[i] * h, traj.omega_rad_s[i + 1] * h
    a0, a1 = traj.alpha_rad_s2[i] * h * h, traj.alpha_rad_s2[i + 1] * h * h
    s2, s3, s4, s5 = s * s, s**3, s**4, s**5
    h00 = 1 - 10 * s3 + 15 * s4 - 6 * s5
    h10 = s - 6 * s3 + 8 * s4 - 3 * s5
    h20 = 0.5 * s2 - 1.5 * s3 + 1.5 * s4 - 0.5 * s5
    h01 = 10 * s3 - 15 * s4 + 6 * s5
    h11 = -4 * s3 + 7 * s4 - 3 * s5
    h21 = 0.5 * s3 - s4 + 0.5 * s5
    phi = h00 * p0 + h10 * v0 + h20 * a0 + h01 * p1 + h11 * v1 + h21 * a1
    d00 = -30 * s2 + 60 * s3 - 30 * s4
    d10 = 1 - 18 * s2 + 32 * s3 - 15 * s4
    d20 = s - 4.5 * s2 + 6 * s3 - 2.5 * s4
    d11 = -12 * s2 + 28 * s3 - 15 * s4
    d21 = 1.5 * s2 - 4 * s3 + 2.5 * s4
    omega = (d00 * p0 + d10 * v0 + d20 * a0 - d00 * p1 + d11 * v1 + d21 * a1) / h
    return phi, omega


def _trajectory_readings(traj: Trajectory, t_s: np.ndarray, first_row: int = 0) -> dict[str, np.ndarray]:
    """MuJoCo's IMU readings (both nodes) at instants t_s (m,) of the run (0 <= t <= end): the
    trajectory's own rows where t_s lies on its step grid, else the quintic Hermite state there.
    ``traj`` may be a block of the run starting at its row ``first_row``."""
    steps = t_s / traj.dt_s
    idx = np.rint(steps).astype(int) - first_row
    names = ("imu_accel_m_s2", "imu_gyro_rad_s", "imu_quat_wxyz", "imu_angacc_rad_s2")
    if len(t_s) and np.max(np.abs(steps - idx - first_row)) <= 1e-6 and idx.min() >= 0 and idx.max() < len(traj.t_s):
        return {name: getattr(traj, name)[idx] for name in names}
    if np.any(traj.tilt_rad):
        raise ParameterError(
            "values between simulation steps are interpolated for the planar model only; the spatial model needs "
            "fusion timing, no fusion phase or clock drift, and a step dividing the 10 ms fusion period"
        )
    from pendsim_mj.engines.simulation import evaluate_states  # start-up: MuJoCo, only for a hold

    phi, omega = _hermite_states(traj, t_s, first_row)
    return evaluate_states(traj.single_params, phi, omega)


def _held_readings(traj: Trajectory, t_s: np.ndarray, config: Bno055, g_m_s2: float) -> dict[str, np.ndarray]:
    """Both nodes while the pendulums are held at their initial angles (t_s < 0, s from the
    release): still, the accelerometer reading gravity alone; with hand wobble, turned by the
    tremor angle about the hinge with the pendulum kinematics of that motion."""
    m = len(t_s)
    quat = np.broadcast_to(traj.imu_quat_wxyz[:1], (m, 2, 4)).copy()
    rate = np.zeros((m, 2))
    alpha = np.zeros((m, 2))
    wobble = config.imperfections.hold_wobble_rad
    if wobble > 0 and m:
        rng = np.random.default_rng([config.seed, 4])
        angle, rate, alpha = imp.hold_wobble(rng, t_s, wobble)
        from pendsim_mj.rig.model import HINGE_AXIS_WORLD  # start-up: MuJoCo

        turn = rotations.from_rotvec(angle[..., None] * HINGE_AXIS_WORLD)  # world side: about the hinge
        quat = rotations.multiply(turn, quat)
    params = traj.single_params
    radius = np.array([params.om1_m, params.om2_m])
    zeros = np.zeros((m, 2))
    kinematic = np.stack([radius * alpha, radius * rate**2, zeros], axis=-1)  # r phi'', r phi'^2, 0
    return {
        "imu_quat_wxyz": quat,
        "imu_gyro_rad_s": np.stack([zeros, zeros, rate], axis=-1),
        "imu_angacc_rad_s2": np.stack([zeros, zeros, alpha], axis=-1),
        "imu_accel_m_s2": rotations.rotate_into_frame(quat, np.array([0.0, 0.0, g_m_s2])) + kinematic,
    }


def _readings_at(traj: Trajectory, t_s: np.ndarray, config: Bno055, first_row: int = 0) -> dict[str, np.ndarray]:
    """Both nodes' ideal readings at instants t_s (m,) from the release (held before it);
    ``traj`` may be a block of the run starting at its row ``first_row`` (held instants: the first)."""
    held = t_s < -1e-9
    g = traj.single_params.g_m_s2
    if not held.any():
        return _trajectory_readings(traj, np.maximum(t_s, 0.0), first_row)
    parts = [
        _held_readings(traj, t_s[held], config, g),
        _trajectory_readings(traj, np.maximum(t_s[~held], 0.0), first_row),
    ]
    out = {}
    for name, value in parts[0].items():
        full = np.empty((len(t_s), *value.shape[1:]))
        full[held], full[~held] = value, parts[1][name]
        out[name] = full
    return out


def sample_imu(traj: Trajectory, config: Bno055 = Bno055(), *, hold_s: float = 0.0) -> ImuSamples:
    """Sample both BNO055 nodes over a simulated run.

    Args:
      traj: a single (not batch) trajectory from either engine.
      config: the node model.
      hold_s: the recording starts this long before the release, with the pendulums held still
        at their initial angles (as a real recording does); rounded to whole samples. The
        trajectory's t = 0 is then at ``hold_s`` in the samples' time.

    Returns:
      ImuSamples with m = floor(duration * sample_rate) + 1 samples (plus the held ones; less the
      last ones a slow node clock did not reach by the end of the run).
    """
    if traj.is_batch:
        raise ParameterError("sample_imu takes a single trajectory; use trajectory.member(i)")
    if not (math.isfinite(hold_s) and hold_s >= 0):
        raise ParameterError(f"hold_s must be a finite number >= 0 s, got {hold_s!r}")
    if not config.fusion_timing and np.any(traj.tilt_rad):
        raise ParameterError("ideal timing interpolates the planar state only; use fusion timing for the spatial model")
    rate = config.sample_rate_hz
    held = round(hold_s * rate)
    hold = held / rate
    m = held + math.floor(float(traj.t_s[-1]) * rate + 1e-9) + 1
    clock_t, sample_t, value_t = node_instants(config, m, hold)
    m = int(np.count_nonzero(np.all(value_t - hold <= traj.t_s[-1] + 1e-9, axis=1)))  # a slow clock ends early
    clock_t, sample_t, value_t = clock_t[:m], sample_t[:m], value_t[:m]
    if np.array_equal(value_t[:, 0], value_t[:, 1]):
        readings = _readings_at(traj, value_t[:, 0] - hold, config)
    else:  # each node at its own instants
        per_node = [_readings_at(traj, value_t[:, n] - hold, config) for n in range(2)]
        readings = {name: np.stack([per_node[n][name][:, n] for n in range(2)], axis=1) for name in per_node[0]}
    return _measure_readings(readings, clock_t, value_t, traj.single_params.g_m_s2, config, sample_t)


def static_imu(params: RigParams, duration_s: float, config: Bno055 = Bno055()) -> ImuSamples:
    """Both nodes at rest on the hanging rig for ``duration_s`` (a static noise test): MuJoCo's
    sensors at the rest pose, repeated at every sample, then the same mount and noise model."""
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ParameterError(f"duration_s must be a finite number > 0 s, got {duration_s!r}")
    from pendsim_mj.engines.simulation import evaluate_states  # start-up: MuJoCo

    m = math.floor(duration_s * config.sample_rate_hz + 1e-9) + 1
    clock_t, sample_t, _ = node_instants(config, m, 0.0)
    rest = evaluate_states(params, np.zeros((1, 2)), np.zeros((1, 2)))
    readings = {name: np.broadcast_to(value, (m, *value.shape[1:])) for name, value in rest.items()}
    return _measure_readings(readings, clock_t, sample_t, params.g_m_s2, config, sample_t)


class ImuSampler:
    """Both BNO055 nodes sampled block by block over a run simulated block by block (memory
    independent of the duration).

    The blocks' samples, concatenated, are those of ``sample_imu`` (or ``static_imu``) on the
    whole run: each sample's value comes from the block that holds its instant, node timing is
    computed sample by sample, and the noise comes from streams that do not depend on how the
    run is cut (``_NoiseStreams``). Fusion error, packet loss and latency are processes over the
    whole run: a node model with them is sampled whole (``sample_imu``), not here.

    Args:
      config: the node model.
      params: the rig (gravity; the sensors at rest for a static test).
      end_t_s: the run's last simulation instant (n_steps * dt_s), or the static duration, s.
      hold_s: the recording starts this long before the release (rounded to whole samples).
      static: both nodes at rest for the whole duration (a noise test): use ``static_block``.

    Raises:
      ParameterError: a node model with whole-run imperfections, or a bad hold.
    """

    def __init__(
        self, config: Bno055, params: RigParams, *, end_t_s: float, hold_s: float = 0.0, static: bool = False
    ) -> None:
        if not (math.isfinite(hold_s) and hold_s >= 0):
            raise ParameterError(f"hold_s must be a finite number >= 0 s, got {hold_s!r}")
        if not streamable(config):
            raise ParameterError(
                "fusion error, packet loss and latency are drawn over the whole run: sample it with sample_imu"
            )
        self.config, self.params, self.static = config, params, static
        rate = config.sample_rate_hz
        self.held = 0 if static else round(hold_s * rate)
        self.hold_s = self.held / rate
        self.total = self.held + math.floor(end_t_s * rate + 1e-9) + 1  # at most (a slow clock ends early)
        self._next = 0
        self._done = False
        self._noise = _NoiseStreams(config, self.total) if config.noise else None
        self._rest: dict[str, np.ndarray] | None = None

    @property
    def done(self) -> bool:
        return self._done or self._next >= self.total

    def block(self, traj: Trajectory, *, first_row: int = 0, last: bool = False) -> ImuSamples:
        """The samples whose values lie in this block of the run.

        Args:
          traj: rows ``first_row`` .. ``first_row + len - 1`` of the run (single, not batch);
            consecutive blocks share their boundary row.
          first_row: the run row of ``traj``'s first row.
          last: the run's final block.
        """
        if traj.is_batch:
            raise ParameterError("sample_imu takes a single trajectory; use trajectory.member(i)")
        config = self.config
        if not config.fusion_timing and np.any(traj.tilt_rad):
            raise ParameterError(
                "ideal timing interpolates the planar state only; use fusion timing for the spatial model"
            )
        end_row = first_row + len(traj.t_s) - 1
        span = math.ceil(len(traj.t_s) * traj.dt_s * config.sample_rate_hz) + 4 + (self.held if not self._next else 0)
        m = min(span, self.total - self._next)
        clock_t, sample_t, value_t = node_instants(config, m, self.hold_s, first=self._next)
        run_t = value_t - self.hold_s  # from the release
        if last:
            count = int(np.count_nonzero(np.all(run_t <= traj.t_s[-1] + 1e-9, axis=1)))
            self._done = True
        else:
            rows = np.floor(np.max(run_t, axis=1) / traj.dt_s + 1e-9)
            count = int(np.searchsorted(rows, end_row, side="left"))
        clock_t, sample_t, value_t, run_t = clock_t[:count], sample_t[:count], value_t[:count], run_t[:count]
        if np.array_equal(value_t[:, 0], value_t[:, 1]):
            readings = _readings_at(traj, run_t[:, 0], config, first_row)
        else:
            per_node = [_readings_at(traj, run_t[:, n], config, first_row) for n in range(2)]
            readings = {name: np.stack([per_node[n][name][:, n] for n in range(2)], axis=1) for name in per_node[0]}
        self._next += count
        g = traj.single_params.g_m_s2
        return _measure_readings(readings, clock_t, value_t, g, config, sample_t, noise=self._noise)

    def static_block(self, count: int) -> ImuSamples:
        """The next ``count`` samples (fewer at the end) of a static test."""
        if not self.static:
            raise ParameterError("static_block is for static tests (ImuSampler(..., static=True))")
        if self._rest is None:
            from pendsim_mj.engines.simulation import evaluate_states  # start-up: MuJoCo

            self._rest = evaluate_states(self.params, np.zeros((1, 2)), np.zeros((1, 2)))
        m = min(count, self.total - self._next)
        clock_t, sample_t, _ = node_instants(self.config, m, 0.0, first=self._next)
        self._next += m
        readings = {name: np.broadcast_to(value, (m, *value.shape[1:])) for name, value in self._rest.items()}
        return _measure_readings(
            readings, clock_t, sample_t, self.params.g_m_s2, self.config, sample_t, noise=self._noise
        )


def streamable(config: Bno055) -> bool:
    """Whether a node model can be sampled block by block (no whole-run imperfection process)."""
    imperfect = config.imperfections
    return not (imperfect.fusion_error_rad > 0 or imperfect.packet_loss > 0 or imperfect.latency_s > 0)


def _fusion_error(config: Bno055, value_t: np.ndarray) -> np.ndarray:
    """(m, 2, 4) small rotations of the fused orientation (sensor axes) at the value instants."""
    imperfect = config.imperfections
    rng = np.random.default_rng([config.seed, 3])
    period = imperfect.fusion_error_period_s
    errors = []
    for n in range(2):
        e, _, _ = imp.smooth_process(rng, value_t[:, n], imperfect.fusion_error_rad, 1 / (3 * period), 3 / period, (3,))
        errors.append(rotations.from_rotvec(e))
    return np.stack(errors, axis=1)


def _measure_readings(
    readings: dict[str, np.ndarray],
    t_s: np.ndarray,
    value_t: np.ndarray,
    g_m_s2: float,
    config: Bno055,
    sample_t: np.ndarray,
    noise: _NoiseStreams | None = None,
) -> ImuSamples:
    """Mount transform, fusion error, gravity, axis remap, heading, linear acceleration, noise,
    packet loss and clocks, for ideal readings at the value instants ``value_t`` (m, 2).
    ``t_s`` (m,): the nodes' clock times k / rate; ``sample_t`` (m, 2): the true sample instants;
    ``noise``: the run's noise streams when it is measured block by block (default: a new run)."""
    accel = readings["imu_accel_m_s2"]
    gyro = readings["imu_gyro_rad_s"]
    angacc = readings["imu_angacc_rad_s2"]
    quat = readings["imu_quat_wxyz"]
    imperfect = config.imperfections

    # Mount: offset by rigid-body kinematics, then the mount rotation (each skipped where it is
    # none: the same values, cheaper for a live loop's few samples at a time).
    d = np.asarray(config.mount_offset_m, dtype=float)  # (2, 3)
    if np.any(d):
        accel = accel + np.cross(angacc, d) + np.cross(gyro, np.cross(gyro, d))
    q_mount = np.asarray(config.mount_quat_wxyz, dtype=float)  # (2, 4)
    if np.any(q_mount != (1.0, 0.0, 0.0, 0.0)):
        r_mount = rotations.to_matrix(q_mount)  # (2, 3, 3)
        accel = np.einsum("kji,mkj->mki", r_mount, accel)
        gyro = np.einsum("kji,mkj->mki", r_mount, gyro)
        quat = rotations.multiply(quat, np.broadcast_to(q_mount, quat.shape))
    if imperfect.fusion_error_rad > 0:  # the fused orientation is off by a slowly varying small angle
        quat = rotations.multiply(quat, _fusion_error(config, value_t))

    gravity = rotations.rotate_into_frame(quat, np.array([0.0, 0.0, g_m_s2]))
    identity = imp.DEFAULT_AXIS_MAP_CONFIG
    if any(imperfect.axis_map_config[n] != identity or imperfect.axis_map_sign[n] for n in range(2)):  # remapped
        remaps = [imp.axis_remap_matrix(imperfect.axis_map_config[n], imperfect.axis_map_sign[n]) for n in range(2)]
        p = np.stack(remaps)  # (2, 3, 3): output = P @ chip axes
        accel, gyro, gravity = (np.einsum("kij,mkj->mki", p, v) for v in (accel, gyro, gravity))
        q_remap = np.stack([imp.remap_quaternion(r) for r in remaps])
        quat = rotations.multiply(quat, np.broadcast_to(q_remap, quat.shape))
    if imperfect.heading_rad:  # the quaternions' world frame is turned by the heading about the vertical
        north = rotations.from_rotvec(np.array([0.0, 0.0, imperfect.heading_rad]))
        quat = rotations.multiply(np.broadcast_to(rotations.conjugate(north), quat.shape), quat)

    if config.noise:
        streams = noise if noise is not None else _NoiseStreams(config, len(t_s))
        accel, gyro, quat, gravity = streams.apply(accel, gyro, quat, gravity)
    linear = accel - gravity
    if config.noise:
        linear = _quantize(linear, ACCEL_LSB_M_S2)
    m = len(t_s)
    calibration = np.broadcast_to(np.asarray(config.calibration, dtype=np.uint8), (m, 2, 4)).copy()
    stamp = log = received = None
    if any(imperfect.clock_offset_s) or imperfect.any_timing or imperfect.latency_s > 0:
        stamp = t_s[:, None] + np.asarray(imperfect.clock_offset_s)[None, :]
        log = sample_t.copy()
        if imperfect.latency_s > 0:  # the recorder takes each node's packets in order
            log += np.random.default_rng([config.seed, 2]).exponential(imperfect.latency_s, (m, 2))
            log = np.maximum.accumulate(log, axis=0)
    if imperfect.packet_loss > 0:
        rng = np.random.default_rng([config.seed, 1])
        received = np.stack(
            [imp.gilbert_loss(rng, m, imperfect.packet_loss, imperfect.loss_burst_samples) for _ in range(2)], axis=1
        )
    return ImuSamples(
        t_s=t_s,
        fused_t_s=value_t[:, 0],
        gyro_rad_s=gyro,
        accel_m_s2=accel,
        linear_accel_m_s2=linear,
        gravity_m_s2=gravity,
        quat_wxyz=quat,
        calibration=calibration,
        config=config,
        value_t_s=value_t,
        stamp_s=stamp,
        log_t_s=log,
        received=received,
    )


def flicker_noise(rng: np.random.Generator, shape: tuple[int, ...], rate_hz: float, b: np.ndarray) -> np.ndarray:
    """Flicker (1/f) noise along axis 0 with one-sided PSD B^2 / (pi f), so that its Allan
    deviation is flat at 0.664 B (IEEE 952 bias instability). ``b`` broadcasts over shape[1:]."""
    n = shape[0]
    f = np.fft.rfftfreq(n, d=1.0 / rate_hz)
    scale = np.zeros_like(f)
    scale[1:] = np.sqrt(1.0 / (np.pi * f[1:]) * n * rate_hz / 4.0)  # E|X_k|^2 = S(f) n fs / 2
    spectrum = rng.standard_normal((len(f), *shape[1:])) + 1j * rng.standard_normal((len(f), *shape[1:]))
    spectrum *= scale.reshape(-1, *([1] * (len(shape) - 1)))
    return np.fft.irfft(spectrum, n=n, axis=0) * np.asarray(b)


def _quantize(x: np.ndarray, lsb: float) -> np.ndarray:
    return np.rint(x / lsb) * lsb


def _white_sigma(sigma: np.ndarray, lsb: float) -> np.ndarray:
    """Sigma to draw so that white noise plus quantisation (variance LSB^2/12) has std sigma."""
    return np.sqrt(np.maximum(np.square(sigma) - lsb * lsb / 12.0, 0.0))


class _NoiseStreams:
    """The noise of a whole run, drawn sample after sample in any block sizes.

    Each component has its own generator spawned from the seed (white accel, white gyro, accel
    walk, gyro walk, flicker), so a block's draws do not depend on how the run is cut. Walks
    carry their running sum; flicker noise is synthesised for all ``total`` samples at once."""

    def __init__(self, config: Bno055, total: int) -> None:
        self.config = config
        streams = np.random.SeedSequence(config.seed).spawn(5)
        self.accel_rng, self.gyro_rng, self.accel_walk_rng, self.gyro_walk_rng, flicker_rng = (
            np.random.default_rng(s) for s in streams
        )
        n = config.noise_model
        self.walk_sum = {"accel": np.zeros((2, 3)), "gyro": np.zeros((2, 3))}
        self.position = 0
        rng = np.random.default_rng(flicker_rng.bit_generator)
        self.flicker = {
            name: flicker_noise(rng, (total, 2, 3), config.sample_rate_hz, np.asarray(b)) if any(b) else None
            for name, b in (("accel", n.accel_bias_instability_m_s2), ("gyro", n.gyro_bias_instability_rad_s))
        }

    def apply(self, accel, gyro, quat, gravity):
        config = self.config
        n = config.noise_model
        m = len(accel)
        dt = 1.0 / config.sample_rate_hz
        accel_sigma = _white_sigma(np.asarray(n.accel_sigma_m_s2), ACCEL_LSB_M_S2)
        gyro_sigma = _white_sigma(np.asarray(n.gyro_sigma_rad_s), GYRO_LSB_RAD_S)
        accel = accel + self.accel_rng.standard_normal((m, 2, 3)) * accel_sigma + np.asarray(n.accel_bias_m_s2)
        gyro = gyro + self.gyro_rng.standard_normal((m, 2, 3)) * gyro_sigma + np.asarray(n.gyro_bias_rad_s)
        walks = (
            ("accel", accel, n.accel_bias_walk_m_s2_per_sqrt_s, self.accel_walk_rng),
            ("gyro", gyro, n.gyro_bias_walk_rad_s_per_sqrt_s, self.gyro_walk_rng),
        )
        for name, values, walk, rng in walks:
            if any(walk):
                steps = rng.standard_normal((m, 2, 3)) * (np.asarray(walk) * math.sqrt(dt))
                if self.position == 0 and m:
                    steps[0] = 0.0
                # Sequential sums from the carried total: the same additions in the same order
                # whatever the block sizes.
                path = np.cumsum(np.concatenate([self.walk_sum[name][None], steps]), axis=0)[1:]
                values += path
                if m:
                    self.walk_sum[name] = path[-1].copy()
        for name, values in (("accel", accel), ("gyro", gyro)):
            flicker = self.flicker[name]
            if flicker is not None:
                values += flicker[self.position : self.position + m]
        self.position += m
        accel = np.clip(accel, -config.accel_range_m_s2, config.accel_range_m_s2)
        return (
            _quantize(accel, ACCEL_LSB_M_S2),
            _quantize(gyro, GYRO_LSB_RAD_S),
            _quantize(quat, QUAT_LSB),
            _quantize(gravity, ACCEL_LSB_M_S2),
        )


def hinge_readings(
    params: RigParams, phi_rad: np.ndarray, omega_rad_s: np.ndarray, alpha_rad_s2: np.ndarray
) -> dict[str, np.ndarray]:
    """Both nodes' ideal readings on the planar rig at given states, in closed form, without MuJoCo:
    MuJoCo's IMU sensors of the model's mount at the disk centres (``simulation.evaluate_states``
    gives the same to rounding, tested), for a live loop that computes them as it goes.

    The orientation is the pendulum's swing by phi about the hinge times the site's rest frame
    (``rotations.pendulum_quat_wxyz``, ``rotations.IMU_SITE_QUAT_WXYZ``); the gyro reads omega on z;
    the accelerometer reads gravity's specific force in the sensor's axes, (g sin phi, g cos phi, 0)
    (spec RIG.md section 6), plus the disk centre's kinematic acceleration (r phi'' tangential on
    x, r phi'^2 toward the pivot on y).

    Args:
      params: the rig (g, the disk centres' radii OM1, OM2).
      phi_rad, omega_rad_s, alpha_rad_s2: (m, 2) angles, rates and angular accelerations.

    Returns:
      dict with ``imu_accel_m_s2``, ``imu_gyro_rad_s``, ``imu_angacc_rad_s2`` (m, 2, 3) and
      ``imu_quat_wxyz`` (m, 2, 4), as ``evaluate_states``.
    """
    phi = np.asarray(phi_rad, dtype=float)
    omega = np.asarray(omega_rad_s, dtype=float)
    alpha = np.asarray(alpha_rad_s2, dtype=float)
    if phi.ndim != 2 or phi.shape[1] != 2 or omega.shape != phi.shape or alpha.shape != phi.shape:
        raise ParameterError(
            f"angles, rates and accelerations must have shape (m, 2), got {phi.shape}, {omega.shape}, {alpha.shape}"
        )
    site = np.broadcast_to(rotations.IMU_SITE_QUAT_WXYZ, (*phi.shape, 4))
    quat = rotations.multiply(rotations.pendulum_quat_wxyz(phi), site)
    radius = np.array([params.om1_m, params.om2_m])
    zeros = np.zeros_like(phi)
    g = params.g_m_s2
    accel = np.stack([g * np.sin(phi) + radius * alpha, g * np.cos(phi) + radius * omega**2, zeros], axis=-1)
    return {
        "imu_accel_m_s2": accel,
        "imu_gyro_rad_s": np.stack([zeros, zeros, omega], axis=-1),
        "imu_angacc_rad_s2": np.stack([zeros, zeros, alpha], axis=-1),
        "imu_quat_wxyz": quat,
    }


class LiveImu:
    """Both nodes measured a few samples at a time from ideal readings a live loop computes (the
    emulated rig with motors): the mount, axis remap, heading, noise, clipping and quantisation of
    ``sample_imu``, the noise drawn from one run's streams as the samples come (seeded: the same
    calls give the same values). A sample's value is its instant's (the caller picks the instant:
    the latest fused tick, or the sample's own).

    Imperfections drawn over a whole run (fusion error, packet loss, latency) and bias instability
    (flicker noise, synthesised for a whole run at once) cannot be drawn live and are refused.

    Args:
      config: the node model.
      g_m_s2: gravity, m/s^2 (the gravity vector output).
    """

    def __init__(self, config: Bno055, g_m_s2: float) -> None:
        n = config.noise_model
        if not streamable(config) or (
            config.noise and (any(n.accel_bias_instability_m_s2) or any(n.gyro_bias_instability_rad_s))
        ):
            raise ParameterError(
                "a live node model cannot draw fusion error, packet loss, latency or bias instability (whole-run "
                "processes); the emulator's own network faults stand for loss and latency"
            )
        self.config, self.g_m_s2 = config, float(g_m_s2)
        self._noise = _NoiseStreams(config, 0) if config.noise else None

    def measure(self, readings: dict[str, np.ndarray], t_s: np.ndarray) -> ImuSamples:
        """Both nodes' measured samples of ideal ``readings`` ((m, 2, ...), ``hinge_readings``)
        taken at instants ``t_s`` (m,), s."""
        t = np.asarray(t_s, dtype=float)
        instants = np.stack([t, t], axis=1)
        return _measure_readings(readings, t, instants, self.g_m_s2, self.config, instants, noise=self._noise)
