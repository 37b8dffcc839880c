"""What a sweep runs: its definition (from TOML, JSON or options) and the table of cases it expands to.

A sweep varies *inputs*: any ``RigParams`` field by name (SI, as ``pendsim info`` lists them),
the release state ``phi1_deg``, ``phi2_deg``, ``omega1_deg_s``, ``omega2_deg_s`` (or the same in
radians: ``phi1_rad``, ..., ``omega2_rad_s``), and a sine drive on any target of
``pendsim_mj.rig.drives`` (``DRIVE_INPUTS``: ``support_x_amplitude_m_s2``, ``support_x_frequency_hz``,
``support_x_phase_rad``, the same for ``pivot_z``, and ``torque_m1_amplitude_n_m``, ... for the
torques). Inputs not varied take their ``base`` value, else the defaults of ``pendsim simulate``
(the paper's rig, M1 released from 30 deg, M2 at rest, nothing driven).

Methods (how cases are made; ``seed`` makes random and lhs repeatable):

- ``grid``: every combination of the values of each varied input (first input slowest);
- ``random``: ``samples`` cases, each input drawn uniformly (or log-uniformly) in its range;
- ``lhs``: ``samples`` cases from a Latin hypercube over the ranges (scipy.stats.qmc);
- ``csv``: one case per row of a CSV file whose header names the inputs;
- ``sensitivity``: the base case, then each parameter alone at (1 - step) and (1 + step) times
  its base value (parameters whose base value is 0 cannot be scaled and are left out).

Definition file (TOML shown; JSON has the same keys)::

    method = "grid"                 # grid | random | lhs | csv | sensitivity
    engine = "fast"                 # fast (compiled planar) | mujoco (planar) | spatial (MuJoCo)
    duration_s = 30.0
    dt_s = 0.01
    features = ["frequency", "amplitude"]
    [base]
    phi1_deg = 30.0
    [vary]
    c1_n_m = {from = 5.0, to = 7.0, num = 11}     # grid: num values; random/lhs: the range
    phi1_deg = [10.0, 20.0, 30.0]                  # grid: these values
    b1_n_m_s = {from = 1e-4, to = 1e-2, num = 5, scale = "log"}
"""

from __future__ import annotations

import array
import csv
import dataclasses
import hashlib
import json
import math
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.errors import ParameterError, did_you_mean
from pendsim_mj.rig.checks import check_input, check_step
from pendsim_mj.rig.drives import Drive, Sine, Target
from pendsim_mj.rig.params import DEFAULT_PARAMS, ParamColumns, RigParams
from pendsim_mj.sweep.features import DEFAULT_GROUPS, check_groups

FloatArray = NDArray[np.float64]

METHODS = ("grid", "random", "lhs", "csv", "sensitivity")
ENGINES = ("fast", "mujoco", "spatial")
PARAMETER_NAMES = tuple(name for name, _, _ in RigParams.describe())
# Release-state inputs: name -> (index into (phi1, phi2, omega1, omega2), factor to SI).
STATE_INPUTS: dict[str, tuple[int, float]] = {
    "phi1_deg": (0, math.pi / 180),
    "phi2_deg": (1, math.pi / 180),
    "omega1_deg_s": (2, math.pi / 180),
    "omega2_deg_s": (3, math.pi / 180),
    "phi1_rad": (0, 1.0),
    "phi2_rad": (1, 1.0),
    "omega1_rad_s": (2, 1.0),
    "omega2_rad_s": (3, 1.0),
}
# Drive inputs (``pendsim_mj.rig.drives``): a sine on each target, amplitude * sin(2 pi f t + phase);
# name -> (target, field). A case drives a target when the sweep sets any of its three inputs.
DRIVE_INPUTS: dict[str, tuple[Target, str]] = {}
for _target in Target:
    _unit = "n_m" if _target.unit == "N m" else "m_s2"
    DRIVE_INPUTS[f"{_target.value}_amplitude_{_unit}"] = (_target, "amplitude")
    DRIVE_INPUTS[f"{_target.value}_frequency_hz"] = (_target, "frequency_hz")
    DRIVE_INPUTS[f"{_target.value}_phase_rad"] = (_target, "phase_rad")
