"""Tilt stiffness and tilt damping of the support, with b1 and b2, from a recorded free decay.

The spatial variant (``pendsim_mj.rig.model.SPATIAL``) lets each pendulum rock about the horizontal
axis across the pivot (world x) on a spring ``tilt_stiffness_n_m_rad`` with damping
``tilt_damping_n_m_s_rad`` (RigParams; both assumed until identified). The rocking shows in each
node's gyro off the hinge axis: in the swing frame the body rate is tilt_rate * (cos phi, sin phi)
along (tangential, toward pivot) plus omega along the hinge, i.e. the model's IMU site axes
(x tangential, y toward the pivot, z the hinge). So all three gyro components of both nodes are
fitted, each in units of its noise sigma, by ``mujoco.sysid`` on the spatial MJCF (Gauss-Newton
over rollouts, 95 % intervals from the Jacobian at the optimum), with the same two corrections as
the planar fit (``pendsim_mj.estimation.identification``): predictions read one step earlier than sysid
stamps them, and taken at the instants the fused values belong to; and a third: each node's
predicted gyro is rotated onto the measured one (``best_rotation``), since the swing frame found
from the data is itself tilted by the tilt motion.

**The start state is fitted too** (``START_RELEASE``, ``START_MOVING``), as in the planar fit
(``pendsim_mj.estimation.planar_fit``), so that the intervals carry its uncertainty: the start angles
phi1_0, phi2_0 and, for a release from rest, an offset tau of the release instant (the model
rests until tau, then swings: the prediction at a sample instant t is the rollout's at t - tau,
zero rates before it); for a start in motion the start rates omega1_0, omega2_0 instead.
mujoco.sysid has no initial-state parameters: the angles and rates enter through its
``custom_rollout`` hook (each finite-difference member's initial state built from its own
parameter values), the offset through the ``modify_residual`` hook (the prediction, a cubic
spline through the rollout's gyros, read at the shifted instants). Taking the alignment's start as
exact left b1 30 half-widths off the truth on a spatial record (its release angle of M1 read
0.09 deg off) and the tilt damping 13 half-widths off.

**The support's tilt at the start** (``TILT_STARTS``): "zero", the support untilted at the
release, as ``pendsim record --model spatial`` simulates it (its hold too repeats the release
state, tilt 0); or "static", the support resting at its static tilt under the pendulums held at
phi_0 (``static_tilt_rad``: where the tilt's generalized force vanishes; with the defaults 2.34 deg for
M1 at rest, 2.04 deg held at 34 deg: the offset coupling springs pull it across), which is
how a real support sits while the pendulums are held. With "static" the start tilts follow the
fitted angles and stiffness in every rollout. Because the tilt oscillation is a fast (1.7-2.1 Hz)
line, the fit is continued over growing windows (``WINDOWS_S``), so that a poor starting
stiffness cannot lock onto a neighbouring cycle.

Intervals: the covariance from the Jacobian at the optimum (``sysid.calculate_intervals``),
scaled by the residuals' mean square in sigmas when that exceeds 1 (model error, or a misjudged
noise sigma, widens them; an overstated sigma does not narrow them below the Jacobian's).
Coverage over seeded records: ``bench/bench_spatial_coverage.py`` and tests/estimation/test_spatial_identify.py.
"""

from __future__ import annotations

import dataclasses
import math
import time

import mujoco
import numpy as np

from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.identification import sensors_only
from pendsim_mj.estimation.least_squares import sysid_least_squares
from pendsim_mj.rig.model import HINGES, SPATIAL, TILTS, build_spec
from pendsim_mj.rig.params import PARAMETER_LIMITS, RigParams

# what is fitted, in this order: the rig's fields, then the start state
NAMES = ("tilt_stiffness_n_m_rad", "tilt_damping_n_m_s_rad", "b1_n_m_s", "b2_n_m_s")
START_RELEASE = ("phi1_0", "phi2_0", "release_offset_s")  # a release from rest
START_MOVING = ("phi1_0", "phi2_0", "omega1_0", "omega2_0")  # a start in motion
TIMING = "timing2_s"  # M2's value instants shifted against M1's (the nodes' relative fusion timing)
TILT_STARTS = ("zero", "static")
GYROS = ("imu_m1_gyro", "imu_m2_gyro")
WINDOWS_S = (4.0, 12.0, math.inf)  # continuation: each fit starts from the previous one's values
MAX_RELEASE_OFFSET_S = 0.05  # the release instant is searched within this of the alignment's
MAX_START_ANGLE_CHANGE_RAD = 0.05  # and the start angles, rates within this (rad, rad/s)
Z95 = 1.959964


