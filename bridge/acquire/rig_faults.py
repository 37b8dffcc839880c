"""Scripted rig faults for the node emulator (``pendsim nodes --fault``): the grammar, its checks
and the faults resolved against a run (values before and after, times on the run's grid).

Grammar (times in s after the release; docs/acquisition.md, "Scripted faults")::

    FAULT  := KIND ":" TARGET CHANGE "@" WHEN
    WHEN   := T            a step at T
            | T ".." T2    a linear ramp from T to T2 (stiffness, damping, friction only)
            | T "~" T2     a step at a time drawn uniformly in [T, T2] from --seed

    stiffness:[c1|c2]CHANGE   spring constant c1 (springs 1-2, 1-3: M1 to M2; the default) or c2
                              (springs 5-6, 5-7: M2 to the frame), N/m
    damping:m1|m2 CHANGE      the hinge's viscous damping b1 or b2, N m s/rad
    friction:m1|m2 CHANGE     the hinge's dry friction friction1_n_m or friction2_n_m, N m
        CHANGE := "*" FACTOR (0 < FACTOR <= 100) | "=" VALUE (the parameter's unit and range)
                | ("+"|"-") PERCENT "%" (-100 < change <= +1000 %)
    mount:m1|m2 "=" ANGLE "deg"   the node turns on its mount about the hinge axis by ANGLE
                                  (0 < |ANGLE| <= 180 deg): orientation, gyro and accelerometer axes
    clock:m1|m2 "=" JUMP ["s"]    the node's device clock jumps by JUMP (0 < |JUMP| <= 1e6 s)

Changes of one parameter apply in time order, each to the value the one before left (two
``stiffness:-5%`` steps leave 0.95^2); changes of one parameter (or one node's mount or clock)
must not overlap in time (a drawn time counts as its whole window). Physics faults act on the
integration grid (times rounded to whole steps); a ramp is constant pieces of ``RAMP_PIECE_S``
at the ramp's value at each piece's midpoint (``pendsim_mj.engines.piecewise``).
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np

from pendsim_mj.engines.piecewise import ParameterChange
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import RigParams

KINDS = ("stiffness", "damping", "friction", "mount", "clock")
PHYSICS_KINDS = ("stiffness", "damping", "friction")
RAMP_PIECE_S = 0.1
"""A ramp's piece: the parameter is held at the ramp's midpoint value over each 0.1 s."""
FACTOR_MAX = 100.0
PERCENT_RANGE = (-100.0, 1000.0)  # (open, closed]
MOUNT_MAX_DEG = 180.0
CLOCK_JUMP_MAX_S = 1e6
FORMS = (
    "stiffness:[c1|c2]CHANGE, damping:m1|m2CHANGE, friction:m1|m2CHANGE (CHANGE: *FACTOR, =VALUE or +-PERCENT%), "
    "mount:m1|m2=ANGLEdeg, clock:m1|m2=JUMP; then @T, @T..T2 (ramp) or @T~T2 (drawn), s after the release"
)
_SEED_STREAM = 0xFA17  # the drawn times' own stream of --seed: adding a fault changes no other draw
_NUMBER = r"[0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?"
_PARAMETERS = {
    ("stiffness", "c1"): ("c1_n_m", "N/m"),
    ("stiffness", "c2"): ("c2_n_m", "N/m"),
    ("damping", "m1"): ("b1_n_m_s", "N m s/rad"),
    ("damping", "m2"): ("b2_n_m_s", "N m s/rad"),
    ("friction", "m1"): ("friction1_n_m", "N m"),
    ("friction", "m2"): ("friction2_n_m", "N m"),
}

Op = Literal["*", "=", "%"]
Timing = Literal["step", "ramp", "drawn"]


@dataclasses.dataclass(frozen=True)
class RigFault:
    """One scripted fault as given on the command line (``parse_fault``).

    Attributes:
      kind: one of ``KINDS``.
      target: "c1" or "c2" (stiffness), "m1" or "m2" (the others).
      op: "*" (a factor), "=" (a value: the parameter's unit, deg for mount, s for clock) or "%"
        (a change in percent of the value before).
      amount: the factor, value or percent.
      start_s, end_s: s after the release; a step has end_s == start_s; a ramp runs from start_s
        to end_s; a drawn step happens at a time drawn in [start_s, end_s].
      timing: "step", "ramp" or "drawn".
      text: the fault as given.
    """

    kind: str
    target: str
    op: Op
    amount: float
    start_s: float
    end_s: float
    timing: Timing = "step"
    text: str = ""

    def __post_init__(self) -> None:
        def bad(why: str) -> ParameterError:
            return ParameterError(f"--fault {self.text or self.kind!r}: {why}")

        if self.kind not in KINDS:
            raise bad(f"unknown kind {self.kind!r}; allowed: {', '.join(KINDS)}")
        targets = ("c1", "c2") if self.kind == "stiffness" else ("m1", "m2")
        if self.target not in targets:
            raise bad(f"unknown target {self.target!r} for {self.kind}; allowed: {', '.join(targets)}")
        if not math.isfinite(self.amount):
            raise bad(f"the change must be a finite number, got {self.amount!r}")
        if self.kind in PHYSICS_KINDS:
            if self.op == "*" and not 0 < self.amount <= FACTOR_MAX:
                raise bad(f"a factor must be in (0, {FACTOR_MAX:g}], got {self.amount:g}")
            if self.op == "%" and not PERCENT_RANGE[0] < self.amount <= PERCENT_RANGE[1]:
                raise bad(
                    f"a change must be in ({PERCENT_RANGE[0]:+g}, {PERCENT_RANGE[1]:+g}] %, got {self.amount:+g} %"
                )
            if self.op == "=" and self.amount < 0:
                raise bad(f"a value must be >= 0, got {self.amount:g}")
        else:
            if self.op != "=":
                raise bad(f"{self.kind} takes =VALUE only")
            limit, unit = (MOUNT_MAX_DEG, "deg") if self.kind == "mount" else (CLOCK_JUMP_MAX_S, "s")
            if not 0 < abs(self.amount) <= limit:
                raise bad(f"the {self.kind} change must be nonzero and within +-{limit:g} {unit}, got {self.amount:g}")
            if self.timing == "ramp":
                raise bad(f"{self.kind} is a step (@T or @T~T2), not a ramp")
        for name in ("start_s", "end_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 <= value <= 1e9):
                raise bad(f"times must be in [0, 1e9] s after the release, got {value!r}")
        if self.timing == "step" and self.end_s != self.start_s:
            raise bad("a step has one time")
        if self.timing != "step" and not self.end_s > self.start_s:
            raise bad(f"T..T2 and T~T2 need T2 > T, got {self.start_s:g} and {self.end_s:g}")

    @property
    def label(self) -> str:
        """The fault as given, or written in the grammar where it was built in code."""
        if self.text:
            return self.text
        change = {"*": f"*{self.amount:g}", "=": f"={self.amount:g}", "%": f"{self.amount:+g}%"}[self.op]
        unit = "deg" if self.kind == "mount" else ""
        when = {"step": f"{self.start_s:g}", "ramp": f"{self.start_s:g}..{self.end_s:g}"}.get(
            self.timing, f"{self.start_s:g}~{self.end_s:g}"
        )
        return f"{self.kind}:{self.target}{change}{unit}@{when}"

    @property
    def node_target(self) -> bool:
        """The target is a node (m1, m2), not a spring group."""
        return self.kind != "stiffness"

    @property
    def physics(self) -> bool:
        """A change of the simulated rig (not of a node's output)."""
        return self.kind in PHYSICS_KINDS

    @property
    def quantity(self) -> tuple[str, str]:
        """(what changes, unit): a RigParams field, "mount_deg" or "clock_s"."""
        if self.kind == "mount":
            return "mount_deg", "deg"
        if self.kind == "clock":
            return "clock_s", "s"
        return _PARAMETERS[(self.kind, self.target)]


def parse_fault(text: str) -> RigFault:
    """``KIND:TARGETCHANGE@WHEN`` (the module's grammar) to a RigFault; ParameterError names
    what is allowed."""

    def bad(why: str) -> ParameterError:
        return ParameterError(f"--fault {text!r}: {why}")

    kind, colon, rest = text.strip().partition(":")
    kind = kind.strip().lower()
    if not colon:
        raise bad(f"expected KIND:TARGETCHANGE@WHEN; forms: {FORMS}")
    if kind not in KINDS:
        raise bad(f"unknown kind {kind!r}; allowed: {', '.join(KINDS)}")
    what, at, when = rest.partition("@")
    if not at:
        raise bad("no time: end with @T, @T..T2 or @T~T2 (s after the release)")
    what = what.strip()
    match = re.fullmatch(r"([a-z][a-z0-9]*)?\s*(.*)", what, flags=re.IGNORECASE)
    assert match is not None
    target, change = (match.group(1) or "").lower(), match.group(2).strip()
    if not target and kind == "stiffness":
        target = "c1"
    targets = ("c1", "c2") if kind == "stiffness" else ("m1", "m2")
    if target not in targets:
        raise bad(f"unknown target {target!r} for {kind}; allowed: {', '.join(targets)}")
    op, amount = _change(kind, change, bad)
    start_s, end_s, timing = _when(when.strip(), bad, ramp=kind in PHYSICS_KINDS)
    return RigFault(kind, target, op, amount, start_s, end_s, timing, text.strip())


def _change(kind: str, change: str, bad: Any) -> tuple[Op, float]:
    number = rf"[+-]?{_NUMBER}"
    if kind == "mount":
        m = re.fullmatch(rf"=\s*({number})\s*deg", change)
        if not m:
            raise bad(f"expected mount:m1|m2=ANGLEdeg (e.g. mount:m1=3deg@20), got {change!r}")
        return "=", float(m.group(1))
    if kind == "clock":
        m = re.fullmatch(rf"=\s*({number})\s*s?", change)
        if not m:
            raise bad(f"expected clock:m1|m2=JUMP in s (e.g. clock:m2=+0.5@20), got {change!r}")
        return "=", float(m.group(1))
    for pattern, op in ((rf"\*\s*({number})", "*"), (rf"=\s*({number})", "="), (rf"([+-]{_NUMBER})\s*%", "%")):
        m = re.fullmatch(pattern, change)
        if m:
            return op, float(m.group(1))  # type: ignore[return-value]
    example = f"{kind}:{'' if kind == 'stiffness' else 'm1'}*2@20"
    raise bad(f"expected a change *FACTOR, =VALUE or +-PERCENT% (e.g. {example}), got {change!r}")


def _when(when: str, bad: Any, *, ramp: bool) -> tuple[float, float, Timing]:
    for sep, timing in (("..", "ramp"), ("~", "drawn")):
        if sep in when:
            a, _, b = when.partition(sep)
            if timing == "ramp" and not ramp:
                raise bad("a ramp (@T..T2) is for stiffness, damping and friction; this kind is a step")
            return _time(a, bad), _time(b, bad), timing  # type: ignore[return-value]
    t = _time(when, bad)
    return t, t, "step"


def _time(text: str, bad: Any) -> float:
    if not re.fullmatch(rf"\+?{_NUMBER}", text.strip()):
        raise bad(f"a time must be a number of s >= 0 after the release, got {text.strip()!r}")
    value = float(text)
    if not value <= 1e9:
        raise bad(f"a time must be at most 1e9 s, got {text.strip()!r}")
    return value


@dataclasses.dataclass(frozen=True)
class PlayedFault:
    """A fault resolved against a run: what changes, from what to what, when.

    Attributes:
      fault: as given.
      quantity: a RigParams field (physics faults), "mount_deg" or "clock_s".
      unit: of before and after.
      before, after: the value before and after (mount: the node's turn on its mount since the
        start, deg; clock: the jumps since the start, s).
      start_s, end_s: s after the release, on the integration grid for physics faults (end_s ==
        start_s for a step; a drawn time as drawn).
    """

    fault: RigFault
    quantity: str
    unit: str
    before: float
    after: float
    start_s: float
    end_s: float

    @property
    def node(self) -> str | None:
        return None if self.fault.kind == "stiffness" else self.fault.target

    def change(self, dt_s: float) -> ParameterChange:
        """The physics fault as a parameter change on the integration grid."""
        assert self.fault.physics, "mount and clock faults act on a node's samples"
        return ParameterChange(self.quantity, self.after, round(self.start_s / dt_s), round(self.end_s / dt_s))

    def as_dict(self) -> dict[str, Any]:
        """For the emulator's log header."""
        return {
            "text": self.fault.label, "kind": self.fault.kind, "target": self.fault.target, "node": self.node,
            "quantity": self.quantity, "unit": self.unit, "before": self.before, "after": self.after,
            "start_s": self.start_s, "end_s": self.end_s, "timing": self.fault.timing,
            "window_s": [self.fault.start_s, self.fault.end_s] if self.fault.timing == "drawn" else None,
        }  # fmt: skip

    def describe(self) -> str:
        """One line: "stiffness c1_n_m 6.173 -> 5.864 N/m at 20 s"."""
        f = self.fault
        when = f"{self.start_s:g}..{self.end_s:g} s" if f.timing == "ramp" else f"{self.start_s:g} s"
        if f.kind == "clock":
            return f"clock {f.target} jumps {f.amount:+g} s at {when}"
        if f.kind == "mount":
            return f"mount {f.target} turns {f.amount:+g} deg (to {self.after:+g} deg) at {when}"
        return f"{f.kind} {self.quantity} {self.before:.6g} -> {self.after:.6g} {self.unit} at {when}"


def resolve_faults(
    faults: Sequence[RigFault],
    *,
    params: RigParams,
    duration_s: float,
    dt_s: float,
    nodes: Sequence[str],
    seed: int,
) -> tuple[PlayedFault, ...]:
    """The faults against a run of ``duration_s`` after the release at step ``dt_s``, sent by
    ``nodes``: drawn times drawn (in the order given, from ``seed``'s own stream), physics times on
    the grid, values before and after, in the order given.

    Raises:
      ParameterError: a node not sent to, a time at or past the run's end, a ramp shorter than a
        step, overlapping changes of one quantity, a factor or percent of a zero friction, or a
        value outside the parameter's range.
    """
    rng = np.random.default_rng([seed, _SEED_STREAM])
    timed: list[tuple[RigFault, float, float]] = []
    for f in faults:

        def bad(why: str, f: RigFault = f) -> ParameterError:
            return ParameterError(f"--fault {f.label!r}: {why}")

        if f.node_target and f.target not in nodes:
            raise bad(f"node {f.target} is not sent to (--node)")
        if f.end_s >= duration_s if f.timing != "ramp" else f.end_s > duration_s:
            raise bad(f"{f.end_s:g} s is past the run's end ({duration_s:g} s after the release)")
        start = float(rng.uniform(f.start_s, f.end_s)) if f.timing == "drawn" else f.start_s
        end = f.end_s if f.timing == "ramp" else start
        if f.physics:
            start, end = round(start / dt_s) * dt_s, round(end / dt_s) * dt_s
            if f.timing == "ramp" and end <= start:
                raise bad(f"the ramp is shorter than one step of {dt_s:g} s")
            if f.timing != "ramp" and start >= duration_s - 0.5 * dt_s:
                raise bad(f"{f.end_s:g} s is past the run's last step ({duration_s:g} s after the release)")
        timed.append((f, start, end))
    _check_overlaps(faults)
    value: dict[tuple[str, str], float] = {}
    played: dict[int, PlayedFault] = {}
    for i in sorted(range(len(timed)), key=lambda i: timed[i][1]):
        f, start, end = timed[i]
        quantity, unit = f.quantity
        key = (quantity, f.target)
        if f.physics:
            before = value.get(key, float(getattr(params, quantity)))
            if f.op != "=" and before == 0.0:
                raise ParameterError(f"--fault {f.label!r}: {quantity} is 0 before the fault; give the value (=VALUE)")
            after = f.amount if f.op == "=" else before * f.amount if f.op == "*" else before * (1 + f.amount / 100)
            try:
                params.with_overrides(**{quantity: after})
            except ParameterError as exc:
                raise ParameterError(f"--fault {f.label!r}: {exc}") from None
        else:
            before = value.get(key, 0.0)
            after = before + f.amount
        value[key] = after
        played[i] = PlayedFault(f, quantity, unit, before, after, start, end)
    return tuple(played[i] for i in range(len(timed)))


def _check_overlaps(faults: Sequence[RigFault]) -> None:
    """Two changes of one quantity (and target) whose times overlap (drawn: their windows)."""
    for i, a in enumerate(faults):
        for b in faults[:i]:
            if a.quantity != b.quantity or a.target != b.target:
                continue
            if a.start_s == b.start_s or (a.start_s < b.end_s and b.start_s < a.end_s):
                what = f"changes of one {a.kind} must not overlap in time"
                raise ParameterError(f"--fault {a.label!r} overlaps --fault {b.label!r}: {what}")
