"""A node's swing in its own axes, found from its data alone: the hinge axis, the mounting, and
the pendulum angle, whatever the heading, mount and axis remap.

For a pendulum turning about a fixed hinge, in the sensor's axes:

- the gyro reads omega a + noise: the hinge axis a is the dominant direction of the gyro samples;
- the orientation relative to any reference sample is a rotation about one axis by an angle
  theta(t); theta is read by the swing-twist decomposition and needs no world frame, so the
  NDOF heading (and any constant orientation of the world frame) drops out;
- the accelerometer, projected on the plane normal to a (2-vectors, a basis e1, e2 with
  e1 x e2 = a in the sensor's numbers), reads gravity turned by the swing plus the kinematic
  acceleration of the sensor's position:

      F(t) = g Rot(-s theta) G0 + (omega^2 I - s alpha J) W,

  with J the quarter turn, s = +1 for right-handed sensor axes and -1 for mirrored ones (a
  mirroring axis remap), G0 the in-plane "up" at theta = 0, and W = r u: u points from the
  sensor toward the hinge axis, r is its distance. Linear least squares gives G0 and W for each s
  (the better fit decides s). phi = 0 where "up" is along u: the rod hangs straight down, so
  phi = theta + c with c the signed angle from G0 to u. Normal acceleration is F . u and
  tangential F . x with x = -s J u, the direction the sensor moves when phi grows.

No rest is needed (the motion carries the information); a hold only adds to it. Which sense of
a counts as positive cannot be told from one node: ``SwingFrame.flipped`` turns it over.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import DTypeLike, NDArray

from pendsim_mj.errors import RecordingError
from pendsim_mj.sensors import rotations

Floats = NDArray[np.float64]

_QUARTER_TURN = np.array([[0.0, -1.0], [1.0, 0.0]])
ANGLE_BLOCK = 1 << 16  # orientations turned into angles at once (SwingFrame.angle)


@dataclasses.dataclass(frozen=True)
class SwingFrame:
    """One node's swing frame in its output axes (unit vectors, (3,) each).

    Attributes:
      hinge_axis: the gyro axis of the swing; a positive rate about it is a growing phi.
      toward_pivot: from the sensor toward the hinge axis, normal to it (the mounting: straight
        up when phi = 0).
      tangential: where the sensor moves when phi grows.
      radius_m: the sensor's distance from the hinge axis, from its accelerations, m.
      quat_axis: the rotation axis in the orientation's own body frame (its sense: growing phi).
      reference_quat_wxyz: (4,) the orientation theta is measured from.
      angle_offset_rad: phi = theta + angle_offset_rad.
      mirrored: the output axes are left-handed (a mirroring axis remap).
      fit_rms_m_s2: rms residual of the accelerometer fit, m/s^2.
    """

    hinge_axis: Floats
    toward_pivot: Floats
    tangential: Floats
    radius_m: float
    quat_axis: Floats
    reference_quat_wxyz: Floats
    angle_offset_rad: float
    mirrored: bool
    fit_rms_m_s2: float

    def flipped(self) -> SwingFrame:
        """The same frame with the other sense of positive phi."""
        return dataclasses.replace(
            self,
            hinge_axis=-self.hinge_axis,
            tangential=-self.tangential,
            quat_axis=-self.quat_axis,
            angle_offset_rad=-self.angle_offset_rad,
            mirrored=self.mirrored,
        )

    def angle(self, quat_wxyz: Floats) -> Floats:
        """phi (n,) of orientations (n, 4), rad (continuous: unwrapped), computed ``ANGLE_BLOCK``
        samples at a time (memory flat with n; each block unwrapped on from the one before)."""
        quat = np.asarray(quat_wxyz)
        out = np.empty(len(quat))
        for lo in range(0, len(quat), ANGLE_BLOCK):
            theta = twist_angle(quat[lo : lo + ANGLE_BLOCK], self.reference_quat_wxyz, self.quat_axis)
            before = out[lo - 1 : lo]  # the previous block's last (unwrapped) angle; none for the first
            out[lo : lo + ANGLE_BLOCK] = np.unwrap(np.concatenate([before, theta]))[len(before) :]
        return out + self.angle_offset_rad

    def rate(self, gyro_rad_s: Floats) -> Floats:
        """omega (n,) from gyro readings (n, 3), rad/s."""
        return _along(gyro_rad_s, self.hinge_axis)

    def tangential_of(self, accel_m_s2: Floats, *, dtype: DTypeLike = np.float64) -> Floats:
        """Accelerations (n, 3) along the tangential direction (n,), m/s^2, as ``dtype``."""
        return _along(accel_m_s2, self.tangential, dtype)

    def normal_of(self, accel_m_s2: Floats, *, dtype: DTypeLike = np.float64) -> Floats:
        """Accelerations (n, 3) toward the pivot (n,), m/s^2, as ``dtype``."""
        return _along(accel_m_s2, self.toward_pivot, dtype)


def _along(vectors: Floats, direction: Floats, dtype: DTypeLike = np.float64) -> Floats:
    """vectors (n, 3) (float64, or float32 sensor values) along a unit direction (3,): (n,)
    computed in float64 and stored as ``dtype``, ``ANGLE_BLOCK`` rows at a time (no float64
    copy of a long run's float32 values)."""
    v = np.asarray(vectors)
    out = np.empty(len(v), dtype=dtype)
    for lo in range(0, len(v), ANGLE_BLOCK):
        out[lo : lo + ANGLE_BLOCK] = v[lo : lo + ANGLE_BLOCK] @ direction
    return out


def dominant_axis(vectors: Floats) -> Floats:
    """The unit direction (3,) along which (n, 3) vectors mostly lie (first right singular
    vector); its sign is arbitrary."""
    v = np.asarray(vectors, dtype=float)
    _, _, vt = np.linalg.svd(v, full_matrices=False)
    return np.asarray(vt[0])


def twist_angle(quat_wxyz: Floats, reference_wxyz: Floats, axis: Floats) -> Floats:
    """The rotation angle (n,) about ``axis`` (body frame of the reference) from the reference
    orientation to each orientation (swing-twist decomposition), rad in (-pi, pi]."""
    rel = rotations.multiply(np.broadcast_to(rotations.conjugate(reference_wxyz), np.shape(quat_wxyz)), quat_wxyz)
    return 2.0 * np.arctan2(rel[:, 1:] @ axis, rel[:, 0])


def relative_axis(quat_wxyz: Floats, reference_wxyz: Floats) -> Floats:
    """The axis (3,) of the rotations from the reference to each orientation (sign arbitrary)."""
    rel = rotations.multiply(np.broadcast_to(rotations.conjugate(reference_wxyz), np.shape(quat_wxyz)), quat_wxyz)
    rel = rel * np.where(rel[:, :1] < 0, -1.0, 1.0)
    return dominant_axis(rel[:, 1:])


def _derivative(t_s: Floats, x: Floats, max_step_s: float) -> tuple[Floats, NDArray[np.bool_]]:
    """Central differences of x over t (n,), and where they are valid (both neighbours within
    ``max_step_s``)."""
    t = np.asarray(t_s, dtype=float)
    d = np.zeros(len(t))
    ok = np.zeros(len(t), dtype=bool)
    if len(t) >= 3:
        span = t[2:] - t[:-2]
        d[1:-1] = (x[2:] - x[:-2]) / np.where(span > 0, span, 1.0)
        ok[1:-1] = (t[1:-1] - t[:-2] <= max_step_s) & (t[2:] - t[1:-1] <= max_step_s) & (span > 0)
    return d, ok


def fit_swing_frame(
    t_s: Floats,
    quat_wxyz: Floats,
    gyro_rad_s: Floats,
    accel_m_s2: Floats,
    *,
    g_m_s2: float,
    max_step_s: float,
) -> SwingFrame:
    """Find a node's swing frame from its samples (see the module docstring).

    Args:
      t_s: (n,) sample instants, increasing, s (gaps allowed).
      quat_wxyz, gyro_rad_s, accel_m_s2: (n, 4), (n, 3), (n, 3) the node's outputs.
      g_m_s2: gravitational acceleration.
      max_step_s: the longest spacing across which the rate is differentiated, s.

    Raises:
      RecordingError: the node does not swing enough to find its hinge axis or mounting.
    """
    gyro = np.asarray(gyro_rad_s, dtype=float)
    axis = dominant_axis(gyro)
    omega = gyro @ axis
    if float(np.max(np.abs(omega))) < 0.02:
        raise RecordingError("a node's gyro never turns faster than 0.02 rad/s: no swing to find its hinge axis in")
    quat = np.asarray(quat_wxyz, dtype=float)
    reference = quat[0].copy()  # not a view: the frame must not keep the node's samples alive
    quat_axis = relative_axis(quat, reference)
    theta = np.unwrap(twist_angle(quat, reference, quat_axis))
    alpha, ok = _derivative(t_s, omega, max_step_s)
    dtheta, _ = _derivative(t_s, theta, max_step_s)
    if float(np.dot(dtheta[ok], omega[ok])) < 0:  # theta grows with omega
        quat_axis, theta = -quat_axis, -theta
    # In-plane basis e1, e2 with e1 x e2 = axis (in the sensor's numbers).
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    accel = np.asarray(accel_m_s2, dtype=float)
    f = np.stack([accel[ok] @ e1, accel[ok] @ e2], axis=1)
    th, w2, al = theta[ok], omega[ok] ** 2, alpha[ok]
    best = None
    for s in (1.0, -1.0):
        c, sn = np.cos(th), s * np.sin(th)
        # unknowns G0x, G0y, Wx, Wy (see the module docstring)
        rows_x = np.stack([g_m_s2 * c, g_m_s2 * sn, w2, s * al], axis=1)
        rows_y = np.stack([-g_m_s2 * sn, g_m_s2 * c, -s * al, w2], axis=1)
        design = np.concatenate([rows_x, rows_y])
        target = np.concatenate([f[:, 0], f[:, 1]])
        solution, *_ = np.linalg.lstsq(design, target, rcond=None)
        rms = float(np.sqrt(np.mean((design @ solution - target) ** 2)))
        if best is None or rms < best[0]:
            best = (rms, s, solution)
    assert best is not None
    rms, s, solution = best
    g0, w = solution[:2], solution[2:]
    radius = float(np.linalg.norm(w))
    if radius < 0.01:
        raise RecordingError(
            f"a node's accelerations put it {1000 * radius:.1f} mm from the hinge axis: too close to find its mounting"
        )
    u = w / radius
    offset = s * (math.atan2(u[1], u[0]) - math.atan2(g0[1], g0[0]))
    offset = (offset + math.pi) % math.tau - math.pi
    x = -s * (_QUARTER_TURN @ u)
    return SwingFrame(
        hinge_axis=axis,
        toward_pivot=u[0] * e1 + u[1] * e2,
        tangential=x[0] * e1 + x[1] * e2,
        radius_m=radius,
        quat_axis=quat_axis,
        reference_quat_wxyz=reference,
        angle_offset_rad=float(offset),
        mirrored=bool(s < 0),
        fit_rms_m_s2=rms,
    )