INPUT_NAMES = PARAMETER_NAMES + tuple(STATE_INPUTS) + tuple(DRIVE_INPUTS)
DEFAULT_STATE = (math.pi / 6, 0.0, 0.0, 0.0)  # pendsim simulate's release: phi1 = 30 deg
SPATIAL_PLANE_OFFSET_M = 0.050  # the spatial engine's plane offset unless given (paper: 50 mm)
_KEYS = frozenset(
    {"method", "engine", "duration_s", "dt_s", "save_every", "features", "seed", "samples", "cases",
     "relative_step", "parameters", "base", "vary", "trajectories"}
)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Axis:
    """One varied input: explicit ``values``, or a range ``low``..``high`` (``num`` values for a
    grid; the sampling range for random and lhs), spaced linearly or, with ``log``, geometrically."""

    name: str
    values: tuple[float, ...] | None = None
    low: float | None = None
    high: float | None = None
    num: int | None = None
    log: bool = False

    def grid_values(self) -> FloatArray:
        if self.values is not None:
            return np.array(self.values, dtype=float)
        if self.num is None:
            raise ParameterError(f"vary {self.name}: a grid needs num (from:to:num) or a list of values")
        assert self.low is not None and self.high is not None
        return np.geomspace(self.low, self.high, self.num) if self.log else np.linspace(self.low, self.high, self.num)

    def scale_unit(self, u: FloatArray) -> FloatArray:
        """Map samples u in [0, 1) onto the range."""
        if self.low is None or self.high is None:
            raise ParameterError(f"vary {self.name}: random and lhs need a range (from:to), not a list of values")
        if self.log:
            return np.exp(np.log(self.low) + u * (np.log(self.high) - np.log(self.low)))
        return self.low + u * (self.high - self.low)


@dataclasses.dataclass(frozen=True)
class CaseTable:
    """The cases of a sweep: ``values[i, j]`` is input ``names[j]`` of case i (units as named).

    For a sensitivity sweep ``varied[i]`` names the parameter case i changes ("" for the base
    case) and ``relative_change[i]`` by how much (-step, 0 or +step).
    """

    names: tuple[str, ...]
    values: FloatArray
    varied: tuple[str, ...] | None = None
    relative_change: FloatArray | None = None

    def __len__(self) -> int:
        return len(self.values)

    def digest(self) -> str:
        """A hash of the exact cases (names, values, labels): what a resumed sweep must match."""
        h = hashlib.sha256(json.dumps(self.names).encode())
        h.update(np.ascontiguousarray(self.values, dtype="<f8").tobytes())
        if self.varied is not None:
            h.update(json.dumps(self.varied).encode())
        return h.hexdigest()


