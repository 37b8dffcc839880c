"""Damping identification from a free decay: the paper's log decrement, the planar least-squares
fit (the default: ``pendsim_mj.estimation.planar_fit``, hinge losses and start state together, damping law
chosen by BIC), and a least-squares fit built on MuJoCo's system-identification toolbox (kept for
the spatial model: ``fit_damping``).

(a) ``log_decrement``: b_n = 2 J_n ln(A0_n / AT_n) / t1 per pendulum, amplitudes over a window
    (default the paper's 120 s).
(b) ``planar_damping``: ``planar_fit.fit_planar`` over the laws asked for, as a DampingFit (the
    fused instants and the lost samples handled as below; the start state fitted too, so the
    intervals are honest: 94-95 % coverage measured over 200 seeded 20 s records).
(c) ``fit_damping``: b1, b2 minimising the gyro residuals of both nodes over the whole record,
    normalised by the noise sigmas, with ``mujoco.sysid`` (Gauss-Newton over rollouts of the MJCF
    model, confidence intervals from the Jacobian at the optimum). Two corrections, both found by
    measurement and supplied through its ``modify_residual`` hook:
      1. sysid stamps each predicted sensor value with the time *after* its step (its rollout
         pairs post-step states with pre-step sensors): read here with the stamps moved back one
         step. Without it the fit of b1 was 1.9 % off and the residual 8 sigma rms.
      2. the node reports the latest 100 Hz fused value at 80 Hz (0-10 ms old): the prediction is
         taken at those fused instants. Without it b1 was 1.1 % off.
    With both, b1 and b2 came back within 0.02 % of the truth on a synthetic 120 s record with the
    paper's noise, and the residual at the noise level.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from pendsim_mj.engines.linearised import linear_modes
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.analysis import log_decrement_damping, peak_amplitudes
from pendsim_mj.estimation.least_squares import sysid_least_squares
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.model import HINGES, build_spec
from pendsim_mj.rig.params import PARAMETER_LIMITS, RigParams
from pendsim_mj.sensors.bno055 import FUSION_RATE_HZ, fused_instants

if TYPE_CHECKING:
    from pendsim_mj.estimation.planar_fit import LawFit


@dataclasses.dataclass(frozen=True)
class LogDecrement:
    """The paper's estimate for one pendulum."""

    b_n_m_s: float
    a0_rad: float
    at_rad: float
    window_s: float


def log_decrement(
    t_s: np.ndarray, phi_rad: np.ndarray, params: RigParams, window_s: float = 120.0
) -> list[LogDecrement]:
    """b per pendulum from the amplitude decay of phi (n, 2) over ``window_s``; t_s (n,) common
    instants, or (n, 2) each node's own (NaN where a node has fewer samples)."""
    out = []
    for k, inertia in enumerate((params.j1_kg_m2, params.j2_kg_m2)):
        t, phi = _node_column(t_s, phi_rad, k)
        b, a0, at, t1 = log_decrement_damping(t, phi, inertia, window_s)
        out.append(LogDecrement(b, a0, at, t1))
    return out


