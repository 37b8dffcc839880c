"""``pendsim import``: lab files (CSV, LabVIEW .lvm, TDMS) into a pendsim recording.

Each file becomes a table of named columns in file order:

- **CSV**: comma, semicolon or tab separated (found from the first line of numbers), an optional
  header row (names), lines starting with ``#`` skipped; lines before the header that are not
  data, an empty field after a delimiter ending a line and a last line cut short are left out,
  each with a note.
- **LabVIEW measurement file** (``.lvm``, read with ``lvm-read``): the first segment's channels
  (``X_Value`` included when the file has an X column; a ``Comment`` column is dropped); the
  header's date and time go to the metadata.
- **TDMS** (read with ``npTDMS``): every channel as ``GROUP/CHANNEL``, all of one length.

A column map names what each column holds, one entry per column (``_`` skips one): a time column
``t_s``, ``t_ms`` or ``t_us``, and per node ``m1.gx`` ... (``packets.COLUMN_NAMES``; the node prefix
is left out with ``--node m1`` for a file of one node). A time column may belong to a node
(``m1.t_s``). Without a time column, the file's own waveform timing is used (LVM X0/Delta_X, TDMS
wf_increment), else a uniform ``rate_hz``. Units as for acquisition (``accel=m/s2,gyro=dps``).
Every value must be a finite number, times must increase, quaternions must be unit length and
calibration levels 0-3: anything else is an error naming the file line (or TDMS sample) and column.
A file without orientation, or whose median acceleration is far from g (a unit mix-up), is noted.
The sample rate in the metadata is ``timing.nominal_rate_hz`` of the first node's times.

Log times are the file's times, taken as UTC when they are Unix times; with ``start_utc_ns`` the
first sample is at that instant (for times counted from a node's boot). /tf_static is at the
first sample. The recording has the layout of ``pendsim record`` (``acquire.sink``), with
metadata ``pendsim/import`` naming the source file (path, size, SHA-256, format, map, units,
time base, notes).
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import math
import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pendsim_mj import __version__
from pendsim_mj.errors import ParameterError, RecordingError, did_you_mean
from pendsim_mj.estimation.timing import nominal_rate_hz
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import ACCEL_LSB_M_S2
from pendsim_mj.units import nanoseconds

from ..io.outputs import atomic_output
from ..io.recording_layout import IMPORT_METADATA, UNIX_2000_S, utc_iso
from .lab_files import MAX_TIME_S, READERS, Table
from .packets import (
    ACCEL_UNITS,
    COLUMN_NAMES,
    GROUP_SLICES,
    GROUPS,
    GYRO_UNITS,
    QUAT_NORM_RANGE,
    ROW_FIELDS,
    ROW_INDEX,
    TIME_COLUMNS,
    Units,
    calib_levels,
    groups_of,
)
from .ports import BNO055_NDOF, NODE_NAMES
from .sink import RecordingSink
from .unit_check import check_units

IMPORT_FORMATS = ("csv", "lvm", "tdms")
SUFFIXES = {".csv": "csv", ".txt": "csv", ".lvm": "lvm", ".tdms": "tdms"}


@dataclasses.dataclass(frozen=True)
class ImportSpec:
    """How to read a file.

    Attributes:
      format: "csv", "lvm", "tdms", or None (from the extension).
      columns: one name per column (None: the file's own names).
      units: units of the values.
      node: the file holds this one node (names without the ``m1.`` prefix).
      rate_hz: sample rate when the file has no time column and no timing of its own.
      trust_units: import with ``units`` even where the data's physics contradict them (a unit
        mix-up becomes a warning, recorded in the metadata, instead of an error).
      start_utc_ns: the UTC time of the file's first sample, ns since 1970 (None: the file's own
        times, taken as UTC when they are Unix times from 2000 on, else as relative: counted from
        the node's boot or the file's zero).
      params, mjcf_xml, mjcf_source: the rig to record with the data.
      compression: chunk compression.
    """

    format: str | None = None
    columns: tuple[str, ...] | None = None
    units: Units = dataclasses.field(default_factory=Units)
    node: str | None = None
    rate_hz: float | None = None
    start_utc_ns: int | None = None
    trust_units: bool = False
    params: RigParams = DEFAULT_PARAMS
    mjcf_xml: str | None = None
    mjcf_source: str = "built by pendsim from the rig parameters"
    compression: str = "zstd"

    def __post_init__(self) -> None:
        if self.format is not None and self.format not in IMPORT_FORMATS:
            raise ParameterError(f"unknown import format {self.format!r}; allowed: {', '.join(IMPORT_FORMATS)}")
        if self.node is not None and self.node not in NODE_NAMES:
            raise ParameterError(f"unknown node {self.node!r}; allowed: {', '.join(NODE_NAMES)}")
        if self.rate_hz is not None and not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ParameterError(f"rate_hz must be a finite number > 0 Hz, got {self.rate_hz!r}")
        if self.start_utc_ns is not None and not 0 <= self.start_utc_ns < 2**63 - 10**18:
            raise ParameterError(f"the start time must be from 1970 on, got {self.start_utc_ns!r} ns")


@dataclasses.dataclass(frozen=True)
class ImportResult:
    path: Path
    source: Path
    format: str
    samples: dict[str, int]  # per node
    duration_s: float
    size_bytes: int
    notes: tuple[str, ...] = ()  # for the user: what was left out, how the times were read
    warnings: tuple[str, ...] = ()  # what the data contradict and was imported as given (--trust-units)


def format_of(path: Path, given: str | None) -> str:
    if given is not None:
        return given
    found = SUFFIXES.get(path.suffix.lower())
    if found is None:
        raise ParameterError(
            f"{path}: cannot tell the format from the extension {path.suffix!r}; give --format "
            f"({', '.join(IMPORT_FORMATS)})"
        )
    return found


# -- reading tables ---------------------------------------------------------------------------


# -- the column map ---------------------------------------------------------------------------

_NAME = re.compile(r"^(?:(m[12])\.)?([a-z_]+)$")
KNOWN_COLUMNS = (
    *TIME_COLUMNS,
    *(f"m{n}.{name}" for n in (1, 2) for name in COLUMN_NAMES if name not in (*TIME_COLUMNS, "seq", "node", "_")),
)
"""Every column name a table may carry (a misspelt one is told its likely spelling)."""


@dataclasses.dataclass(frozen=True)
class NodeColumns:
    """Which table column holds each quantity of one node (and its time column, if any)."""

    node: str
    time: tuple[int, str] | None  # (column, name)
    quantities: dict[str, int]  # ROW_FIELDS name or "calib" -> column
    groups: tuple[str, ...]


def map_columns(names: tuple[str, ...], columns: tuple[str, ...] | None, node: str | None) -> list[NodeColumns]:
    """Resolve the column map against a table's names."""
    given = columns if columns is not None else names
    if len(given) != len(names):
        raise ParameterError(f"the column map has {len(given)} entries, the file {len(names)} columns")
    shared_time: tuple[int, str] | None = None
    per_node: dict[str, dict[str, int]] = {}
    times: dict[str, tuple[int, str]] = {}
    for i, entry in enumerate(given):
        entry = entry.strip()
        if entry == "_":
            continue
        m = _NAME.match(entry)
        prefix, name = (m.group(1), m.group(2)) if m else (None, entry)
        if m is None or name not in COLUMN_NAMES or name in ("seq", "node", "_"):
            hint = "" if columns is not None else "; give --columns (one name per column, _ to skip)"
            spelt = did_you_mean(entry, KNOWN_COLUMNS)
            raise ParameterError(f"column {i + 1} {entry!r} is not a pendsim name{spelt} (t_s, m1.gx, ...){hint}")
        owner = prefix or node
        if name in TIME_COLUMNS:
            if owner is None:
                if shared_time is not None:
                    raise ParameterError(f"two time columns: {shared_time[1]!r} and {entry!r}")
                shared_time = (i, name)
            else:
                if owner in times:
                    raise ParameterError(f"two time columns for {owner}")
                times[owner] = (i, name)
            continue
        if owner is None:
            raise ParameterError(f"column {entry!r}: say which node (m1.{name} or m2.{name}), or give --node")
        if node is not None and prefix is not None and prefix != node:
            raise ParameterError(f"column {entry!r} belongs to {prefix}, but --node {node} says the file holds {node}")
        quantities = per_node.setdefault(owner, {})
        if name in quantities:
            raise ParameterError(f"{owner}.{name} appears twice in the column map")
        quantities[name] = i
    if not per_node:
        raise ParameterError("the column map names no sensor quantity (e.g. m1.gx,m1.gy,m1.gz)")
    out = []
    for owner in sorted(per_node):
        try:
            groups = groups_of(list(per_node[owner]))
        except ParameterError as exc:
            raise ParameterError(f"{owner}: {exc}") from None
        if not groups:
            raise ParameterError(f"{owner}: no complete quantity (e.g. {owner}.gx,{owner}.gy,{owner}.gz)")
        out.append(NodeColumns(owner, times.get(owner, shared_time), per_node[owner], groups))
    if len({c.groups for c in out}) > 1:
        raise ParameterError(
            "the nodes carry different quantities (" + "; ".join(f"{c.node}: {', '.join(c.groups)}" for c in out) + ")"
        )
    return out


