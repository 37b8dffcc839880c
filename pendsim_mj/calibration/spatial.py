"""Calibration on the spatial model: the rig's in-plane parameters and the support's tilt stiffness
and damping fitted together to both nodes' gyros, all three axes (``calibrate --model spatial``).

Why a fit of its own: on a rig whose support tilts, the tilt changes the hinges' motion (the
tilt line at 1.7-2.1 Hz beats with the swing); a planar calibration absorbs that into wrong
springs and inertias (2.5 noise sigmas left, not white, on a 60 s record of a rig with a 50 mm
plane offset), and fitting the tilt after it, or alternating the two fits (each holding the
other's values), does not converge: measured, the tilt stiffness moved between -5 % and +3 % of
the truth over five rounds and the hinge rates the two models predict differed by up to 1 rad/s.
So everything is fitted in one least-squares problem on the spatial MJCF.

Model: the spatial MuJoCo model (``rig.model.SPATIAL``) at the rig's parameters, from each
recording's start state (fitted as the planar calibration fits it; the support untilted or at its
static tilt at the start, ``spatial_identification.TILT_STARTS``). Residuals: each node's gyro
along (tangential, toward pivot, hinge) in its swing frame minus the model's, in noise sigmas,
with the model's vectors rotated onto the measured ones per node (``best_rotation``: the swing
frame found from the data is itself tilted by the tilt motion).

Unknowns and their units: the same relative units as the planar calibration
(``parameters.ParameterSpace``, with the tilt stiffness and damping among the free parameters),
shared by all recordings, and each recording's own start state. Jacobian: forward differences of
the rollouts (one rollout per unknown per recording, all of a recording's rollouts in one
``mujoco.rollout`` call over the machine's threads); each model compiled from the rig's parameters
(``rig.model.build_spec``, about 4 ms).

Steps and what is determined: as ``calibration.fit`` (Levenberg-Marquardt moving the shared
unknowns only along the directions the information determines; the rest held at the stated rig;
windows growing by ``WINDOW_FACTOR`` from ``FIRST_WINDOW_S``, since the tilt line is fast and a
poor stated tilt stiffness could otherwise lock onto a neighbouring cycle), and the same
``fit.determine`` turns the information into directions, intervals and determined quantities.

Start: the caller's (``start``): ``pendsim calibrate --model spatial`` starts from the planar
calibration of the same recordings (``bridge/run/calibrate.py``), which converged on every rig
tried; from the stated rig, a rig with J2 -5 %, OC2 -5 % and c2 +4 % ended at 96 noise sigmas.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence

import mujoco
import numpy as np
from numpy.typing import NDArray

from pendsim_mj.calibration import information as info
from pendsim_mj.calibration.fit import (
    CHI2_TOLERANCE,
    LOSSES,
    MIN_DURATION_S,
    Calibration,
    RunResult,
    _basis,
    _step,
    determine,
)
from pendsim_mj.calibration.parameters import SPATIAL_FREE, SPATIAL_PARAMETERS, ParameterSpace, free_set
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.identification import sensors_only
from pendsim_mj.estimation.planar_fit import MAX_RELEASE_OFFSET_S, ljung_box_p
from pendsim_mj.estimation.spatial_identification import GYROS, TILT_STARTS, _static_tilts, best_rotation
from pendsim_mj.rig.model import HINGES, SPATIAL, TILTS, build_spec
from pendsim_mj.rig.params import RigParams

Floats = NDArray[np.float64]

FIRST_WINDOW_S = 4.0  # the first window: a 15 % tilt-stiffness error is half a tilt cycle by its end
WINDOW_FACTOR = 3.0  # then 12 s, 36 s, ...: each fit starts from the previous one's values
SHARED_STEP = 1e-6  # forward-difference step of the shared unknowns (relative units)
LOCAL_STEP = {"phi1_0": 1e-7, "phi2_0": 1e-7, "omega1_0": 1e-7, "omega2_0": 1e-7}  # rad, rad/s
TIME_STEP_S = 1e-6  # of the release offset and M2's timing shift, s
ITERATIONS_PER_WINDOW = 25
TILT_GRID = tuple(float(f) for f in np.geomspace(0.4, 2.5, 41))  # start values of the tilt stiffness tried, x stated


@dataclasses.dataclass(frozen=True)
class SpatialRun:
    """One recording's data for the spatial calibration.

    Attributes:
      name: how the report names it (the file).
      value_t_s: (m, 2) each node's value instants since the start, s (NaN where a node has fewer
        samples).
      gyro_rad_s: (m, 2, 3) each node's gyro along (tangential, toward pivot, hinge), rad/s.
      gyro_sigma_rad_s: (2, 3) their noise sigmas, rad/s.
      phi0_rad, omega0_rad_s: the alignment's start state (the first guess; fitted).
      moving: the run starts in motion (start rates fitted) rather than released from rest.
      timing_range_s: where M2's value instants may shift against M1's, s (None: fixed).
      tilt_start: the support's tilt at the start, "zero" or "static" (``TILT_STARTS``).
    """

    name: str
    value_t_s: Floats
    gyro_rad_s: Floats
    gyro_sigma_rad_s: Floats
    phi0_rad: tuple[float, float]
    omega0_rad_s: tuple[float, float] = (0.0, 0.0)
    moving: bool = False
    timing_range_s: tuple[float, float] | None = None
    tilt_start: str = "zero"

    def __post_init__(self) -> None:
        t, g, s = (np.asarray(a, dtype=float) for a in (self.value_t_s, self.gyro_rad_s, self.gyro_sigma_rad_s))
        if t.ndim != 2 or t.shape[1] != 2 or g.shape != (*t.shape, 3) or s.shape != (2, 3):
            raise ParameterError(
                f"{self.name}: expected value_t_s (m, 2), gyro_rad_s (m, 2, 3), sigmas (2, 3); got {t.shape}, "
                f"{g.shape}, {s.shape}"
            )
        if not np.all(s > 0):
            raise ParameterError(f"{self.name}: gyro sigmas must be > 0, got {s.tolist()}")
        if self.tilt_start not in TILT_STARTS:
            raise ParameterError(f"tilt_start must be one of {TILT_STARTS}, got {self.tilt_start!r}")

    @property
    def duration_s(self) -> float:
        t = np.asarray(self.value_t_s, dtype=float)
        return float(np.nanmax(t)) if np.any(np.isfinite(t)) else 0.0

    @property
    def local_names(self) -> tuple[str, ...]:
        names = ["phi1_0", "phi2_0", *(("omega1_0", "omega2_0") if self.moving else ("release_offset_s",))]
        if self.timing_range_s is not None:
            names.append("timing2_s")
        return tuple(names)

    def columns(self, window_s: float) -> list[tuple[Floats, Floats]]:
        """Each node's (instants (n,), gyros (n, 3)) within the first ``window_s``, finite only."""
        t = np.asarray(self.value_t_s, dtype=float)
        g = np.asarray(self.gyro_rad_s, dtype=float)
        out = []
        for k in range(2):
            ok = np.isfinite(t[:, k]) & np.all(np.isfinite(g[:, k]), axis=1) & (t[:, k] >= 0) & (t[:, k] <= window_s)
            out.append((t[ok, k], g[ok, k]))
        return out