@dataclasses.dataclass(frozen=True)
class SweepPlan:
    """A sweep definition; ``cases()`` expands it. Build with ``from_mapping`` or ``load``."""

    method: str = "grid"
    engine: str = "fast"
    duration_s: float = 30.0
    dt_s: float = 0.01
    save_every: int = 1
    features: tuple[str, ...] = DEFAULT_GROUPS
    base: tuple[tuple[str, float], ...] = ()
    axes: tuple[Axis, ...] = ()
    samples: int | None = None
    seed: int = 0
    csv_cases: CaseTable | None = None
    relative_step: float = 0.01
    parameters: tuple[str, ...] | None = None
    trajectories: bool = False

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ParameterError(f"unknown method {self.method!r}; allowed: {', '.join(METHODS)}")
        if self.engine not in ENGINES:
            raise ParameterError(f"unknown engine {self.engine!r}; allowed: {', '.join(ENGINES)}")
        for name in ("duration_s", "dt_s"):
            check_input(name, getattr(self, name))
        nstep = check_step(self.duration_s, self.dt_s)
        if isinstance(self.save_every, bool) or not isinstance(self.save_every, int) or self.save_every < 1:
            raise ParameterError(f"save_every must be a whole number >= 1, got {self.save_every!r}")
        if nstep % self.save_every or nstep // self.save_every < 8:
            raise ParameterError(
                f"save_every = {self.save_every} must divide the {nstep} steps and leave at least 8 samples"
            )
        check_groups(self.features)
        if "lyapunov" in self.features and self.engine != "fast":
            raise ParameterError("the lyapunov feature needs the fast engine")
        for name, value in self.base:
            _check_input(name, "base")
            _check_number(value, f"base {name}")
            _check_range(name, value, "base")
        names = [a.name for a in self.axes]
        for axis in self.axes:
            _check_input(axis.name, "vary")
            for what, bound in (("from", axis.low), ("to", axis.high)):
                if bound is not None:
                    _check_range(axis.name, bound, f"vary {axis.name} {what}:")
            for listed in axis.values or ():
                _check_range(axis.name, listed, f"vary {axis.name}:")
        if len(set(names)) != len(names):
            raise ParameterError(f"an input is varied twice: {', '.join(names)}")
        fixed = sorted({name for name, _ in self.base} & set(names))
        if fixed:
            raise ParameterError(f"{', '.join(fixed)} both set (base) and varied; give each input one or the other")
        given = [name for name, _ in self.base] + names
        for index in range(4):  # a release state in two units (phi1_deg and phi1_rad): which one is meant?
            units = [name for name in given if name in STATE_INPUTS and STATE_INPUTS[name][0] == index]
            if len(units) > 1:
                raise ParameterError(f"{' and '.join(units)} give the same release state; give it once, in one unit")
        if self.method == "sensitivity" and self.axes:
            raise ParameterError(
                "a sensitivity sweep steps each parameter about its base: vary does not apply to it (give the base "
                "with --set, or base in a file)"
            )
        for axis in self.axes:
            self._check_spread(axis)
        if self.method in ("random", "lhs") and (
            not isinstance(self.samples, int) or isinstance(self.samples, bool) or self.samples < 1
        ):
            raise ParameterError(f"method {self.method} needs samples >= 1, got {self.samples!r}")
        for axis in self.axes:
            if self.method in ("random", "lhs") and (axis.low is None or axis.high is None):
                raise ParameterError(f"vary {axis.name}: random and lhs need a range (from:to), not a list of values")
            if self.method in ("random", "lhs") and axis.num is not None:
                raise ParameterError(
                    f"vary {axis.name}: {self.method} draws its {self.samples} cases in the range; give from:to "
                    f"without num ({axis.num})"
                )
            if self.method == "grid" and axis.values is None and axis.num is None:
                raise ParameterError(f"vary {axis.name}: a grid needs num (from:to:num) or a list of values")
        if self.method in ("grid", "random", "lhs") and not self.axes:
            raise ParameterError(f"method {self.method} needs at least one varied input (vary NAME=...)")
        if self.method == "csv" and self.csv_cases is None:
            raise ParameterError("method csv needs a cases file")
        if self.method == "sensitivity":
            if not (math.isfinite(self.relative_step) and 0 < self.relative_step < 1):
                raise ParameterError(f"relative_step must be in (0, 1), got {self.relative_step!r}")
            for name in self.parameters or ():
                if name not in PARAMETER_NAMES:
                    raise ParameterError(
                        f"unknown parameter {name!r}{did_you_mean(name, PARAMETER_NAMES)}; "
                        f"allowed: {', '.join(PARAMETER_NAMES)}"
                    )

    def _check_spread(self, axis: Axis) -> None:
        """Refuse a range that cannot mean what it says: random draws from a high to a low bound
        (a descending grid runs in its order, a draw has none), and cases that repeat themselves
        (a zero-width range, a list naming a value twice)."""
        if axis.values is not None:
            values, counts = np.unique(np.asarray(axis.values, dtype=float), return_counts=True)
            repeated = values[counts > 1].tolist()  # (a count per value would be quadratic in a long list)
            if repeated:
                raise ParameterError(
                    f"vary {axis.name}: the list names {repeated[0]:g} more than once (the same cases twice)"
                )
            return
        if axis.low is None or axis.high is None:
            return
        if self.method in ("random", "lhs") and axis.low > axis.high:
            raise ParameterError(
                f"vary {axis.name}: {self.method} draws between from and to, low to high: give "
                f"{axis.high:g}:{axis.low:g} (got {axis.low:g}:{axis.high:g})"
            )
        if axis.low == axis.high and (self.method in ("random", "lhs") or (axis.num or 1) > 1):
            raise ParameterError(
                f"vary {axis.name}: a range of zero width ({axis.low:g}:{axis.high:g}) gives one case again and again; "
                f"set {axis.name} instead (--set {axis.name}={axis.low:g})"
            )

    @property
    def nstep(self) -> int:
        return check_step(self.duration_s, self.dt_s)

    def on_rig(self, values: Mapping[str, float]) -> SweepPlan:
        """This plan on a rig given as parameter values (one the user calibrated or identified:
        ``pendsim sweep --params-file``): they become base values under the plan's own base,
        except for the inputs the plan varies (its axes, its CSV's columns), which keep theirs."""
        varied = {a.name for a in self.axes} | set(self.csv_cases.names if self.csv_cases is not None else ())
        own = dict(self.base)
        rig = {name: float(v) for name, v in values.items() if name not in varied and name not in own}
        return dataclasses.replace(self, base=(*rig.items(), *self.base))

    def base_params(self) -> RigParams:
        """RigParams of the base case (defaults, the spatial engine's plane offset, then ``base``)."""
        values = dict(self.base)
        overrides = {k: v for k, v in values.items() if k in PARAMETER_NAMES}
        if self.engine == "spatial" and "plane_offset_m" not in overrides:
            overrides["plane_offset_m"] = SPATIAL_PLANE_OFFSET_M
        return DEFAULT_PARAMS.with_mapping(overrides)

    def cases(self) -> CaseTable:
        """Expand the definition into its cases."""
        if self.method == "grid":
            grids = [a.grid_values() for a in self.axes]
            mesh = np.meshgrid(*grids, indexing="ij")
            values = np.stack([g.ravel() for g in mesh], axis=1)
            return CaseTable(names=tuple(a.name for a in self.axes), values=values)
        if self.method in ("random", "lhs"):
            assert self.samples is not None
            rng = np.random.default_rng(self.seed)
            if self.method == "random":
                unit = rng.random((self.samples, len(self.axes)))
            else:
                from scipy.stats import qmc  # start-up: scipy, only for these samplers

                unit = qmc.LatinHypercube(d=len(self.axes), seed=rng).random(self.samples)
            values = np.stack([a.scale_unit(unit[:, j]) for j, a in enumerate(self.axes)], axis=1)
            return CaseTable(names=tuple(a.name for a in self.axes), values=values)
        if self.method == "csv":
            assert self.csv_cases is not None
            return self.csv_cases
        return self._sensitivity_cases()

    def unscaled(self) -> tuple[str, ...]:
        """A sensitivity sweep's parameters left out: zero in the base (a relative step of zero
        is none: dry friction, the planes' offset of the planar model)."""
        if self.method != "sensitivity":
            return ()
        base = self.base_params()
        return tuple(n for n in (self.parameters or PARAMETER_NAMES) if getattr(base, n) == 0)

    def _sensitivity_cases(self) -> CaseTable:
        base = self.base_params()
        names = tuple(n for n in (self.parameters or PARAMETER_NAMES) if getattr(base, n) != 0)
        if not names:
            raise ParameterError("no parameter with a non-zero base value to scale")
        base_row = np.array([getattr(base, n) for n in names])
        rows, varied, change = [base_row], [""], [0.0]
        for j, name in enumerate(names):
            for sign in (-1.0, 1.0):
                row = base_row.copy()
                row[j] = base_row[j] * (1.0 + sign * self.relative_step)
                rows.append(row)
                varied.append(name)
                change.append(sign * self.relative_step)
        return CaseTable(names=names, values=np.array(rows), varied=tuple(varied), relative_change=np.array(change))

    def case_inputs(self, table: CaseTable, rows: NDArray[np.int64]) -> tuple[ParamColumns, FloatArray, FloatArray]:
        """Parameters (checked, as columns) and release states (phi0 (k, 2) rad, omega0 (k, 2)
        rad/s) of the cases ``rows`` of ``table``.

        Raises:
          ParameterError: naming the first case whose parameters are not allowed.
        """
        state0 = np.array(DEFAULT_STATE)
        for name, value in self.base:
            if name in STATE_INPUTS:
                index, factor = STATE_INPUTS[name]
                state0[index] = value * factor
        states = np.tile(state0, (len(rows), 1))
        columns = {}
        for j, name in enumerate(table.names):
            if name in STATE_INPUTS:
                index, factor = STATE_INPUTS[name]
                states[:, index] = table.values[rows, j] * factor
            elif name in PARAMETER_NAMES:
                columns[name] = table.values[rows, j]
        params = ParamColumns.from_base(self.base_params(), len(rows), columns, case_ids=[int(r) for r in rows])
        return params, states[:, :2].copy(), states[:, 2:].copy()

    def driven_targets(self, table: CaseTable) -> tuple[Target, ...]:
        """The targets this sweep drives (any of their inputs set in ``base`` or varied)."""
        names = {n for n, _ in self.base} | set(table.names)
        return tuple(t for t in Target if any(DRIVE_INPUTS[n][0] is t for n in names if n in DRIVE_INPUTS))

    def case_drives(self, table: CaseTable, rows: NDArray[np.int64]) -> list[Drive | None]:
        """The drive of each case ``rows``: on every target the sweep drives, a ``drives.Sine`` of
        its amplitude (default 0), frequency and phase (default 0); None when nothing is driven.
        Every case of a sweep drives the same targets (a zero amplitude drives nothing).

        Raises:
          ParameterError: a driven target without a frequency, or a bad value, naming the case.
        """
        targets = self.driven_targets(table)
        if not targets:
            return [None] * len(rows)
        base = dict(self.base)
        out: list[Drive | None] = []
        for r in rows:
            case = {**base, **{n: float(table.values[r, j]) for j, n in enumerate(table.names) if n in DRIVE_INPUTS}}
            signals = {}
            for target in targets:
                names = {field: n for n, (t, field) in DRIVE_INPUTS.items() if t is target}
                if names["frequency_hz"] not in case:
                    raise ParameterError(f"the sweep drives {target.value}: set or vary {names['frequency_hz']} too")
                try:
                    signals[target.value] = Sine(
                        case.get(names["amplitude"], 0.0),
                        case[names["frequency_hz"]],
                        case.get(names["phase_rad"], 0.0),
                    )
                except ParameterError as exc:
                    raise ParameterError(f"case {int(r)}: {target.value} {exc}") from None
            out.append(Drive(**signals))
        return out

    def to_mapping(self) -> dict[str, Any]:
        """The definition as plain JSON-able data (what ``from_mapping`` reads; CSV cases inline)."""
        out: dict[str, Any] = {
            "method": self.method,
            "engine": self.engine,
            "duration_s": self.duration_s,
            "dt_s": self.dt_s,
            "save_every": self.save_every,
            "features": list(self.features),
            "seed": self.seed,
            "base": dict(self.base),
            "vary": {a.name: axis_mapping(a) for a in self.axes},
            "trajectories": self.trajectories,
        }
        if self.samples is not None:
            out["samples"] = self.samples
        if self.method == "sensitivity":
            out["relative_step"] = self.relative_step
            if self.parameters is not None:
                out["parameters"] = list(self.parameters)
        if self.csv_cases is not None:
            out["cases"] = {"names": list(self.csv_cases.names), "values": self.csv_cases.values.tolist()}
        return out

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], *, base_dir: Path | None = None) -> SweepPlan:
        """A plan from parsed TOML/JSON (keys in the module docstring); a relative ``cases`` path
        is read from ``base_dir``.

        Raises:
          ParameterError: an unknown key, input or method, or a value of the wrong kind.
        """
        if not isinstance(data, Mapping):
            raise ParameterError("a sweep definition must be a table/object of keys")
        unknown = sorted(set(data) - _KEYS)
        if unknown:
            raise ParameterError(
                f"unknown key(s) {', '.join(unknown)} in the sweep definition; allowed: {', '.join(sorted(_KEYS))}"
            )
        kw: dict[str, Any] = {}
        for key in ("method", "engine"):
            if key in data:
                kw[key] = _text(data[key], key)
        for key in ("duration_s", "dt_s", "relative_step"):
            if key in data:
                kw[key] = _check_number(data[key], key)
        for key in ("save_every", "samples", "seed"):
            if key in data:
                kw[key] = _whole(data[key], key)
        if "trajectories" in data:
            if not isinstance(data["trajectories"], bool):
                raise ParameterError(f"trajectories must be true or false, got {data['trajectories']!r}")
            kw["trajectories"] = data["trajectories"]
        if "features" in data:
            kw["features"] = check_groups(_names(data["features"], "features"))
        if "parameters" in data:
            kw["parameters"] = tuple(_names(data["parameters"], "parameters"))
        stray = [key for key in ("relative_step", "parameters") if key in data]
        if stray and data.get("method", "grid") != "sensitivity":
            raise ParameterError(
                f"{stray[0]} (--{stray[0].replace('_', '-')}) applies to a sensitivity sweep only (--sensitivity, "
                f"method sensitivity); this one is {data.get('method', 'grid')}"
            )
        if "base" in data:
            base = data["base"]
            if not isinstance(base, Mapping):
                raise ParameterError("base must be a table of NAME = value")
            for k in base:  # a name first: an option's text there (engine = "fast") is not a number's fault
                _check_input(str(k), "base")
            kw["base"] = tuple((str(k), _check_number(v, f"base {k}")) for k, v in base.items())
        if "vary" in data:
            vary = data["vary"]
            if not isinstance(vary, Mapping):
                raise ParameterError("vary must be a table of NAME = [values] or {from, to, num}")
            kw["axes"] = tuple(_axis(str(k), v) for k, v in vary.items())
        if "cases" in data:
            cases = data["cases"]
            if isinstance(cases, Mapping):
                kw["csv_cases"] = _table(cases.get("names"), cases.get("values"), "cases")
            else:
                path = Path(_text(cases, "cases"))
                kw["csv_cases"] = read_cases_csv(path if path.is_absolute() or base_dir is None else base_dir / path)
            kw.setdefault("method", "csv")
        return cls(**kw)

    @classmethod
    def load(cls, path: str | Path) -> SweepPlan:
        """A plan from a .toml or .json file."""
        path = Path(path)
        if path.suffix.lower() not in (".toml", ".json"):
            raise ParameterError(f"sweep definition {str(path)!r} must end in .toml or .json")
        try:
            text = path.read_text()
        except OSError as exc:
            raise ParameterError(f"cannot read sweep definition {str(path)!r}: {exc.strerror or exc}") from None
        try:
            data = tomllib.loads(text) if path.suffix.lower() == ".toml" else json.loads(text)
        except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
            raise ParameterError(
                f"sweep definition {str(path)!r} is not valid {path.suffix[1:].upper()}: {exc}"
            ) from None
        return cls.from_mapping(data, base_dir=path.parent)


