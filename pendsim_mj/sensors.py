"""A simulated BNO055 node on each pendulum (spec RIG.md section 6; FIELD-NOTES: BNO055).

What the real node does, and how it is modelled:

- **Sampling**: the ESP32 node reads the chip at 80 Hz; samples carry timestamps k/80 s.
- **Fusion timing** (``fusion_timing=True``, default): in NDOF mode the chip fuses at 100 Hz, and
  the node reads the latest fused value, so each sample is 0-10 ms old and about one fused value
  in five is never read. The fused instants lie on the 10 ms simulation grid, so the values are
  the trajectory's own rows, exactly.
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
"""

from __future__ import annotations

import dataclasses
import math
from fractions import Fraction

import numpy as np

from pendsim_mj import rotations
from pendsim_mj.errors import ParameterError
from pendsim_mj.params import RigParams
from pendsim_mj.trajectory import Trajectory

STANDARD_GRAVITY_M_S2 = 9.80665  # the "g" of the chip's range setting
ACCEL_LSB_M_S2 = 0.01  # BNO055 datasheet: 1 m/s^2 = 100 LSB (acceleration, linear, gravity)
GYRO_LSB_RAD_S = 1.0 / 900.0  # BNO055 datasheet: 1 rad/s = 900 LSB
QUAT_LSB = 2.0**-14  # BNO055 datasheet: quaternion 1 = 2^14 LSB
CALIBRATION_FIELDS = ("system", "gyro", "accel", "mag")

