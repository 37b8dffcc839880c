"""Alignment's start fit (steps 4 and 5 of ``pendsim_mj.estimation.alignment``): the model of the
run's first seconds (``StartModel``) fitted to both nodes' angles and rates by least squares
(``fit_start``: the release instant and angles from rest, or the full state at the first
samples), and the nodes' relative fusion timing chosen by it (``relative_fusion_timing``). The
parts of ``alignment.align``; no public API of their own.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from pendsim_mj.engines import dispatch as engines
from pendsim_mj.estimation.least_squares import gauss_newton
from pendsim_mj.estimation.measured_run import Floats, StartKind
from pendsim_mj.estimation.node_alignment import AlignedNode
from pendsim_mj.estimation.timing import fusion_phase_stretch
from pendsim_mj.rig.drives import Drive, Target, recorded_drive
from pendsim_mj.rig.params import RigParams

ANGLE_SIGMA_RAD = 0.002  # weight of the fused angle in the start fit (the gyro's own sigma weights rates)
TIMING_PROBE = 0.25  # the nodes' relative fusion timing is probed this share of its open range either side
TIMING_FIT_S = 3.0  # the start fit's window when it chooses that timing (at least start_fit_s), s
TIMING_MIN_RANGE_S = 1e-4  # a relative timing open by less than this is left as the nodes' own data give it, s


@dataclasses.dataclass(frozen=True)
class StartModel:
    """The model of the run's first seconds, parametrised for the start fit."""

    kind: StartKind
    t0: float  # the fixed start (in motion, given) or the first guess of the release
    params: RigParams
    engine: str
    horizon_s: float
    drive_input: tuple[Floats, Floats] | None = None  # (t_s on the recorder's clock, held (n, 4))

    @property
    def timed(self) -> bool:
        """The values' instants get a common shift fitted too (``shift_s``): a driven run that
        starts in motion. The drive is fixed on the recorder's clock, so a few ms error of the
        fused values' instants (the fusion phase) is no longer absorbed by the start state as it
        is in a free decay; a release fits its instant, which the drive starts with, instead."""
        return self.drive_input is not None and self.kind == "in motion"

    def shift_s(self, x: Floats) -> float:
        """The shift of the values' instants, s: a value at ``at`` belongs to at + shift."""
        return float(x[4]) if self.timed else 0.0

    def drive(self) -> Drive | None:
        """The recorded drive from t0 on (None: a free run). A driven release starts at t0, its
        drive's onset; the fitted release instant then moves the drive with it (it absorbs an
        error of the values' instants: ``align`` turns it into their shift)."""
        if self.drive_input is None:
            return None
        return recorded_drive(*self.drive_input, self.t0, until_s=self.horizon_s + 0.1)

    def states(self, x: Floats) -> tuple[Floats, Floats, float]:
        """(phi0 (2,), omega0 (2,), start instant) of a parameter vector."""
        if self.kind == "release":
            return x[1:3], np.zeros(2), float(x[0])
        return x[0:2], x[2:4], self.t0

    def rollouts(self, xs: Sequence[Floats]):
        phi0 = np.array([self.states(x)[0] for x in xs])
        omega0 = np.array([self.states(x)[1] for x in xs])
        drive = self.drive()
        duration = engines.whole_steps_s(self.horizon_s)
        return engines.run_batch(self.engine, self.params, phi0, omega0, duration, drive=drive)


def _predict(traj_t: Floats, phi: Floats, omega: Floats, at: Floats, rest_phi: float | None) -> tuple[Floats, Floats]:
    """A member's phi, omega (n,) at instants ``at`` since its start (at rest before it): cubic
    Hermite interpolation through phi and its derivative omega (and omega through its own
    derivative, by central differences), fourth order in the step."""
    h = float(traj_t[1] - traj_t[0])
    inside = np.clip(at, 0.0, traj_t[-1])
    i = np.clip((inside / h).astype(int), 0, len(traj_t) - 2)
    s = inside / h - i
    alpha = np.gradient(omega, h)
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    p = h00 * phi[i] + h10 * h * omega[i] + h01 * phi[i + 1] + h11 * h * omega[i + 1]
    w = h00 * omega[i] + h10 * h * alpha[i] + h01 * omega[i + 1] + h11 * h * alpha[i + 1]
    if rest_phi is not None:
        p = np.where(at < 0, rest_phi, p)
        w = np.where(at < 0, 0.0, w)
    return p, w


def _residuals(model: StartModel, traj, member: int, x: Floats, data) -> Floats:
    phi0, _, start = model.states(x)
    start -= model.shift_s(x)
    out = []
    for k, (at, phi, omega, sigma) in enumerate(data):
        rest = float(phi0[k]) if model.kind == "release" else None
        p, w = _predict(traj.t_s, traj.phi_rad[member, :, k], traj.omega_rad_s[member, :, k], at - start, rest)
        out += [(p - phi) / ANGLE_SIGMA_RAD, (w - omega) / sigma]
    return np.concatenate(out)