@dataclasses.dataclass(frozen=True)
class TiltFit:
    """Least-squares tilt stiffness, tilt damping, b1, b2 (those of ``NAMES`` fitted) with the
    start state (``START_RELEASE`` or ``START_MOVING``).

    Attributes:
      values: (P,) the estimates in the order of ``names``, SI units (N m/rad, N m s/rad, rad,
        rad/s, s).
      ci95: (P,) half-widths of their 95 % confidence intervals.
      covariance: (P, P) of the estimates (from the Jacobian at the optimum, scaled by the
        residuals' mean square in sigmas when that exceeds 1); it carries the start's
        uncertainty, the start being fitted together with the rest.
      residual_rms_sigma: rms of all residuals in units of the gyro noise sigmas (about 1 when the
        model explains the data to the noise level).
      channel_rms_sigma: (2, 3) the same per node and gyro component (tangential, toward pivot,
        hinge).
      iterations: optimiser iterations over all windows; seconds: wall time.
      names: the P unknowns.
      tilt_start: "zero" or "static" (``TILT_STARTS``).
    """

    values: np.ndarray
    ci95: np.ndarray
    covariance: np.ndarray
    residual_rms_sigma: float
    channel_rms_sigma: np.ndarray
    iterations: int
    seconds: float
    names: tuple[str, ...] = NAMES
    tilt_start: str = "zero"

    def value(self, name: str) -> float:
        """The estimate of one unknown by name."""
        return float(self.values[self.names.index(name)])

    def half_width(self, name: str) -> float:
        """The 95 % half-width of one unknown by name."""
        return float(self.ci95[self.names.index(name)])

    def as_mapping(self) -> dict[str, float]:
        """The rig's estimates by parameter name (for ``RigParams.with_mapping`` and --write);
        the start state is left out."""
        return {name: float(v) for name, v in zip(self.names, self.values, strict=True) if name in NAMES}


def static_tilt_rad(params: RigParams, phi_rad: tuple[float, float]) -> tuple[float, float]:
    """The tilts (rad) at which the spatial model's support rests while both pendulums are held
    at ``phi_rad``: the tilts' generalized forces (springs, tilt stiffness, gravity) are zero."""
    model = build_spec(params, variant=SPATIAL).compile()
    tilt = _static_tilts(model, mujoco.MjData(model), np.asarray(phi_rad, dtype=float))
    return float(tilt[0]), float(tilt[1])


def _static_tilts(model: mujoco.MjModel, data: mujoco.MjData, phi_rad: np.ndarray) -> np.ndarray:
    """Newton's method on the tilt dofs' generalized force with the hinges held at phi_rad, at
    rest (forces nearly linear in the tilt: 3 to 4 iterations reach 1e-12 rad)."""
    qadr = [int(model.joint(n).qposadr[0]) for n in TILTS]
    vadr = [int(model.joint(n).dofadr[0]) for n in TILTS]
    data.qvel[:] = 0.0
    for k, hinge in enumerate(HINGES):
        data.qpos[model.joint(hinge).qposadr[0]] = phi_rad[k]

    def force(tilt: np.ndarray) -> np.ndarray:
        data.qpos[qadr] = tilt
        mujoco.mj_forward(model, data)
        return np.asarray(data.qfrc_passive[vadr] - data.qfrc_bias[vadr])

    tilt = np.zeros(2)
    step = 1e-6
    for _ in range(12):
        f = force(tilt)
        jac = np.stack([(force(tilt + step * e) - f) / step for e in np.eye(2)], axis=1)
        delta = np.linalg.solve(jac, -f)
        tilt = tilt + delta
        if np.max(np.abs(delta)) < 1e-12:
            break
    return tilt


