"""Tilt stiffness and tilt damping of the support, with b1 and b2, from a recorded free decay.

The spatial variant (``pendsim_mj.model.SPATIAL``) lets each pendulum rock about the horizontal
axis across the pivot (world x) on a spring ``tilt_stiffness_n_m_rad`` with damping
``tilt_damping_n_m_s_rad`` (RigParams; both assumed until identified). The rocking shows in each
node's gyro off the hinge axis: in the swing frame the body rate is tilt_rate * (cos phi, sin phi)
along (tangential, toward pivot) plus omega along the hinge, i.e. the model's IMU site axes
(x tangential, y toward the pivot, z the hinge). So all three gyro components of both nodes are
fitted, each in units of its noise sigma, by ``mujoco.sysid`` on the spatial MJCF (Gauss-Newton
over rollouts, 95 % intervals from the Jacobian at the optimum), with the same two corrections as
the planar fit (``pendsim_mj.identification``): predictions read one step earlier than sysid
stamps them, and taken at the instants the fused values belong to; and a third: each node's
predicted gyro is rotated onto the measured one (``best_rotation``), since the swing frame found
from the data is itself tilted by the tilt motion.

The fit starts from the release with the support untilted (tilt 0, tilt rate 0), as
``pendsim record --model spatial`` does; a real support held at the release rests at its static
tilt instead (about 2.3 deg for M1 with the defaults), which this start does not model. Because
the tilt oscillation is a fast (1.7-2.1 Hz) line, the fit is continued over growing windows
(``WINDOWS_S``), so that a poor starting stiffness cannot lock onto a neighbouring cycle.
"""

from __future__ import annotations

import dataclasses
import math
import time

import mujoco
import numpy as np

from pendsim_mj.errors import ParameterError
from pendsim_mj.identification import sensors_only, sysid_least_squares
from pendsim_mj.model import HINGES, SPATIAL, TILTS, build_spec
from pendsim_mj.params import PARAMETER_LIMITS, RigParams

# what is fitted, in this order
NAMES = ("tilt_stiffness_n_m_rad", "tilt_damping_n_m_s_rad", "b1_n_m_s", "b2_n_m_s")
GYROS = ("imu_m1_gyro", "imu_m2_gyro")
WINDOWS_S = (4.0, 12.0, math.inf)  # continuation: each fit starts from the previous one's values


@dataclasses.dataclass(frozen=True)
class TiltFit:
    """Least-squares tilt stiffness, tilt damping, b1 and b2 (``NAMES``).

    Attributes:
      values: (4,) the estimates, SI units of their names.
      ci95: (4,) half-widths of their 95 % confidence intervals.
      covariance: (4, 4) of the estimates (from the Jacobian at the optimum, scaled by the
        residuals' mean square in sigmas when that exceeds 1). It does not hold the uncertainty
        of the start state, which is taken as given.
      residual_rms_sigma: rms of all residuals in units of the gyro noise sigmas (about 1 when the
        model explains the data to the noise level).
      channel_rms_sigma: (2, 3) the same per node and gyro component (tangential, toward pivot,
        hinge).
      iterations: optimiser iterations over all windows; seconds: wall time.
    """

    values: np.ndarray
    ci95: np.ndarray
    covariance: np.ndarray
    residual_rms_sigma: float
    channel_rms_sigma: np.ndarray
    iterations: int
    seconds: float
    names: tuple[str, ...] = NAMES

    def as_mapping(self) -> dict[str, float]:
        """The estimates by parameter name (for ``RigParams.with_mapping`` and --write)."""
        return {name: float(v) for name, v in zip(self.names, self.values, strict=True)}


