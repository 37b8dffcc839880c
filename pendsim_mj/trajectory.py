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
from pathlib import Path

import numpy as np

from pendsim_mj.params import RigParams

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
      dissipated_j: (..., n) energy dissipated by the hinge damping since t = 0, J.
      engine: "mujoco" or "reference".
      dt_s: integration step, s.
      params: the RigParams used (a tuple of them for a batch).
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
    )

    @property
    def total_energy_j(self) -> np.ndarray:
        """Kinetic + potential energy above rest, J, shape (..., n)."""
        return self.kinetic_j + self.potential_j

    def body_quat_wxyz(self) -> np.ndarray:
        """(..., n, 2, 4) orientation of each pendulum body in the world: its tilt about world x
        (spatial variant), then its swing by phi about the rocked -y axis."""
        half_t, half_p = self.tilt_rad / 2, self.phi_rad / 2
        zero = np.zeros_like(half_p)
        c_t, s_t, c_p, s_p = np.cos(half_t), np.sin(half_t), np.cos(half_p), np.sin(half_p)
        # (c_t, s_t, 0, 0) * (c_p, 0, -s_p, 0)
        return np.stack([c_t * c_p, s_t * c_p, -c_t * s_p, -s_t * s_p + zero], axis=-1)

    @property
    def is_batch(self) -> bool:
        return self.phi_rad.ndim == 3

    def __len__(self) -> int:
        """Number of batch members (a single run counts as 1)."""
        return self.phi_rad.shape[0] if self.is_batch else 1

    def member(self, index: int) -> Trajectory:
        """One run of a batch as a plain trajectory."""
        if not self.is_batch:
            raise IndexError("not a batch trajectory")
        fields = {name: getattr(self, name)[index] for name in self.ARRAY_FIELDS}
        params = self.params[index] if isinstance(self.params, tuple) else self.params
        return dataclasses.replace(self, **fields, params=params)

    def save(self, path: str | Path) -> Path:
        """Write a single run to ``.npz`` (all arrays) or ``.csv`` (scalar columns), atomically.

        The file appears only when complete: it is written beside its target and renamed.
        """
        if self.is_batch:
            raise ValueError("save one member at a time: trajectory.member(i).save(path)")
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in (".npz", ".csv"):
            raise ValueError(f"output must end in .npz or .csv, got {path.name!r}")
        tmp = path.with_name(f".{path.name}.partial")
        try:
            if suffix == ".npz":
                with open(tmp, "wb") as f:
                    np.savez(f, t_s=self.t_s, **{n: getattr(self, n) for n in self.ARRAY_FIELDS}, dt_s=self.dt_s)
            else:
                header, columns = self.table()
                np.savetxt(tmp, np.column_stack(columns), delimiter=",", header=",".join(header), comments="")
            tmp.replace(path)
        finally:
            tmp.unlink(missing_ok=True)
        return path

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
        return names, cols
