"""Argument checks shared by both engines; each error names the argument and what is allowed.

Imports no physics engine, so the reference solver can use it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from pendsim_mj.errors import ParameterError, SimulationDiverged
from pendsim_mj.rig.drives import Drive, Target
from pendsim_mj.rig.params import PARAMETER_LIMITS, RigParams, check_field

MAX_STEPS = 10_000_000  # about 10 GB of trajectory arrays; a day of simulated time at 10 ms is 8.6e6


@dataclasses.dataclass(frozen=True)
class Range:
    """The allowed values of one input: ``low <= value <= high`` (``low < value`` with
    ``low_open``), in ``unit``."""

    low: float
    high: float
    unit: str = ""
    low_open: bool = False

    def describe(self) -> str:
        """The range as text, e.g. "[-180, 180] deg" or "(0, 86400] s"."""
        return f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}]{' ' + self.unit if self.unit else ''}"

    def check(self, name: str, value: ArrayLike, *, case_ids: Sequence[int] | None = None) -> None:
        """Raise ParameterError naming ``name`` (and the case, for an array) unless every value is
        finite and in the range."""
        arr = np.asarray(value, dtype=float)
        bad = ~np.isfinite(arr) | (arr > self.high) | (arr < self.low) | ((arr == self.low) & self.low_open)
        if not np.any(bad):
            return
        i = int(np.flatnonzero(bad.ravel())[0])
        where = "" if arr.ndim == 0 else f"case {i if case_ids is None else case_ids[i]}: "
        raise ParameterError(f"{where}{name} must be a finite number in {self.describe()}, got {arr.flat[i]:g}")


def _input_ranges() -> dict[str, Range]:
    ranges = {
        "duration_s": Range(0.0, 86400.0, "s", low_open=True),  # a day of simulated time
        "dt_s": Range(0.0, 0.1, "s", low_open=True),  # RK4 on the rig is unstable long before 0.1 s
    }
    for n in (1, 2):
        ranges[f"phi{n}_deg"] = Range(-180.0, 180.0, "deg")
        ranges[f"phi{n}_rad"] = Range(-math.pi, math.pi, "rad")
        ranges[f"omega{n}_deg_s"] = Range(-3600.0, 3600.0, "deg/s")  # ten turns a second
        ranges[f"omega{n}_rad_s"] = Range(-math.radians(3600.0), math.radians(3600.0), "rad/s")
    for target in Target:
        # far beyond the rig (its pendulums' gravity torque is about 0.7 N m) yet where the
        # integration stays meaningful
        limit = 10.0 if target.unit == "N m" else 100.0
        unit = "n_m" if target.unit == "N m" else "m_s2"
        ranges[f"{target.value}_amplitude_{unit}"] = Range(-limit, limit, target.unit)
        ranges[f"{target.value}_frequency_hz"] = Range(0.0, 1000.0, "Hz", low_open=True)
        ranges[f"{target.value}_phase_rad"] = Range(-2 * math.pi, 2 * math.pi, "rad")
    return ranges


INPUT_RANGES: dict[str, Range] = _input_ranges()
"""The one table of allowed values of every input of a run other than the rig's parameters
(those are ``params.PARAMETER_LIMITS``): the release state (``phi1_deg``, ..., ``omega2_rad_s``),
duration and step, and each drive target's sine (``TARGET_amplitude_UNIT``, ``TARGET_frequency_hz``,
``TARGET_phase_rad``). The command line's options and the sweeps' inputs are checked against it."""


def drive_amplitude_limit(target: Target) -> float:
    """The largest drive amplitude on ``target`` (in its unit) that ``INPUT_RANGES`` allows."""
    unit = "n_m" if target.unit == "N m" else "m_s2"
    return INPUT_RANGES[f"{target.value}_amplitude_{unit}"].high


def check_input(name: str, value: ArrayLike, *, case_ids: Sequence[int] | None = None) -> None:
    """Check an input against its range: ``INPUT_RANGES``, or for a rig parameter its own rules
    (``params.check_field``); names in neither are left to their owner.

    Raises:
      ParameterError: naming the input, the allowed range and the value (and the case, for arrays).
    """
    if name in INPUT_RANGES:
        INPUT_RANGES[name].check(name, value, case_ids=case_ids)
    elif name in PARAMETER_LIMITS:
        check_field(name, value, case_ids=case_ids)


def check_step(duration_s: float, dt_s: float) -> int:
    """Validate duration and step (s); return the number of steps."""
    for name, value in (("duration_s", duration_s), ("dt_s", dt_s)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise ParameterError(f"{name} must be a finite number > 0 s, got {value!r}")
    if dt_s > duration_s:
        raise ParameterError(f"dt_s = {dt_s} s must not exceed duration_s = {duration_s} s")
    if duration_s / dt_s > MAX_STEPS:
        raise ParameterError(
            f"duration_s / dt_s = {duration_s / dt_s:.3g} steps is over the limit of {MAX_STEPS:.0e} "
            "(memory grows with the steps); shorten the run or lengthen the step"
        )
    nstep = round(duration_s / dt_s)
    if abs(nstep * dt_s - duration_s) > 1e-9 * max(1.0, duration_s):
        fitting = duration_s / math.ceil(duration_s / dt_s)  # the largest step below dt_s that fits
        raise ParameterError(
            f"duration_s = {duration_s} s must be a whole number of steps of dt_s = {dt_s} s "
            f"(e.g. dt_s = {fitting:.12g} s: {math.ceil(duration_s / dt_s)} steps)"
        )
    return nstep


def check_params(params: RigParams | Sequence[RigParams]) -> list[RigParams]:
    """One RigParams or a non-empty sequence of them, as a list."""
    if isinstance(params, RigParams):
        return [params]
    plist = list(params) if isinstance(params, Sequence) else []
    if not plist or not all(isinstance(p, RigParams) for p in plist):
        raise ParameterError("params must be a RigParams or a non-empty sequence of RigParams")
    return plist


def check_initial(
    phi0_rad: ArrayLike, omega0_rad_s: ArrayLike, nbatch: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Initial angles (rad) and velocities (rad/s) as (nbatch, 2) float arrays, checked."""
    out = []
    for name, value in (("phi0_rad", phi0_rad), ("omega0_rad_s", omega0_rad_s)):
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise ParameterError(f"{name} must be numbers, got {value!r}") from None
        given_shape = arr.shape
        if arr.ndim == 1:
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise ParameterError(f"{name} must have shape (2,) or (nbatch, 2), got {given_shape}")
        if not np.all(np.isfinite(arr)):
            raise ParameterError(f"{name} must be finite, got {arr.tolist() if arr.size <= 8 else 'non-finite values'}")
        out.append(arr)
    phi, omega = out
    n = max(len(phi), len(omega), nbatch or 1)
    for name, arr in (("phi0_rad", phi), ("omega0_rad_s", omega)):
        if len(arr) not in (1, n):
            raise ParameterError(f"{name} has {len(arr)} rows; expected 1 or {n}")
    return np.broadcast_to(phi, (n, 2)).copy(), np.broadcast_to(omega, (n, 2)).copy()


