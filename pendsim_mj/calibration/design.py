"""Experiment design: which further recording would determine best what the calibration left open,
computed from the same information matrix.

Each candidate experiment (a release in a mode at an amplitude, a known drive torque, a known added
mass; ``candidates``) is simulated on the planar model at the calibrated rig, with the recordings'
gyro noise and length; its information about the free parameters (the Schur complement of its own
start state, as in ``information``) is added to what the recordings hold, and the directions and
quantities are determined again (``fit.determine``). A candidate is ranked by how many quantities
it newly determines, then by how much it narrows the widest direction the recordings leave held:
no fixed list of advice, the numbers of this rig and these recordings.

A known drive torque or a known added mass changes the equations by a known moment, not by one
divided by an unknown inertia: they break the common scale no free swing sees.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.calibration import information as info
from pendsim_mj.calibration.fit import Calibration, CalibrationRun, _Problem, determine
from pendsim_mj.calibration.parameters import ParameterSpace, added_mass_constants
from pendsim_mj.engines import fast_planar
from pendsim_mj.engines.linearised import linear_modes
from pendsim_mj.estimation.planar_fit import FIT_DT_S
from pendsim_mj.rig.drives import Drive, Sine, stage_inputs
from pendsim_mj.rig.params import RigParams

Floats = NDArray[np.float64]

SAMPLE_RATE_HZ = 80.0  # the nodes' output rate (sensors.bno055)
ADDED_MASS_KG = 0.05  # a known mass clamped at the sensor disk, for the candidate
TORQUE_AMPLITUDE_N_M = 0.005  # a known motor torque's amplitude, for the candidate


@dataclasses.dataclass(frozen=True)
class Experiment:
    """A candidate recording: a release from rest at phi0_deg, for duration_s, with a known drive
    or added mass (``added_coef``: the constants it adds) and how to say it."""

    label: str
    phi0_deg: tuple[float, float]
    drive: Drive | None = None
    added_coef: Floats | None = None


@dataclasses.dataclass(frozen=True)
class Suggestion:
    """A candidate's effect: the quantities it would newly determine (labels), and the widest held
    direction's half-width (relative) before and after."""

    experiment: Experiment
    newly_determined: tuple[str, ...]
    widest_before: float
    widest_after: float

    def describe(self) -> str:
        what = "would determine " + ", ".join(self.newly_determined) if self.newly_determined else "narrows"
        if math.isinf(self.widest_before) and math.isinf(self.widest_after):
            return f"{self.experiment.label}: {what}"
        before = "not seen" if math.isinf(self.widest_before) else f"+-{100 * self.widest_before:.2g} %"
        after = "not seen" if math.isinf(self.widest_after) else f"+-{100 * self.widest_after:.2g} %"
        return (
            f"{self.experiment.label}: {what} (the least determined direction's 95 % half-width: {before} -> {after})"
        )

    @property
    def helps(self) -> bool:
        """It determines something more, or narrows what stays held by at least a fifth."""
        return bool(self.newly_determined) or self.widest_after < 0.8 * self.widest_before

    def to_json(self) -> dict[str, object]:
        return {
            "experiment": self.experiment.label,
            "phi0_deg": list(self.experiment.phi0_deg),
            "newly_determined": list(self.newly_determined),
            "widest_half_width_before": None if math.isinf(self.widest_before) else self.widest_before,
            "widest_half_width_after": None if math.isinf(self.widest_after) else self.widest_after,
        }