def fit_tilt(
    params: RigParams,
    phi0_rad: tuple[float, float],
    value_t_s: np.ndarray,
    gyro_rad_s: np.ndarray,
    gyro_sigma_rad_s: np.ndarray,
    *,
    omega0_rad_s: tuple[float, float] = (0.0, 0.0),
    names: tuple[str, ...] = NAMES,
    moving: bool | None = None,
    tilt_start: str = "zero",
    timing_range_s: tuple[float, float] | None = None,
) -> TiltFit:
    """Fit ``names`` and the start state to both nodes' gyros in their swing frames.

    Args:
      params: the rig (plane offset, geometry; its tilt and damping values are the start).
      phi0_rad, omega0_rad_s: the alignment's start state at t = 0 (the first guess; fitted).
      value_t_s: (m, 2) each node's instants the values belong to, s after the start (NaN where
        a node has fewer samples).
      gyro_rad_s: (m, 2, 3) each node's gyro along (tangential, toward pivot, hinge), rad/s
        (NaN where missing).
      gyro_sigma_rad_s: (2, 3) noise sigmas of those components, rad/s.
      names: the rig's parameters fitted (a subset of ``NAMES``; the others keep their values in
        ``params``), e.g. only b1, b2 for the spatial model's damping at given tilt values.
      moving: the run starts in motion (fit the start rates, no release offset); default: any
        |omega_0| above 0.
      tilt_start: the support's tilt at the start, "zero" or "static" (``TILT_STARTS``).
      timing_range_s: (lo_s <= 0, hi_s >= 0): fit the shift of M2's value instants against M1's
        within it, s (``MeasuredRun.relative_timing_range_s``, as the planar fit does: the
        alignment leaves the nodes' relative fusion timing open within it); None: as given.
    """
    if not names or any(n not in NAMES for n in names):
        raise ParameterError(f"names must be a non-empty subset of {NAMES}, got {names!r}")
    if tilt_start not in TILT_STARTS:
        raise ParameterError(f"tilt_start must be one of {TILT_STARTS}, got {tilt_start!r}")
    from mujoco import sysid  # start-up: MuJoCo

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
    if moving is None:
        moving = any(abs(w) > 0 for w in omega0_rad_s)
    start_names = START_MOVING if moving else START_RELEASE
    start_values = [*phi0_rad, *omega0_rad_s] if moving else [*phi0_rad, 0.0]
    if timing_range_s is not None:
        start_names, start_values = (*start_names, TIMING), [*start_values, 0.0]
    start = time.perf_counter()
    values = np.array([getattr(params, n) for n in names] + start_values, dtype=float)
    all_names = (*names, *start_names)
    bounds = _bounds(all_names, values)
    if timing_range_s is not None:
        bounds[TIMING] = (float(timing_range_s[0]), float(timing_range_s[1]))
    iterations = 0
    end_s = max(float(c[0][-1]) for c in columns)
    for window in WINDOWS_S:
        inside = [(t[t <= window], g[t <= window]) for t, g in columns]
        values, covariance, residuals, its = _fit_window(
            sysid, params, inside, sigma, values, all_names, bounds, tilt_start
        )
        iterations += its
        if window >= end_s:
            break
    channel = np.array([[math.sqrt(np.mean(r * r)) for r in node] for node in residuals])
    every = np.concatenate([r for node in residuals for r in node])
    rms = float(math.sqrt(np.mean(every * every)))
    # residuals above the noise level are model error or a misjudged sigma: widen accordingly
    covariance = covariance * max(1.0, rms * rms)
    return TiltFit(
        values=values,
        ci95=Z95 * np.sqrt(np.clip(np.diag(covariance), 0.0, None)),
        covariance=covariance,
        residual_rms_sigma=rms,
        channel_rms_sigma=channel,
        iterations=iterations,
        seconds=time.perf_counter() - start,
        names=all_names,
        tilt_start=tilt_start,
    )


def _bounds(names: tuple[str, ...], values: np.ndarray) -> dict[str, tuple[float, float]]:
    """Search bounds of each unknown: the rig's within its limits, the start near the alignment's."""
    out = {}
    for name, value in zip(names, values, strict=True):
        if name in NAMES:
            out[name] = (0.0, min(PARAMETER_LIMITS[name][1], _SEARCH_MAX[name]))
        elif name == "release_offset_s":
            out[name] = (-MAX_RELEASE_OFFSET_S, MAX_RELEASE_OFFSET_S)
        else:
            out[name] = (value - MAX_START_ANGLE_CHANGE_RAD, value + MAX_START_ANGLE_CHANGE_RAD)
    return out


