"""Alignment's start fit (steps 4 and 5 of ``pendsim_mj.estimation.alignment``): the model of the
run's first seconds (``StartModel``) fitted to both nodes' angles and rates by least squares
(``fit_start``: the release instant and angles from rest, or the full state at the first
samples), and M2's sense and the nodes' relative timing chosen by it (``sense_and_timing``). The
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
    relative: bool = False
    """The shift of node 2's value instants against node 1's is fitted too (the last unknown,
    ``relative_s``): a value of node 2 at ``at`` belongs to at + shift."""

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

    def relative_s(self, x: Floats) -> float:
        """The shift of node 2's value instants against node 1's, s (0 unless ``relative``)."""
        return float(x[-1]) if self.relative else 0.0

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
        since = at - start + (model.relative_s(x) if k == 1 else 0.0)
        p, w = _predict(traj.t_s, traj.phi_rad[member, :, k], traj.omega_rad_s[member, :, k], since, rest)
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
    if model.relative:  # node 2's shift against node 1: none either
        steps[-1] = 1e-4
        rolled.remove(len(x) - 1)

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
        since = at - start + (model.relative_s(x) if k == 1 else 0.0)
        after = since >= 0
        p, _ = _predict(traj.t_s, traj.phi_rad[0, :, k], traj.omega_rad_s[0, :, k], since[after], None)
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
    if model.relative:
        x = np.append(x, 0.0)
    return _solve_start(model, x if x0 is None else x0, _fit_data(nodes, instants, lo, hi), iterations=iterations)


SENSE_CLEAR = 4.0
"""M2's sense against M1's is clear when the other sense's start fit has this many times the mean
square residual (a wrong sense after a mode-1 release: hundreds of times; the right one with the
nodes' timing off by 10 ms: under 2)."""


@dataclasses.dataclass(frozen=True)
class SenseAndTiming:
    """What ``sense_and_timing`` chose.

    Attributes:
      nodes: both nodes, M2's swing frame in the sense chosen.
      phases: each node's fusion phase (s in [0, 1 / fusion rate)), or None without fusion timing.
      instants: (m_k,) each node's value instants at the chosen timing, s on the recorder's clock.
      fitted: the start fit there, (x, rms, unexplained) as ``fit_start`` gives them.
      relative_s: M2's value instants moved by this against M1's from where the nodes' own
        data put them, s.
      timing_range_s: (lo_s < 0, hi_s > 0): how far M2's value instants may still move against
        M1's about the choice, s (None: nothing was left open).
      notes: one-line warnings: a sense the fit could not tell, a timing at the edge of its room.
    """

    nodes: list[AlignedNode]
    phases: list[float | None]
    instants: list[Floats]
    fitted: tuple[Floats, float, float]
    relative_s: float
    timing_range_s: tuple[float, float] | None
    notes: tuple[str, ...]


def sense_and_timing(
    model: StartModel,
    nodes: Sequence[AlignedNode],
    phases: Sequence[float | None],
    fusion_rate_hz: float | None,
    start_fit_s: float,
    fitted: tuple[Floats, float, float],
    open_s: float = 0.0,
) -> SenseAndTiming:
    """M2's sense against M1's and the shift of M2's value instants against M1's, both by the fit
    of the model to both nodes' first TIMING_FIT_S seconds.

    **Sense.** The swing frames' sense is M1's convention (``node_alignment.orient``) and, for
    M2, a regression of its angular acceleration on both angles: where the two angles move
    nearly together (a release in mode 1: phi2 = 0.10 phi1) that regression is ill-conditioned
    and can come out mirrored (b2 then 170 times the truth). So both senses of M2 are fitted and
    the one whose mean square residual is lower by SENSE_CLEAR is kept; where neither is, the
    lower is kept and a note says so.

    **Timing.** A node's own data leave its fusion phase open within a stretch
    (``timing.fusion_phase_stretch``: 2.5 ms wide at 80 Hz sampling of 100 Hz fusion), and a lab
    file's time columns may be off against each other (``open_s`` either way: a constant offset
    per node, one column shared by nodes sampled at other instants). A common shift of both is
    absorbed by the start fit; M2's shift against M1's is not, and it costs the damping fit (a
    ms reads as dry friction). That shift, anywhere the stretches and ``open_s`` allow, is an
    unknown of the start fit over TIMING_FIT_S (its column needs no rollout), fitted for both
    senses at once; the phases keep the middle of what both stretches allow, the rest moves
    M2's instants. A shift the fit puts beyond the room is held at its edge, with a note.

    Args:
      model, nodes, start_fit_s: as for ``fit_start``.
      phases: (2,) each node's phase from its own data (``timing.fusion_phase``), s, or None
        (no fusion timing).
      fusion_rate_hz: the chips' fusion rate, Hz, or None.
      fitted: ``fit_start``'s (x, rms, unexplained) at those phases and the frames' senses.
      open_s: how far each node's times may be off against the other's beyond the fusion
        timing, s (0: the recorder's clocks are trusted).
    """
    room = [(0.0, 0.0), (0.0, 0.0)]  # each node's phase may move by d with lo < d <= hi; 1 us margins
    if fusion_rate_hz:
        for k, (node, phase) in enumerate(zip(nodes, phases, strict=True)):
            assert phase is not None
            lo, hi = fusion_phase_stretch(node.stamp, fusion_rate_hz, phase)
            room[k] = (lo - phase + 1e-6, hi - phase - 1e-6)
    (lo1, hi1), (lo2, hi2) = room
    f_lo, f_hi = lo2 - hi1, hi2 - lo1  # what the phases allow of node 2's shift against node 1's
    r_lo, r_hi = f_lo - open_s, f_hi + open_s

    def split(r: float) -> tuple[float, float]:
        d1 = 0.5 * (max(lo1, lo2 - r) + min(hi1, hi2 - r))  # the middle of what both stretches allow
        return d1, d1 + r

    def moved(r: float) -> tuple[list[float | None], list[Floats]]:
        r_phase = min(max(r, f_lo), f_hi) if fusion_rate_hz else 0.0
        shifts = split(r_phase) if fusion_rate_hz else (0.0, 0.0)
        new = [None if p is None else p + d for p, d in zip(phases, shifts, strict=True)]
        at = [n.value_instants(fusion_rate_hz, p) for n, p in zip(nodes, new, strict=True)]
        if r != r_phase:
            at[1] = at[1] + (r - r_phase)
        return new, at

    timed = r_lo < 0.0 < r_hi and r_hi - r_lo >= TIMING_MIN_RANGE_S
    window_s = max(start_fit_s, TIMING_FIT_S)
    longer = dataclasses.replace(model, horizon_s=model.horizon_s + window_s - start_fit_s, relative=timed)
    _, instants = moved(0.0)
    senses = [list(nodes), [nodes[0], nodes[1].with_frame(nodes[1].frame.flipped())]]  # type: ignore[union-attr]
    fits = [fit_start(longer, candidate, instants, window_s) for candidate in senses]
    costs = [f[1] ** 2 for f in fits]
    best = int(np.argmin(costs))
    notes = []
    if costs[1 - best] < SENSE_CLEAR * costs[best]:
        notes.append(
            f"M2's sense against M1's is not clear from the first {window_s:g} s: the model fits "
            f"{fits[best][1]:.3g} sigmas rms with it as taken, {fits[1 - best][1]:.3g} with M2 mirrored"
            " (M2 hardly moves, or the model is far off); check the sign of M2's angle"
        )
    chosen_nodes = senses[best]
    r = longer.relative_s(fits[best][0])
    if timed and not r_lo < r < r_hi:
        held = min(max(r, r_lo + 1e-6), r_hi - 1e-6)
        notes.append(
            f"M2's values seem {1e3 * r:+.1f} ms off against M1's, beyond the {1e3 * r_lo:+.1f} to "
            f"{1e3 * r_hi:+.1f} ms their timing allows; held at {1e3 * held:+.1f} ms: check the file's time columns"
        )
        r = held
    if not timed:
        r = 0.0
    new_phases, instants = moved(r)
    if timed or best == 1:
        fitted = fit_start(model, chosen_nodes, instants, start_fit_s, x0=fitted[0] if best == 0 else None)
    return SenseAndTiming(
        nodes=chosen_nodes,
        phases=new_phases,
        instants=instants,
        fitted=fitted,
        relative_s=r,
        timing_range_s=(r_lo - r, r_hi - r) if timed else None,
        notes=tuple(notes),
    )