def _solve_start(model: StartModel, x0: Floats, data, *, iterations: int = 8) -> tuple[Floats, float, float]:
    """Gauss-Newton on the start parameters (``least_squares.gauss_newton``: at most
    ``iterations`` steps, stopping below 1 us, 1 urad, 1 urad/s); the Jacobian by finite
    differences, one batch of rollouts per iteration (a shift of the release instant needs no
    rollout). Returns (x, rms of the residuals in sigmas, ``_unexplained``) at the end."""
    x = np.asarray(x0, dtype=float)
    steps = np.full(len(x), 1e-5)
    rolled = list(range(len(x)))
    if model.kind == "release":
        steps[0] = 1e-4
        rolled = rolled[1:]
    if model.timed:  # the values' shift: no rollout either
        steps[4] = 1e-4
        rolled.remove(4)

    def linearise(x: Floats) -> tuple[Floats, Floats]:
        xs = [x] + [x + steps[j] * np.eye(len(x))[j] for j in rolled]
        batch = model.rollouts(xs)
        r0 = _residuals(model, batch, 0, x, data)
        columns = []
        for j in range(len(x)):
            if j in rolled:
                rj = _residuals(model, batch, 1 + rolled.index(j), xs[1 + rolled.index(j)], data)
            else:
                rj = _residuals(model, batch, 0, x + steps[j] * np.eye(len(x))[j], data)
            columns.append((rj - r0) / steps[j])
        return r0, np.stack(columns, axis=1)

    x = gauss_newton(linearise, x, iterations=iterations, tolerance=1e-6)
    batch = model.rollouts([x])
    r = _residuals(model, batch, 0, x, data)
    return x, float(np.sqrt(np.mean(r * r))), _unexplained(model, batch, x, data)


def _unexplained(model: StartModel, traj, x: Floats, data) -> float:
    """rms of the model's angle residuals after the start over the rms of the measured angles'
    change since the start (both nodes): 0 a perfect fit, about 1 or more a model that does not
    describe what follows the start at all."""
    phi0, _, start = model.states(x)
    start -= model.shift_s(x)
    residual, motion = [], []
    for k, (at, phi, _omega, _sigma) in enumerate(data):
        after = at >= start
        p, _ = _predict(traj.t_s, traj.phi_rad[0, :, k], traj.omega_rad_s[0, :, k], at[after] - start, None)
        residual.append(p - phi[after])
        motion.append(phi[after] - phi0[k])
    r, m = np.concatenate(residual), np.concatenate(motion)
    if len(r) == 0:
        return math.inf
    return float(np.sqrt(np.mean(r * r)) / max(float(np.sqrt(np.mean(m * m))), 1e-9))


def _fit_data(nodes: Sequence[AlignedNode], instants: Sequence[Floats], lo: float, hi: float):
    """Per node (value instants, phi, omega, sigma) of the samples whose values lie in [lo, hi]."""
    out = []
    for node, at in zip(nodes, instants, strict=True):
        inside = (at >= lo) & (at <= hi)
        out.append((at[inside], node.phi[inside], node.omega[inside], node.sigma))
    return out


def mirrored_differs(drive: Drive | None) -> bool:
    """The mirror image of the run (both angles negated) is driven differently: a hinge torque or
    a sideways support acceleration changes sign under it; a vertical one does not."""
    return drive is not None and any(t is not Target.PIVOT_Z for t in drive.targets)


def fit_start(
    model: StartModel,
    nodes: Sequence[AlignedNode],
    instants: Sequence[Floats],
    start_fit_s: float,
    x0: Floats | None = None,
    iterations: int = 8,
) -> tuple[Floats, float, float]:
    """The start parameters fitted from the nodes' series at model.t0: (x, rms, unexplained) of
    ``_solve_start`` (at most ``iterations`` steps), from ``x0`` (None: from the series at t0)."""
    t0, kind = model.t0, model.kind
    lo = t0 - 0.3 if kind == "release" else t0
    hi = t0 + start_fit_s
    phi_now = [float(np.interp(t0, at, n.phi)) for n, at in zip(nodes, instants, strict=True)]
    omega_now = [float(np.interp(t0, at, n.omega)) for n, at in zip(nodes, instants, strict=True)]
    if kind == "release":
        held = [n.phi[(at >= t0 - 0.3) & (at <= t0)] for n, at in zip(nodes, instants, strict=True)]
        x = np.array([t0] + [float(np.mean(h)) if len(h) else p for h, p in zip(held, phi_now, strict=True)])
    else:
        x = np.array(phi_now + omega_now + ([0.0] if model.timed else []))
    return _solve_start(model, x if x0 is None else x0, _fit_data(nodes, instants, lo, hi), iterations=iterations)


