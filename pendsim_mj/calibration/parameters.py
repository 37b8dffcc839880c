"""The calibration's parameter space: which rig parameters it may change, in which units it moves
them, how the planar model's force-law constants depend on them, and the quantities a free swing
can determine.

Units of the fit (``ParameterSpace``): each free parameter theta_i moves as
theta_i = stated_i + scale_i x_i with scale_i = |stated_i| (or ``FALLBACK_SCALE`` where the stated
value is 0, e.g. a dry friction): x_i is the relative change (0.01 = 1 % of the stated value), so
one information matrix compares springs, inertias and lengths on one footing.

The planar model sees the rig only through its force-law constants (``fast_planar.COEFFICIENTS``:
J_n, m_n g OC_n, K_s = 2 c1 l01 l04, K_c = c1 l01 (l24 - l34), F_s = 2 c2 l05 l08,
F_c = c2 l05 (l68 - l78), b_n, F_n, m_n OC_n), and a gyro only through their ratios to the
inertias: each equation of motion is divided by its J_n. Those ratios (``QUANTITIES``) are what a
free swing can determine; the parameters themselves only where the ratios pin them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.engines.fast_planar.closed_form import COEFFICIENTS, coefficients
from pendsim_mj.errors import ParameterError, did_you_mean
from pendsim_mj.rig.params import FIELD_NAMES, ParamColumns, RigParams

Floats = NDArray[np.float64]

# What the planar model depends on (every field that enters ``coefficients``); the calibration may
# free any of them.
PLANAR_PARAMETERS = (
    "c1_n_m",
    "c2_n_m",
    "j1_kg_m2",
    "j2_kg_m2",
    "oc1_m",
    "oc2_m",
    "m1_kg",
    "m2_kg",
    "l01_m",
    "l04_m",
    "l24_m",
    "l34_m",
    "l05_m",
    "l08_m",
    "l68_m",
    "l78_m",
    "g_m_s2",
    "b1_n_m_s",
    "b2_n_m_s",
    "friction1_n_m",
    "friction2_n_m",
)
# What the spatial model adds (``rig.model.SPATIAL``): the support's tilt about the horizontal axis
# across the pivot, and the offset between the pendulums' planes. They enter no planar force-law
# constant. The spatial calibration frees the tilt's two by default (``SPATIAL_FREE``); the offset,
# a length a ruler measures, only when asked.
SPATIAL_PARAMETERS = ("tilt_stiffness_n_m_rad", "tilt_damping_n_m_s_rad", "plane_offset_m")
SPATIAL_FREE = ("tilt_stiffness_n_m_rad", "tilt_damping_n_m_s_rad")
_TILT_MOMENTS = SPATIAL_FREE  # moments per angle and per rate: they scale with the moments
# Free by default: what differs between rigs built from the same drawings (springs, inertias,
# centres of mass, the anchors' asymmetries). Held by default: the masses and g (weighed and
# known), and the anchor lengths that enter only in products with a spring's stiffness (c1 l01 l04:
# freeing them adds directions no swing can see).
DEFAULT_FREE = ("c1_n_m", "c2_n_m", "j1_kg_m2", "j2_kg_m2", "oc1_m", "oc2_m", "l24_m", "l68_m")
DAMPING_BY_LAW = {
    "viscous": ("b1_n_m_s", "b2_n_m_s"),
    "coulomb": ("friction1_n_m", "friction2_n_m"),
    "both": ("b1_n_m_s", "b2_n_m_s", "friction1_n_m", "friction2_n_m"),
}
FALLBACK_SCALE = {"friction1_n_m": 1e-3, "friction2_n_m": 1e-3}  # the unit of x where the stated value is 0
_FD_STEP = 1e-6  # relative step of the central differences of the (polynomial) force-law constants


@dataclasses.dataclass(frozen=True)
class Quantity:
    """A quantity the calibration reports: a function of the rig's parameters.

    Attributes:
      name: identifier (JSON key); label: how the report writes it; unit: its unit.
      of: its value from the force-law constants (NCOEF,) (``fast_planar.coefficients``).
      parameter: the RigParams field it is, or "" for a derived ratio.
      over: with ``parameter``, the field it is divided by (a ratio of two parameters, e.g. the
        tilt stiffness over J1), "" for the parameter itself.
    """

    name: str
    label: str
    unit: str
    of: Callable[[Floats], float]
    parameter: str = ""
    over: str = ""


def _row(name: str) -> int:
    return COEFFICIENTS.index(name)


def _ratio(top: str, bottom: str) -> Callable[[Floats], float]:
    i, j = _row(top), _row(bottom)
    return lambda c: float(c[i] / c[j])


# The ratios a gyro sees (each equation of motion over its inertia), 1/s^2 (1/s for b / J).
QUANTITIES = (
    Quantity("gravity1_per_j1", "m1 g OC1 / J1", "1/s^2", _ratio("gravity1_n_m", "j1_kg_m2")),
    Quantity("gravity2_per_j2", "m2 g OC2 / J2", "1/s^2", _ratio("gravity2_n_m", "j2_kg_m2")),
    Quantity("coupling_per_j1", "2 c1 l01 l04 / J1", "1/s^2", _ratio("coupling_sin_n_m", "j1_kg_m2")),
    Quantity("coupling_per_j2", "2 c1 l01 l04 / J2", "1/s^2", _ratio("coupling_sin_n_m", "j2_kg_m2")),
    Quantity("frame_per_j2", "2 c2 l05 l08 / J2", "1/s^2", _ratio("frame_sin_n_m", "j2_kg_m2")),
    # the frame springs act on M2 as extra gravity (both times sin phi2): a swing sees their sum
    Quantity(
        "gravity2_frame_per_j2",
        "(m2 g OC2 + 2 c2 l05 l08) / J2",
        "1/s^2",
        lambda c: float((c[_row("gravity2_n_m")] + c[_row("frame_sin_n_m")]) / c[_row("j2_kg_m2")]),
    ),
    Quantity("coupling_cos_per_j1", "c1 l01 (l24 - l34) / J1", "1/s^2", _ratio("coupling_cos_n_m", "j1_kg_m2")),
    Quantity("frame_cos_per_j2", "c2 l05 (l68 - l78) / J2", "1/s^2", _ratio("frame_cos_n_m", "j2_kg_m2")),
    Quantity("b1_per_j1", "b1 / J1", "1/s", _ratio("b1_n_m_s", "j1_kg_m2")),
    Quantity("b2_per_j2", "b2 / J2", "1/s", _ratio("b2_n_m_s", "j2_kg_m2")),
    Quantity("friction1_per_j1", "F1 / J1", "1/s^2", _ratio("friction1_n_m", "j1_kg_m2")),
    Quantity("friction2_per_j2", "F2 / J2", "1/s^2", _ratio("friction2_n_m", "j2_kg_m2")),
)


def _unused(c: Floats) -> float:
    return float("nan")


# What the spatial model adds that a swing determines: the tilt's stiffness and damping over an
# inertia (the common scale of all moments and inertias stays out of sight, as in the planar model).
SPATIAL_QUANTITIES = (
    Quantity(
        "tilt_stiffness_per_j1", "k_tilt / J1", "1/s^2", _unused, parameter="tilt_stiffness_n_m_rad", over="j1_kg_m2"
    ),
    Quantity("tilt_damping_per_j1", "c_tilt / J1", "1/s", _unused, parameter="tilt_damping_n_m_s_rad", over="j1_kg_m2"),
)


def added_mass_constants(params: RigParams, pendulum: int, mass_kg: float, radius_m: float) -> Floats:
    """The force-law constants (NCOEF,) a point mass ``mass_kg`` clamped on pendulum 1 or 2 at
    ``radius_m`` from the axis adds: m g r, m r^2 and m r (known: they break the common scale)."""
    if pendulum not in (1, 2):
        raise ParameterError(f"an added mass goes on pendulum 1 or 2, got {pendulum!r}")
    if not (0.0 < mass_kg <= 5.0 and 0.0 < radius_m <= 1.0):
        raise ParameterError(
            f"an added mass must be 0-5 kg at 0-1 m from the axis, got {mass_kg!r} kg at {radius_m!r} m"
        )
    add = np.zeros(len(COEFFICIENTS))
    add[COEFFICIENTS.index(f"gravity{pendulum}_n_m")] = mass_kg * params.g_m_s2 * radius_m
    add[COEFFICIENTS.index(f"j{pendulum}_kg_m2")] = mass_kg * radius_m**2
    add[COEFFICIENTS.index(f"moc{pendulum}_kg_m")] = mass_kg * radius_m
    return add


def parameter_quantity(name: str, unit: str) -> Quantity:
    """A free parameter as a reported quantity (its value read from the parameters, not the
    constants: ``ParameterSpace.quantity_values`` handles it)."""
    return Quantity(name, name, unit, lambda c: float("nan"), parameter=name)


class ParameterSpace:
    """The free parameters of a calibration around stated values, in relative units (module
    docstring).

    Args:
      stated: the rig as stated (the paper's, with the user's fixed values).
      free: the RigParams fields to fit, each from ``PLANAR_PARAMETERS``.
    """

    def __init__(self, stated: RigParams, free: Sequence[str]) -> None:
        unknown = [n for n in free if n not in (*PLANAR_PARAMETERS, *SPATIAL_PARAMETERS)]
        if unknown:
            raise ParameterError(
                f"cannot calibrate {unknown[0]!r}; the planar model depends on: {', '.join(PLANAR_PARAMETERS)} "
                f"(the spatial model also on {', '.join(SPATIAL_PARAMETERS)})"
            )
        if len(set(free)) != len(free):
            raise ParameterError("each free parameter once")
        self.stated = stated
        self.free = tuple(free)
        values = stated.as_dict()
        self._stated_row = np.array([values[n] for n in FIELD_NAMES])  # every field, for ``coefficients``
        self.stated_values = np.array([values[n] for n in self.free])
        self._index = [FIELD_NAMES.index(n) for n in self.free]
        self.scale = np.array(
            [
                abs(v) if v != 0 else FALLBACK_SCALE.get(n, 1.0)
                for n, v in zip(self.free, self.stated_values, strict=True)
            ]
        )

    def values(self, x: Floats) -> dict[str, float]:
        """The free parameters at x, SI."""
        theta = self.stated_values + self.scale * np.asarray(x, dtype=float)
        return {n: float(v) for n, v in zip(self.free, theta, strict=True)}

    def params(self, x: Floats) -> RigParams:
        """The rig at x (a ParameterError where a value leaves its range: a negative length)."""
        return self.stated.with_mapping(self.values(x))

    def coefficients(self, x: Floats) -> Floats:
        """The force-law constants at x, (NCOEF,), without the rig's checks: along a direction no
        swing sees, a fit may pass through parameters no rig has (an inertia below m OC^2) and
        still be right in everything it determines (``valid_along`` brings it back)."""
        row = self._stated_row.copy()
        row[self._index] = self.stated_values + self.scale * np.asarray(x, dtype=float)
        return coefficients(ParamColumns(row[None, :]))[:, 0]

    def coefficient_jacobian(self, x: Floats) -> Floats:
        """d constants / d x, (NCOEF, nfree): central differences of ``coefficients`` (products of
        the parameters: exact to ~1e-10 relative)."""
        x = np.asarray(x, dtype=float)
        out = np.zeros((len(COEFFICIENTS), len(self.free)))
        for i in range(len(self.free)):
            step = np.zeros(len(self.free))
            step[i] = _FD_STEP
            out[:, i] = (self.coefficients(x + step) - self.coefficients(x - step)) / (2 * _FD_STEP)
        return out

    def scale_direction(self, x: Floats) -> Floats | None:
        """The x (nfree,) that scales every nonzero force-law constant by one factor (1 % per unit),
        or None where the free parameters cannot (an inertia or a mass held). The spatial model's
        tilt stiffness and damping (moments per angle and rate) scale with the moments."""
        jac = self.coefficient_jacobian(x)
        coef = self.coefficients(x)
        target = 0.01 * coef
        solution, *_ = np.linalg.lstsq(jac, target, rcond=None)
        if np.linalg.norm(jac @ solution - target) > 1e-6 * np.linalg.norm(target):
            return None
        for i, name in enumerate(self.free):
            if name in _TILT_MOMENTS:
                solution[i] = 0.01 * (1.0 + x[i])  # x is relative to the stated value: 1 % of the current one
        return np.asarray(solution, dtype=float)

    def valid_along(self, x: Floats, directions: Sequence[Floats]) -> Floats:
        """x itself if it is a rig (``params`` accepts it), else the nearest x + sum s_k d_k along
        the given directions (those the data do not see: nothing determined changes) that is,
        searched over up to +-20 % per direction; a ParameterError naming the check if none is."""
        x = np.asarray(x, dtype=float)
        try:
            self.params(x)
            return x
        except ParameterError as exc:
            first = exc
        steps = sorted(np.linspace(-0.2, 0.2, 81), key=abs)
        for step in steps:
            for d in directions:
                try:
                    self.params(x + step * d)
                    return x + step * d
                except ParameterError:
                    continue
        advice = "; fix a measured inertia with --fix" if "must exceed" in str(first) else ""
        raise ParameterError(f"the calibrated parameters are no rig ({first}){advice}")

    def quantity_gradient(self, quantity: Quantity, x: Floats) -> Floats:
        """d quantity / d x, (nfree,)."""
        x = np.asarray(x, dtype=float)
        if quantity.over:
            grad = np.zeros(len(self.free))
            for i in range(len(self.free)):
                step = np.zeros(len(self.free))
                step[i] = _FD_STEP
                grad[i] = (self.quantity_value(quantity, x + step) - self.quantity_value(quantity, x - step)) / (
                    2 * _FD_STEP
                )
            return grad
        if quantity.parameter:
            out = np.zeros(len(self.free))
            if quantity.parameter in self.free:
                i = self.free.index(quantity.parameter)
                out[i] = self.scale[i]
            return out
        grad = np.zeros(len(self.free))
        for i in range(len(self.free)):
            step = np.zeros(len(self.free))
            step[i] = _FD_STEP
            grad[i] = (quantity.of(self.coefficients(x + step)) - quantity.of(self.coefficients(x - step))) / (
                2 * _FD_STEP
            )
        return grad

    def quantity_value(self, quantity: Quantity, x: Floats) -> float:
        if quantity.parameter:
            values = self.stated.as_dict() | self.values(x)
            return values[quantity.parameter] / (values[quantity.over] if quantity.over else 1.0)
        return quantity.of(self.coefficients(x))


def free_set(law: str, free: Sequence[str] | None, fixed: Mapping[str, float]) -> tuple[str, ...]:
    """The parameters to fit: ``free`` (default ``DEFAULT_FREE``) and the law's damping, less the
    fixed ones."""
    if law not in DAMPING_BY_LAW:
        raise ParameterError(f"law must be one of {', '.join(DAMPING_BY_LAW)}, got {law!r}")
    unknown = [n for n in fixed if n not in FIELD_NAMES]
    if unknown:
        raise ParameterError(
            f"unknown parameter {unknown[0]!r}{did_you_mean(unknown[0], FIELD_NAMES)} to fix; 'pendsim info' lists "
            "the names"
        )
    names = [*(DEFAULT_FREE if free is None else free), *DAMPING_BY_LAW[law]]
    return tuple(dict.fromkeys(n for n in names if n not in fixed))