def broadcast_params(plist: list[RigParams], nbatch: int) -> list[RigParams]:
    """Repeat a single parameter set over the batch, or check the counts match."""
    if len(plist) == 1:
        return plist * nbatch
    if len(plist) != nbatch:
        raise ParameterError(f"got {len(plist)} parameter sets for {nbatch} initial conditions")
    return plist


def check_drives(
    drive: object, nbatch: int, *, same_targets: bool = True
) -> tuple[list[Drive | None], tuple[Target, ...]]:
    """One Drive (or None) for every run, or a sequence of nbatch of them (driving the same
    targets unless not ``same_targets``); returns the per-run list and the driven targets (all
    of them, in Target order; empty when nothing is driven)."""
    if drive is None or isinstance(drive, Drive):
        drives: list[Drive | None] = [drive] * nbatch
    elif isinstance(drive, Sequence) and all(d is None or isinstance(d, Drive) for d in drive):
        drives = list(drive)
        if len(drives) != nbatch:
            raise ParameterError(f"got {len(drives)} drives for {nbatch} runs")
    else:
        raise ParameterError(f"drive must be a drives.Drive, a sequence of them, or None; got {drive!r}")
    kinds = {d.targets if d is not None else () for d in drives}
    if len(kinds) > 1 and same_targets:
        names = sorted(", ".join(t.value for t in k) or "nothing" for k in kinds)
        raise ParameterError(f"the drives of one batch must drive the same targets, got {'; '.join(names)}")
    union = set().union(*kinds)
    return drives, tuple(t for t in Target if t in union)