def parse_vary(text: str) -> Axis:
    """A command-line axis: NAME=FROM:TO:NUM[:log] (grid), NAME=FROM:TO[:log] (random, lhs) or
    NAME=V1,V2,... (grid values)."""
    name, sep, spec = text.partition("=")
    name = name.strip()
    if not sep or not name or not spec:
        raise ParameterError(f"expected NAME=FROM:TO:NUM[:log], NAME=FROM:TO[:log] or NAME=V1,V2,..., got {text!r}")
    if ":" in spec:
        parts = spec.split(":")
        log = parts[-1].strip().lower() == "log"
        if log:
            parts = parts[:-1]
        if len(parts) not in (2, 3):
            raise ParameterError(f"vary {name}: expected FROM:TO[:log] or FROM:TO:NUM[:log], got {spec!r}")
        mapping: dict[str, Any] = {"from": _float_text(parts[0], name), "to": _float_text(parts[1], name)}
        if len(parts) == 3:
            mapping["num"] = _whole(_float_text(parts[2], name), f"vary {name} num")
        if log:
            mapping["scale"] = "log"
        return _axis(name, mapping)
    return _axis(name, [_float_text(v, name) for v in spec.split(",")])


MAX_CASES_LINE_CHARS = 1 << 16
"""The longest line of a cases file: a row of a few dozen numbers is a few hundred characters."""


