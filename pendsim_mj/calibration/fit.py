"""Calibration: the rig's physical parameters fitted to one or several recorded swings at once,
on the planar model, along the directions the recordings determine.

Model: the planar equations (``fast_planar``) at the rig's parameters, integrated by the compiled
RK4 at ``FIT_DT_S``, as the damping fit (``estimation.planar_fit``) does. Unknowns: the free
parameters x (relative units, ``parameters.ParameterSpace``), shared by all recordings, and each
recording's own start state (phi_0; a release offset, or omega_0 for a run that starts moving;
M2's relative timing where the alignment leaves it open). Residuals: each node's gyro about its
hinge minus the model's rate, in noise sigmas, at the fused values' instants.

Jacobian: exact, from the kernel's variational equations (``fast_planar.normal_equations_at``
with the force-law constants as unknowns), times d constants / d x; the normal equations are
summed in one pass per recording (no n x P matrix: a 1 h record is n = 0.6 M per node).

Steps: Gauss-Newton with a Levenberg-Marquardt damping, the shared unknowns moved only along the
directions the recordings determine (``information``): the rest are held at the stated rig. A
long record whose model is a few per cent off in frequency is a phase off by radians at its end,
where a Gauss-Newton step may lock onto the wrong cycle: the fit starts on the first
``FIRST_WINDOW_S`` of each recording and doubles the window until the whole record is used, the
frequency pinned better at each stage.

Intervals: covariance s^2 (J'J)^-1 of the fitted directions with s^2 = RSS / (n - P), projected
onto each reported quantity (delta method); a quantity is reported as determined only where the
held directions cannot move it by a fifth of its interval (``information.held_bias``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.calibration import information as info
from pendsim_mj.calibration.parameters import (
    QUANTITIES,
    SPATIAL_QUANTITIES,
    ParameterSpace,
    Quantity,
    free_set,
    parameter_quantity,
)
from pendsim_mj.engines import fast_planar
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.planar_fit import FIT_DT_S, MAX_RELEASE_OFFSET_S, ljung_box_p
from pendsim_mj.rig.drives import Drive, TimeSeries, stage_inputs
from pendsim_mj.rig.params import RigParams

Floats = NDArray[np.float64]

FIRST_WINDOW_S = 3.0  # the first window (a 5 % frequency error: 0.8 rad of phase at its end), then doubled
MAX_ITERATIONS = 100  # Gauss-Newton iterations over all stages
CHI2_TOLERANCE = 1e-3  # a stage ends when an iteration moves the sum of squared residuals (sigmas^2) by less
DRIVE_MARGIN_S = 0.15  # the instants a recorded drive's last samples leave for the release offset and timing shift
LOSSES = ("b1_n_m_s", "b2_n_m_s", "friction1_n_m", "friction2_n_m")  # never below 0
MAX_DRIVE_SHIFT_S = 0.02  # how far a driven run's instants may shift against its recorded drive, s
MIN_DURATION_S = 5.0  # a recording shorter than this after its start cannot calibrate anything
_SENSITIVE = ("b1_n_m_s", "b2_n_m_s", "friction1_n_m", "friction2_n_m", *fast_planar.COEF_SENSITIVITIES)
_UNITS = {"N/m": "N/m"}


@dataclasses.dataclass(frozen=True)
class CalibrationRun:
    """One recording's data for the calibration (from a ``MeasuredRun``: ``from_measured``).

    Attributes:
      name: how the report names it (the file).
      value_t_s: each node's value instants since the start, s, ascending and finite: (m1,), (m2,).
      gyro_z_rad_s: each node's measured rate about its hinge, rad/s, at those instants.
      gyro_sigma_rad_s: (2,) each node's gyro noise sigma, rad/s.
      phi0_rad, omega0_rad_s: the alignment's start state (the first guess).
      moving: the run starts in motion (omega_0 fitted) rather than released from rest.
      drive: the run's known drive (time 0 at the release), None for a free swing.
      timing_range_s: where M2's value instants may shift against M1's, s (None: fixed).
      added_coef: (NCOEF,) known additions to the force-law constants (an added mass: its
        m g r, m r^2 and m r), or None.
    """

    name: str
    value_t_s: tuple[Floats, Floats]
    gyro_z_rad_s: tuple[Floats, Floats]
    gyro_sigma_rad_s: tuple[float, float]
    phi0_rad: tuple[float, float]
    omega0_rad_s: tuple[float, float] = (0.0, 0.0)
    moving: bool = False
    drive: Drive | None = None
    timing_range_s: tuple[float, float] | None = None
    added_coef: Floats | None = None

    @property
    def duration_s(self) -> float:
        return max(float(a[-1]) for a in self.value_t_s)

    @property
    def shifts_drive(self) -> bool:
        """A driven run that starts in motion: its instants may shift against its drive (a release
        offset does that for a driven release)."""
        return self.moving and bool(self.drive)

    @property
    def local_names(self) -> tuple[str, ...]:
        names = ["phi1_0", "phi2_0", *(("omega1_0", "omega2_0") if self.moving else ("release_offset_s",))]
        if self.shifts_drive:
            names.append("drive_shift_s")
        if self.timing_range_s is not None:
            names.append("timing2_s")
        return tuple(names)

    @staticmethod
    def from_measured(name: str, run: object, drive: Drive | None = None) -> CalibrationRun:
        """From an aligned recording (``estimation.MeasuredRun``; typed loosely so that this module
        does not import the alignment): finite samples only, each node's own instants."""
        nodes = run.nodes  # type: ignore[attr-defined]
        at, gyro = [], []
        for node in nodes:
            t = np.asarray(node.value_t_s, dtype=float)
            y = np.asarray(node.omega_rad_s, dtype=float)
            ok = np.isfinite(t) & np.isfinite(y)
            order = np.argsort(t[ok], kind="stable")
            at.append(np.ascontiguousarray(t[ok][order]))
            gyro.append(np.ascontiguousarray(y[ok][order]))
        covered = _drive_end_s(drive) - DRIVE_MARGIN_S
        if covered < math.inf:  # a recorded drive ends with the recording: the last instants' steps need it
            for k in range(2):
                n = int(np.searchsorted(at[k], covered, side="right"))
                at[k], gyro[k] = at[k][:n], gyro[k][:n]
        start = run.start  # type: ignore[attr-defined]
        phi0, omega0 = tuple(start.phi_rad), tuple(start.omega_rad_s)
        if start.kind != "release":  # in motion: the measured state at the start, not a model's guess of it
            phi0 = tuple(float(np.interp(0.0, node.t_s, node.phi_rad)) for node in nodes)
            omega0 = tuple(float(np.interp(0.0, at[k], gyro[k])) for k in range(2))
        return CalibrationRun(
            name=name,
            value_t_s=(at[0], at[1]),
            gyro_z_rad_s=(gyro[0], gyro[1]),
            gyro_sigma_rad_s=tuple(run.gyro_sigma_rad_s),  # type: ignore[attr-defined]
            phi0_rad=phi0,
            omega0_rad_s=omega0,
            moving=start.kind != "release",
            drive=drive,
            timing_range_s=run.relative_timing_range_s,  # type: ignore[attr-defined]
        )