def candidates(params: RigParams) -> list[Experiment]:
    """Releases in mode 1, mode 2 and of one pendulum at small and large amplitude, a known torque
    at M1's hinge at the first mode's frequency, and a known mass at each disk."""
    f1 = float(linear_modes(params).frequency_hz[0])
    out = [Experiment(f"a release in mode 1 at {a:g} deg (M1 and M2 together)", (a, a)) for a in (10.0, 30.0, 60.0)]
    out += [Experiment(f"a release in mode 2 at {a:g} deg (M1 and M2 opposed)", (a, -a)) for a in (10.0, 30.0)]
    out += [Experiment("a release of M1 alone at 30 deg (M2 at rest)", (30.0, 0.0))]
    out += [Experiment("a release of M2 alone at 30 deg (M1 at rest)", (0.0, 30.0))]
    torque = Drive(torque_m1=Sine(TORQUE_AMPLITUDE_N_M, f1))
    out.append(
        Experiment(
            f"a known torque of {1000 * TORQUE_AMPLITUDE_N_M:g} mN m at M1's hinge at {f1:.3f} Hz (/drive), "
            "both released from 20 deg",
            (20.0, 20.0),
            drive=torque,
        )
    )
    for n in (1, 2):
        out.append(
            Experiment(
                f"a release of both at 30 deg with a known {1000 * ADDED_MASS_KG:g} g mass clamped at the sensor disk "
                f"of M{n}",
                (30.0, 30.0),
                added_coef=added_mass_constants(params, n, ADDED_MASS_KG, params.om1_m if n == 1 else params.om2_m),
            )
        )
    return out


def information_of(
    experiment: Experiment, space: ParameterSpace, x: Floats, sigma_rad_s: float, duration_s: float
) -> Floats:
    """The information (nfree, nfree) about x of one noise-free simulated recording of the
    experiment at the rig x (its start state eliminated), in the fit's units (residuals in sigmas)."""
    params = space.params(x)
    coef = fast_planar.coefficients([params])
    if experiment.added_coef is not None:
        coef = coef + experiment.added_coef[:, None]
    t = np.arange(1.0 / SAMPLE_RATE_HZ, duration_s, 1.0 / SAMPLE_RATE_HZ)
    phi0 = np.radians(experiment.phi0_deg)
    inputs = None
    if experiment.drive is not None:
        inputs = stage_inputs(experiment.drive, math.ceil(duration_s / FIT_DT_S) + 2, FIT_DT_S)
    (r1, r2), _, _ = fast_planar.rates_at(coef, phi0, (0.0, 0.0), (t, t), FIT_DT_S, inputs=inputs, slopes=False)
    run = CalibrationRun(
        experiment.label, (t, t), (r1, r2), (sigma_rad_s, sigma_rad_s), (float(phi0[0]), float(phi0[1])),
        drive=experiment.drive, added_coef=experiment.added_coef,
    )  # fmt: skip
    problem = _Problem(space, [run])
    y = problem.start()
    y[: len(x)] = x
    return problem.normal_equations(y, math.inf)[4]


def suggest(cal: Calibration, *, sigma_rad_s: float, duration_s: float, top: int = 3) -> list[Suggestion]:
    """The ``top`` candidates (``candidates``) that add most to what the calibration determines
    (module docstring), best first."""
    space = ParameterSpace(cal.stated, cal.free)
    held = [d for d in cal.directions if not d.determined]
    widest = max((d.half_width95 for d in held), default=0.0)
    known = {q.name for q in cal.quantities if q.determined}
    scored = []
    for experiment in candidates(cal.params):
        combined = cal.information + information_of(experiment, space, cal.x, sigma_rad_s, duration_s)
        dirs, _, quantities = determine(space, cal.x, combined, cal.residual_variance)
        new = tuple(q.label for q in quantities if q.determined and q.name not in known)
        after = max((d.half_width95 for d in dirs if not d.determined), default=0.0)
        # rank: more newly determined, then the held directions narrowed most (their log half-widths)
        narrowed = sum(math.log(min(info.Z95 * 1e6, d.half_width95)) for d in dirs if not d.determined)
        scored.append((-len(new), narrowed, Suggestion(experiment, new, widest, after)))
    scored.sort(key=lambda s: (s[0], s[1]))
    return [s[2] for s in scored if s[2].helps][:top]