def relative_fusion_timing(
    model: StartModel,
    nodes: Sequence[AlignedNode],
    phases: Sequence[float],
    fusion_rate_hz: float,
    start_fit_s: float,
    fitted: tuple[Floats, float, float],
) -> tuple[list[float], list[Floats], tuple[Floats, float, float], tuple[float, float] | None]:
    """The nodes' fusion phases (s) within their stretches (``timing.fusion_phase_stretch``).

    A node's own data leave its phase open within its stretch (2.5 ms wide at 80 Hz sampling of
    100 Hz fusion, each estimate within 1.25 ms). A common shift of both nodes' values is absorbed
    by the start fit (the release instant, the state in motion, a driven run's fitted shift); the
    shift of one node's values against the other's is not, and it costs the damping fit (a ms
    reads as dry friction). So that relative shift, anywhere both stretches allow (up to 5 ms
    wide: node 1's phase is as open as node 2's), is chosen by the start fit over TIMING_FIT_S:
    its cost (mean square residual in sigmas, the start re-fitted) is quadratic in a shift of a few
    ms on swings of about a second, so three probes (one Gauss-Newton step from ``fitted`` each)
    give the parabola whose vertex, held inside that range, is taken. Each node then keeps the
    middle of the phases its stretch allows with that relative shift, and the start is fitted
    there as before. Only the value instants and the start fit change: a ms does not move the
    swing frames.

    Args:
      model, nodes, start_fit_s: as for ``fit_start``.
      phases: (2,) each node's phase from its own data (``timing.fusion_phase``), s.
      fusion_rate_hz: the chips' fusion rate, Hz.
      fitted: ``fit_start``'s (x, rms, unexplained) at those phases.

    Returns:
      The chosen phases (2,), s in [0, 1 / fusion_rate_hz); the value instants (recorder clock,
      s) at them; the start fit there (x, rms, unexplained); the shifts of node 2's values
      against node 1's that both stretches still allow about the choice, (lo_s < 0, hi_s > 0) s
      (None: the timing was pinned, nothing was chosen).
    """
    period = 1.0 / fusion_rate_hz
    # each node's phase may move by d with lo < d <= hi (its stretch about its phase); 1 us margins
    room = []
    for node, phase in zip(nodes, phases, strict=True):
        lo, hi = fusion_phase_stretch(node.stamp, fusion_rate_hz, phase)
        room.append((lo - phase + 1e-6, hi - phase - 1e-6))
    (lo1, hi1), (lo2, hi2) = room
    r_lo, r_hi = lo2 - hi1, hi2 - lo1  # node 2's shift against node 1's: d2 - d1

    def split(r: float) -> tuple[float, float]:
        d1 = 0.5 * (max(lo1, lo2 - r) + min(hi1, hi2 - r))  # the middle of what both stretches allow
        return d1, d1 + r

    def moved(r: float) -> list[Floats]:
        return [n.value_instants(fusion_rate_hz, p + d) for n, p, d in zip(nodes, phases, split(r), strict=True)]

    if not (r_lo < 0.0 < r_hi and r_hi - r_lo >= TIMING_MIN_RANGE_S):  # pinned by clocks sweeping the period
        given = [n.value_instants(fusion_rate_hz, p) for n, p in zip(nodes, phases, strict=True)]
        return list(phases), given, fitted, None
    window_s = max(start_fit_s, TIMING_FIT_S)
    longer = dataclasses.replace(model, horizon_s=model.horizon_s + window_s - start_fit_s)
    probe = TIMING_PROBE * (r_hi - r_lo)
    r = np.array([max(-probe, r_lo), 0.0, min(probe, r_hi)])
    # one Gauss-Newton step from the start fit's x: the cost with the start re-fitted, to second order
    cost = [fit_start(longer, nodes, moved(float(v)), window_s, x0=fitted[0], iterations=1)[1] ** 2 for v in r]
    curvature, slope, _ = np.polyfit(r, cost, 2)
    best = float(np.clip(-slope / (2 * curvature), r_lo, r_hi)) if curvature > 0 else float(r[np.argmin(cost)])
    best = min(max(best, r_lo + 1e-6), r_hi - 1e-6)  # strictly inside: the damping fit refines it within
    instants = moved(best)
    chosen = fit_start(model, nodes, instants, start_fit_s, x0=fitted[0])
    chosen_phases = [(p + d) % period for p, d in zip(phases, split(best), strict=True)]
    return chosen_phases, instants, chosen, (r_lo - best, r_hi - best)