def _times_s(path: Path, table: Table, columns: NodeColumns, rate_hz: float | None) -> tuple[NDArray[np.float64], str]:
    if columns.time is not None:
        index, name = columns.time
        t = np.asarray(table.values[:, index] * (TIME_COLUMNS[name] * 1e-6), dtype=np.float64)
        return t, f"column {table.names[index]!r} as {name}"
    if table.timing is not None and rate_hz is None:
        delta, x0 = table.timing
        return np.asarray(
            x0 + delta * np.arange(len(table.values)), dtype=np.float64
        ), f"the file's timing: start {x0:g} s, step {delta:g} s"
    if rate_hz is None:
        raise ParameterError(
            f"{path}: no time column (t_s, t_ms or t_us in the map) and no timing in the file; give --rate-hz"
        )
    return np.asarray(np.arange(len(table.values)) / rate_hz, dtype=np.float64), f"uniform at {rate_hz:g} Hz"


def node_samples(
    path: Path, table: Table, columns: NodeColumns, units: Units, rate_hz: float | None
) -> tuple[NDArray[np.float64], NDArray[np.float64], str]:
    """(t_s (n,), rows (n, len(ROW_FIELDS)) in SI, how time was found) of one node, checked."""
    t, timing = _times_s(path, table, columns, rate_hz)
    scales = units.scales()
    rows = np.full((len(t), len(ROW_FIELDS)), np.nan)
    for name, index in columns.quantities.items():
        column = table.values[:, index]
        bad = np.flatnonzero(~np.isfinite(column))
        if len(bad):
            raise RecordingError(f"{path}: {table.where(bad[0])}, column {table.names[index]!r}: not a finite number")
        if name == "calib":
            if np.any((column != np.rint(column)) | (column < 0) | (column > 255)):
                raise RecordingError(f"{path}: column {table.names[index]!r}: CALIB_STAT must be an integer 0-255")
            levels = np.array([calib_levels(int(v)) for v in column], dtype=float)
            rows[:, GROUP_SLICES["calib"]] = levels
        else:
            rows[:, ROW_INDEX[name]] = column * scales[ROW_INDEX[name]]
    bad_t = np.flatnonzero(~np.isfinite(t))
    if len(bad_t):
        raise RecordingError(f"{path}: {table.where(bad_t[0])}: the time is not a finite number")
    far = np.flatnonzero(np.abs(t) > MAX_TIME_S)
    if len(far):
        raise RecordingError(
            f"{path}: {table.where(far[0])}: the time {t[far[0]]:.6g} s is out of range (allowed: within "
            f"+-{MAX_TIME_S:g} s, Unix time up to the year 2096); is the time column's unit right (t_s, t_ms, t_us)?"
        )
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        where = table.where(back[0] + 1)
        raise RecordingError(
            f"{path}: time does not increase at {where}: {times_going_back(*t[back[0] : back[0] + 2])}"
        )
    if "quat" in columns.groups:
        norm = np.linalg.norm(rows[:, GROUP_SLICES["quat"]], axis=1)
        off = np.flatnonzero((norm < QUAT_NORM_RANGE[0]) | (norm > QUAT_NORM_RANGE[1]))
        if len(off):
            raise RecordingError(f"{path}: {table.where(off[0])}: the quaternion has norm {norm[off[0]]:.3g}, not 1")
    if "calib" in columns.groups:
        levels = rows[:, GROUP_SLICES["calib"]]
        if np.any(~np.isin(levels, (0.0, 1.0, 2.0, 3.0))):
            raise RecordingError(f"{path}: calibration levels must be 0-3")
    return t, rows, timing