@dataclasses.dataclass(frozen=True)
class Determination:
    """One reported quantity.

    Attributes:
      name, label, unit: as ``parameters.Quantity``.
      stated: its value at the stated rig; value: calibrated.
      half_width95: 95 % half-width (the fitted directions' uncertainty), in its unit.
      held_bias: the most the held directions could move it (``information.held_bias``).
      determined: the recordings determine it (held_bias small against the interval).
    """

    name: str
    label: str
    unit: str
    stated: float
    value: float
    half_width95: float
    held_bias: float
    determined: bool


@dataclasses.dataclass(frozen=True)
class RunResult:
    """One recording at the calibrated rig: its start state, residual rms (sigmas), whiteness."""

    name: str
    start: dict[str, float]
    residual_rms_sigma: float
    ljung_box_p: tuple[float, float]
    n_residuals: int


@dataclasses.dataclass(frozen=True)
class Calibration:
    """The result of ``calibrate``.

    Attributes:
      params: the calibrated rig; stated: the rig held where the data say nothing.
      free: the parameters fitted (in the order of x); law: the damping law fitted.
      x: (nfree,) relative changes from the stated values; covariance_x: (nfree, nfree).
      directions: the information's eigen-directions, best determined first.
      quantities: every free parameter, then every ratio the free ones move (``QUANTITIES``).
      runs: each recording's fit; residual_rms_sigma: over all of them.
      information: (nfree, nfree) S, the Fisher information about x (residuals in sigmas; divide
        by residual_variance for the covariance's scale).
      residual_variance: s^2 = RSS / (n - P).
      iterations: Gauss-Newton iterations; seconds: wall time.
      model: "planar" (``calibrate``) or "spatial" (``spatial.calibrate_spatial``: the tilt's
        stiffness and damping among the free parameters, the residuals over all three gyro axes).
    """

    params: RigParams
    stated: RigParams
    free: tuple[str, ...]
    law: str
    x: Floats
    covariance_x: Floats
    directions: tuple[info.Direction, ...]
    quantities: tuple[Determination, ...]
    runs: tuple[RunResult, ...]
    residual_rms_sigma: float
    information: Floats
    residual_variance: float
    iterations: int
    seconds: float
    model: str = "planar"

    def overrides(self) -> dict[str, float]:
        """The calibrated free parameters (a parameter file for ``--params-file``); for the spatial
        model also the planes' offset it was calibrated with."""
        values = self.params.as_dict()
        out = {name: values[name] for name in self.free}
        if self.model == "spatial":
            out["plane_offset_m"] = values["plane_offset_m"]
        return out

    def parameter_file(self) -> dict[str, float]:
        """Every parameter of the calibrated rig (the free ones as calibrated, the others as the
        stated rig held them): what ``params.json`` holds, so that the file stands on its own. A
        command puts a parameter file on top of its own base (validate and a replay: the rig a
        recording states), and the free values alone, on a recording that states another rig than
        the one they were calibrated on, counted that difference twice."""
        return self.params.as_dict()

    def quantity(self, name: str) -> Determination:
        for q in self.quantities:
            if q.name == name:
                return q
        raise KeyError(name)

    @property
    def undetermined(self) -> tuple[info.Direction, ...]:
        return tuple(d for d in self.directions if not d.determined)