def _case_lines(f: Any, where: str) -> Any:
    """(line number, fields) of each non-empty line, read one at a time with a bounded length."""
    number = 0
    while True:
        text = f.readline(MAX_CASES_LINE_CHARS + 1)
        if not text:
            return
        number += 1
        if len(text) > MAX_CASES_LINE_CHARS:
            raise ParameterError(f"{where} line {number} is over {MAX_CASES_LINE_CHARS} characters; not a cases file")
        row = next(csv.reader([text]), [])
        if any(cell.strip() for cell in row):
            yield number, row


def read_cases_csv(path: Path) -> CaseTable:
    """Cases from a CSV file: a header of input names, then one row of numbers per case. Read
    line by line into an array (memory: the cases' numbers, not the file's text); a file that is
    not text (a NUL byte in its first block) or has an overlong line is refused when met."""
    where = f"cases file {str(path)!r}"
    header: list[str] | None = None
    values = array.array("d")
    try:
        with open(path, "rb") as raw:
            if b"\0" in raw.read(4096):
                raise ParameterError(f"{where} is not text (NUL bytes); give a CSV of a header and rows of numbers")
        with open(path, newline="", encoding="utf-8") as f:
            for line, row in _case_lines(f, where):
                if header is None:
                    header = [h.strip() for h in row]
                    continue
                if len(row) != len(header):
                    raise ParameterError(f"{where} line {line}: {len(row)} values for {len(header)} columns")
                try:
                    values.extend(float(v) for v in row)
                except ValueError:
                    raise ParameterError(f"{where} line {line}: not all numbers: {row!r}") from None
    except OSError as exc:
        raise ParameterError(f"cannot read cases file {str(path)!r}: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ParameterError(f"{where} is not a readable CSV file: {exc}") from None
    if header is None or not values:
        raise ParameterError(f"{where} needs a header row and at least one case")
    return _table(header, np.frombuffer(values, dtype=float).reshape(-1, len(header)), where)


def _table(names: object, values: object, where: str) -> CaseTable:
    if not isinstance(names, Sequence) or isinstance(names, str) or not names:
        raise ParameterError(f"{where}: names must be a non-empty list of input names")
    names = tuple(str(n) for n in names)
    for name in names:
        _check_input(name, where)
    if len(set(names)) != len(names):
        raise ParameterError(f"{where}: an input appears twice in {', '.join(names)}")
    try:
        arr = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"{where}: values must be rows of numbers") from None
    if arr.ndim != 2 or arr.shape[1] != len(names) or len(arr) == 0:
        raise ParameterError(f"{where}: expected rows of {len(names)} numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{where}: values must be finite")
    for j, name in enumerate(names):
        _check_range(name, arr[:, j], f"{where}:")
    return CaseTable(names=names, values=arr)


