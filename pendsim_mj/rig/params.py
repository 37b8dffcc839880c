"""The rig's physical parameters: one frozen object, every field with unit and source.

Source of every printed number: B. Ganev, M. B. Marinov, I. Kralov, A. Ivanov, "Modeling and
Validation of a Spring-Coupled Two-Pendulum System Under Large Free Nonlinear Oscillations",
Machines 2025, 13(8), 660, doi:10.3390/machines13080660 (cited below as "paper"), as
transcribed in shared/spec/RIG.md.

Frames (paper): origin O on the pivot axis, x vertically down, y horizontal in the swing plane,
z along the pivot axis. Angles phi_n from the downward vertical, positive about +z.

Mass derivation (the paper prints no masses; spec section 1 asks us to derive them):

    main rod (OK1 = OK2 = 510 mm, d = 5.1 mm, steel 7850 kg/m^3)
        m_rod  = 7850 * pi * 0.00255^2 * 0.510            = 0.081778 kg
    transverse rod on M1 (l23 = 300 mm, d = 3 mm, steel)
        m_trod = 7850 * pi * 0.0015^2 * 0.300             = 0.016650 kg
    disk (paper)                                          = 0.100 kg
    sensor node (paper: "added to the pendulum's weight")  = 0.0128 kg

    m1 = m_rod + m_disk + m_trod + m_node                 = 0.211228 kg
    m2 = m_rod + m_disk + m_node                          = 0.194578 kg

Check that confirms the approach: M2's rod + disk alone give
OC = (0.081778*0.255 + 0.1*0.384) / 0.181778 = 0.32597 m (paper 326 mm) and
J = 0.081778*0.51^2/3 + 0.1*0.384^2 + 0.1*0.03025^2/2 = 0.021882 kg m^2 (paper 0.02188).
The paper's own OC1, OC2, J1, J2 are used unchanged in the model; the masses are not tuned.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.errors import ParameterError, did_you_mean

STEEL_DENSITY_KG_M3 = 7850.0


def rod_mass_kg(length_m: float, diameter_m: float, density_kg_m3: float = STEEL_DENSITY_KG_M3) -> float:
    """Mass of a solid cylindrical rod, kg."""
    return density_kg_m3 * math.pi * (diameter_m / 2.0) ** 2 * length_m


# Component masses, kg (derivation in the module docstring).
MAIN_ROD_MASS_KG = rod_mass_kg(0.510, 0.0051)
TRANSVERSE_ROD_MASS_KG = rod_mass_kg(0.300, 0.003)
DISK_MASS_KG = 0.100
SENSOR_NODE_MASS_KG = 0.0128


# Default damping. The paper identifies b_n by the logarithmic decrement
# b_n = 2 J_n ln(A0_n / AT_n) / t1 (t1 = 120 s) but prints neither A0 nor AT. We assume the
# amplitude of each pendulum falls to 20 % of its start over 120 s (a typical free decay of a
# ball-bearing pendulum; identify the real values from a recording).
DEFAULT_DECAY_RATIO = 0.2
DEFAULT_DECAY_WINDOW_S = 120.0


def log_decrement_b(j_kg_m2: float, decay_ratio: float, window_s: float) -> float:
    """The paper's damping formula b = 2 J ln(A0/AT) / t1, N m s/rad, with decay_ratio = AT/A0."""
    return 2.0 * j_kg_m2 * math.log(1.0 / decay_ratio) / window_s


# Dry friction in the planar solvers: the moment -F omega / sqrt(omega^2 + w_s^2), an ideal
# -F sign(omega) smoothed below w_s (a sign law cannot be integrated by a fixed-step RK4, and MuJoCo's
# frictionloss is itself a soft constraint). Model choice; the measured agreement with MuJoCo is in
# docs/identification.md. The square root (not tanh) keeps the compiled kernel's SIMD lanes and its
# scalar remainder bit-identical.
FRICTION_SMOOTHING_RAD_S = 0.01