class _Problem:
    """The calibration's unknowns and one pass of normal equations per recording."""

    def __init__(self, space: ParameterSpace, runs: Sequence[CalibrationRun]) -> None:
        self.space = space
        self.runs = tuple(runs)
        self.nfree = len(space.free)
        self.offsets = [self.nfree]
        for run in self.runs:
            self.offsets.append(self.offsets[-1] + len(run.local_names))
        self.size = self.offsets[-1]
        self.inputs = [None if not run.drive else _held(run) for run in self.runs]

    def start(self) -> Floats:
        y = np.zeros(self.size)
        for r, run in enumerate(self.runs):
            lo = self.offsets[r]
            y[lo : lo + 2] = run.phi0_rad
            if run.moving:
                y[lo + 2 : lo + 4] = run.omega0_rad_s
        return y

    def clip(self, y: Floats) -> Floats:
        """Hinge losses at least 0, release offsets and timing shifts within their ranges."""
        y = y.copy()
        for i, name in enumerate(self.space.free):
            if name in LOSSES:  # a loss the data put at 0 stays there (a fit may step below it)
                y[i] = max(y[i], -self.space.stated_values[i] / self.space.scale[i])
        for r, run in enumerate(self.runs):
            names, lo = run.local_names, self.offsets[r]
            if "release_offset_s" in names:
                k = lo + names.index("release_offset_s")
                y[k] = min(max(y[k], -MAX_RELEASE_OFFSET_S), MAX_RELEASE_OFFSET_S)
            if run.timing_range_s is not None:
                k = lo + names.index("timing2_s")
                y[k] = min(max(y[k], run.timing_range_s[0]), run.timing_range_s[1])
            if run.shifts_drive:
                k = lo + names.index("drive_shift_s")
                y[k] = min(max(y[k], -MAX_DRIVE_SHIFT_S), MAX_DRIVE_SHIFT_S)
        return y

    def _run_arguments(
        self, r: int, y: Floats, window_s: float
    ) -> tuple[Floats, Floats, Floats, float, tuple[Floats, Floats], tuple[Floats, Floats]]:
        run, lo = self.runs[r], self.offsets[r]
        local = dict(zip(run.local_names, y[lo : self.offsets[r + 1]], strict=True))
        coef = self.space.coefficients(y[: self.nfree])
        if run.added_coef is not None:
            coef = coef + run.added_coef
        phi0 = np.array([local["phi1_0"], local["phi2_0"]])
        omega0 = np.array([local.get("omega1_0", 0.0), local.get("omega2_0", 0.0)])
        release = float(local.get("release_offset_s", 0.0))
        shift = float(local.get("timing2_s", 0.0))
        common = float(local.get("drive_shift_s", 0.0))
        at, gyro = [], []
        for k in range(2):
            n = int(np.searchsorted(run.value_t_s[k], window_s, side="right"))
            t = run.value_t_s[k][:n]
            moved = common + (shift if k == 1 else 0.0)
            at.append(t + moved if moved else t)
            gyro.append(run.gyro_z_rad_s[k][:n])
        return coef[:, None].copy(), phi0, omega0, release, (at[0], at[1]), (gyro[0], gyro[1])

    def normal_equations(self, y: Floats, window_s: float) -> tuple[Floats, Floats, float, int, Floats]:
        """(N (size, size), g (size,), r.r, n, S (nfree, nfree)) of all recordings over the first
        ``window_s`` of each, at y; S the information about x (``information.schur_complement``)."""
        x = y[: self.nfree]
        jac = self.space.coefficient_jacobian(x)
        rows = [name for name in _SENSITIVE if np.any(jac[fast_planar.COEFFICIENTS.index(name)] != 0)]
        normal = np.zeros((self.size, self.size))
        gradient = np.zeros(self.size)
        rr, n = 0.0, 0
        schur = np.zeros((self.nfree, self.nfree))
        for r, run in enumerate(self.runs):
            coef, phi0, omega0, release, at, gyro = self._run_arguments(r, y, window_s)
            state = ["phi1_0", "phi2_0", *(("omega1_0", "omega2_0") if run.moving else ())]
            jtj, jtr, rr_r = fast_planar.normal_equations_at(
                coef, phi0, omega0, at, gyro, run.gyro_sigma_rad_s, FIT_DT_S, release_s=release,
                wrt=[*rows, *state], release_column=not run.moving or run.shifts_drive,
                timing_column=run.timing_range_s is not None,
                inputs=self.inputs[r],
            )  # fmt: skip
            if not (np.all(np.isfinite(jtj)) and np.all(np.isfinite(jtr)) and math.isfinite(rr_r)):
                raise ParameterError(f"{run.name}: the planar model diverged during the calibration")
            nloc = len(run.local_names)
            t = np.zeros((len(rows) + nloc, self.nfree + nloc))
            t[: len(rows), : self.nfree] = jac[[fast_planar.COEFFICIENTS.index(name) for name in rows]]
            t[len(rows) :, self.nfree :] = np.eye(nloc)
            if run.shifts_drive:  # the kernel's release column is d rate / d tau = -d rate / d (the instants' shift)
                k = run.local_names.index("drive_shift_s")
                t[len(rows) + k, self.nfree + k] = -1.0
            nr = t.T @ jtj @ t
            gr = t.T @ jtr
            index = np.r_[np.arange(self.nfree), np.arange(self.offsets[r], self.offsets[r + 1])]
            normal[np.ix_(index, index)] += nr
            gradient[index] += gr
            schur += info.schur_complement(nr, self.nfree)
            rr += rr_r
            n += len(at[0]) + len(at[1])
        return normal, gradient, rr, n, schur

    def residuals(self, y: Floats) -> list[tuple[Floats, Floats]]:
        """Each recording's normalised residuals at y over its whole record."""
        out = []
        for r, run in enumerate(self.runs):
            coef, phi0, omega0, release, at, gyro = self._run_arguments(r, y, math.inf)
            rates, _, _ = fast_planar.rates_at(
                coef, phi0, omega0, at, FIT_DT_S, release_s=release, inputs=self.inputs[r], slopes=False
            )
            sigma = run.gyro_sigma_rad_s
            out.append(((rates[0] - gyro[0]) / sigma[0], (rates[1] - gyro[1]) / sigma[1]))
        return out