def _node_column(t_s: np.ndarray, values: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Node k's instants and values from common (n,) or per-node (n, 2) instants, NaNs dropped."""
    t = np.asarray(t_s, dtype=float)
    t = t[:, k] if t.ndim == 2 else t
    v = np.asarray(values, dtype=float)[:, k]
    ok = np.isfinite(t) & np.isfinite(v)
    return t[ok], v[ok]


MISFIT_SIGMAS = 3.0  # a damping fit whose residual rms is above this many noise sigmas chooses no law


@dataclasses.dataclass(frozen=True)
class DampingFit:
    """Least-squares damping.

    Attributes:
      b_n_m_s: (2,) b1, b2.
      ci95_n_m_s: (2,) half-widths of the 95 % confidence intervals.
      covariance: (2, 2) of b1, b2.
      residual_rms_sigma: rms of the residuals in units of the gyro noise sigma (about 1 for a
        model that explains the data to the noise level).
      iterations: optimiser iterations (Jacobian evaluations); seconds: wall time.
      method: "planar" (``planar_fit``) or "mujoco.sysid".
      law: the damping law of the estimates ("viscous", "coulomb", "both").
      friction_n_m, friction_ci95_n_m: (2,) dry friction F1, F2 and half-widths (0 without it).
      laws: every law's fit (planar), the chosen one first.
      timing2_s, timing2_ci95_s: the fitted shift of M2's value instants against M1's (the nodes'
        relative fusion timing, ``planar_fit``) and its 95 % half-width, s; None where it was not
        fitted.
    """

    b_n_m_s: np.ndarray
    ci95_n_m_s: np.ndarray
    covariance: np.ndarray
    residual_rms_sigma: float
    iterations: int
    seconds: float
    method: str = "mujoco.sysid"
    law: str = "viscous"
    friction_n_m: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(2))
    friction_ci95_n_m: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(2))
    laws: tuple[LawFit, ...] = ()
    timing2_s: float | None = None
    timing2_ci95_s: float = 0.0

    @property
    def misfit(self) -> bool:
        """The residual is far above the noise (MISFIT_SIGMAS): the model, not the damping law, is
        what is wrong (the rig's parameters most often: ``pendsim calibrate``), so no law is chosen."""
        return not self.residual_rms_sigma <= MISFIT_SIGMAS

    def misfit_note(self) -> str:
        """One line naming the misfit and what to do, or "" when the fit explains the data."""
        if not self.misfit:
            return ""
        return (
            f"the damping fit leaves {self.residual_rms_sigma:.1f} gyro noise sigmas rms (a fitting model: about 1): "
            "the model, not the damping law, is off (most often the rig's parameters; or motion the planar model "
            "leaves out); no law chosen. Run 'pendsim calibrate REC': it fits the rig and tests the causes"
        )

    def overrides(self) -> dict[str, float]:
        """The fitted hinge losses as RigParams fields (b and friction of both hinges); a value
        below the smallest nonzero one RigParams takes (a fit's 1e-53) is 0."""
        b, f = self.b_n_m_s, self.friction_n_m
        values = {"b1_n_m_s": b[0], "b2_n_m_s": b[1], "friction1_n_m": f[0], "friction2_n_m": f[1]}
        return {k: float(v) if abs(v) >= PARAMETER_LIMITS[k][0] else 0.0 for k, v in values.items()}


def planar_damping(
    params: RigParams,
    value_t_s: np.ndarray | Sequence[np.ndarray],
    gyro_z_rad_s: np.ndarray | Sequence[np.ndarray],
    *,
    gyro_sigma_rad_s: tuple[float, float],
    phi0_rad: tuple[float, float],
    omega0_rad_s: tuple[float, float] = (0.0, 0.0),
    moving: bool | None = None,
    law: str = "auto",
    drive: Drive | None = None,
    timing_range_s: tuple[float, float] | None = None,
) -> DampingFit:
    """The planar fit (``planar_fit.fit_planar``, same arguments) as a DampingFit: the law with
    the smallest BIC (or the one asked for), every law tried in ``laws``."""
    from pendsim_mj.estimation.planar_fit import fit_planar  # numba's compiled kernel: imported when a fit runs

    start = time.perf_counter()
    fits = fit_planar(
        params, value_t_s, gyro_z_rad_s, gyro_sigma_rad_s=gyro_sigma_rad_s, phi0_rad=phi0_rad,
        omega0_rad_s=omega0_rad_s, moving=moving, law=law, drive=drive, timing_range_s=timing_range_s,
    )  # fmt: skip
    best = fits[0]
    names = ("b1_n_m_s", "b2_n_m_s")
    rows = [best.names.index(n) for n in names if n in best.names]
    covariance = np.zeros((2, 2))
    if len(rows) == 2:
        covariance = best.covariance[np.ix_(rows, rows)]
    return DampingFit(
        b_n_m_s=np.array([best.value(n) for n in names]),
        ci95_n_m_s=np.array([best.half_width(n) for n in names]),
        covariance=covariance,
        residual_rms_sigma=best.residual_rms_sigma,
        iterations=sum(f.iterations for f in fits),
        seconds=time.perf_counter() - start,
        method="planar",
        law=best.law,
        friction_n_m=np.array([best.value(f"friction{n}_n_m") for n in (1, 2)]),
        friction_ci95_n_m=np.array([best.half_width(f"friction{n}_n_m") for n in (1, 2)]),
        laws=tuple(fits),
        timing2_s=best.value("timing2_s") if "timing2_s" in best.names else None,
        timing2_ci95_s=best.half_width("timing2_s"),
    )


