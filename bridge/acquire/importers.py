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
import logging
import math
import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pendsim_mj import __version__
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.estimation.timing import nominal_rate_hz
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import STANDARD_GRAVITY_M_S2
from pendsim_mj.units import nanoseconds

from ..io.outputs import atomic_output
from ..io.recording_layout import IMPORT_METADATA, UNIX_2000_S, utc_iso
from .packets import (
    ACCEL_UNITS,
    COLUMN_NAMES,
    GROUP_SLICES,
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

IMPORT_FORMATS = ("csv", "lvm", "tdms")
SUFFIXES = {".csv": "csv", ".txt": "csv", ".lvm": "lvm", ".tdms": "tdms"}
TDMS_VERSIONS = (4712, 4713)  # the lead-in's version number: TDMS 1.0 and 2.0


@dataclasses.dataclass(frozen=True)
class Table:
    """A file's columns in file order: names and (n, ncols) float values; ``timing`` is the file's
    own sample spacing (s) and start offset (s) if it declares one; ``notes`` go to the metadata."""

    names: tuple[str, ...]
    values: NDArray[np.float64]
    timing: tuple[float, float] | None = None  # (delta_s, x0_s)
    notes: tuple[tuple[str, str], ...] = ()
    skipped: tuple[str, ...] = ()  # what reading left out, for the user (lines before the header, ...)
    lines: tuple[int, ...] | None = None  # the file line (1-based, all lines counted) of each row; None: no lines

    def where(self, row: int) -> str:
        """Where row ``row`` (0-based) is in the file, for messages: "line 12" (text files: the
        file's own line number, header and skipped lines counted) or "sample 12" (TDMS)."""
        if self.lines is not None and 0 <= row < len(self.lines):
            return f"line {self.lines[row]}"
        return f"sample {row + 1}"


@dataclasses.dataclass(frozen=True)
class ImportSpec:
    """How to read a file.

    Attributes:
      format: "csv", "lvm", "tdms", or None (from the extension).
      columns: one name per column (None: the file's own names).
      units: units of the values.
      node: the file holds this one node (names without the ``m1.`` prefix).
      rate_hz: sample rate when the file has no time column and no timing of its own.
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


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _fields(line: str, delimiter: str) -> list[str]:
    return [c.strip() for c in line.split(delimiter)]


def _first_data_line(lines: list[tuple[int, str]]) -> tuple[int, str] | None:
    """(index into lines, delimiter) of the first line whose fields are all numbers (two or more,
    with the delimiter that gives the most), or None."""
    for index, (_, line) in enumerate(lines):
        best = max((",", ";", "\t"), key=line.count)
        if line.count(best) and all(_is_number(c) for c in _fields(line.rstrip(best + " "), best)):
            return index, best
    return None


def read_csv(path: Path) -> Table:
    """A CSV file as a Table: a header row optional; lines before the header that are not data
    (a node's boot messages) skipped, an empty field after the last delimiter of a line ignored, a
    last line cut short (a logger stopped mid-line) dropped, each with a note."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise RecordingError(f"{path}: not UTF-8 text; is it a CSV file?") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None
    lines = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip() and not line.startswith("#")]
    if not lines:
        raise RecordingError(f"{path}: no data lines")
    found = _first_data_line(lines)
    if found is None:
        raise RecordingError(f"{path}: no data lines (no line of numbers separated by commas, semicolons or tabs)")
    first, delimiter = found
    notes: list[str] = []
    start = first
    if first > 0 and delimiter in lines[first - 1][1]:
        start = first - 1  # the header
    if start > 0:
        numbers = f"line {lines[0][0]}" if start == 1 else f"lines {lines[0][0]}-{lines[start - 1][0]}"
        notes.append(f"skipped {numbers} before the {'header' if start < first else 'data'}: not data")
    rows: list[tuple[int, list[str]]] = []
    trailing = 0
    for number, line in lines[start:]:
        body = line.rstrip()
        if body.endswith(delimiter) and delimiter.strip():
            body, trailing = body[: -len(delimiter)], trailing + 1
        rows.append((number, _fields(body, delimiter)))
    if trailing:
        notes.append(f"{trailing} line(s) end in {delimiter!r}: the empty field after it is not a column")
    head = rows[0][1]
    header = start < first
    names = tuple(head) if header else tuple(f"column{i + 1}" for i in range(len(head)))
    data = rows[1:] if header else rows
    if data:  # a last line cut short: fewer fields, or its last field not (yet) a number
        number, parts = data[-1]
        short = len(parts) < len(names) or (
            len(parts) == len(names) and not _is_number(parts[-1]) and all(_is_number(p) for p in parts[:-1])
        )
        if short:
            why = f"{len(parts)} of {len(names)} fields" if len(parts) < len(names) else f"ends in {parts[-1]!r}"
            if len(data) == 1:
                raise RecordingError(f"{path}: no complete data line (line {number} is cut short: {why})")
            notes.append(f"dropped the last line {number}: cut short ({why})")
            data = data[:-1]
    if not data:
        raise RecordingError(f"{path}: a header but no data lines")
    try:  # numpy's conversion; the loop below finds the line to blame when it fails
        values = np.array([parts for _, parts in data], dtype=float)
        if values.shape == (len(data), len(names)):
            return Table(names, values, skipped=tuple(notes), lines=tuple(number for number, _ in data))
    except ValueError:
        pass
    values = np.empty((len(data), len(names)))
    for r, (number, parts) in enumerate(data):
        if len(parts) != len(names):
            first_line = "header" if header else "first line"
            raise RecordingError(f"{path}: line {number} has {len(parts)} fields, the {first_line} {len(names)}")
        try:
            values[r] = [float(p) for p in parts]
        except ValueError:
            k = next(i for i, p in enumerate(parts) if not _is_number(p))
            what = f"column {k + 1} ({names[k]!r})" if header else f"column {k + 1}"
            raise RecordingError(f"{path}: line {number}, {what}: {parts[k]!r} is not a number") from None
    return Table(names, values, skipped=tuple(notes), lines=tuple(number for number, _ in data))


def _lvm_data_lines(path: Path, rows: int) -> tuple[int, ...] | None:
    """The file lines (1-based) of the first segment's ``rows`` data rows: the non-empty lines
    after the channel-name line that follows the second ``***End_of_Header***``; None if the file
    does not have that layout."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return None
    ends = [i for i, line in enumerate(text) if line.startswith("***End_of_Header***")]
    if len(ends) < 2:
        return None
    found = [i + 1 for i in range(ends[1] + 2, len(text)) if text[i].strip()][:rows]
    return tuple(found) if len(found) == rows else None


def read_lvm(path: Path) -> Table:
    """A LabVIEW measurement file's first segment as a Table."""
    import lvm_read  # only for .lvm files

    try:
        # Never the pickle cache beside the user's file: read the text, write nothing.
        lvm = lvm_read.read(str(path), read_from_pickle=False, dump_file=False)
    except (ValueError, IndexError, KeyError, SyntaxError) as exc:
        why = re.sub(r"\s*If the header has no .*", "", str(exc), flags=re.S).rstrip(". ")  # advice for lvm-read's API
        raise RecordingError(
            f"{path}: not a LabVIEW measurement file ({why}); import reads .lvm files as LabVIEW writes them: a "
            "'LabVIEW Measurement' header whose Separator (Tab or Comma) splits the data; a plain table is --format csv"
        ) from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None
    segment = lvm.get(0)
    if not isinstance(segment, dict) or "Channel names" not in segment:
        raise RecordingError(f"{path}: no data segment with channel names (is it an .lvm file?)")
    names = [str(n).strip() for n in segment["Channel names"]]
    data = np.atleast_2d(np.asarray(segment["data"], dtype=float))
    if names and names[-1] == "Comment":
        names = names[:-1]
    data = data[:, : len(names)]
    if data.shape[1] != len(names) or not len(data):
        raise RecordingError(f"{path}: {data.shape[1]} data columns for {len(names)} channel names")
    timing = None
    if "X_Value" not in names and segment.get("Delta_X"):
        deltas = [d for d in segment["Delta_X"] if isinstance(d, (int, float)) and math.isfinite(d)]
        x0 = [x for x in segment.get("X0", [0.0]) if isinstance(x, (int, float)) and math.isfinite(x)]
        if deltas and deltas[0] > 0:
            timing = (float(deltas[0]), float(x0[0]) if x0 else 0.0)
    notes = tuple((f"lvm_{key.lower()}", str(lvm[key])) for key in ("Date", "Time", "Operator") if key in lvm)
    return Table(tuple(names), data, timing, notes, lines=_lvm_data_lines(path, len(data)))


def read_tdms(path: Path) -> Table:
    """Every channel of a TDMS file (``GROUP/CHANNEL``) as a Table."""
    from nptdms import TdmsFile  # only for .tdms files

    try:
        with open(path, "rb") as f:
            lead_in = f.read(12)
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None
    if len(lead_in) < 12 or lead_in[:4] != b"TDSm" or int.from_bytes(lead_in[8:12], "little") not in TDMS_VERSIONS:
        raise RecordingError(f"{path}: not a TDMS file (no TDMS 2.0 lead-in)")
    quiet = logging.getLogger("nptdms")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # its warnings about damaged segments become our one-line error
    try:
        tdms = TdmsFile.read(str(path))
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except Exception as exc:  # npTDMS raises ValueError, KeyError, struct.error ... on foreign input
        raise RecordingError(f"{path}: not a TDMS file ({type(exc).__name__}: {exc})") from None
    finally:
        quiet.setLevel(level)
    names, columns, timing = [], [], None
    for group in tdms.groups():
        for channel in group.channels():
            data = np.asarray(channel[:])
            if data.dtype.kind not in "iuf":
                raise RecordingError(f"{path}: channel {group.name}/{channel.name} is not numeric ({data.dtype})")
            names.append(f"{group.name}/{channel.name}")
            columns.append(data.astype(float))
            increment = channel.properties.get("wf_increment")
            if timing is None and increment:
                timing = (float(increment), float(channel.properties.get("wf_start_offset", 0.0)))
    if not columns:
        raise RecordingError(f"{path}: a TDMS file with no channels")
    lengths = {len(c) for c in columns}
    if len(lengths) != 1:
        raise RecordingError(f"{path}: channels have different lengths ({', '.join(map(str, sorted(lengths)))})")
    notes = tuple(
        (f"tdms_{k}", str(v)) for k, v in tdms.properties.items() if isinstance(v, (str, int, float, np.datetime64))
    )
    return Table(tuple(names), np.stack(columns, axis=1), timing, notes)


READERS = {"csv": read_csv, "lvm": read_lvm, "tdms": read_tdms}


# -- the column map ---------------------------------------------------------------------------

_NAME = re.compile(r"^(?:(m[12])\.)?([a-z_]+)$")


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
            raise ParameterError(f"column {i + 1} {entry!r} is not a pendsim name (t_s, m1.gx, ...){hint}")
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
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        raise RecordingError(
            f"{path}: time does not increase at {table.where(back[0] + 1)} ({t[back[0]]:g} s, then "
            f"{t[back[0] + 1]:g} s)"
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


ACCEL_G_RANGE = (0.5, 2.0)
"""A file's median acceleration magnitude outside this range of g is noted as a likely unit mix-up
(a node at rest reads 1 g; a swinging pendulum stays within it over most of a run)."""


def data_notes(groups: tuple[str, ...], rows: list[NDArray[np.float64]], units: Units) -> list[str]:
    """Notes on what the imported values cannot serve or look wrong: no orientation (validate,
    identify and view need it), or a median acceleration far from g (the --units wrong).

    Args:
      groups: the quantities the file carries (``packets.GROUPS`` names).
      rows: per node (n, len(ROW_FIELDS)) values in SI units.
      units: the units the values were read in.
    """
    notes = []
    if "quat" not in groups:
        notes.append(
            "no orientation (quaternion columns qw,qx,qy,qz): validate, identify and view need it; "
            "inspect and allan read the recording"
        )
    group = "accel" if "accel" in groups else "gravity" if "gravity" in groups else None
    if group is not None:
        magnitude = np.concatenate([np.linalg.norm(r[:, GROUP_SLICES[group]], axis=1) for r in rows])
        median = float(np.median(magnitude))
        low, high = (f * STANDARD_GRAVITY_M_S2 for f in ACCEL_G_RANGE)
        if not low <= median <= high:
            raw = median / ACCEL_UNITS[units.accel]  # in the file's own numbers
            fits = [u for u, scale in ACCEL_UNITS.items() if low <= raw * scale <= high and u != units.accel]
            hint = f"are the values in {fits[0]}? give --units accel={fits[0]}" if fits else "check --units accel"
            notes.append(
                f"the median {'acceleration' if group == 'accel' else 'gravity'} magnitude is {median:.3g} m/s2 "
                f"(read as accel={units.accel}), far from g = {STANDARD_GRAVITY_M_S2:.2f} m/s2 as at rest: {hint}"
            )
    return notes


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
    mapped = map_columns(table.names, spec.columns, spec.node)
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
    notes += data_notes(mapped[0].groups, [rows for _, rows, _ in per_node.values()], spec.units)
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