class _Rollouts:
    """The spatial model's gyros for many rigs and start states at once (``mujoco.rollout``)."""

    def __init__(self) -> None:
        from mujoco import rollout  # start-up: MuJoCo's threaded rollouts

        self._rollout = rollout
        self._threads = max(1, min(8, os.cpu_count() or 1))
        self._models: dict[bytes, mujoco.MjModel] = {}

    def model(self, params: RigParams) -> mujoco.MjModel:
        values = params.as_dict()
        key = np.array([values[n] for n in sorted(values)]).tobytes()
        if key not in self._models:
            if len(self._models) > 64:
                self._models.clear()
            try:
                self._models[key] = sensors_only(build_spec(params, variant=SPATIAL), GYROS).compile()
            except ValueError as exc:  # MuJoCo's checks (an inertia tensor no body has): no rig
                raise ParameterError(f"no rig: {' '.join(str(exc).split())}") from None
        return self._models[key]

    def gyros(
        self, models: Sequence[mujoco.MjModel], starts: Sequence[tuple[Floats, Floats]], tilt_start: str, nstep: int
    ) -> Floats:
        """(nbatch, nstep, 6) both nodes' gyros in their sensor axes at t = i dt, i < nstep, from
        each (phi_0, omega_0); the support untilted or at its static tilt."""
        m0 = models[0]
        datas = [mujoco.MjData(m0) for _ in range(self._threads)]
        hinge_q = [int(m0.joint(h).qposadr[0]) for h in HINGES]
        hinge_v = [int(m0.joint(h).dofadr[0]) for h in HINGES]
        tilt_q = [int(m0.joint(n).qposadr[0]) for n in TILTS]
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        state = np.zeros((len(models), mujoco.mj_stateSize(m0, spec)))
        work = mujoco.MjData(m0)
        for i, (m, (phi, omega)) in enumerate(zip(models, starts, strict=True)):
            work.qpos[:] = 0.0
            work.qvel[:] = 0.0
            work.time = 0.0
            work.qpos[hinge_q] = phi
            work.qvel[hinge_v] = omega
            if tilt_start == "static":
                tilt = _static_tilts(m, work, np.asarray(phi, dtype=float))
                work.qpos[:] = 0.0
                work.qpos[hinge_q] = phi
                work.qpos[tilt_q] = tilt
                work.qvel[:] = 0.0
                work.qvel[hinge_v] = omega
            mujoco.mj_getState(m, work, state[i], spec)
        _, sensordata = self._rollout.rollout(list(models), datas, state, nstep=nstep)
        # mj_step evaluates the sensors of the state it starts from: row i belongs to t = i dt
        return np.asarray(sensordata)