UNDETERMINED_SHARE = 0.02
"""A fitted hinge loss whose 95 % half-width exceeds this share of its value is named in a warning
(``fit_warnings``): the recording does not determine it (a release in one mode moves one
pendulum little; a short record)."""
TIMING_EDGE_S = 1e-5  # a fitted relative timing this close to its range's end is at the edge, s


def timing_at_edge(fit: DampingFit, timing_range_s: tuple[float, float] | None) -> str | None:
    """Where a damping fit put M2's timing against M1's at an end of the range alignment left
    open (``timing_range_s``, s), one line saying so (the nodes' times are off by more than it
    allows, and the damping took up the rest); else None."""
    if fit.timing2_s is None or timing_range_s is None:
        return None
    lo, hi = timing_range_s
    if min(fit.timing2_s - lo, hi - fit.timing2_s) >= TIMING_EDGE_S:
        return None
    return (
        f"M2's values are fitted {1e3 * fit.timing2_s:+.2f} ms against M1's, at the edge of the "
        f"{1e3 * lo:+.2f} to {1e3 * hi:+.2f} ms left open: the nodes' times are off by more, and the damping "
        "would take up the rest; check the file's time columns"
    )


def fit_warnings(fit: DampingFit, timing_range_s: tuple[float, float] | None) -> tuple[str, ...]:
    """One-line warnings on what a damping fit could not determine: a hinge loss known only to
    more than ``UNDETERMINED_SHARE`` of its value, and M2's timing against M1's at the edge of
    its range (``timing_at_edge``). A misfit (``DampingFit.misfit``) says nothing of the damping's
    precision: its numbers are not the rig's, and ``misfit_note`` says why."""
    notes = []
    values = []
    if fit.misfit:
        pass
    elif fit.law != "coulomb":
        values += [(f"b{k + 1}", fit.b_n_m_s[k], fit.ci95_n_m_s[k], "N m s/rad") for k in range(2)]
    if fit.law != "viscous" and not fit.misfit:
        values += [(f"F{k + 1}", fit.friction_n_m[k], fit.friction_ci95_n_m[k], "N m") for k in range(2)]
    for name, value, half, unit in values:
        if not half <= UNDETERMINED_SHARE * abs(value):
            share = f"{100 * half / abs(value):.0f} %" if value else f"{half:.2g} {unit}"
            notes.append(
                f"{name} = {value:.4g} {unit} is determined only to +-{share} (95 %) by this recording "
                "(a release in one mode barely moves one pendulum against the other; a longer record or a "
                "release in both modes pins it)"
            )
    edge = None if fit.misfit else timing_at_edge(fit, timing_range_s)  # a misfit's timing is the rig's doing
    return (*notes, edge) if edge is not None else tuple(notes)


def _sysid():
    from mujoco import sysid  # start-up: MuJoCo

    if not hasattr(sysid, "optimize"):
        raise ParameterError("mujoco.sysid is missing its extras: pip install 'mujoco[sysid]'")
    return sysid


def fit_damping(
    params: RigParams,
    phi0_rad: tuple[float, float],
    t_s: np.ndarray,
    gyro_z_rad_s: np.ndarray,
    *,
    gyro_sigma_rad_s: tuple[float, float],
    fusion_rate_hz: float | None = FUSION_RATE_HZ,
    start_b_n_m_s: tuple[float, float] = (1e-3, 1e-3),
    max_b_n_m_s: float = 0.05,
    omega0_rad_s: tuple[float, float] = (0.0, 0.0),
) -> DampingFit:
    """Fit b1, b2 to the measured angular velocities of a free decay from ``phi0_rad``.

    Args:
      params: the rig (its b1, b2 are replaced by the fit).
      phi0_rad: angles at the start (the release); the start is at t = 0.
      t_s: (m,) sample instants after the start, s; or (m, 2) each node's own instants (NaN
        where a node has fewer samples: lost packets).
      gyro_z_rad_s: (m, 2) measured omega1, omega2 (NaN where missing).
      gyro_sigma_rad_s: noise sigma of each node's gyro z, for weighting.
      fusion_rate_hz: the chip's fusion rate (each sample carries the latest fused value), or
        None if the samples are instantaneous.
      start_b_n_m_s: starting guess.
      max_b_n_m_s: upper bound of the search.
      omega0_rad_s: rates at the start (a run that starts mid-swing), rad/s.
    """
    return _fit(
        _sysid(), params, phi0_rad, t_s, gyro_z_rad_s, gyro_sigma_rad_s, fusion_rate_hz, start_b_n_m_s, max_b_n_m_s,
        omega0_rad_s,
    )  # fmt: skip