Vec3 = tuple[float, float, float]


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

    sample_rate_hz: float = 80.0
    fusion_rate_hz: float = 100.0
    fusion_timing: bool = True
    noise: bool = True
    noise_model: ImuNoise = ImuNoise()
    accel_range_m_s2: float = 4 * STANDARD_GRAVITY_M_S2
    mount_offset_m: tuple[Vec3, Vec3] = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    mount_quat_wxyz: tuple[tuple[float, float, float, float], ...] = ((1.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
    calibration: tuple[int, int, int, int] = (3, 3, 3, 3)
    seed: int = 0

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
      t_s: (m,) sample instants, s.
      fused_t_s: (m,) instant of the value each sample carries (= t_s without fusion timing).
      gyro_rad_s: (m, 2, 3) angular velocity.
      accel_m_s2: (m, 2, 3) acceleration including gravity (specific force).
      linear_accel_m_s2: (m, 2, 3) acceleration with gravity removed.
      gravity_m_s2: (m, 2, 3) gravity vector (reads +g upward, like the accelerometer at rest).
      quat_wxyz: (m, 2, 4) orientation of the sensor frame in the world frame.
      calibration: (m, 2, 4) uint8 status 0-3 of (system, gyro, accel, mag).
      config: the Bno055 configuration that made them.
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


def _grid_ratio(a_hz: float, b_hz: float) -> Fraction:
    return Fraction(a_hz).limit_denominator(10**6) / Fraction(b_hz).limit_denominator(10**6)


def sample_instants(traj: Trajectory, config: Bno055) -> tuple[np.ndarray, np.ndarray]:
    """Sample indices k and the instants (s) of the values they carry, as (m,) arrays."""
    duration = traj.t_s[-1]
    m = math.floor(duration * config.sample_rate_hz + 1e-9) + 1
    k = np.arange(m)
    if config.fusion_timing:
        # latest fused value: j = floor(k * fusion / sample), exactly, with rational rates
        ratio = _grid_ratio(config.fusion_rate_hz, config.sample_rate_hz)
        j = (k * ratio.numerator) // ratio.denominator
        return k, j / config.fusion_rate_hz
    return k, k / config.sample_rate_hz


def _hermite_states(traj: Trajectory, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """phi, omega (m, 2) at arbitrary instants: quintic Hermite through (phi, omega, alpha)."""
    h = traj.dt_s
    i = np.clip(np.floor(t_s / h + 1e-9).astype(int), 0, len(traj.t_s) - 2)
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


def _ideal_readings(traj: Trajectory, fused_t_s: np.ndarray, on_grid: bool) -> dict[str, np.ndarray]:
    if on_grid:
        steps = fused_t_s / traj.dt_s
        idx = np.rint(steps).astype(int)
        if np.max(np.abs(steps - idx)) > 1e-6 or idx[-1] >= len(traj.t_s):
            raise ParameterError(
                f"fusion timing needs a simulation step that divides the fusion period; got dt_s = {traj.dt_s} s"
            )
        return {
            "imu_accel_m_s2": traj.imu_accel_m_s2[idx],
            "imu_gyro_rad_s": traj.imu_gyro_rad_s[idx],
            "imu_quat_wxyz": traj.imu_quat_wxyz[idx],
            "imu_angacc_rad_s2": traj.imu_angacc_rad_s2[idx],
        }
    from pendsim_mj.simulation import evaluate_states

    params = traj.params[0] if isinstance(traj.params, tuple) else traj.params
    phi, omega = _hermite_states(traj, fused_t_s)
    return evaluate_states(params, phi, omega)


def sample_imu(traj: Trajectory, config: Bno055 = Bno055(), *, hold_s: float = 0.0) -> ImuSamples:
    """Sample both BNO055 nodes over a simulated run.

    Args:
      traj: a single (not batch) trajectory from either engine.
      config: the node model.
      hold_s: the recording starts this long before the release, with the pendulums held still
        at their initial angles (as a real recording does); rounded to whole samples. The
        trajectory's t = 0 is then at ``hold_s`` in the samples' time.

    Returns:
      ImuSamples with m = floor(duration * sample_rate) + 1 samples (plus the held ones).
    """
    if traj.is_batch:
        raise ParameterError("sample_imu takes a single trajectory; use trajectory.member(i)")
    if not (math.isfinite(hold_s) and hold_s >= 0):
        raise ParameterError(f"hold_s must be a finite number >= 0 s, got {hold_s!r}")
    if not config.fusion_timing and np.any(traj.tilt_rad):
        raise ParameterError("ideal timing interpolates the planar state only; use fusion timing for the spatial model")
    k, fused_t = sample_instants(traj, config)
    readings = _ideal_readings(traj, fused_t, on_grid=config.fusion_timing)
    params = traj.params[0] if isinstance(traj.params, tuple) else traj.params
    t_s = k / config.sample_rate_hz
    held = round(hold_s * config.sample_rate_hz)
    if held:
        # Held still: no rotation, and the accelerometer reads gravity alone (specific force -g).
        quat = readings["imu_quat_wxyz"][:1]
        at_rest = {
            "imu_quat_wxyz": quat,
            "imu_gyro_rad_s": np.zeros((1, 2, 3)),
            "imu_angacc_rad_s2": np.zeros((1, 2, 3)),
            "imu_accel_m_s2": rotations.rotate_into_frame(quat, np.array([0.0, 0.0, params.g_m_s2])),
        }
        readings = {
            name: np.concatenate([np.broadcast_to(at_rest[name], (held, 2, value.shape[-1])), value])
            for name, value in readings.items()
        }
        offset = held / config.sample_rate_hz
        t_s = np.arange(held + len(t_s)) / config.sample_rate_hz
        fused_t = np.concatenate([t_s[:held], fused_t + offset])
    return _measure_readings(readings, t_s, fused_t, params.g_m_s2, config)


def static_imu(params: RigParams, duration_s: float, config: Bno055 = Bno055()) -> ImuSamples:
    """Both nodes at rest on the hanging rig for ``duration_s`` (a static noise test): MuJoCo's
    sensors at the rest pose, repeated at every sample, then the same mount and noise model."""
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ParameterError(f"duration_s must be a finite number > 0 s, got {duration_s!r}")
    from pendsim_mj.simulation import evaluate_states

    m = math.floor(duration_s * config.sample_rate_hz + 1e-9) + 1
    t_s = np.arange(m) / config.sample_rate_hz
    rest = evaluate_states(params, np.zeros((1, 2)), np.zeros((1, 2)))
    readings = {name: np.broadcast_to(value, (m, *value.shape[1:])) for name, value in rest.items()}
    return _measure_readings(readings, t_s, t_s, params.g_m_s2, config)


def _measure_readings(
    readings: dict[str, np.ndarray], t_s: np.ndarray, fused_t: np.ndarray, g_m_s2: float, config: Bno055
) -> ImuSamples:
    """Mount transform, gravity, linear acceleration and (optionally) noise, for ideal readings."""
    accel = readings["imu_accel_m_s2"]
    gyro = readings["imu_gyro_rad_s"]
    angacc = readings["imu_angacc_rad_s2"]
    quat = readings["imu_quat_wxyz"]

    # Mount: offset by rigid-body kinematics, then the mount rotation.
    d = np.asarray(config.mount_offset_m, dtype=float)  # (2, 3)
    accel = accel + np.cross(angacc, d) + np.cross(gyro, np.cross(gyro, d))
    q_mount = np.asarray(config.mount_quat_wxyz, dtype=float)  # (2, 4)
    r_mount = rotations.to_matrix(q_mount)  # (2, 3, 3)
    accel = np.einsum("kji,mkj->mki", r_mount, accel)
    gyro = np.einsum("kji,mkj->mki", r_mount, gyro)
    quat = rotations.multiply(quat, np.broadcast_to(q_mount, quat.shape))

    gravity = rotations.rotate_into_frame(quat, np.array([0.0, 0.0, g_m_s2]))
    if config.noise:
        accel, gyro, quat, gravity = _measure(accel, gyro, quat, gravity, config, t_s)
    linear = accel - gravity
    if config.noise:
        linear = _quantize(linear, ACCEL_LSB_M_S2)
    calibration = np.broadcast_to(np.asarray(config.calibration, dtype=np.uint8), (len(t_s), 2, 4)).copy()
    return ImuSamples(
        t_s=t_s,
        fused_t_s=fused_t,
        gyro_rad_s=gyro,
        accel_m_s2=accel,
        linear_accel_m_s2=linear,
        gravity_m_s2=gravity,
        quat_wxyz=quat,
        calibration=calibration,
        config=config,
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


def _measure(accel, gyro, quat, gravity, config: Bno055, t_s: np.ndarray):
    rng = np.random.default_rng(config.seed)
    n = config.noise_model
    m = len(t_s)
    dt = 1.0 / config.sample_rate_hz
    accel_sigma = _white_sigma(np.asarray(n.accel_sigma_m_s2), ACCEL_LSB_M_S2)
    gyro_sigma = _white_sigma(np.asarray(n.gyro_sigma_rad_s), GYRO_LSB_RAD_S)
    accel = accel + rng.standard_normal((m, 2, 3)) * accel_sigma + np.asarray(n.accel_bias_m_s2)
    gyro = gyro + rng.standard_normal((m, 2, 3)) * gyro_sigma + np.asarray(n.gyro_bias_rad_s)
    for values, walk in ((accel, n.accel_bias_walk_m_s2_per_sqrt_s), (gyro, n.gyro_bias_walk_rad_s_per_sqrt_s)):
        if any(walk):
            steps = rng.standard_normal((m, 2, 3)) * (np.asarray(walk) * math.sqrt(dt))
            steps[0] = 0.0
            values += np.cumsum(steps, axis=0)
    for values, b in ((accel, n.accel_bias_instability_m_s2), (gyro, n.gyro_bias_instability_rad_s)):
        if any(b):
            values += flicker_noise(rng, (m, 2, 3), config.sample_rate_hz, np.asarray(b))
    accel = np.clip(accel, -config.accel_range_m_s2, config.accel_range_m_s2)
    return (
        _quantize(accel, ACCEL_LSB_M_S2),
        _quantize(gyro, GYRO_LSB_RAD_S),
        _quantize(quat, QUAT_LSB),
        _quantize(gravity, ACCEL_LSB_M_S2),
    )