def fit_tilt(
    params: RigParams,
    phi0_rad: tuple[float, float],
    value_t_s: np.ndarray,
    gyro_rad_s: np.ndarray,
    gyro_sigma_rad_s: np.ndarray,
    *,
    omega0_rad_s: tuple[float, float] = (0.0, 0.0),
    names: tuple[str, ...] = NAMES,
) -> TiltFit:
    """Fit ``NAMES`` to both nodes' gyros in their swing frames after the release.

    Args:
      params: the rig (plane offset, geometry; its tilt and damping values are the start).
      phi0_rad, omega0_rad_s: the state at the start (t = 0), tilts zero.
      value_t_s: (m, 2) each node's instants the values belong to, s after the start (NaN where
        a node has fewer samples).
      gyro_rad_s: (m, 2, 3) each node's gyro along (tangential, toward pivot, hinge), rad/s
        (NaN where missing).
      gyro_sigma_rad_s: (2, 3) noise sigmas of those components, rad/s.
      names: the parameters fitted (a subset of ``NAMES``; the others keep their values in
        ``params``), e.g. only b1, b2 for the spatial model's damping at given tilt values.
    """
    if not names or any(n not in NAMES for n in names):
        raise ParameterError(f"names must be a non-empty subset of {NAMES}, got {names!r}")
    from mujoco import sysid

    if not hasattr(sysid, "optimize"):
        raise ParameterError("mujoco.sysid is missing its extras: pip install 'mujoco[sysid]'")
    times = np.asarray(value_t_s, dtype=float)
    gyro = np.asarray(gyro_rad_s, dtype=float)
    sigma = np.asarray(gyro_sigma_rad_s, dtype=float)
    if times.ndim != 2 or times.shape[1] != 2 or gyro.shape != (*times.shape, 3) or sigma.shape != (2, 3):
        raise ParameterError(
            f"expected value_t_s (m, 2), gyro_rad_s (m, 2, 3), sigmas (2, 3); got {times.shape}, {gyro.shape}, "
            f"{sigma.shape}"
        )
    if not np.all(sigma > 0):
        raise ParameterError(f"gyro sigmas must be > 0, got {sigma.tolist()}")
    if params.plane_offset_m <= 0:
        raise ParameterError("the tilt fit needs the planes offset (plane_offset_m > 0): without it nothing tilts")
    columns = []
    for k in range(2):
        ok = np.isfinite(times[:, k]) & np.all(np.isfinite(gyro[:, k]), axis=1) & (times[:, k] >= 0)
        columns.append((times[ok, k], gyro[ok, k]))
    if min(len(c[0]) for c in columns) < 50:
        raise ParameterError("the tilt fit needs at least 50 samples of each node after the start")
    start = time.perf_counter()
    values = np.array([getattr(params, n) for n in names], dtype=float)
    iterations = 0
    end_s = max(float(c[0][-1]) for c in columns)
    for window in WINDOWS_S:
        inside = [(t[t <= window], g[t <= window]) for t, g in columns]
        values, covariance, residuals, its = _fit_window(
            sysid, params, phi0_rad, omega0_rad_s, inside, sigma, values, names
        )
        iterations += its
        if window >= end_s:
            break
    channel = np.array([[math.sqrt(np.mean(r * r)) for r in node] for node in residuals])
    every = np.concatenate([r for node in residuals for r in node])
    rms = float(math.sqrt(np.mean(every * every)))
    # residuals above the noise level are model error (e.g. the start state): widen accordingly
    covariance = covariance * max(1.0, rms * rms)
    return TiltFit(
        values=values,
        ci95=1.959964 * np.sqrt(np.clip(np.diag(covariance), 0.0, None)),
        covariance=covariance,
        residual_rms_sigma=rms,
        channel_rms_sigma=channel,
        iterations=iterations,
        seconds=time.perf_counter() - start,
        names=tuple(names),
    )


