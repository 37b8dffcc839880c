"""Units of imported IMU data checked against the data's own physics.

A gyro and an orientation measured by the same chip describe one rotation: over any stretch the
gyro's integral turns the sensor as far as its quaternions do (``gyro_against_orientation``),
whatever the mounting, heading or quaternion convention. Their ratio is 1 when the gyro's unit
is right, 180/pi = 57.3 (or 1/57.3) for degrees and radians mixed up, 16 or 900 for the BNO055's
raw counts. Without quaternions the fused gravity vector, turning with the sensor, gives the
rotation about every horizontal axis (all of a pendulum's). The accelerometer's unit follows
from gravity's magnitude (``gravity_level``): 9.81 m/s^2 at rest, and exactly that at any time
for the fused gravity vector.

``check_units`` turns the ratios into findings: a ratio that only a unit mix-up explains (more
than ``MIX_UP_FACTOR`` from 1) names the units that fit it and the ``--units`` text that imports
the file right. The accelerometer cannot check a gyro (a swinging pendulum's specific force does
not follow its tilt), so a file without quaternions or gravity has an unchecked gyro, said so.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import STANDARD_GRAVITY_M_S2

from .packets import ACCEL_UNITS, GROUP_SLICES, GYRO_UNITS, Units

WINDOW_S = 0.25
"""The stretch over which rotations are compared: shorter than a quarter of the rig's slowest
period (1.1 s), long enough that each turns by degrees against the quaternion's 0.007 deg grid."""
MIN_TURN_RAD = math.radians(1.0)  # a window counts when the orientation turns by more than this
MIN_WINDOWS = 8  # and a ratio needs this many such windows
MIX_UP_FACTOR = 1.5
"""A ratio further than this from 1 (either way) is a unit mix-up, not a scale error: a BNO055's
gyro scale is within a few per cent, its fusion lags by at most 10 ms."""
FIT_TOLERANCE = 0.1  # a candidate unit explains a ratio within 10 %
STEADY = 0.01
"""An accelerometer window is at rest when its magnitude's standard deviation is under 1 % of its
mean (a BNO055 at rest: 0.15 %; a swing changes it by tens of per cent within a window)."""
G_RANGE = (0.7, 1.4)  # gravity's level (in g) that passes; beyond MIX_UP_FACTOR^2 off it is a mix-up

GYRO_WORDS = {
    "rad/s": "rad/s",
    "dps": "deg/s",
    "raw-dps": "the BNO055's raw counts in its dps mode (16 per deg/s)",
    "raw-rad/s": "the BNO055's raw counts in its rad/s mode (900 per rad/s)",
}
ACCEL_WORDS = {
    "m/s2": "m/s2",
    "g": "g",
    "mg": "mg (also the BNO055's raw counts in its mg mode)",
    "raw-m/s2": "the BNO055's raw counts in its m/s2 mode (100 per m/s2)",
}


@dataclasses.dataclass(frozen=True)
class Ratio:
    """How far one quantity is from what the physics says, and on what evidence.

    value: measured / expected (1: the unit is right): the gyro's turn over the orientation's, or
      gravity's magnitude over g.
    source: what the physics was read from ("the quaternions", "the gravity vector",
      "the accelerometer at rest", ...).
    extent: how much of it, in words ("1673 deg of rotation", "1.8 s").
    """

    value: float
    source: str
    extent: str

    @property
    def evidence(self) -> str:
        return f"{self.source}, {self.extent}"


def _rotation_angles(q_from: NDArray[np.float64], q_to: NDArray[np.float64]) -> NDArray[np.float64]:
    """The angle (rad, 0-pi) of each relative rotation from ``q_from`` to ``q_to`` ((k, 4) wxyz):
    the same for either quaternion convention."""
    rel = rotations.multiply(rotations.conjugate(q_from), q_to)
    return 2.0 * np.arctan2(np.linalg.norm(rel[:, 1:], axis=1), np.abs(rel[:, 0]))


