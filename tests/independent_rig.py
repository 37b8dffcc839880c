"""An independent generator of two-node lab recordings of the rig, for tests of what pendsim reads
from files it did not make: none of pendsim's engines, sensor model, rotations or writers is used.

- Physics: the planar equations of /work/shared/spec/RIG.md section 4 written out again here (the
  moments of the spring forces as x Fy - y Fx at points 1, 2, 3 and 5), integrated by scipy's
  ``solve_ivp`` (DOP853, rtol 1e-11, atol 1e-12); only the rig's numbers come from
  ``DEFAULT_PARAMS``.
- Release: from rest after a hold, in mode 1, mode 2 or in between (the linear mode shapes of
  these equations, found here by finite differences and ``numpy.linalg.eig``).
- Sensors: each node's chip turned on its mount (a given rotation: e.g. 180 deg about the rod, so
  that its z axis points the other way), a heading about the vertical; gyro (chip axes), specific
  force (chip axes, gravity included) and a unit quaternion (w, x, y, z) of the chip in a z-up
  world frame, each with its own white noise; sampled at each node's own regular instants
  (80-100 Hz).
- Times as a lab logger may write them: each node's own column with an offset, one shared column
  (M1's instants, or the mean of both nodes' instants), and a step of the clock at some instant.

The CSV is in ``pendsim import``'s format (docs/acquisition.md): a header of pendsim names
(``t_s`` or ``m1.t_s``/``m2.t_s``, ``m1.ax`` ... ``m2.qz``), accelerations in m/s2, gyro in dps.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from pendsim_mj import DEFAULT_PARAMS

P = DEFAULT_PARAMS
GYRO_SIGMA_RAD_S = 0.0015
ACCEL_SIGMA_M_S2 = 0.012
QUAT_SIGMA_RAD = 5e-4
RADIUS_M = (P.om1_m, P.om2_m)  # the nodes at the disks' centres
NAMES = ("ax", "ay", "az", "gx", "gy", "gz", "qw", "qx", "qy", "qz")


def _moments(phi1: np.ndarray, phi2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The springs' moments about O on M1 and M2 (paper frame: x down, y horizontal), N m."""
    c1, s1, c2, s2 = np.cos(phi1), np.sin(phi1), np.cos(phi2), np.sin(phi2)
    p1 = np.array([P.l01_m * c2, P.l01_m * s2])
    p2 = np.array([P.l04_m * c1 - P.l24_m * s1, P.l04_m * s1 + P.l24_m * c1])
    p3 = np.array([P.l04_m * c1 + P.l34_m * s1, P.l04_m * s1 - P.l34_m * c1])
    p5 = np.array([P.l05_m * c2, P.l05_m * s2])
    p6 = np.array([P.l08_m + 0 * c1, P.l68_m + 0 * c1])
    p7 = np.array([P.l08_m + 0 * c1, -P.l78_m + 0 * c1])

    def torque(r, f):
        return r[0] * f[1] - r[1] * f[0]

    f2, f3 = P.c1_n_m * (p1 - p2), P.c1_n_m * (p1 - p3)
    f1 = -f2 - f3
    f5 = P.c2_n_m * (p6 - p5) + P.c2_n_m * (p7 - p5)
    return torque(p2, f2) + torque(p3, f3), torque(p1, f1) + torque(p5, f5)


def _accelerations(phi, omega, b):
    m1, m2 = _moments(phi[0], phi[1])
    a1 = (-b[0] * omega[0] - P.m1_kg * P.g_m_s2 * P.oc1_m * np.sin(phi[0]) + m1) / P.j1_kg_m2
    a2 = (-b[1] * omega[1] - P.m2_kg * P.g_m_s2 * P.oc2_m * np.sin(phi[1]) + m2) / P.j2_kg_m2
    return np.array([a1, a2])


def mode_shapes() -> np.ndarray:
    """(2, 2): the linear modes' shapes as columns (mode 1, the slower, first), M1's entry 1."""
    eps = 1e-6
    k = np.zeros((2, 2))
    for j in range(2):
        d = np.zeros(2)
        d[j] = eps
        k[:, j] = -(_accelerations(d, np.zeros(2), (0, 0)) - _accelerations(-d, np.zeros(2), (0, 0))) / (2 * eps)
    w2, shapes = np.linalg.eig(k)
    order = np.argsort(w2)
    shapes = shapes[:, order]
    return shapes / shapes[0]


@dataclasses.dataclass(frozen=True)
class Lab:
    """One recording. Angles in degrees (M1's release; M2's from ``mode``: 1, 2, or a float
    ratio phi2/phi1 instead), times in s."""

    phi1_deg: float = 34.0
    mode: float = 1  # 1, 2: the linear mode shapes; any other value: phi2 = mode * phi1
    b: tuple[float, float] = (P.b1_n_m_s, P.b2_n_m_s)
    duration_s: float = 30.0
    hold_s: float = 1.0
    rate_hz: tuple[float, float] = (80.0, 80.0)
    first_s: tuple[float, float] = (0.0, 0.004)  # each node's first true sampling instant
    offset_s: tuple[float, float] = (0.0, 0.0)  # added to each node's time column
    shared: str | None = None  # None: a column per node; "m1": M1's instants for both; "mean"
    step_at_s: float | None = None  # the clock steps at this true instant ...
    step_s: float = 0.0  # ... by this much (both columns)
    mounts: tuple[tuple[float, float, float], tuple[float, float, float]] = ((0, 0, 0), (0, 0, 0))
    """Each chip's mount as a rotation vector (deg) in the ideal frame (x tangential, y toward the
    pivot, z along the hinge): (0, 180, 0) turns it over about the rod."""
    heading_deg: float = 30.0
    seed: int = 0

    def release_angles_rad(self) -> np.ndarray:
        ratio = mode_shapes()[1, int(self.mode) - 1] if self.mode in (1, 2) else float(self.mode)
        return np.radians(self.phi1_deg) * np.array([1.0, ratio])


