"""Bifurcation diagrams: stroboscopic (Poincare) samples of the sine-driven rig against the drive
frequency or level.

For each parameter value the rig runs ``transient_periods`` drive periods and then records its
state once per period (at the drive's phase 0) for ``sample_periods`` periods: a period-1 response
gives one point, period doubling two, a quasi-periodic or chaotic response a cloud. The angles are
recorded wrapped to (-pi, pi] (a pendulum driven over the top is back where it started after a
whole turn). With the rig's light default damping (amplitudes fall to 20 % in 120 s) the
transient needs hundreds of periods to die out. The sweep runs
up and down at once (two runs in one batch, N steps per period at each value), each value starting
from the state the previous one ended in, so coexisting attractors and jumps show as differences
between the two directions.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.errors import ParameterError
from pendsim_mj.nonlinear.flow import RigFlow
from pendsim_mj.nonlinear.periodic import drive_frequency_hz, period_inputs
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.params import RigParams

PARAMETERS = ("frequency", "level")


@dataclasses.dataclass(frozen=True)
class PoincareSweep:
    """One direction of a sweep.

    Attributes:
      direction: "up" or "down". values: (P,) parameter values in the order run (Hz for
      "frequency", the drive's amplitude factor times its amplitude for "level": the first
      driven sine's amplitude in its unit). samples: (P, S, 4) state at each sampled period
      (angles wrapped to (-pi, pi]). period: (P,) the smallest p <= 8 with samples repeating
      every p periods (to ``repeat_tol`` rad), 0 when none (quasi-periodic, chaotic or not settled).
    """

    direction: str
    values: NDArray[np.float64]
    samples: NDArray[np.float64]
    period: NDArray[np.int64]


@dataclasses.dataclass(frozen=True)
class PoincareDiagram:
    parameter: str
    unit: str
    sweeps: tuple[PoincareSweep, ...]
    transient_periods: int
    sample_periods: int
    steps_per_period: int


def wrap_rad(angle: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angles wrapped to (-pi, pi]."""
    return np.asarray(np.pi - np.mod(np.pi - np.asarray(angle), 2 * np.pi), dtype=np.float64)


def response_period(samples: NDArray[np.float64], *, max_period: int = 8, tol: float = 1e-3) -> int:
    """Smallest p with |x_{j+p} - x_j| < tol (angles, rad, modulo a whole turn) for every
    sample, 0 if none <= max_period."""
    s = np.asarray(samples)[:, :2]
    for p in range(1, max_period + 1):
        if len(s) > p and np.max(np.abs(wrap_rad(s[p:] - s[:-p]))) < tol:
            return p
    return 0


def poincare_sweep(
    params: RigParams,
    drive: Drive,
    values: ArrayLike,
    *,
    parameter: str = "frequency",
    steps_per_period: int = 128,
    transient_periods: int = 200,
    sample_periods: int = 40,
    x0: ArrayLike = (0.0, 0.0, 0.0, 0.0),
    directions: Sequence[str] = ("up", "down"),
    repeat_tol: float = 1e-3,
    progress: Callable[[int], None] | None = None,
) -> PoincareDiagram:
    """Stroboscopic samples against the drive frequency (Hz) or level (module docstring).

    Args:
      drive: sines at one frequency. For parameter "frequency" the values are frequencies; for
        "level" they are the first driven sine's amplitude (every sine scaled alike), at the
        drive's own frequency.
      values: (P,) ascending.
    """
    if parameter not in PARAMETERS:
        raise ParameterError(f"parameter must be one of {', '.join(PARAMETERS)}, got {parameter!r}")
    f0 = drive_frequency_hz(drive)
    v = np.asarray(values, dtype=float)
    if v.ndim != 1 or len(v) < 1 or np.any(np.diff(v) <= 0) or not np.all(np.isfinite(v)):
        raise ParameterError("values must be finite and ascending")
    if parameter == "frequency" and np.any(v <= 0):
        raise ParameterError("frequencies must be > 0 Hz")
    if transient_periods < 0 or sample_periods < 1:
        raise ParameterError("need transient_periods >= 0 and sample_periods >= 1")
    first = drive.signal(drive.targets[0])
    base_amplitude = getattr(first, "amplitude", 1.0)
    if parameter == "level" and base_amplitude == 0:
        raise ParameterError("a level sweep needs a drive with a non-zero amplitude")
    n = steps_per_period
    order = {"up": v, "down": v[::-1]}
    nb = len(directions)
    x = np.tile(np.asarray(x0, dtype=float), (nb, 1))
    unit = period_inputs(drive, n)  # (N, 4) at the drive's own amplitudes
    total = transient_periods + sample_periods
    samples = np.zeros((nb, len(v), sample_periods, 4))
    with RigFlow(params, drive.targets) as flow:
        for i in range(len(v)):
            value = np.array([order[d][i] for d in directions])
            if parameter == "frequency":
                f = value
                factor = np.ones(nb)
            else:
                f = np.full(nb, f0)
                factor = value / base_amplitude
            inputs = np.tile(unit, (total, 1))[None] * factor[:, None, None]
            out = flow.run(x, 1.0 / (f * n), n * total, inputs)
            x = out[:, -1].copy()
            samples[:, i] = out[:, n * (transient_periods + 1) :: n][:, :sample_periods]
            samples[:, i, :, :2] = wrap_rad(samples[:, i, :, :2])
            if progress is not None:
                progress(1)
    unit_name = "Hz" if parameter == "frequency" else first_unit(drive)
    sweeps = tuple(
        PoincareSweep(
            direction=d,
            values=order[d].copy(),
            samples=samples[b],
            period=np.array([response_period(s, tol=repeat_tol) for s in samples[b]], dtype=np.int64),
        )
        for b, d in enumerate(directions)
    )
    return PoincareDiagram(parameter, unit_name, sweeps, transient_periods, sample_periods, steps_per_period)


def first_unit(drive: Drive) -> str:
    return drive.targets[0].unit if drive else ""


def default_values(low: float, high: float, count: int) -> NDArray[np.float64]:
    if not (math.isfinite(low) and math.isfinite(high) and high > low) or count < 2:
        raise ParameterError(f"need low < high and count >= 2, got {low}, {high}, {count}")
    return np.linspace(low, high, count)