def _windows(t_s: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(start, end) sample indices of consecutive windows of about ``WINDOW_S``, each end the next
    start; a window never spans a gap longer than half of it."""
    edges = np.searchsorted(t_s, np.arange(t_s[0], t_s[-1], WINDOW_S))
    edges = np.unique(np.append(edges, len(t_s) - 1))
    start, end = edges[:-1], edges[1:]
    keep = (end > start) & (t_s[end] - t_s[start] < 1.5 * WINDOW_S)
    return start[keep], end[keep]


def _gyro_integrals(t_s: NDArray[np.float64], gyro: NDArray[np.float64]) -> NDArray[np.float64]:
    """The running trapezoid integral of the gyro ((n, 3), rad)."""
    steps = 0.5 * (gyro[1:] + gyro[:-1]) * np.diff(t_s)[:, None]
    return np.vstack([np.zeros((1, 3)), np.cumsum(steps, axis=0)])


def _median_ratio(turned: NDArray[np.float64], reference: NDArray[np.float64]) -> float | None:
    chosen = reference > MIN_TURN_RAD
    if np.count_nonzero(chosen) < MIN_WINDOWS:
        return None
    return float(np.median(turned[chosen] / reference[chosen]))


def gyro_against_orientation(
    t_s: NDArray[np.float64], gyro: NDArray[np.float64], quat: NDArray[np.float64]
) -> Ratio | None:
    """How far the gyro ((n, 3), as read) turns the sensor over each window against its
    quaternions ((n, 4) wxyz): the median ratio, or None where the orientation turns too little.
    Both are in the sensor's frame, so mounting, heading and axis remap do not matter."""
    start, end = _windows(t_s)
    if not len(start):
        return None
    turned_q = _rotation_angles(quat[start], quat[end])
    integral = _gyro_integrals(t_s, gyro)
    turned_g = np.linalg.norm(integral[end] - integral[start], axis=1)
    ratio = _median_ratio(turned_g, turned_q)
    if ratio is None:
        return None
    swing = math.degrees(float(np.sum(turned_q[turned_q > MIN_TURN_RAD])))
    return Ratio(ratio, "the quaternions", f"{swing:.0f} deg of rotation")


def gyro_against_gravity(
    t_s: NDArray[np.float64], gyro: NDArray[np.float64], gravity: NDArray[np.float64]
) -> Ratio | None:
    """As ``gyro_against_orientation`` with the fused gravity vector ((n, 3), sensor frame): its
    direction turns by the rotation about horizontal axes, compared with the gyro's integral less
    its part along gravity."""
    norm = np.linalg.norm(gravity, axis=1)
    if not np.all(norm > 0):
        return None
    down = gravity / norm[:, None]
    start, end = _windows(t_s)
    if not len(start):
        return None
    cosine = np.clip(np.sum(down[start] * down[end], axis=1), -1.0, 1.0)
    turned_v = np.arccos(cosine)
    integral = _gyro_integrals(t_s, gyro)
    step = integral[end] - integral[start]
    mean_down = down[start] + down[end]
    mean_down /= np.maximum(np.linalg.norm(mean_down, axis=1), 1e-12)[:, None]
    across = step - np.sum(step * mean_down, axis=1)[:, None] * mean_down
    ratio = _median_ratio(np.linalg.norm(across, axis=1), turned_v)
    if ratio is None:
        return None
    swing = math.degrees(float(np.sum(turned_v[turned_v > MIN_TURN_RAD])))
    count = np.count_nonzero(turned_v > MIN_TURN_RAD)
    return Ratio(ratio, "the gravity vector", f"{swing:.0f} deg of rotation in {count} windows")


def gravity_level(
    t_s: NDArray[np.float64], accel: NDArray[np.float64] | None, gravity: NDArray[np.float64] | None
) -> Ratio | None:
    """Gravity's magnitude (as read) over g: the fused gravity vector's median, else the
    accelerometer's median over the windows where it is at rest (its magnitude steady within
    ``STEADY``), else over all samples (a swing stays near 1 g on the median)."""
    if gravity is not None:
        level = float(np.median(np.linalg.norm(gravity, axis=1))) / STANDARD_GRAVITY_M_S2
        return Ratio(level, "the gravity vector", f"median over {t_s[-1] - t_s[0]:.1f} s")
    if accel is None or not len(accel):
        return None
    magnitude = np.linalg.norm(accel, axis=1)
    start, end = _windows(t_s)
    steady = [
        magnitude[a : b + 1]
        for a, b in zip(start, end, strict=True)
        if np.std(magnitude[a : b + 1]) <= STEADY * max(float(np.mean(magnitude[a : b + 1])), 1e-300)
    ]
    if len(steady) * WINDOW_S >= 1.0:  # a second at rest, or more
        level = float(np.median(np.concatenate(steady))) / STANDARD_GRAVITY_M_S2
        return Ratio(level, "the accelerometer at rest", f"median over {len(steady) * WINDOW_S:.1f} s")
    level = float(np.median(magnitude)) / STANDARD_GRAVITY_M_S2
    return Ratio(level, "the accelerometer", f"median over {t_s[-1] - t_s[0]:.1f} s, not at rest")


@dataclasses.dataclass(frozen=True)
class Mismatch:
    """One node's quantity whose ratio only a unit mix-up explains: ``fits``, the units that
    explain it (closest first; none: no unit does)."""

    node: str
    quantity: str  # "gyro" or "accel"
    ratio: Ratio
    fits: tuple[str, ...]


@dataclasses.dataclass(frozen=True)
class UnitFindings:
    """What ``check_units`` found: ``mismatches``, ``fixed`` (the units that explain the data,
    None where no unit does), ``checks`` (every ratio, for the metadata) and ``notes`` (what
    could not be checked)."""

    mismatches: tuple[Mismatch, ...]
    fixed: Units | None
    checks: tuple[str, ...]
    notes: tuple[str, ...]

    def describe(self, given: Units) -> str:
        """The mismatches in words, the nodes that agree together, e.g. "the gyro (m1, m2), read
        as gyro=dps, turns 0.0175 and 0.0174 times as far as the orientation (quaternions turn
        1673 and 256 deg): the values are in rad/s"."""
        parts = []
        for quantity in ("gyro", "accel"):
            found = [m for m in self.mismatches if m.quantity == quantity]
            for fits in dict.fromkeys(m.fits for m in found):
                same = [m for m in found if m.fits == fits]
                parts.append(_mismatch_text(quantity, same, getattr(given, quantity), fits))
        return "; ".join(parts)

    def advice(self, given: Units) -> str:
        if self.fixed is not None and self.fixed != given:
            return f"give --units {self.fixed.describe()}"
        return "check the column map and --units"


def _mismatch_text(quantity: str, same: list[Mismatch], given: str, fits: tuple[str, ...]) -> str:
    def each(texts: list[str]) -> str:  # "0.0175 and 0.0174", or once where the nodes agree
        return texts[0] if len(set(texts)) == 1 else " and ".join(texts)

    nodes = " and ".join(m.node for m in same)
    source = each([m.ratio.source for m in same])
    extent = each([m.ratio.extent for m in same])
    if quantity == "gyro":
        ratios = each([f"{m.ratio.value:.3g}" for m in same])
        what = f"{nodes}: the gyro, read as gyro={given}, turns {ratios} times as far as {source} ({extent})"
        words = GYRO_WORDS
    else:
        levels = each([f"{m.ratio.value * STANDARD_GRAVITY_M_S2:.4g} m/s2" for m in same])
        what = f"{nodes}: gravity, read as accel={given}, measures {levels} by {source} ({extent}), not 9.81 m/s2"
        words = ACCEL_WORDS
    if not fits:
        return f"{what}: no unit explains it"
    also = ""
    if len(fits) > 1:  # 16 per dps and 900 per rad/s, 100 per m/s2 and 1 per mg: 1.9 % apart, a scale error's size
        also = f" (or {words[fits[1]]}, {quantity}={fits[1]}: too close to tell apart)"
    return f"{what}: the values are in {words[fits[0]]}{also}"


def check_units(
    nodes: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]], groups: tuple[str, ...], units: Units
) -> UnitFindings:
    """Check the gyro's and the accelerometer's units of every node.

    Args:
      nodes: node -> (t_s (n,), rows (n, len(ROW_FIELDS)) in SI as read with ``units``).
      groups: the quantities the file carries (``packets.GROUPS`` names).
      units: the units the values were read in.
    """
    mismatches: list[Mismatch] = []
    checks, notes = [], []
    for node, (t, rows) in nodes.items():
        if len(t) < 2:
            continue
        part = {g: rows[:, GROUP_SLICES[g]] for g in groups if g in GROUP_SLICES}
        if "gyro" in part:
            ratio = None
            if "quat" in part:
                ratio = gyro_against_orientation(t, part["gyro"], part["quat"])
            if ratio is None and "gravity" in part:
                ratio = gyro_against_gravity(t, part["gyro"], part["gravity"])
            if ratio is None:
                why = (
                    "no quaternion or gravity columns to compare it with"
                    if not {"quat", "gravity"} & set(part)
                    else f"its orientation turns too little (fewer than {MIN_WINDOWS} stretches of "
                    f"{WINDOW_S:g} s turning by {math.degrees(MIN_TURN_RAD):g} deg)"
                )
                notes.append(f"{node}: the gyro's unit cannot be checked: {why}")
            else:
                checks.append(f"{node}: gyro/orientation {ratio.value:.4g} ({ratio.evidence})")
                if not math.isfinite(ratio.value) or abs(math.log(ratio.value)) > math.log(MIX_UP_FACTOR):
                    fits = tuple(_fitting(ratio.value, units.gyro, GYRO_UNITS))
                    mismatches.append(Mismatch(node, "gyro", ratio, fits))
        level = gravity_level(t, part.get("accel"), part.get("gravity"))
        if level is not None:
            checks.append(f"{node}: gravity {level.value:.4g} g ({level.evidence})")
            low, high = (G_RANGE[0] / MIX_UP_FACTOR, G_RANGE[1] * MIX_UP_FACTOR)
            if level.value > 0 and not low <= level.value <= high:
                fits = tuple(_fitting(level.value, units.accel, ACCEL_UNITS))
                mismatches.append(Mismatch(node, "accel", level, fits))
            elif not G_RANGE[0] <= level.value <= G_RANGE[1]:
                notes.append(
                    f"{node}: gravity, read as accel={units.accel}, measures {level.value:.3g} g by {level.evidence}, "
                    "not near 1 g; check --units accel"
                )
    fixed: Units | None = units
    for quantity in ("gyro", "accel"):
        choices = {m.fits[0] if m.fits else None for m in mismatches if m.quantity == quantity}
        if None in choices or len(choices) > 1:  # no unit, or the nodes disagree
            fixed = None
        elif choices and fixed is not None:
            unit = choices.pop()
            assert unit is not None
            fixed = Units(accel=fixed.accel, gyro=unit) if quantity == "gyro" else Units(accel=unit, gyro=fixed.gyro)
    return UnitFindings(tuple(mismatches), fixed, tuple(checks), tuple(notes))


def _fitting(ratio: float, given: str, table: dict[str, float]) -> list[str]:
    """The units that explain ``ratio`` (values read in ``given`` come out ``ratio`` times too
    large when they are really in the unit), closest first."""
    if not (math.isfinite(ratio) and ratio > 0):
        return []
    scores = []
    for unit, scale in table.items():
        expected = table[given] / scale
        off = abs(math.log(ratio / expected))
        if off <= math.log1p(FIT_TOLERANCE):
            scores.append((off, unit))
    return [unit for _, unit in sorted(scores)]