def _drive_end_s(drive: Drive | None) -> float:
    """Where a drive's recorded samples end (time 0 at the release), s; inf for signals."""
    ends = [float(s.t_s[-1]) for t in (drive.targets if drive else ()) if isinstance(s := drive.signal(t), TimeSeries)]  # type: ignore[union-attr]
    return min(ends, default=math.inf)


def _held(run: CalibrationRun) -> Floats:
    """The run's drive held over the steps the latest release offset and timing shift need (as
    ``planar_fit``), from the release on."""
    assert run.drive is not None
    end_s = run.duration_s + MAX_RELEASE_OFFSET_S + max((0.0, *(run.timing_range_s or ())))
    return stage_inputs(run.drive, math.ceil(end_s / FIT_DT_S) + 2, FIT_DT_S)


def _windows(duration_s: float) -> list[float]:
    out = []
    w = FIRST_WINDOW_S
    while w < duration_s:
        out.append(w)
        w *= 2.0
    return [*out, math.inf]


def _step(normal: Floats, gradient: Floats, basis: Floats, mu: float) -> Floats:
    """The Levenberg-Marquardt step of the unknowns y, the shared ones moved only in span(basis)."""
    p = basis.T @ normal @ basis
    g = basis.T @ gradient
    d = np.sqrt(np.maximum(np.diag(p), 1e-300))
    scaled = p / np.outer(d, d) + mu * np.eye(len(d))
    return np.asarray(basis @ (-np.linalg.solve(scaled, g / d) / d))