class _Problem:
    """The spatial calibration's unknowns, residuals and forward-difference Jacobians."""

    def __init__(self, space: ParameterSpace, runs: Sequence[SpatialRun]) -> None:
        self.space = space
        self.runs = tuple(runs)
        self.nfree = len(space.free)
        self.offsets = [self.nfree]
        for run in self.runs:
            self.offsets.append(self.offsets[-1] + len(run.local_names))
        self.size = self.offsets[-1]
        self.engine = _Rollouts()
        self.dt_s = float(self.engine.model(space.params(np.zeros(self.nfree))).opt.timestep)
        self.seen = np.zeros((self.nfree, self.nfree))  # the last information, the common scale in it

    def start(self) -> Floats:
        y = np.zeros(self.size)
        for r, run in enumerate(self.runs):
            lo = self.offsets[r]
            y[lo : lo + 2] = run.phi0_rad
            if run.moving:
                y[lo + 2 : lo + 4] = run.omega0_rad_s
        return y

    def clip(self, y: Floats) -> Floats:
        """Losses and tilt values at least 0; release offsets and timing shifts within their ranges."""
        y = y.copy()
        for i, name in enumerate(self.space.free):
            if name in LOSSES or name in SPATIAL_PARAMETERS:
                y[i] = max(y[i], -self.space.stated_values[i] / self.space.scale[i])
        for r, run in enumerate(self.runs):
            names, lo = run.local_names, self.offsets[r]
            if "release_offset_s" in names:
                k = lo + names.index("release_offset_s")
                y[k] = min(max(y[k], -MAX_RELEASE_OFFSET_S), MAX_RELEASE_OFFSET_S)
            if run.timing_range_s is not None:
                k = lo + names.index("timing2_s")
                y[k] = min(max(y[k], run.timing_range_s[0]), run.timing_range_s[1])
        return y

    def _members(self, r: int, y: Floats, jacobian: bool) -> tuple[list[Floats], list[int], list[float]]:
        """The unknowns of each rollout of recording r (the point, then one step per column), the
        column each perturbs (-1: the point) and its step: forward, or backward where the
        forward step leaves the rigs MuJoCo accepts (a point at the edge of valid inertias)."""
        lo, hi = self.offsets[r], self.offsets[r + 1]
        members, columns, steps = [y], [-1], [0.0]
        if jacobian:
            for j in [*range(self.nfree), *range(lo, hi)]:
                step = self._step(r, j)
                z = y.copy()
                z[j] += step
                if j < self.nfree and not self._valid(z):
                    step = -step
                    z[j] = y[j] + step
                members.append(z)
                columns.append(j)
                steps.append(step)
        return members, columns, steps

    def _valid(self, z: Floats) -> bool:
        try:
            self.engine.model(self.space.params(z[: self.nfree]))
        except ParameterError:
            return False
        return True

    def _step(self, r: int, j: int) -> float:
        if j < self.nfree:
            return SHARED_STEP
        name = self.runs[r].local_names[j - self.offsets[r]]
        return LOCAL_STEP.get(name, TIME_STEP_S)

    def run_residuals(self, r: int, y: Floats, window_s: float, jacobian: bool) -> tuple[Floats, Floats | None]:
        """Recording r's residuals (n,) in sigmas at y over the first ``window_s``, and with
        ``jacobian`` their forward-difference Jacobian (n, size) (zero outside the shared unknowns
        and r's own)."""
        run, lo = self.runs[r], self.offsets[r]
        columns = run.columns(window_s)
        members, perturbed, steps = self._members(r, y, jacobian)
        models, starts, timing = [], [], []
        for z in members:
            local = dict(zip(run.local_names, z[lo : self.offsets[r + 1]], strict=True))
            models.append(self.engine.model(self.space.params(z[: self.nfree])))
            starts.append(
                (
                    np.array([local["phi1_0"], local["phi2_0"]]),
                    np.array([local.get("omega1_0", 0.0), local.get("omega2_0", 0.0)]),
                )
            )
            timing.append((float(local.get("release_offset_s", 0.0)), float(local.get("timing2_s", 0.0))))
        end_s = max(float(t[-1]) for t, _ in columns if len(t)) + MAX_RELEASE_OFFSET_S + 0.05
        nstep = math.ceil(end_s / self.dt_s) + 4
        gyros = self.engine.gyros(models, starts, run.tilt_start, nstep)
        stamps: Floats = np.asarray(self.dt_s * np.arange(nstep), dtype=np.float64)
        sigma = np.asarray(run.gyro_sigma_rad_s, dtype=float)
        out = [self._residual(gyros[i], stamps, columns, sigma, *timing[i]) for i in range(len(members))]
        base = out[0]
        if not jacobian:
            return base, None
        jac = np.zeros((len(base), self.size))
        for i in range(1, len(members)):
            jac[:, perturbed[i]] = (out[i] - base) / steps[i]
        return base, jac

    @staticmethod
    def _residual(
        gyro: Floats, stamps: Floats, columns: list[tuple[Floats, Floats]], sigma: Floats, tau: float, shift2: float
    ) -> Floats:
        """Both nodes' residuals in sigmas, node by node, axis by axis (tangential, toward pivot,
        hinge), each axis's samples in time order."""
        parts = []
        for k, (at, measured) in enumerate(columns):
            since = at + (shift2 if k == 1 else 0.0) - tau  # the model rests until the release at tau
            predicted = _cubic(stamps, gyro[:, 3 * k : 3 * k + 3], np.maximum(since, 0.0))
            predicted[since < 0] = 0.0
            predicted = predicted @ best_rotation(predicted, measured).T
            parts.append(((predicted - measured) / sigma[k]).T.ravel())
        return np.concatenate(parts)

    def normal_equations(self, y: Floats, window_s: float) -> tuple[Floats, Floats, float, int, Floats]:
        """(N, g, r.r, n, S) as ``fit._Problem.normal_equations``: S the information about the
        shared unknowns (the runs' own eliminated)."""
        normal = np.zeros((self.size, self.size))
        gradient = np.zeros(self.size)
        schur = np.zeros((self.nfree, self.nfree))
        rr, n = 0.0, 0
        for r in range(len(self.runs)):
            res, jac = self.run_residuals(r, y, window_s, True)
            assert jac is not None
            if not (np.all(np.isfinite(res)) and np.all(np.isfinite(jac))):
                raise ParameterError(f"{self.runs[r].name}: the spatial model diverged during the calibration")
            index = np.r_[np.arange(self.nfree), np.arange(self.offsets[r], self.offsets[r + 1])]
            block = jac[:, index]
            nr = block.T @ block
            normal[np.ix_(index, index)] += nr
            gradient[index] += block.T @ res
            schur += info.schur_complement(nr, self.nfree)
            rr += float(res @ res)
            n += len(res)
        self.seen = schur
        return normal, gradient, rr, n, self.without_scale(schur, y[: self.nfree])

    def without_scale(self, information: Floats, x: Floats) -> Floats:
        """The information with the common scale of all moments and inertias taken out: the tilt's
        inertia (the masses at their offsets, held) makes it faintly visible (a 3 % half-width on a
        60 s record of the paper's rig), too faintly to fit on: a scale off by a few per cent is
        absorbed elsewhere (measured: every parameter 6 % low at 0.99 sigma). So it is held at the
        stated rig and the rest is determined without it, as in the planar model."""
        scale = self.space.scale_direction(x)
        if scale is None:
            return information
        u = scale / np.linalg.norm(scale)
        keep = np.eye(len(u)) - np.outer(u, u)
        return np.asarray(keep @ information @ keep)

    def chi2(self, y: Floats, window_s: float) -> tuple[float, int]:
        rr, n = 0.0, 0
        for r in range(len(self.runs)):
            res, _ = self.run_residuals(r, y, window_s, False)
            rr += float(res @ res)
            n += len(res)
        return rr, n