def friction_direction(omega_rad_s: NDArray[np.float64]) -> NDArray[np.float64]:
    """omega / sqrt(omega^2 + w_s^2): the smoothed sign(omega) of the dry-friction law (any shape)."""
    return omega_rad_s / np.sqrt(omega_rad_s * omega_rad_s + FRICTION_SMOOTHING_RAD_S * FRICTION_SMOOTHING_RAD_S)


J1_KG_M2 = 0.02592  # paper: J1
J2_KG_M2 = 0.02188  # paper: J2


def _field(default: float, unit: str, source: str) -> Any:
    return dataclasses.field(default=default, metadata={"unit": unit, "source": source})


@dataclasses.dataclass(frozen=True)
class RigParams:
    """Physical parameters of the two-pendulum rig, SI units.

    Every field carries its unit and source in ``dataclasses.fields(RigParams)[i].metadata``;
    ``describe()`` lists them. Build variants with ``with_overrides(b1_n_m_s=0.0, ...)``.
    """

    # Masses (derived, see module docstring).
    m1_kg: float = _field(
        MAIN_ROD_MASS_KG + DISK_MASS_KG + TRANSVERSE_ROD_MASS_KG + SENSOR_NODE_MASS_KG,
        "kg",
        "derived: steel rod 510 mm x 5.1 mm + disk 100 g + transverse rod 300 mm x 3 mm + node 12.8 g",
    )
    m2_kg: float = _field(
        MAIN_ROD_MASS_KG + DISK_MASS_KG + SENSOR_NODE_MASS_KG,
        "kg",
        "derived: steel rod 510 mm x 5.1 mm + disk 100 g + node 12.8 g",
    )
    # Mass distribution (paper).
    oc1_m: float = _field(0.3274, "m", "paper: OC1, pivot to centre of mass of M1")
    oc2_m: float = _field(0.326, "m", "paper: OC2, pivot to centre of mass of M2")
    j1_kg_m2: float = _field(J1_KG_M2, "kg m^2", "paper: J1, inertia of M1 about the pivot axis")
    j2_kg_m2: float = _field(J2_KG_M2, "kg m^2", "paper: J2, inertia of M2 about the pivot axis")
    # Geometry of the spring anchor points (paper, Figure 2 and its table).
    l01_m: float = _field(0.0525, "m", "paper: l01, O to point 1 along M2")
    l04_m: float = _field(0.187, "m", "paper: l04, O to point 4 along M1")
    l24_m: float = _field(0.150, "m", "paper: l24, point 4 to point 2, perpendicular to M1")
    l34_m: float = _field(0.150, "m", "paper: l34, point 4 to point 3, perpendicular to M1")
    l05_m: float = _field(0.322, "m", "paper: l05, O to point 5 along M2")
    l08_m: float = _field(0.266, "m", "paper: l08, O to frame point 8 (vertical); X6 = X7")
    l68_m: float = _field(0.150, "m", "paper: l68, point 8 to fixed point 6 (Y6 = +l68)")
    l78_m: float = _field(0.150, "m", "paper: l78, point 8 to fixed point 7 (Y7 = -l78)")
    # Sensor mounts: the disk centres (spec section 6, default mount).
    om1_m: float = _field(0.417, "m", "paper: OM1, pivot to disk centre of M1 (IMU mount)")
    om2_m: float = _field(0.384, "m", "paper: OM2, pivot to disk centre of M2 (IMU mount)")
    # Springs (paper): zero free length, force = c * whole length.
    c1_n_m: float = _field(6.173, "N/m", "paper: c1, springs 1-2 and 1-3")
    c2_n_m: float = _field(6.562, "N/m", "paper: c2, springs 5-6 and 5-7")
    # Hinge damping: assumed, see DEFAULT_DECAY below (paper prints no A0, AT).
    b1_n_m_s: float = _field(
        log_decrement_b(J1_KG_M2, DEFAULT_DECAY_RATIO, DEFAULT_DECAY_WINDOW_S),
        "N m s/rad",
        "assumed: log decrement b = 2 J ln(A0/AT)/t1 with AT/A0 = 0.2 over t1 = 120 s",
    )
    b2_n_m_s: float = _field(
        log_decrement_b(J2_KG_M2, DEFAULT_DECAY_RATIO, DEFAULT_DECAY_WINDOW_S),
        "N m s/rad",
        "assumed: log decrement b = 2 J ln(A0/AT)/t1 with AT/A0 = 0.2 over t1 = 120 s",
    )
    # Dry (Coulomb) friction at each hinge: a moment of this size opposing the swing (MuJoCo joint
    # frictionloss; the planar solvers' smooth law, FRICTION_SMOOTHING_RAD_S).
    friction1_n_m: float = _field(
        0.0, "N m", "paper: names dry friction in bearings and joints as a cause of discrepancy, gives no value"
    )
    friction2_n_m: float = _field(
        0.0, "N m", "paper: names dry friction in bearings and joints as a cause of discrepancy, gives no value"
    )
    g_m_s2: float = _field(9.81, "m/s^2", "paper: g")
    # Component geometry: drawn by the visual geoms; sets the inertia about the two axes
    # the planar model does not use (see inertia_about_com_kg_m2).
    rod_length_m: float = _field(0.510, "m", "paper: OK1 = OK2, steel rod length")
    rod_diameter_m: float = _field(0.0051, "m", "paper: steel rod diameter d")
    disk_diameter_m: float = _field(0.0605, "m", "paper: disk D")
    disk_thickness_m: float = _field(0.0118, "m", "paper: disk h")
    transverse_rod_length_m: float = _field(0.300, "m", "paper: l23, transverse rod on M1")
    transverse_rod_diameter_m: float = _field(0.003, "m", "paper: transverse rod d")
    # Spatial model (issue 7). The planes of the two pendulums are apart along the pivot axis.
    plane_offset_m: float = _field(
        0.0, "m", "paper: 50 mm in one place, 23 mm in another (presets); 0 = the planar model"
    )
    tilt_stiffness_n_m_rad: float = _field(
        2.0,
        "N m/rad",
        "assumed: support/bearing compliance about the horizontal axis across the pivot; 0 = free tilt",
    )
    tilt_damping_n_m_s_rad: float = _field(0.0007, "N m s/rad", "assumed: like the swing damping b1")

    def inertia_about_com_kg_m2(self, pendulum: int) -> tuple[float, float, float]:
        """Principal inertia of pendulum 1 or 2 about its centre of mass, kg m^2.

        Axes: (in the swing plane perpendicular to the rod, along the pivot axis, along the rod).
        The pivot-axis value is exactly the paper's J - m OC^2. The other two come from the
        components (main rod, disk, transverse rod on M1, node as a point at the disk): the
        difference I_inplane - I_pivot is the sum of the components' own differences (offsets
        along the rod add equally to both), and I_rod is the sum of the components' own moments
        about the rod axis. Neither matters for the planar model.
        """
        if pendulum not in (1, 2):
            raise ParameterError(f"pendulum must be 1 or 2, got {pendulum!r}")
        m = self.m1_kg if pendulum == 1 else self.m2_kg
        oc = self.oc1_m if pendulum == 1 else self.oc2_m
        j = self.j1_kg_m2 if pendulum == 1 else self.j2_kg_m2
        r_rod = self.rod_diameter_m / 2
        r_disk = self.disk_diameter_m / 2
        h_disk = self.disk_thickness_m
        # Own moments (in-plane, pivot, along-rod) of each component about its own centre.
        rod = (
            MAIN_ROD_MASS_KG * (3 * r_rod**2 + self.rod_length_m**2) / 12,
            MAIN_ROD_MASS_KG * (3 * r_rod**2 + self.rod_length_m**2) / 12,
            MAIN_ROD_MASS_KG * r_rod**2 / 2,
        )
        disk_flat = DISK_MASS_KG * (3 * r_disk**2 + h_disk**2) / 12
        disk = (disk_flat, DISK_MASS_KG * r_disk**2 / 2, disk_flat)
        parts = [rod, disk]
        if pendulum == 1:
            r_t = self.transverse_rod_diameter_m / 2
            across = TRANSVERSE_ROD_MASS_KG * (3 * r_t**2 + self.transverse_rod_length_m**2) / 12
            parts.append((TRANSVERSE_ROD_MASS_KG * r_t**2 / 2, across, across))
        i_pivot = j - m * oc**2
        i_inplane = i_pivot + sum(p[0] - p[1] for p in parts)
        i_rod = sum(p[2] for p in parts)
        return (i_inplane, i_pivot, i_rod)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise ParameterError(f"{f.name} must be a number, got {value!r}")
        check_values({f.name: getattr(self, f.name) for f in dataclasses.fields(self)})

    @classmethod
    def _checked(cls, fields: Mapping[str, float]) -> RigParams:
        """A RigParams of every field's value (floats) that ``check_values`` has already passed
        (a table of cases checked at once, ``ParamColumns.to_params``): not checked again (the
        object check costs 1-2 ms, a sweep's thousand distinct cases 1-2 s)."""
        params = object.__new__(cls)
        for name in FIELD_NAMES:
            object.__setattr__(params, name, float(fields[name]))
        return params

    def with_overrides(self, **overrides: float) -> RigParams:
        """A copy with the named fields replaced; unknown names raise ParameterError."""
        return self.with_mapping(overrides)

    def with_mapping(self, overrides: Mapping[str, float]) -> RigParams:
        """Like ``with_overrides`` but from a mapping."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise ParameterError(unknown_parameters(unknown))
        return dataclasses.replace(self, **{k: float(v) for k, v in overrides.items()})

    def as_dict(self) -> dict[str, float]:
        """All fields as a plain dict (name -> value in SI units)."""
        return dataclasses.asdict(self)

    @staticmethod
    def describe() -> list[tuple[str, str, str]]:
        """(name, unit, source) for every field, in declaration order."""
        return [(f.name, f.metadata["unit"], f.metadata["source"]) for f in dataclasses.fields(RigParams)]


_MAY_BE_ZERO = frozenset(
    {
        "b1_n_m_s", "b2_n_m_s", "friction1_n_m", "friction2_n_m", "c1_n_m", "c2_n_m", "g_m_s2", "l24_m", "l34_m",
        "l68_m", "l78_m",
        "plane_offset_m", "tilt_stiffness_n_m_rad", "tilt_damping_n_m_s_rad",
    }
)  # fmt: skip


def check_values(values: Mapping[str, ArrayLike], *, case_ids: Sequence[int] | None = None) -> None:
    """The rules of every RigParams, on all fields at once; each value may be an array of cases.

    A field must be finite and > 0 (>= 0 for those that may be zero), and each pendulum's
    inertia about the pivot must exceed its point-mass term m OC^2. Used by ``RigParams`` on its own
    values and by sweeps on columns of thousands of cases without building each object.

    Args:
      values: every field by name: a number or an array (one value per case).
      case_ids: with arrays, the case numbers named in the message (default: positions).

    Raises:
      ParameterError: the first rule broken ("case 12: c1_n_m must be >= 0 N/m, got -1.0" with
        arrays).
    """
    arrays = {name: np.asarray(v, dtype=float) for name, v in values.items()}

    def first(bad: NDArray[np.bool_]) -> tuple[int, str]:
        """Position of the first bad case and the message prefix naming it ("" for scalars)."""
        if bad.ndim == 0:
            return 0, ""
        i = int(np.flatnonzero(bad)[0])
        return i, f"case {i if case_ids is None else case_ids[i]}: "

    for name in _UNITS:
        check_field(name, arrays[name], case_ids=case_ids)
    for n in (1, 2):
        m, oc, j = arrays[f"m{n}_kg"], arrays[f"oc{n}_m"], arrays[f"j{n}_kg_m2"]
        shape = np.broadcast_shapes(m.shape, oc.shape, j.shape)
        point = np.broadcast_to(m * oc**2, shape)
        bad = np.broadcast_to(j, shape) <= point
        if np.any(bad):
            i, prefix = first(bad)
            raise ParameterError(
                f"{prefix}j{n}_kg_m2 = {np.broadcast_to(j, shape).flat[i]} must exceed m{n}_kg * oc{n}_m^2 = "
                f"{point.flat[i]:.6g} (inertia about the pivot includes the point-mass term)"
            )


def check_field(name: str, value: ArrayLike, *, case_ids: Sequence[int] | None = None) -> None:
    """The rules of one RigParams field alone (finite, sign, ``PARAMETER_LIMITS``); ``value`` may
    be an array of cases (named by ``case_ids``, default positions).

    Raises:
      ParameterError: the first rule broken, naming the field, the allowed values and the value.
    """
    unit = _UNITS[name]
    value = np.asarray(value, dtype=float)

    def first(bad: NDArray[np.bool_]) -> tuple[int, str]:
        if bad.ndim == 0:
            return 0, ""
        i = int(np.flatnonzero(bad)[0])
        return i, f"case {i if case_ids is None else case_ids[i]}: "

    allowed_zero = name in _MAY_BE_ZERO
    for bad, rule in (
        (~np.isfinite(value), "must be finite"),
        ((value < 0) | ((value == 0) & (not allowed_zero)), f"must be {'>= 0' if allowed_zero else '> 0'} {unit}"),
    ):
        if np.any(bad):
            i, prefix = first(bad)
            raise ParameterError(f"{prefix}{name} {rule}, got {value.flat[i]}")
    low, high = PARAMETER_LIMITS[name]
    bad = (value > high) | ((value != 0) & (value < low))
    if np.any(bad):
        i, prefix = first(bad)
        raise ParameterError(
            f"{prefix}{name} must be {'0 or ' if allowed_zero else ''}between {low:g} and {high:g} {unit}, "
            f"got {value.flat[i]:g}"
        )


PLAUSIBLE_FACTOR = 10.0
"""A value more than this factor from the paper's rig (``DEFAULT_PARAMS``) is likely a unit slip."""
_BUILT_UNITS = frozenset({"kg", "m", "kg m^2", "N/m", "m/s^2"})
"""What the rig is built of (masses, lengths, inertias, springs, gravity): the losses (damping,
friction) and the tilt bearings' constants differ by orders of magnitude between real rigs."""


