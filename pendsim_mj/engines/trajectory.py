"""The trajectory container both engines return. Imports no physics engine.

Shapes: ``n`` samples at t_s = k * dt_s, k = 0..n-1. A batch from ``simulate_batch`` /
``reference.solve_batch`` has one more leading axis ``nbatch`` on every array but ``t_s``.
Every quantity in row k belongs to the instant t_s[k].

Frames: pendulum index 0 is M1, 1 is M2. IMU readings are in sensor axes: x tangential
(direction of increasing phi), y along the rod toward the pivot, z along the pivot axis
(paper +z). Quaternions are w, x, y, z (MuJoCo's order) and give the sensor frame in the
MuJoCo world frame (z up; see models/pendulums.xml for the mapping to the paper frame).
Springs are ordered 1-2, 1-3, 5-6, 5-7.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pendsim_mj.rig.drives import CHANNEL_LABELS, Drive
from pendsim_mj.rig.params import RigParams
from pendsim_mj.sensors import rotations

SPRING_LABELS = ("1-2", "1-3", "5-6", "5-7")


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """A simulated run, every quantity paired with its own instant.

    Attributes:
      t_s: (n,) time, s.
      phi_rad: (..., n, 2) angles phi1, phi2 from the downward vertical, rad.
      omega_rad_s: (..., n, 2) angular velocities, rad/s.
      alpha_rad_s2: (..., n, 2) angular accelerations, rad/s^2.
      imu_accel_m_s2: (..., n, 2, 3) accelerometer (specific force, gravity included) per IMU,
        sensor axes, m/s^2. At rest: (0, +g, 0).
      imu_gyro_rad_s: (..., n, 2, 3) gyroscope per IMU, sensor axes, rad/s.
      imu_quat_wxyz: (..., n, 2, 4) orientation of each IMU frame in the world frame.
      imu_angacc_rad_s2: (..., n, 2, 3) angular acceleration of each pendulum, sensor axes
        (planar model: (0, 0, alpha)).
      tilt_rad: (..., n, 2) out-of-plane tilt of each pendulum's support (spatial variant; 0 in
        the planar model and the reference).
      spring_length_m: (..., n, 4) spring lengths, m.
      spring_force_n: (..., n, 4) spring tensions c * L, N.
      spring_moment_n_m: (..., n, 2) moment of the spring forces about the pivot axis on
        M1 and M2 (positive about paper +z), N m.
      kinetic_j: (..., n) kinetic energy, J.
      potential_j: (..., n) gravity + spring potential energy above the rest pose, J.
      dissipated_j: (..., n) energy dissipated by the hinges' damping and dry friction since t = 0, J.
      engine: "mujoco", "reference" or "fast" (the compiled planar kernel, ``fast_planar``).
      dt_s: integration step, s.
      params: the RigParams used (a tuple of them for a batch).
      tilt_rate_rad_s: (..., n, 2) tilt rates of the spatial variant, rad/s (None where the
        engine has no tilt freedoms).
      drive_input: (..., n, 4) the input at each sample: torque_m1, torque_m2 (N m), support_x,
        pivot_z (m/s^2), see ``pendsim_mj.rig.drives``; zeros without a drive. Under the "stages"
        sampling the signal at the sample's instant; under "held" the input held over the step
        that starts there (the last sample repeats the last step's).
      support_m: (..., n, 2) displacement of the support (the frame and pivot axis) from its
        start, horizontal (world x, paper +y) and vertical (world z, up), m; zeros unless driven.
      drive: the Drive of the run (a tuple of them for a batch), or None.
      drive_sampling: how the RK4 stages saw the drive (``drives.Sampling`` value): "stages" (the
        signal at each stage's time, fourth order: the planar engines' default) or "held" (each
        step's midpoint value over the step, second order: MuJoCo).

    Energies are relative to the support: kinetic energy in the support's frame, potential energy
    with heights measured from the pivot (the same as in the reference, driven or not).
    """

    t_s: np.ndarray
    phi_rad: np.ndarray
    omega_rad_s: np.ndarray
    alpha_rad_s2: np.ndarray
    imu_accel_m_s2: np.ndarray
    imu_gyro_rad_s: np.ndarray
    imu_quat_wxyz: np.ndarray
    imu_angacc_rad_s2: np.ndarray
    tilt_rad: np.ndarray
    spring_length_m: np.ndarray
    spring_force_n: np.ndarray
    spring_moment_n_m: np.ndarray
    kinetic_j: np.ndarray
    potential_j: np.ndarray
    dissipated_j: np.ndarray
    engine: str
    dt_s: float
    params: RigParams | tuple[RigParams, ...]
    tilt_rate_rad_s: np.ndarray | None = None
    drive_input: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    support_m: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    drive: Drive | tuple[Drive | None, ...] | None = None
    drive_sampling: str = "held"

    def __post_init__(self) -> None:
        shape = self.phi_rad.shape[:-1]
        if self.drive_input.size == 0:  # not given: no drive
            object.__setattr__(self, "drive_input", np.zeros((*shape, len(CHANNEL_LABELS))))
        if self.support_m.size == 0:
            object.__setattr__(self, "support_m", np.zeros((*shape, 2)))

    ARRAY_FIELDS = (
        "phi_rad",
        "omega_rad_s",
        "alpha_rad_s2",
        "imu_accel_m_s2",
        "imu_gyro_rad_s",
        "imu_quat_wxyz",
        "imu_angacc_rad_s2",
        "tilt_rad",
        "spring_length_m",
        "spring_force_n",
        "spring_moment_n_m",
        "kinetic_j",
        "potential_j",
        "dissipated_j",
        "drive_input",
        "support_m",
    )

    @property
    def total_energy_j(self) -> np.ndarray:
        """Kinetic + potential energy above rest, J, shape (..., n)."""
        total: np.ndarray = self.kinetic_j + self.potential_j
        return total

    def body_quat_wxyz(self) -> np.ndarray:
        """(..., n, 2, 4) orientation of each pendulum body in the world: its tilt about world x
        (spatial variant), then its swing by phi about the rocked -y axis."""
        return rotations.pendulum_quat_wxyz(self.phi_rad, self.tilt_rad)

    @property
    def single_params(self) -> RigParams:
        """The parameters of a single run (the first member's for a batch)."""
        return self.params[0] if isinstance(self.params, tuple) else self.params

    @property
    def is_batch(self) -> bool:
        return self.phi_rad.ndim == 3

    def __len__(self) -> int:
        """Number of batch members (a single run counts as 1)."""
        return self.phi_rad.shape[0] if self.is_batch else 1

    def rows(self, rows: slice) -> Trajectory:
        """Some rows (instants) of a single run, as a trajectory of its own (views, no copy)."""
        if self.is_batch:
            raise IndexError("rows of a batch: take a member first")
        fields = {name: getattr(self, name)[rows] for name in self.ARRAY_FIELDS}
        tilt_rate = None if self.tilt_rate_rad_s is None else self.tilt_rate_rad_s[rows]
        return dataclasses.replace(self, t_s=self.t_s[rows], tilt_rate_rad_s=tilt_rate, **fields)

    def member(self, index: int) -> Trajectory:
        """One run of a batch as a plain trajectory."""
        if not self.is_batch:
            raise IndexError("not a batch trajectory")
        fields = {name: getattr(self, name)[index] for name in self.ARRAY_FIELDS}
        params = self.params[index] if isinstance(self.params, tuple) else self.params
        drive = self.drive[index] if isinstance(self.drive, tuple) else self.drive
        tilt_rate = None if self.tilt_rate_rad_s is None else self.tilt_rate_rad_s[index]
        return dataclasses.replace(self, **fields, params=params, drive=drive, tilt_rate_rad_s=tilt_rate)

    def table(self) -> tuple[list[str], list[np.ndarray]]:
        """Column names and (n,) columns of the scalar quantities, for CSV and printing."""
        names: list[str] = ["t_s"]
        cols: list[np.ndarray] = [self.t_s]
        for n in (1, 2):
            for label, arr in (("phi", self.phi_rad), ("omega", self.omega_rad_s), ("alpha", self.alpha_rad_s2)):
                unit = {"phi": "rad", "omega": "rad_s", "alpha": "rad_s2"}[label]
                names.append(f"{label}{n}_{unit}")
                cols.append(arr[:, n - 1])
        for n in (1, 2):
            for axis_i, axis in enumerate("xyz"):
                names.append(f"imu_m{n}_accel_{axis}_m_s2")
                cols.append(self.imu_accel_m_s2[:, n - 1, axis_i])
            for axis_i, axis in enumerate("xyz"):
                names.append(f"imu_m{n}_gyro_{axis}_rad_s")
                cols.append(self.imu_gyro_rad_s[:, n - 1, axis_i])
        for i, label in enumerate(SPRING_LABELS):
            tag = label.replace("-", "")
            names += [f"spring_{tag}_length_m", f"spring_{tag}_force_n"]
            cols += [self.spring_length_m[:, i], self.spring_force_n[:, i]]
        for n in (1, 2):
            names.append(f"spring_moment{n}_n_m")
            cols.append(self.spring_moment_n_m[:, n - 1])
        names += ["kinetic_j", "potential_j", "dissipated_j"]
        cols += [self.kinetic_j, self.potential_j, self.dissipated_j]
        if self.drive is not None:  # driven runs: the held inputs and the support's displacement
            names += [*CHANNEL_LABELS, "support_x_m", "support_z_m"]
            cols += [self.drive_input[:, i] for i in range(len(CHANNEL_LABELS))]
            cols += [self.support_m[:, 0], self.support_m[:, 1]]
        return names, cols


def planar_imu_readings(
    phi_rad: np.ndarray,
    omega_rad_s: np.ndarray,
    alpha_rad_s2: np.ndarray,
    radius_m: np.ndarray,
    g_m_s2: np.ndarray,
    *,
    support_h_m_s2: np.ndarray | None = None,
    support_v_m_s2: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ideal IMU readings of the planar model (spec RIG.md section 6), in the sensor axes above.

    Args:
      phi_rad, omega_rad_s, alpha_rad_s2: (..., 2) angle, rate and angular acceleration of M1, M2.
      radius_m: (..., 2) mount radius of each IMU (OM1, OM2), broadcastable against phi_rad.
      g_m_s2: gravity, broadcastable against phi_rad.
      support_h_m_s2, support_v_m_s2: the support's horizontal (paper +y) and upward acceleration
        (``pendsim_mj.rig.drives``), broadcastable against phi_rad, or None for a fixed support.

    Returns:
      accel (..., 2, 3): specific force (r alpha + g sin phi, r omega^2 + g cos phi, 0), m/s^2; with
      a moving support (r alpha + (g + a_v) sin phi + a_h cos phi, r omega^2 + (g + a_v) cos phi
      - a_h sin phi, 0); gyro (..., 2, 3): (0, 0, omega), rad/s; quat (..., 2, 4): the sensor frame
      in the MuJoCo world (rotation by phi about world -y applied to the mount: sensor x = world x,
      y = world z, z = world -y at rest); angacc (..., 2, 3): (0, 0, alpha), rad/s^2.
    """
    zero = np.zeros_like(phi_rad)
    if support_h_m_s2 is None and support_v_m_s2 is None:
        tangential = radius_m * alpha_rad_s2 + g_m_s2 * np.sin(phi_rad)
        normal = radius_m * omega_rad_s**2 + g_m_s2 * np.cos(phi_rad)
    else:  # the support's acceleration is part of the specific force
        a_h = 0.0 if support_h_m_s2 is None else support_h_m_s2
        g_v = g_m_s2 + (0.0 if support_v_m_s2 is None else support_v_m_s2)
        s, c = np.sin(phi_rad), np.cos(phi_rad)
        tangential = radius_m * alpha_rad_s2 + g_v * s + a_h * c
        normal = radius_m * omega_rad_s**2 + g_v * c - a_h * s
    accel = np.stack([tangential, normal, zero], axis=-1)
    gyro = np.stack([zero, zero, omega_rad_s], axis=-1)
    angacc = np.stack([zero, zero, alpha_rad_s2], axis=-1)
    quat = rotations.multiply(rotations.pendulum_quat_wxyz(phi_rad), rotations.IMU_SITE_QUAT_WXYZ)
    return accel, gyro, quat, angacc