def sensors_only(spec: mujoco.MjSpec, names: tuple[str, ...]) -> mujoco.MjSpec:
    """``spec`` with every sensor but ``names`` deleted (in place; returned): a sysid fit then
    measures every sensor of its model, so sysid has no missing sensor data to warn about."""
    for sensor in list(spec.sensors):
        if sensor.name not in names:
            spec.delete(sensor)
    return spec


def _fit(
    sysid, params, phi0_rad, t_s, gyro_z_rad_s, gyro_sigma_rad_s, fusion_rate_hz, start_b_n_m_s, max_b_n_m_s,
    omega0_rad_s,
):  # fmt: skip
    times = np.asarray(t_s, dtype=float)
    y = np.asarray(gyro_z_rad_s, dtype=float)
    per_node = times if times.ndim == 2 else np.stack([times, times], axis=1)
    if per_node.shape != y.shape or y.shape[-1:] != (2,) or len(y) < 10:
        raise ParameterError(
            f"expected t_s (m,) or (m, 2) and gyro_z_rad_s (m, 2) with m >= 10, got {times.shape}, {y.shape}"
        )
    if np.nanmin(per_node) < 0:
        raise ParameterError("samples before the release (t < 0) cannot be fitted; cut them first")
    columns_t = [_node_column(per_node, y, k) for k in range(2)]
    # sysid rolls out over its measured series' span: a grid from 0 to the last sample
    gyro_names = ("imu_m1_gyro", "imu_m2_gyro")
    spec = sensors_only(build_spec(params), gyro_names)
    model = spec.compile()
    dt = model.opt.timestep
    t = dt * np.arange(math.ceil(max(float(c[0][-1]) for c in columns_t) / dt) + 2)
    columns = np.array([model.sensor(n).adr[0] + 2 for n in gyro_names])  # z components
    measured = np.zeros((len(t), 6))
    sensor_ts = sysid.TimeSeries.from_names(t, measured, model, names=list(gyro_names))
    control_ts = sysid.TimeSeries(t, np.zeros((len(t), 0)))
    data = mujoco.MjData(model)
    initial = sysid.create_initial_state(
        model, np.asarray(phi0_rad, dtype=float), np.asarray(omega0_rad_s, dtype=float), data.act
    )
    sample_at = [fused_instants(c[0], fusion_rate_hz) for c in columns_t]
    sigma = np.asarray(gyro_sigma_rad_s, dtype=float)

    def residual(_params, pred, meas, _model, _return_all, state=None):
        # (1) predicted sensor rows belong to the state one step earlier than their stamps;
        # (2) each sample carries the latest fused value.
        stamps = pred.times - dt
        predictions = [np.interp(sample_at[k], stamps, pred.data[:, columns[k]]) for k in range(2)]
        res = np.concatenate([(predictions[k] - columns_t[k][1]) / sigma[k] for k in range(2)])
        full = np.zeros((len(t), 6))
        full[:, 2], full[:, 5] = (np.interp(t, stamps, pred.data[:, c]) for c in columns)
        return res, sysid.TimeSeries(meas.times, full, signal_mapping=meas.signal_mapping), meas

    parameters = sysid.ParameterDict()
    for k, hinge in enumerate(HINGES):
        parameters.add(
            sysid.Parameter(
                f"b{k + 1}",
                nominal=start_b_n_m_s[k],
                min_value=0.0,
                max_value=max_b_n_m_s,
                modifier=lambda s, p, hinge=hinge: setattr(s.joint(hinge), "damping", [p.value[0], 0.0, 0.0]),
            )
        )
    sequences = sysid.ModelSequences("rig", spec, "decay", initial, control_ts, sensor_ts)
    residual_fn = sysid.build_residual_fn(models_sequences=[sequences], modify_residual=residual)
    start = time.perf_counter()
    x, final, covariance, iterations = sysid_least_squares(sysid, parameters, residual_fn)
    seconds = time.perf_counter() - start
    # sysid's half-widths are in its internal scaling; the 95 % half-width from the covariance:
    ci = 1.959964 * np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    return DampingFit(
        b_n_m_s=x,
        ci95_n_m_s=ci,
        covariance=np.asarray(covariance),
        residual_rms_sigma=float(math.sqrt(np.mean(final * final))),
        iterations=iterations,
        seconds=seconds,
    )