def far_from_paper(values: Mapping[str, float]) -> list[str]:
    """For each named value of what the rig is built of (``_BUILT_UNITS``) more than
    ``PLAUSIBLE_FACTOR`` times above or below the paper's rig (both non-zero), one line saying by
    how much: allowed (another rig may differ that much), but a spring in N/mm or a mass in grams
    is the likelier cause ("c1_n_m = 0.0064 N/m is 1/964.5 of the paper's rig's (6.173 N/m)")."""
    lines = []
    for name, value in values.items():
        paper = getattr(DEFAULT_PARAMS, name, 0.0)
        if not value or not paper or _UNITS.get(name) not in _BUILT_UNITS:
            continue
        ratio = value / paper
        if ratio > PLAUSIBLE_FACTOR or ratio < 1 / PLAUSIBLE_FACTOR:
            times = f"{ratio:.4g} times" if ratio > 1 else f"1/{1 / ratio:.4g} of"
            unit = _UNITS[name]
            lines.append(f"{name} = {value:.6g} {unit} is {times} the paper's rig's ({paper:.6g} {unit})")
    return lines


def unknown_parameters(unknown: Sequence[str]) -> str:
    """The message for names that are not RigParams fields: each with its likely spelling, then
    every allowed name ("unknown parameter(s) c1_nm (did you mean 'c1_n_m'?); allowed: ...")."""
    names = ", ".join(f"{name}{did_you_mean(name, FIELD_NAMES)}" for name in unknown)
    return f"unknown parameter(s) {names}; allowed: {', '.join(sorted(FIELD_NAMES))}"