def _axis(name: str, spec: object) -> Axis:
    _check_input(name, "vary")
    if isinstance(spec, Sequence) and not isinstance(spec, str):
        if not spec:
            raise ParameterError(f"vary {name}: the list of values is empty")
        return Axis(name=name, values=tuple(_check_number(v, f"vary {name}") for v in spec))
    if not isinstance(spec, Mapping):
        raise ParameterError(f"vary {name}: expected a list of values or {{from, to, num}}, got {spec!r}")
    extra = sorted(set(spec) - {"from", "to", "num", "scale"})
    if extra or "from" not in spec or "to" not in spec:
        raise ParameterError(f"vary {name}: expected keys from, to and optionally num, scale; got {sorted(spec)}")
    low = _check_number(spec["from"], f"vary {name} from")
    high = _check_number(spec["to"], f"vary {name} to")
    num = _whole(spec["num"], f"vary {name} num") if "num" in spec else None
    if num is not None and num < 1:
        raise ParameterError(f"vary {name}: num must be >= 1, got {num}")
    scale = spec.get("scale", "linear")
    if scale not in ("linear", "log"):
        raise ParameterError(f"vary {name}: scale must be linear or log, got {scale!r}")
    if scale == "log" and (low <= 0 or high <= 0):
        raise ParameterError(f"vary {name}: a log scale needs from and to > 0")
    return Axis(name=name, low=low, high=high, num=num, log=scale == "log")