@dataclasses.dataclass(frozen=True)
class ModalDecrement:
    """The per-mode decrement (``modal_decrement``).

    Attributes:
      b_n_m_s: (2,) b1, b2 mapped back from the two modal decay rates.
      decay_rate_1_s: (2,) each mode's envelope decay rate sigma_i, 1/s (ascending frequency).
      frequency_hz: (2,) the linearised modes' frequencies.
      peaks: (2,) modal amplitude peaks used per mode.
      window_s: the span measured, s.
    """

    b_n_m_s: np.ndarray
    decay_rate_1_s: np.ndarray
    frequency_hz: np.ndarray
    peaks: tuple[int, int]
    window_s: float


def modal_decrement(t_s: np.ndarray, phi_rad: np.ndarray, params: RigParams, window_s: float = 120.0) -> ModalDecrement:
    """b1, b2 from the decay of each normal mode's amplitude (the per-mode log decrement).

    phi (n, 2) is projected onto the modal coordinates of the rig linearised at rest
    (``engines.linearised.linear_modes``: M = diag(J1, J2), stiffness of gravity and springs; the
    same parameters as the fit), q = Phi^-1 phi with mass-normalised shapes Phi (Phi^T M Phi = I).
    Each q_i's half-cycle peaks (``analysis.peak_amplitudes``) over ``window_s`` from the first
    give its decay rate sigma_i: the slope of ln(peak) by least squares. The modal damping
    matrix is Phi^T B Phi with B = diag(b1, b2); taken diagonal (the approximation: the modes'
    coupling through the off-diagonal term, nonzero unless b1/J1 = b2/J2, is neglected) each mode
    obeys q_i'' + c_ii q_i' + w_i^2 q_i = 0, so sigma_i = c_ii / 2 = (Phi_1i^2 b1 + Phi_2i^2 b2) / 2:
    two equations for b1, b2. Exact for the linear rig with proportional damping; small swings
    otherwise (the modes are those of the linearised rig; measured errors in
    docs/identification.md).

    Args:
      t_s: (n,) common instants or (n, 2) each node's own (NaN where a node has fewer samples).
      phi_rad: (n, 2) measured angles.
      params: the rig (its inertias, masses, springs).
      window_s: span after the first modal peak, s.
    """
    if not (math.isfinite(window_s) and window_s > 0):
        raise ParameterError(f"window_s must be > 0 s, got {window_s}")
    columns = [_node_column(t_s, phi_rad, k) for k in range(2)]
    start = max(float(c[0][0]) for c in columns)
    end = min(float(c[0][-1]) for c in columns)
    dt = float(np.median(np.diff(columns[0][0])))
    if not end - start > 10 * dt:
        raise ParameterError("the two nodes' angle records do not overlap: cannot project onto the modes")
    grid = start + dt * np.arange(int((end - start) / dt) + 1)
    phi = np.stack([np.interp(grid, c[0], c[1]) for c in columns])  # (2, m)
    modes = linear_modes(params)
    shapes = modes.shapes / np.sqrt(np.einsum("im,ij,jm->m", modes.shapes, modes.mass_kg_m2, modes.shapes))
    q = np.linalg.solve(shapes, phi)  # (2, m) modal coordinates
    rates, counts = np.zeros(2), [0, 0]
    for i in range(2):
        tp, ap = peak_amplitudes(grid, q[i])
        inside = (tp <= tp[0] + window_s + 1e-9) if len(tp) else tp > 0
        tp, ap = tp[inside], ap[inside]
        if len(tp) < 3 or np.any(ap <= 0):
            raise ParameterError(f"mode {i + 1}: fewer than three amplitude peaks; cannot measure its decay")
        slope = np.polyfit(tp - tp[0], np.log(ap), 1)[0]
        rates[i], counts[i] = -slope, len(tp)
    b = np.linalg.solve(shapes.T**2, 2.0 * rates)  # row i: (Phi_1i^2, Phi_2i^2) . (b1, b2) = 2 sigma_i
    return ModalDecrement(b, rates, modes.frequency_hz, (counts[0], counts[1]), float(window_s))