PLANE_OFFSET_PRESETS_M = (0.023, 0.050)  # paper: both values appear
_UNITS = {f.name: f.metadata["unit"] for f in dataclasses.fields(RigParams)}
FIELD_NAMES = tuple(_UNITS)
"""Every RigParams field, in declaration order."""


@dataclasses.dataclass(frozen=True)
class ParamColumns:
    """Many parameter sets as columns (a sweep's thousands of cases without thousands of objects).

    Attributes:
      values: (ncases, len(FIELD_NAMES)): ``values[:, i]`` is field ``FIELD_NAMES[i]`` of every case.
    """

    values: NDArray[np.float64]

    @classmethod
    def from_params(cls, params: Sequence[RigParams]) -> ParamColumns:
        return cls(
            np.array([[getattr(p, n) for n in FIELD_NAMES] for p in params], dtype=float).reshape(-1, len(FIELD_NAMES))
        )

    @classmethod
    def from_base(
        cls, base: RigParams, ncases: int, columns: Mapping[str, ArrayLike], *, case_ids: Sequence[int] | None = None
    ) -> ParamColumns:
        """``base`` for every case, with the named fields set per case (arrays of ncases); checked
        by ``check_values`` (the error names the case by ``case_ids``)."""
        unknown = sorted(set(columns) - set(FIELD_NAMES))
        if unknown:
            raise ParameterError(unknown_parameters(unknown))
        values = np.tile(np.array([getattr(base, n) for n in FIELD_NAMES], dtype=float), (ncases, 1))
        for name, column in columns.items():
            values[:, FIELD_NAMES.index(name)] = np.asarray(column, dtype=float)
        check_values({n: values[:, i] for i, n in enumerate(FIELD_NAMES)}, case_ids=case_ids)
        return cls(values)

    def __len__(self) -> int:
        return len(self.values)

    def column(self, name: str) -> NDArray[np.float64]:
        """One field of every case, (ncases,)."""
        return self.values[:, FIELD_NAMES.index(name)]

    def to_params(self) -> list[RigParams]:
        """A RigParams per case (each distinct set built once; the table checked at once by
        ``check_values``, the cases' positions named).

        Raises:
          ParameterError: the first rule a case breaks.
        """
        check_values({n: self.values[:, i] for i, n in enumerate(FIELD_NAMES)})
        built: dict[bytes, RigParams] = {}
        out = []
        for row in self.values:
            key = row.tobytes()
            if key not in built:
                built[key] = RigParams._checked(dict(zip(FIELD_NAMES, row.tolist(), strict=True)))
            out.append(built[key])
        return out


_LIMITS_BY_UNIT = {
    # unit: (smallest non-zero value, largest value). Far beyond any tabletop rig, yet inside the
    # range where the simulation's arithmetic (squares, products of these) stays finite and the
    # MuJoCo compiler's minimum mass and inertia (mjMINVAL = 1e-15) hold.
    "kg": (1e-6, 1e3),
    "m": (1e-6, 10.0),
    "kg m^2": (1e-9, 1e3),
    "N/m": (1e-9, 1e6),
    "N m s/rad": (1e-12, 1e3),
    "m/s^2": (1e-3, 100.0),
    "N m/rad": (1e-9, 1e6),
    "N m": (1e-12, 1e3),
}
PARAMETER_LIMITS: dict[str, tuple[float, float]] = {
    f.name: _LIMITS_BY_UNIT[f.metadata["unit"]] for f in dataclasses.fields(RigParams)
}
"""Allowed range of every parameter (name: (smallest non-zero, largest), SI units); zero is
allowed only where the parameter may vanish (damping, stiffness, offsets, g)."""

DEFAULT_PARAMS = RigParams()
"""The rig as the paper describes it, with the assumed default damping."""