def axis_mapping(axis: Axis) -> Any:
    """An axis as definition data (what ``from_mapping`` reads under ``vary``)."""
    if axis.values is not None:
        return list(axis.values)
    out: dict[str, Any] = {"from": axis.low, "to": axis.high}
    if axis.num is not None:
        out["num"] = axis.num
    if axis.log:
        out["scale"] = "log"
    return out


def _check_input(name: str, where: str) -> None:
    if name not in INPUT_NAMES:
        raise ParameterError(
            f"{where}: unknown input {name!r}{did_you_mean(name, INPUT_NAMES)}; allowed: any RigParams field "
            "(pendsim info), "
            f"{', '.join(STATE_INPUTS)}, or a drive's TARGET_amplitude_UNIT, TARGET_frequency_hz, TARGET_phase_rad "
            f"(TARGET: {', '.join(t.value for t in Target)})"
        )


def _check_range(name: str, value: float | FloatArray, where: str) -> None:
    """An input's values within its range (``pendsim_mj.rig.checks.INPUT_RANGES``, or a
    parameter's own), the message prefixed with ``where``; in an array (a cases file's column)
    each value's position is named as its case."""
    try:
        check_input(name, value)
    except ParameterError as exc:
        raise ParameterError(f"{where} {exc}") from None