def times_going_back(before_s: float, after_s: float) -> str:
    """Two times that do not increase, readable: "t = 1712345678.123456 s, then 1712345678.100000 s
    (23.456 ms back)", with as many decimals as show the difference (microseconds at least)."""
    step = before_s - after_s
    shown = step * 1.001  # a step of 1 us read from a millisecond column is 0.999999 us in binary
    decimals = 6 if step == 0 else min(12, max(6, 1 - math.floor(math.log10(shown))))
    if step == 0:
        how = "the same time twice"
    else:
        units = (("s", 1.0), ("ms", 1e-3), ("us", 1e-6))
        unit, scale = next(((u, f) for u, f in units if shown >= f), ("ns", 1e-9))
        how = f"{step / scale:.5g} {unit} back"
    return f"t = {before_s:.{decimals}f} s, then {after_s:.{decimals}f} s ({how})"


GYRO_LIMIT_RAD_S = math.radians(32767 / 16)
"""The largest rate a BNO055 reports: its int16 register at 16 LSB per dps (2048 dps, 35.7 rad/s)."""
ACCEL_LIMIT_M_S2 = 32767 * ACCEL_LSB_M_S2
"""The largest acceleration a BNO055 reports: its int16 register at 100 LSB per m/s2 (327.67 m/s2, 33 g)."""


