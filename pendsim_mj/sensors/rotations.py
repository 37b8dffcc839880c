"""Quaternion helpers, vectorised over leading axes. Order w, x, y, z (MuJoCo's, the BNO055's).

ROS and Rerun use x, y, z, w: convert only at that boundary with ``wxyz_to_xyzw``.
"""

from __future__ import annotations

import math

import numpy as np


def multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of (..., 4) quaternions."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions to (..., 3, 3) rotation matrices (columns: the frame's axes)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def rotate_into_frame(q: np.ndarray, v_world: np.ndarray) -> np.ndarray:
    """Express world vectors (..., 3) in the frame whose orientation is q (..., 4): R^T v."""
    return np.einsum("...ji,...j->...i", to_matrix(q), v_world)


def wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    """Reorder (..., 4) quaternions from w, x, y, z to x, y, z, w (ROS, Rerun)."""
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def xyzw_to_wxyz(q: np.ndarray) -> np.ndarray:
    """Reorder (..., 4) quaternions from x, y, z, w to w, x, y, z."""
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


# The IMU site's axes in its pendulum body at rest (models/pendulums.xml: xyaxes="1 0 0 0 0 1"):
# sensor x = world x (tangential), y = world z (toward the pivot), z = world -y (paper +z).
IMU_SITE_QUAT_WXYZ = np.array([math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])


def pendulum_quat_wxyz(phi_rad: np.ndarray, tilt_rad: np.ndarray | None = None) -> np.ndarray:
    """(..., 4) orientation of a pendulum body in the MuJoCo world: its support's tilt about world
    x (spatial variant; None or 0 in the planar model), then its swing by phi about the (rocked)
    hinge axis, world -y (paper +z)."""
    phi = np.asarray(phi_rad, dtype=float)
    half_t = np.zeros_like(phi) if tilt_rad is None else np.asarray(tilt_rad, dtype=float) / 2
    half_p = phi / 2
    c_t, s_t, c_p, s_p = np.cos(half_t), np.sin(half_t), np.cos(half_p), np.sin(half_p)
    # (c_t, s_t, 0, 0) * (c_p, 0, -s_p, 0)
    return np.stack([c_t * c_p, s_t * c_p, -c_t * s_p, -s_t * s_p], axis=-1)


def conjugate(q: np.ndarray) -> np.ndarray:
    """The inverse rotation of (..., 4) unit quaternions."""
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def from_rotvec(v: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors (axis times angle, rad) to (..., 4) unit quaternions."""
    v = np.asarray(v, dtype=float)
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(half)/angle, with its limit 1/2 at angle 0
    scale = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate([np.cos(half), v * scale], axis=-1)


def from_matrix(r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices (proper: det +1) to (..., 4) unit quaternions with w >= 0."""
    r = np.asarray(r, dtype=float)
    m = r.reshape(-1, 3, 3)
    out = np.empty((len(m), 4))
    for i, a in enumerate(m):  # Shepperd's method: the largest of w, x, y, z first
        trace = np.trace(a)
        k = int(np.argmax([trace, a[0, 0], a[1, 1], a[2, 2]]))
        if k == 0:
            s = 2.0 * np.sqrt(1.0 + trace)
            q = [0.25 * s, (a[2, 1] - a[1, 2]) / s, (a[0, 2] - a[2, 0]) / s, (a[1, 0] - a[0, 1]) / s]
        elif k == 1:
            s = 2.0 * np.sqrt(1.0 + a[0, 0] - a[1, 1] - a[2, 2])
            q = [(a[2, 1] - a[1, 2]) / s, 0.25 * s, (a[0, 1] + a[1, 0]) / s, (a[0, 2] + a[2, 0]) / s]
        elif k == 2:
            s = 2.0 * np.sqrt(1.0 - a[0, 0] + a[1, 1] - a[2, 2])
            q = [(a[0, 2] - a[2, 0]) / s, (a[0, 1] + a[1, 0]) / s, 0.25 * s, (a[1, 2] + a[2, 1]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 - a[0, 0] - a[1, 1] + a[2, 2])
            q = [(a[1, 0] - a[0, 1]) / s, (a[0, 2] + a[2, 0]) / s, (a[1, 2] + a[2, 1]) / s, 0.25 * s]
        out[i] = q if q[0] >= 0 else -np.asarray(q)
    return out.reshape(*r.shape[:-2], 4)