def _check_number(value: object, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ParameterError(f"{what} must be a finite number, got {value!r}")
    return float(value)


def _float_text(text: str, name: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ParameterError(f"vary {name}: not a number: {text!r}") from None
    return _check_number(value, f"vary {name}")


def _whole(value: object, what: str) -> int:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or value != int(value)
    ):
        raise ParameterError(f"{what} must be a whole number, got {value!r}")
    return int(value)


def _text(value: object, what: str) -> str:
    if not isinstance(value, str):
        raise ParameterError(f"{what} must be text, got {value!r}")
    return value


def _names(value: object, what: str) -> list[str]:
    if isinstance(value, str):
        return [v.strip() for v in value.split(",") if v.strip()]
    if not isinstance(value, Sequence) or not all(isinstance(v, str) for v in value):
        raise ParameterError(f"{what} must be a list of names, got {value!r}")
    return list(value)


def elasticities(table: CaseTable, values: FloatArray) -> FloatArray:
    """Relative sensitivities of a sensitivity sweep: for each parameter p and feature column f,
    (f(p (1 + step)) - f(p (1 - step))) / (2 step f(base)) = d ln f / d ln p (central difference).

    Args:
      table: the cases of a sensitivity sweep (``varied`` and ``relative_change`` set).
      values: (ncases, k) feature values of those cases.

    Returns:
      (nparam, k), rows in the order of ``table.names``; NaN where f(base) is 0 or a value is NaN.
    """
    if table.varied is None or table.relative_change is None:
        raise ParameterError("elasticities need the cases of a sensitivity sweep")
    varied = np.array(table.varied)
    base = values[varied == ""][0]
    out = np.full((len(table.names), values.shape[1]), np.nan)
    for j, name in enumerate(table.names):
        rows = np.flatnonzero(varied == name)
        change = table.relative_change[rows]
        lo, hi = values[rows[np.argmin(change)]], values[rows[np.argmax(change)]]
        with np.errstate(divide="ignore", invalid="ignore"):
            out[j] = (hi - lo) / ((change.max() - change.min()) * base)
    out[~np.isfinite(out)] = np.nan
    return out