def out_of_range(
    path: Path, table: Table, columns: NodeColumns, rows: NDArray[np.float64], units: Units
) -> tuple[str, str, float] | None:
    """(message, quantity, its largest magnitude) for the first gyro or acceleration value beyond
    what a BNO055 can report (``GYRO_LIMIT_RAD_S``, ``ACCEL_LIMIT_M_S2``), naming its line and
    column; None if every value is within range."""
    for name, index in columns.quantities.items():
        if name == "calib":
            continue
        group = next(g for g, members in GROUPS.items() if name in members)
        if group == "quat":
            continue
        gyro = group == "gyro"
        limit = GYRO_LIMIT_RAD_S if gyro else ACCEL_LIMIT_M_S2
        values = np.abs(rows[:, ROW_INDEX[name]])
        over = np.flatnonzero(values > limit)
        if len(over):
            value, unit = float(rows[over[0], ROW_INDEX[name]]), "rad/s" if gyro else "m/s2"
            read = f"gyro={units.gyro}" if gyro else f"accel={units.accel}"
            chip = "2048 dps = 35.7 rad/s" if gyro else "327.67 m/s2 = 33.4 g"
            return (
                f"{path}: {table.where(over[0])}, column {table.names[index]!r}: {value:.6g} {unit} (read as {read}) "
                f"is beyond what a BNO055 can report ({chip})",
                "gyro" if gyro else "accel",
                float(np.max(values)),
            )
    return None