def _basis(problem: _Problem, determined: Sequence[info.Direction]) -> Floats:
    """Columns spanning the determined shared directions and every recording's own unknowns."""
    nloc = problem.size - problem.nfree
    cols = [np.r_[d.vector, np.zeros(nloc)] for d in determined]
    local = np.zeros((problem.size, nloc))
    local[problem.nfree :, :] = np.eye(nloc)
    return np.column_stack([*cols, local]) if cols else local


def calibrate(
    runs: Sequence[CalibrationRun],
    params: RigParams,
    *,
    law: str = "viscous",
    free: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    start: Mapping[str, float] | None = None,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """Fit the rig's parameters to recordings (see the module docstring).

    Args:
      runs: the recordings (``CalibrationRun.from_measured``), each at least MIN_DURATION_S long.
      params: the stated rig (the paper's or the user's file): where the fit starts and what it
        holds along the directions the data do not determine.
      law: the hinges' damping law fitted with the rig: "viscous", "coulomb" or "both".
      free: the parameters to fit besides the damping (``parameters.DEFAULT_FREE``).
      fixed: parameters held at given values (SI), e.g. a weighed mass or a measured inertia.
      start: values of free parameters to start from (e.g. an earlier calibration's), SI; the
        stated rig stays what the undetermined directions are held at.
      progress: called with one line per stage.

    Raises:
      ParameterError: no recording, one too short or too still to determine anything, a fixed
        name unknown, or recordings of different rigs (residuals far above the noise in one
        recording only after the joint fit).
    """
    start_time = time.perf_counter()
    if not runs:
        raise ParameterError("calibrate needs at least one recording")
    fixed = dict(fixed or {})
    names = free_set(law, free, fixed)
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
    windows = _windows(max(run.duration_s for run in runs))
    iterations = 0
    normal, gradient, rr, n, schur = problem.normal_equations(y, windows[0])
    for window in windows:
        if iterations:
            normal, gradient, rr, n, schur = problem.normal_equations(y, window)
        mu = 1e-3
        for _ in range(12):
            if iterations >= MAX_ITERATIONS:
                break
            variance = rr / max(1, n - problem.size)
            determined = [d for d in info.directions(schur, variance) if d.determined]
            trial = problem.clip(y + _step(normal, gradient, _basis(problem, determined), mu))
            t_normal, t_gradient, t_rr, t_n, t_schur = problem.normal_equations(trial, window)
            iterations += 1
            if t_rr < rr:
                done = rr - t_rr < max(CHI2_TOLERANCE, 1e-12 * rr)
                y, normal, gradient, rr, n, schur = trial, t_normal, t_gradient, t_rr, t_n, t_schur
                mu = max(mu / 10.0, 1e-9)
                if done:
                    break
            else:
                mu *= 10.0
                if mu > 1e6:
                    break
        if progress is not None:
            shown = "the whole record" if math.isinf(window) else f"the first {window:g} s"
            progress(f"calibrate: {shown}: residual rms {math.sqrt(rr / max(n, 1)):.2f} sigma")
    return _result(problem, y, stated, law, iterations, time.perf_counter() - start_time)


def determine(
    space: ParameterSpace, x: Floats, information: Floats, variance: float, *, seen: Floats | None = None
) -> tuple[list[info.Direction], Floats, list[Determination]]:
    """The directions of the information S (nfree, nfree) at residual variance s^2, the covariance
    of x along the determined ones (s^2 sum v v' / lambda), and every quantity the free parameters
    move (each free parameter, then ``QUANTITIES``) with its interval and whether it is determined.
    ``seen``: the model's whole information where S leaves out what it sees only faintly (the
    spatial model's common scale): the held bias then includes what the fit makes up for it
    (``information.compensated``)."""
    dirs = info.directions(information, variance)
    held = [d for d in dirs if not d.determined]
    shifts = None
    if seen is not None:
        fitted = [d.vector for d in dirs if d.determined]
        shifts = [info.compensated(d.vector, fitted, seen) for d in held]
    cov_x = np.zeros((len(x), len(x)))
    for d in dirs:
        if d.determined:
            cov_x += (d.half_width95 / info.Z95) ** 2 * np.outer(d.vector, d.vector)
    units = {name: unit for name, unit, _ in space.stated.describe()}
    candidates: list[Quantity] = [parameter_quantity(name, units.get(name, "")) for name in space.free]
    candidates += list(QUANTITIES)
    candidates += [q for q in SPATIAL_QUANTITIES if q.parameter in space.free]
    quantities = []
    for q in candidates:
        grad = space.quantity_gradient(q, x)
        if not np.any(np.abs(grad) > 0):
            continue
        half = info.Z95 * math.sqrt(max(float(grad @ cov_x @ grad), 0.0))
        bias = info.held_bias(grad, held, shifts)
        value = space.quantity_value(q, x)
        ok = bias <= info.HELD_BIAS_FRACTION * half or bias <= 1e-9 * abs(value)
        if not ok and bias <= info.NEGLIGIBLE_BIAS * abs(value):
            # a bias far below what "determined" means for a direction (1 %), though above a very
            # narrow interval (the spatial model's weakly seen directions leak a little into the
            # ratios): determined, its interval widened by the bias
            ok, half = True, half + bias
        stated = space.quantity_value(q, np.zeros_like(x))
        quantities.append(Determination(q.name, q.label, q.unit, stated, value, half, bias, ok))
    return dirs, cov_x, quantities


def _result(problem: _Problem, y: Floats, stated: RigParams, law: str, iterations: int, seconds: float) -> Calibration:
    space = problem.space
    _, _, rr, n, schur = problem.normal_equations(y, math.inf)
    variance = rr / max(1, n - problem.size)
    x = y[: problem.nfree]
    dirs, cov_x, quantities = determine(space, x, schur, variance)
    held = [d.vector for d in dirs if not d.determined]
    scale = space.scale_direction(x)
    if scale is not None:
        held.insert(0, scale / np.linalg.norm(scale))
    x = space.valid_along(x, held)  # along directions no recording sees: nothing determined moves
    if not np.array_equal(x, y[: problem.nfree]):
        dirs, cov_x, quantities = determine(space, x, schur, variance)
    if not any(d.determined for d in dirs):
        raise ParameterError(
            "the recordings determine none of the rig's parameters to 1 %: too short or too still (record a "
            "release of at least 20 deg for 60 s or more)"
        )
    results = []
    for r, (run, res) in enumerate(zip(problem.runs, problem.residuals(y), strict=True)):
        lo, hi = problem.offsets[r], problem.offsets[r + 1]
        m = len(res[0]) + len(res[1])
        rss = float(res[0] @ res[0]) + float(res[1] @ res[1])
        results.append(
            RunResult(
                run.name,
                dict(zip(run.local_names, map(float, y[lo:hi]), strict=True)),
                math.sqrt(rss / max(m, 1)),
                (ljung_box_p(res[0]), ljung_box_p(res[1])),
                m,
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
    )