def _cubic(stamps: Floats, values: Floats, at: Floats) -> Floats:
    """Catmull-Rom cubic through values (nstep, c) on the uniform stamps, read at ``at`` (n,):
    (n, c). Local (four samples), so a rollout's length does not cost a spline solve; its error
    on the 10 ms grid is ~1e-6 of a 1 Hz swing's rate, far below a gyro's noise."""
    dt = stamps[1] - stamps[0]
    u = np.clip(at / dt, 1.0, len(stamps) - 3.0 - 1e-9)
    i = np.floor(u).astype(int)
    s = (u - i)[:, None]
    p0, p1, p2, p3 = values[i - 1], values[i], values[i + 1], values[i + 2]
    out = p1 + 0.5 * s * (p2 - p0 + s * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3 + s * (3.0 * (p1 - p2) + p3 - p0)))
    early = at < dt  # below the first interval: the linear piece from t = 0 (the rollout's start)
    if np.any(early):
        w = (at[early] / dt)[:, None]
        out[early] = (1.0 - w) * values[0] + w * values[1]
    return np.asarray(out)


def _windows(duration_s: float) -> list[float]:
    out = []
    w = FIRST_WINDOW_S
    while w < duration_s:
        out.append(w)
        w *= WINDOW_FACTOR
    return [*out, math.inf]