def _units_in_range(quantity: str, largest_si: float, units: Units) -> list[str]:
    """The units that would put ``largest_si`` (as read in ``units``) within the chip's range."""
    table, given = (GYRO_UNITS, units.gyro) if quantity == "gyro" else (ACCEL_UNITS, units.accel)
    limit = GYRO_LIMIT_RAD_S if quantity == "gyro" else ACCEL_LIMIT_M_S2
    return [u for u, scale in table.items() if u != given and largest_si / table[given] * scale <= limit]


def check_values(
    path: Path,
    table: Table,
    mapped: list[NodeColumns],
    per_node: dict[str, tuple[NDArray[np.float64], NDArray[np.float64], str]],
    units: Units,
    *,
    trust_units: bool = False,
) -> tuple[list[str], list[str], dict[str, str]]:
    """The physics of the values against their units (``unit_check.check_units``) and the chip's
    ranges: (notes, warnings, metadata entries).

    Raises:
      RecordingError: a unit mix-up (unless ``trust_units``: then a warning), or a value beyond what a
        BNO055 can report (always).
    """
    groups = mapped[0].groups
    with np.errstate(all="ignore"):  # absurd values are named by the range check below
        found = check_units({n: (t, rows) for n, (t, rows, _) in per_node.items()}, groups, units)
    notes, warnings = list(found.notes), []
    if "quat" not in groups:
        notes.insert(
            0,
            "no orientation (quaternion columns qw,qx,qy,qz): validate, identify and view need it; "
            "inspect and allan read the recording",
        )
    advice = found.advice(units)
    if found.mismatches and not trust_units:
        raise RecordingError(
            f"{path}: the units do not fit the data: {found.describe(units)}: {advice} (or --trust-units to "
            "import with the units given)"
        )
    for columns in mapped:
        rows = per_node[columns.node][1]
        problem = out_of_range(path, table, columns, rows, units)
        if problem is not None:
            message, quantity, largest = problem
            fits = _units_in_range(quantity, largest, units)
            hint = f"; in {' or '.join(fits)} every value would be within it: check --units" if fits else ""
            raise RecordingError(message + hint)
    if found.mismatches:
        warnings.append(
            f"the units do not fit the data: {found.describe(units)}; imported as given (--trust-units; {advice})"
        )
    metadata = {"units_check": "; ".join(found.checks) or "nothing to check"}
    if found.mismatches:
        metadata["units_trusted_over"] = found.describe(units)
    return notes, warnings, metadata


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def import_file(
    source: str | Path, output: str | Path, spec: ImportSpec = ImportSpec(), *, replace: bool = False
) -> ImportResult:
    """Read ``source`` and write it as a pendsim recording ``output`` (published when complete).

    Raises:
      ParameterError: a bad column map, units or format.
      RecordingError: the file is not what it claims or holds bad values (nothing is written).
      OutputError: the output exists (without ``replace``) or cannot be written.
    """
    from pendsim_mj.rig.model import exact_mjcf  # MuJoCo: only when an import runs

    source, output = Path(source), Path(output)
    fmt = format_of(source, spec.format)
    table = READERS[fmt](source)
    try:
        mapped = map_columns(table.names, spec.columns, spec.node)
    except ParameterError as exc:  # the file's own header (or --columns against it): name the file
        where = "" if spec.columns is None else " (--columns)"
        raise ParameterError(f"{source}{where}: {exc}") from None
    per_node = {c.node: node_samples(source, table, c, spec.units, spec.rate_hz) for c in mapped}
    t0 = min(float(t[0]) for t, _, _ in per_node.values())
    timings = {node: how for node, (_, _, how) in per_node.items()}
    notes = list(table.skipped)
    if spec.start_utc_ns is not None:  # the first sample at the given instant
        base_ns, shift_s, time_base = spec.start_utc_ns, -t0, f"utc: the first sample at {utc_iso(spec.start_utc_ns)}"
    elif t0 >= UNIX_2000_S:
        base_ns, shift_s, time_base = 0, 0.0, "utc: the file's times are Unix times"
    else:
        base_ns, shift_s = 0, -t0 if t0 < 0 else 0.0  # log times are not negative
        time_base = "relative: the file's own times (e.g. from the node's boot), not UTC"
        notes.append(
            f"the times are not UTC (the first is {t0:g} s): log times count from the file's zero; "
            "--start-utc places the first sample in time"
        )
    if len(per_node) == 1:
        notes.append(
            f"one node ({next(iter(per_node))}): inspect and allan read the recording; validate, identify and view "
            "need both nodes"
        )
    found, warnings, checked = check_values(source, table, mapped, per_node, spec.units, trust_units=spec.trust_units)
    notes += found
    first_t = next(iter(per_node.values()))[0]
    rate = round(nominal_rate_hz(first_t), 6) if len(first_t) > 1 else 0.0
    metadata = {
        IMPORT_METADATA: {
            "source_file": str(source.resolve()),
            "source_name": source.name,
            "source_size_bytes": str(source.stat().st_size),
            "source_sha256": _sha256(source),
            "format": fmt,
            "columns": ",".join(spec.columns if spec.columns is not None else table.names),
            "units": spec.units.describe(),
            "time": "; ".join(f"{n}: {how}" for n, how in timings.items()),
            "time_shift_s": repr(shift_s),
            "time_base": time_base,
            **({"notes": "; ".join(notes)} if notes else {}),
            **checked,
            "pendsim_version": __version__,
            "mjcf": spec.mjcf_source,
            **dict(table.notes),
        },
        "pendsim/imu": {"sample_rate_hz": repr(rate), **BNO055_NDOF},
    }
    mjcf = spec.mjcf_xml if spec.mjcf_xml is not None else exact_mjcf(spec.params)
    log_ns = {node: base_ns + nanoseconds(t + shift_s) for node, (t, _, _) in per_node.items()}
    with atomic_output(output, replace=replace) as tmp:
        sink = RecordingSink(
            tmp,
            nodes=tuple(per_node),
            groups=mapped[0].groups,
            params=spec.params,
            mjcf_xml=mjcf,
            metadata=metadata,
            start_time_ns=min(int(t[0]) for t in log_ns.values()),  # /tf_static with the first sample
            compression=spec.compression,
        )
        for node, (_, rows, _) in per_node.items():
            sink.add_samples(node, log_ns[node], rows)
        sink.close()
    duration = max(float(t[-1] - t[0]) for t, _, _ in per_node.values())
    return ImportResult(
        output,
        source,
        fmt,
        {n: len(t) for n, (t, _, _) in per_node.items()},
        duration,
        output.stat().st_size,
        tuple(notes),
        tuple(warnings),
    )


def parse_utc(text: str) -> int:
    """An ISO 8601 time with its zone (``2026-11-25T10:00:00Z``, ``...+01:00``) as ns since 1970."""
    try:
        moment = datetime.datetime.fromisoformat(text.strip())
    except ValueError:
        raise ParameterError(f"{text!r} is not an ISO 8601 time such as 2026-11-25T10:00:00Z") from None
    if moment.tzinfo is None:
        raise ParameterError(f"{text!r} has no time zone: end it in Z (UTC) or an offset such as +01:00")
    since = moment - datetime.datetime(1970, 1, 1, tzinfo=datetime.UTC)
    if since < datetime.timedelta(0):
        raise ParameterError(f"{text!r} is before 1970")
    return since // datetime.timedelta(microseconds=1) * 1000