def _fit_window(sysid, params, columns, sigma, start_values, names, bounds, tilt_start):
    """One sysid fit over the samples given; returns (values, covariance, residuals per node and
    component, iterations)."""
    from scipy.interpolate import CubicSpline  # start-up: scipy

    spec = sensors_only(build_spec(params, variant=SPATIAL), GYROS)
    model = spec.compile()
    dt = model.opt.timestep
    end_s = max(float(c[0][-1]) for c in columns) + MAX_RELEASE_OFFSET_S
    t = dt * np.arange(math.ceil(end_s / dt) + 3)
    adr = [int(model.sensor(n).adr[0]) for n in GYROS]
    sensor_ts = sysid.TimeSeries.from_names(t, np.zeros((len(t), 6)), model, names=list(GYROS))
    control_ts = sysid.TimeSeries(t, np.zeros((len(t), 0)))
    initial = sysid.create_initial_state(model, np.zeros(model.nq), np.zeros(model.nv), mujoco.MjData(model).act)
    hinge_q = [int(model.joint(h).qposadr[0]) for h in HINGES]
    hinge_v = [int(model.joint(h).dofadr[0]) for h in HINGES]
    tilt_q = [int(model.joint(n).qposadr[0]) for n in TILTS]
    last: list = []

    def value(p, name: str, default: float = 0.0) -> float:
        return float(p[name].value[0]) if name in names else default

    def rollout(*, models, datas, initial_states, param_dicts, **kwargs):
        # each member starts from its own start state (sysid has no initial-state parameters)
        states = []
        per_member = len(models) // len(param_dicts)
        for i, m in enumerate(models):
            p = param_dicts[i // per_member]
            qpos = np.zeros(m.nq)
            qvel = np.zeros(m.nv)
            phi = np.array([value(p, "phi1_0"), value(p, "phi2_0")])
            qpos[hinge_q] = phi
            qvel[hinge_v] = [value(p, "omega1_0"), value(p, "omega2_0")]
            if tilt_start == "static":
                qpos[tilt_q] = _static_tilts(m, datas[0], phi)
            states.append(sysid.create_initial_state(m, qpos, qvel, datas[0].act))
        return sysid.sysid_rollout(models=models, datas=datas, initial_states=states, **kwargs)

    def residual(p, pred, meas, _model, _return_all, state=None):
        stamps = pred.times - dt  # sysid stamps each prediction one step late (see identification.py)
        tau = value(p, "release_offset_s")
        shift = (0.0, value(p, TIMING))  # M2's values may belong a little later than the alignment put them
        spline = (
            CubicSpline(stamps, pred.data[:, adr[0] : adr[0] + 3]),
            CubicSpline(stamps, pred.data[:, adr[1] : adr[1] + 3]),
        )
        per_node = []
        for k, (at, measured) in enumerate(columns):
            since = at + shift[k] - tau  # the model rests until the release at tau
            predicted = np.where((since >= 0)[:, None], spline[k](np.maximum(since, 0.0)), 0.0)
            predicted = predicted @ best_rotation(predicted, measured).T
            per_node.append([(predicted[:, j] - measured[:, j]) / sigma[k, j] for j in range(3)])
        last[:] = [per_node]
        full = np.concatenate([spline[0](t), spline[1](t)], axis=1)
        res = np.concatenate([r for node in per_node for r in node])
        return res, sysid.TimeSeries(meas.times, full, signal_mapping=meas.signal_mapping), meas

    parameters = sysid.ParameterDict()
    for name, v in zip(names, start_values, strict=True):
        low, high = bounds[name]
        parameters.add(
            sysid.Parameter(
                name,
                nominal=float(np.clip(v, low, high)),
                min_value=low,
                max_value=high,
                modifier=_modifier(name) if name in NAMES else None,
            )
        )
    sequences = sysid.ModelSequences("rig", spec, "decay", initial, control_ts, sensor_ts)
    residual_fn = sysid.build_residual_fn(
        models_sequences=[sequences], modify_residual=residual, custom_rollout=rollout
    )
    x, _, covariance, iterations = sysid_least_squares(sysid, parameters, residual_fn)
    return x, covariance, last[0], iterations  # last: the residuals at x (sysid_least_squares ends there)


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