def calibrate_spatial(
    runs: Sequence[SpatialRun],
    params: RigParams,
    *,
    law: str = "viscous",
    free: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    start: Mapping[str, float] | None = None,
    refine: bool = False,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """Fit the rig's in-plane parameters and the support's tilt stiffness and damping to
    recordings on the spatial model (module docstring).

    Args:
      runs: the recordings (free decays), each at least ``fit.MIN_DURATION_S`` long.
      params: the stated rig, with its plane offset (> 0: without it nothing tilts).
      law: the hinges' damping law ("viscous", "coulomb" or "both").
      free: the parameters to fit besides the damping (default ``DEFAULT_FREE``; may include
        ``plane_offset_m``); the tilt stiffness and damping are fitted unless fixed.
      fixed: parameters held at given values, SI.
      start: values of free parameters to start from (e.g. an earlier calibration's), SI.
      refine: ``start`` is a fit of these recordings already (aligned again since): one pass over
        the whole records, without the growing windows and the tilt stiffness's search.
      progress: called with one line per window.

    Returns:
      A ``Calibration`` whose free parameters include the tilt's, its quantities and directions
      from the spatial model's information, its runs' residuals over all three gyro axes.
    """
    start_time = time.perf_counter()
    if not runs:
        raise ParameterError("calibrate needs at least one recording")
    if params.plane_offset_m <= 0:
        raise ParameterError(
            "the spatial calibration needs the planes' offset (plane_offset_m > 0): without it nothing tilts"
        )
    fixed = dict(fixed or {})
    names = tuple(dict.fromkeys([*free_set(law, free, fixed), *(n for n in SPATIAL_FREE if n not in fixed)]))
    stated = params.with_mapping(fixed)
    for run in runs:
        if run.duration_s < MIN_DURATION_S:
            raise ParameterError(
                f"{run.name}: {run.duration_s:.1f} s after the start; calibration needs at least {MIN_DURATION_S:g} s "
                "of swing"
            )
    space = ParameterSpace(stated, names)
    problem = _Problem(space, runs)
    y = problem.start()
    for name, value in (start or {}).items():
        if name in space.free:
            i = space.free.index(name)
            y[i] = (value - space.stated_values[i]) / space.scale[i]
    windows = [math.inf] if refine else _windows(max(run.duration_s for run in runs))
    if not refine:
        y = _tilt_start(problem, y, windows[0])
    iterations = 0
    for window in windows:
        normal, gradient, rr, n, schur = problem.normal_equations(y, window)
        # the directions moved are fixed for the window: a weakly seen one (the common scale, which
        # the tilt's inertia makes all but invisible) recomputed each step would drift the rig
        variance = rr / max(1, n - problem.size)
        basis = _basis(problem, [d for d in info.directions(schur, variance) if d.determined])  # type: ignore[arg-type]
        mu = 1e-3
        for _ in range(ITERATIONS_PER_WINDOW):
            trial = problem.clip(y + _step(normal, gradient, basis, mu))
            iterations += 1
            try:
                t_rr, _ = problem.chi2(trial, window)
            except ParameterError:  # a trial rig that is no rig (a length below 0): a shorter step
                t_rr = math.inf
            if t_rr < rr:
                done = rr - t_rr < max(CHI2_TOLERANCE, 1e-12 * rr)
                y = trial
                normal, gradient, rr, n, schur = problem.normal_equations(y, window)
                mu = max(mu / 10.0, 1e-9)
                if done:
                    break
            else:
                mu *= 10.0
                if mu > 1e6:
                    break
        if progress is not None:
            shown = "the whole record" if math.isinf(window) else f"the first {window:g} s"
            progress(f"calibrate (spatial): {shown}: residual rms {math.sqrt(rr / max(n, 1)):.2f} sigma")
    return _result(problem, y, stated, law, normal, rr, n, schur, iterations, time.perf_counter() - start_time)


def _tilt_start(problem: _Problem, y: Floats, window_s: float) -> Floats:
    """y with the tilt stiffness where the first window fits best over ``TILT_GRID`` times its
    start value (the tilt line's frequency goes with its square root: a stated value 30 % off is
    more than a cycle off within 4 s, where a local fit locks onto a neighbouring cycle)."""
    if "tilt_stiffness_n_m_rad" not in problem.space.free:
        return y
    i = problem.space.free.index("tilt_stiffness_n_m_rad")
    stated, scale = problem.space.stated_values[i], problem.space.scale[i]
    value = stated + scale * y[i]
    best, best_rr = y, math.inf
    for factor in TILT_GRID:
        trial = y.copy()
        trial[i] = (factor * value - stated) / scale
        rr, _ = problem.chi2(trial, window_s)
        if rr < best_rr:
            best, best_rr = trial, rr
    return best


def _result(
    problem: _Problem,
    y: Floats,
    stated: RigParams,
    law: str,
    normal: Floats,
    rr: float,
    n: int,
    schur: Floats,
    iterations: int,
    seconds: float,
) -> Calibration:
    space = problem.space
    variance = rr / max(1, n - problem.size)
    x = y[: problem.nfree]
    dirs, cov_x, quantities = determine(space, x, schur, variance, seen=problem.seen)
    if not any(d.determined for d in dirs):
        raise ParameterError(
            "the recordings determine none of the rig's parameters to 1 %: too short or too still (record a "
            "release of at least 20 deg for 60 s or more)"
        )
    results = []
    for r, run in enumerate(problem.runs):
        res, _ = problem.run_residuals(r, y, math.inf, False)
        lo, hi = problem.offsets[r], problem.offsets[r + 1]
        sizes = [len(t) for t, _ in run.columns(math.inf)]
        hinge = [res[3 * sizes[0] - sizes[0] : 3 * sizes[0]], res[3 * sizes[0] + 2 * sizes[1] :]]
        results.append(
            RunResult(
                run.name,
                dict(zip(run.local_names, map(float, y[lo:hi]), strict=True)),
                math.sqrt(float(res @ res) / max(len(res), 1)),
                (ljung_box_p(hinge[0]), ljung_box_p(hinge[1])),
                len(res),
            )
        )
    return Calibration(
        params=space.params(x),
        stated=stated,
        free=space.free,
        law=law,
        x=x.copy(),
        covariance_x=cov_x,
        directions=tuple(dirs),
        quantities=tuple(quantities),
        runs=tuple(results),
        residual_rms_sigma=math.sqrt(rr / max(n, 1)),
        information=schur,
        residual_variance=variance,
        iterations=iterations,
        seconds=seconds,
        model="spatial",
    )