def _fit_window(sysid, params, phi0_rad, omega0_rad_s, columns, sigma, start_values, names):
    """One sysid fit over the samples given; returns (values, covariance, residuals per node and
    component, iterations)."""
    spec = sensors_only(build_spec(params, variant=SPATIAL), GYROS)
    model = spec.compile()
    dt = model.opt.timestep
    t = dt * np.arange(math.ceil(max(float(c[0][-1]) for c in columns) / dt) + 2)
    adr = [int(model.sensor(n).adr[0]) for n in GYROS]
    sensor_ts = sysid.TimeSeries.from_names(t, np.zeros((len(t), 6)), model, names=list(GYROS))
    control_ts = sysid.TimeSeries(t, np.zeros((len(t), 0)))
    qpos = np.zeros(model.nq)
    qvel = np.zeros(model.nv)
    for k, hinge in enumerate(HINGES):
        qpos[model.joint(hinge).qposadr[0]] = phi0_rad[k]
        qvel[model.joint(hinge).dofadr[0]] = omega0_rad_s[k]
    initial = sysid.create_initial_state(model, qpos, qvel, mujoco.MjData(model).act)
    last: list = []

    def residual(_params, pred, meas, _model, _return_all, state=None):
        stamps = pred.times - dt  # sysid stamps each prediction one step late (see identification.py)
        per_node = []
        for k, (at, measured) in enumerate(columns):
            predicted = np.stack([np.interp(at, stamps, pred.data[:, adr[k] + j]) for j in range(3)], axis=1)
            predicted = predicted @ best_rotation(predicted, measured).T
            per_node.append([(predicted[:, j] - measured[:, j]) / sigma[k, j] for j in range(3)])
        last[:] = [per_node]
        full = np.stack([np.interp(t, stamps, pred.data[:, a + j]) for a in adr for j in range(3)], axis=1)
        res = np.concatenate([r for node in per_node for r in node])
        return res, sysid.TimeSeries(meas.times, full, signal_mapping=meas.signal_mapping), meas

    parameters = sysid.ParameterDict()
    for name, value in zip(names, start_values, strict=True):
        low, high = PARAMETER_LIMITS[name]
        parameters.add(
            sysid.Parameter(
                name,
                nominal=float(np.clip(value, low, high)),
                min_value=0.0,
                max_value=min(high, _SEARCH_MAX[name]),
                modifier=_modifier(name),
            )
        )
    sequences = sysid.ModelSequences("rig", spec, "decay", initial, control_ts, sensor_ts)
    residual_fn = sysid.build_residual_fn(models_sequences=[sequences], modify_residual=residual)
    x, _, covariance, iterations = sysid_least_squares(sysid, parameters, residual_fn)
    return x, covariance, last[0], iterations


def best_rotation(predicted: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """(3, 3) rotation R that best maps predicted (m, 3) vectors onto measured ones (least squares
    of measured - predicted R^T; Kabsch). The swing frame estimated from the data is tilted by the
    tilt motion itself (its hinge axis is the dominant gyro axis, which the tilt rate pulls off
    by a few mrad; a few mrad of a 3 rad/s swing is several gyro sigmas): fitted per node with
    every rollout, the frame's error drops out of the residuals."""
    u, _, vt = np.linalg.svd(predicted.T @ measured)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return np.asarray(vt.T @ np.diag([1.0, 1.0, d]) @ u.T)


# upper ends of the search (the parameter limits allow more than a decay can tell apart)
_SEARCH_MAX = {
    "tilt_stiffness_n_m_rad": 200.0,
    "tilt_damping_n_m_s_rad": 0.5,
    "b1_n_m_s": 0.05,
    "b2_n_m_s": 0.05,
}


def _modifier(name: str):
    """How a fitted value is written into the spatial MjSpec."""
    if name.startswith("tilt_stiffness"):

        def set_stiffness(s: mujoco.MjSpec, p) -> None:
            for tilt in TILTS:
                s.joint(tilt).stiffness = [p.value[0], 0.0, 0.0]

        return set_stiffness
    if name.startswith("tilt_damping"):

        def set_damping(s: mujoco.MjSpec, p) -> None:
            for tilt in TILTS:
                s.joint(tilt).damping = [p.value[0], 0.0, 0.0]

        return set_damping
    hinge = HINGES[int(name[1]) - 1]

    def set_b(s: mujoco.MjSpec, p) -> None:
        s.joint(hinge).damping = [p.value[0], 0.0, 0.0]

    return set_b