# An unforced rig with non-negative damping cannot gain energy; RK4 at a stable step keeps the
# energy error near 1e-5 of the energy (measured in tests/engines/test_physics.py). A growth above this
# share of (initial energy + one pendulum's gravity scale m g OC) means the step is unstable.
ENERGY_GROWTH_LIMIT = 0.01


UNRESOLVED_SHARE = 1e-3
"""A run whose energy balance is off by more than this share of m1 g OC1 is not resolved by its
step (healthy planar runs at 10 ms: below 2e-6 of it; a 3000 N/m spring at 10 ms: 10)."""


def unresolved_balance(residual_j: ArrayLike, energy_scale_j: ArrayLike) -> np.ndarray:
    """True where a run's energy balance (energy lost less the losses' and the inputs' work, J) is
    off by more than ``UNRESOLVED_SHARE`` of its energy scale (m1 g OC1, J): its step does not
    resolve it (a stiff spring, a violent swing) and its numbers are not to be trusted."""
    out: np.ndarray = np.abs(np.asarray(residual_j, dtype=float)) > UNRESOLVED_SHARE * np.asarray(energy_scale_j)
    return out


def first_nonfinite_run(values: np.ndarray, run_axis: int) -> int | None:
    """The first run (an index along ``run_axis`` of ``values``, any shape) with a value that is
    not finite, or None where all are: which run a diverged batch's message speaks of."""
    runs = np.moveaxis(np.asarray(values), run_axis, 0)
    bad = np.flatnonzero(~np.isfinite(runs.reshape(len(runs), -1)).all(axis=1))
    return int(bad[0]) if len(bad) else None


def energy_grew(total_energy_j: np.ndarray, energy_scale_j: np.ndarray) -> np.ndarray:
    """(nbatch,) True where a run's total energy (nbatch, n) grew past the limit, or is not finite.

    Args:
      total_energy_j: (nbatch, n) kinetic + potential energy above rest, J.
      energy_scale_j: (nbatch,) a natural energy scale of each run (m1 g OC1), J.
    """
    e0 = total_energy_j[:, 0]
    growth = np.max(total_energy_j, axis=1) - e0
    limit = ENERGY_GROWTH_LIMIT * (np.abs(e0) + energy_scale_j)
    grew: np.ndarray = ~(growth <= limit)  # also catches NaN
    return grew


def check_energy_bounded(
    total_energy_j: np.ndarray,
    energy_scale_j: np.ndarray,
    dt_s: float,
    advice: Callable[[int], str],
) -> None:
    """Raise SimulationDiverged where the total energy (..., n) grew past the limit.

    Args:
      total_energy_j: (nbatch, n) kinetic + potential energy above rest, J.
      energy_scale_j: (nbatch,) a natural energy scale of each run (m1 g OC1), J.
      dt_s: the step, named in the message.
      advice: what to change for run i (``engines.reference.diverged_advice``: the stable step and
        what sets it).
    """
    bad = energy_grew(total_energy_j, energy_scale_j)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        e0 = total_energy_j[i, 0]
        top = np.max(total_energy_j[i])
        which = f" of run {i}" if len(bad) > 1 else ""
        raise SimulationDiverged(
            f"simulation diverged: the energy{which} grew from {e0:.4g} J to {top:.4g} J "
            f"without any input; " + advice(i)
        )