def motion(lab: Lab, t_s: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """phi, omega, alpha (2, n_k) at each list entry's true instants (n_k,) (at rest before
    ``hold_s``): one integration, its dense output (DOP853's, 7th order) evaluated there."""
    phi0 = lab.release_angles_rad()
    end = max(float(t[-1]) for t in t_s) - lab.hold_s + 0.01
    sol = solve_ivp(
        lambda _t, y: np.concatenate([y[2:], _accelerations(y[:2], y[2:], lab.b)]),
        (0.0, end),
        np.concatenate([phi0, [0.0, 0.0]]),
        method="DOP853",
        rtol=1e-11,
        atol=1e-12,
        dense_output=True,
    )
    out = []
    for t in t_s:
        after = t > lab.hold_s
        phi = np.repeat(phi0[:, None], len(t), axis=1)
        omega = np.zeros_like(phi)
        state = sol.sol(t[after] - lab.hold_s)
        phi[:, after], omega[:, after] = state[:2], state[2:]
        alpha = _accelerations(phi, omega, lab.b)
        alpha[:, ~after] = 0.0
        out.append((phi, omega, alpha))
    return out


def _readings(lab: Lab, node: int, phi, omega, alpha, rng) -> np.ndarray:
    """(n, 10): ax, ay, az (m/s2), gx, gy, gz (dps), qw, qx, qy, qz of one chip."""
    n = len(phi)
    c, s = np.cos(phi), np.sin(phi)
    r = RADIUS_M[node]
    # the ideal sensor frame in the paper frame (x down, y horizontal, z the hinge): columns
    x_s = np.stack([-s, c, np.zeros(n)], axis=1)
    y_s = np.stack([-c, -s, np.zeros(n)], axis=1)
    z_s = np.broadcast_to([0.0, 0.0, 1.0], (n, 3))
    frame = np.stack([x_s, y_s, z_s], axis=2)  # (n, 3, 3): sensor -> paper
    accel_p = r * alpha[:, None] * x_s - r * (omega**2)[:, None] * np.stack([c, s, np.zeros(n)], axis=1)
    specific_p = accel_p - np.array([P.g_m_s2, 0.0, 0.0])  # gravity along +x (down)
    mount = Rotation.from_rotvec(np.radians(lab.mounts[node])).as_matrix()  # chip -> sensor
    to_chip = np.einsum("ji,njk->nik", mount, np.transpose(frame, (0, 2, 1)))  # paper -> chip
    specific = np.einsum("nij,nj->ni", to_chip, specific_p)
    gyro = np.einsum("nij,nj->ni", to_chip, omega[:, None] * z_s)
    paper_to_world = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])  # x down -> -z up
    heading = Rotation.from_rotvec([0.0, 0.0, math.radians(lab.heading_deg)]).as_matrix()
    chip_to_world = heading @ paper_to_world @ np.einsum("nij,jk->nik", frame, mount)
    noise = Rotation.from_rotvec(rng.normal(0.0, QUAT_SIGMA_RAD, (n, 3)))
    q = (Rotation.from_matrix(chip_to_world) * noise).as_quat()  # x, y, z, w
    q = np.round(q * 2**14) / 2**14
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    accel = specific + rng.normal(0.0, ACCEL_SIGMA_M_S2, (n, 3))
    gyro_dps = np.degrees(gyro + rng.normal(0.0, GYRO_SIGMA_RAD_S, (n, 3)))
    return np.concatenate([accel, gyro_dps, q[:, [3, 0, 1, 2]]], axis=1)


def write_csv(lab: Lab, path: Path) -> None:
    """The recording as a lab's CSV (module docstring)."""
    rng = np.random.default_rng(lab.seed)
    count = min(int(lab.duration_s * f) for f in lab.rate_hz)
    true_t = [lab.first_s[k] + np.arange(count) / lab.rate_hz[k] for k in range(2)]
    states = motion(lab, true_t)
    readings = [_readings(lab, k, *(a[k] for a in states[k]), rng) for k in range(2)]

    def column(t: np.ndarray) -> np.ndarray:
        stepped = t + (lab.step_s if lab.step_at_s is not None else 0.0) * (t >= (lab.step_at_s or 0.0))
        return stepped

    if lab.shared is None:
        times = [column(true_t[k]) + lab.offset_s[k] for k in range(2)]
        names, columns = ["m1.t_s", "m2.t_s"], times
    else:
        t = true_t[0] if lab.shared == "m1" else 0.5 * (true_t[0] + true_t[1])
        names, columns = ["t_s"], [column(t) + lab.offset_s[0]]
    for k in range(2):
        names += [f"m{k + 1}.{name}" for name in NAMES]
        columns += list(readings[k].T)
    table = np.stack(columns, axis=1)
    formats = ["%.6f"] * (len(columns) - 20) + ["%.6g"] * 20
    np.savetxt(path, table, delimiter=",", header=",".join(names), comments="", fmt=formats)
