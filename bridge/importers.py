"""``pendsim import``: lab files (CSV, LabVIEW .lvm, TDMS) into a pendsim recording.

Each file becomes a table of named columns in file order:

- **CSV**: comma, semicolon or tab separated (found from the first line), an optional header row
  (names), lines starting with ``#`` skipped.
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
calibration levels 0-3: anything else is an error naming the row and column.

The recording has the layout of ``pendsim record`` (``acquire.sink``), with metadata
``pendsim/import`` naming the source file (path, size, SHA-256, format, map, units).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import math
import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pendsim_bridge.acquire.packets import (
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
from pendsim_bridge.acquire.ports import BNO055_NDOF, NODE_NAMES
from pendsim_mj import __version__
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.outputs import atomic_output
from pendsim_mj.params import DEFAULT_PARAMS, RigParams

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


@dataclasses.dataclass(frozen=True)
class ImportSpec:
    """How to read a file.

    Attributes:
      format: "csv", "lvm", "tdms", or None (from the extension).
      columns: one name per column (None: the file's own names).
      units: units of the values.
      node: the file holds this one node (names without the ``m1.`` prefix).
      rate_hz: sample rate when the file has no time column and no timing of its own.
      params, mjcf_xml, mjcf_source: the rig to record with the data.
      compression: chunk compression.
    """

    format: str | None = None
    columns: tuple[str, ...] | None = None
    units: Units = dataclasses.field(default_factory=Units)
    node: str | None = None
    rate_hz: float | None = None
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


@dataclasses.dataclass(frozen=True)
class ImportResult:
    path: Path
    source: Path
    format: str
    samples: dict[str, int]  # per node
    duration_s: float
    size_bytes: int


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


def read_csv(path: Path) -> Table:
    """A CSV file as a Table (header row optional)."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise RecordingError(f"{path}: not UTF-8 text; is it a CSV file?") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None
    lines = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip() and not line.startswith("#")]
    if not lines:
        raise RecordingError(f"{path}: no data lines")
    first = lines[0][1]
    delimiter = max((",", ";", "\t"), key=first.count)
    head = [c.strip() for c in first.split(delimiter)]
    header = not all(_is_number(c) for c in head)
    names = tuple(head) if header else tuple(f"column{i + 1}" for i in range(len(head)))
    rows = lines[1:] if header else lines
    if not rows:
        raise RecordingError(f"{path}: a header but no data lines")
    try:  # numpy's C parser; the loop below finds the line to blame when it fails
        values = np.loadtxt(io.StringIO("\n".join(line for _, line in rows)), delimiter=delimiter, ndmin=2)
        if values.shape[1] == len(names):
            return Table(names, values)
    except ValueError:
        pass
    values = np.empty((len(rows), len(names)))
    for r, (number, line) in enumerate(rows):
        parts = line.split(delimiter)
        if len(parts) != len(names):
            raise RecordingError(f"{path}: line {number} has {len(parts)} fields, the header {len(names)}")
        try:
            values[r] = [float(p) for p in parts]
        except ValueError:
            bad = next(p for p in parts if not _is_number(p))
            raise RecordingError(f"{path}: line {number}: {bad.strip()!r} is not a number") from None
    return Table(names, values)


def read_lvm(path: Path) -> Table:
    """A LabVIEW measurement file's first segment as a Table."""
    import lvm_read

    try:
        # Never the pickle cache beside the user's file: read the text, write nothing.
        lvm = lvm_read.read(str(path), read_from_pickle=False, dump_file=False)
    except (ValueError, IndexError, KeyError, SyntaxError) as exc:
        raise RecordingError(f"{path}: not a LabVIEW measurement file ({exc})") from None
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
    return Table(tuple(names), data, timing, notes)


def read_tdms(path: Path) -> Table:
    """Every channel of a TDMS file (``GROUP/CHANNEL``) as a Table."""
    import logging

    from nptdms import TdmsFile

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
            raise RecordingError(f"{path}: row {bad[0] + 1}, column {table.names[index]!r}: not a finite number")
        if name == "calib":
            if np.any((column != np.rint(column)) | (column < 0) | (column > 255)):
                raise RecordingError(f"{path}: column {table.names[index]!r}: CALIB_STAT must be an integer 0-255")
            levels = np.array([calib_levels(int(v)) for v in column], dtype=float)
            rows[:, GROUP_SLICES["calib"]] = levels
        else:
            rows[:, ROW_INDEX[name]] = column * scales[ROW_INDEX[name]]
    if not np.all(np.isfinite(t)):
        raise RecordingError(f"{path}: the time column holds a value that is not a finite number")
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        raise RecordingError(
            f"{path}: time does not increase at row {back[0] + 2} ({t[back[0]]:g} s, then {t[back[0] + 1]:g} s)"
        )
    if "quat" in columns.groups:
        norm = np.linalg.norm(rows[:, GROUP_SLICES["quat"]], axis=1)
        off = np.flatnonzero((norm < QUAT_NORM_RANGE[0]) | (norm > QUAT_NORM_RANGE[1]))
        if len(off):
            raise RecordingError(f"{path}: row {off[0] + 1}: the quaternion has norm {norm[off[0]]:.3g}, not 1")
    if "calib" in columns.groups:
        levels = rows[:, GROUP_SLICES["calib"]]
        if np.any(~np.isin(levels, (0.0, 1.0, 2.0, 3.0))):
            raise RecordingError(f"{path}: calibration levels must be 0-3")
    return t, rows, timing


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
    from pendsim_bridge.acquire.sink import RecordingSink
    from pendsim_mj.model import exact_mjcf

    source, output = Path(source), Path(output)
    fmt = format_of(source, spec.format)
    table = READERS[fmt](source)
    mapped = map_columns(table.names, spec.columns, spec.node)
    per_node = {c.node: node_samples(source, table, c, spec.units, spec.rate_hz) for c in mapped}
    t0 = min(float(t[0]) for t, _, _ in per_node.values())
    shift_s = -t0 if t0 < 0 else 0.0  # log times are not negative
    timings = {node: how for node, (_, _, how) in per_node.items()}
    rate = float(np.median(np.diff(next(iter(per_node.values()))[0]))) if len(table.values) > 1 else 0.0
    metadata = {
        "pendsim/import": {
            "source_file": str(source.resolve()),
            "source_name": source.name,
            "source_size_bytes": str(source.stat().st_size),
            "source_sha256": _sha256(source),
            "format": fmt,
            "columns": ",".join(spec.columns if spec.columns is not None else table.names),
            "units": spec.units.describe(),
            "time": "; ".join(f"{n}: {how}" for n, how in timings.items()),
            "time_shift_s": repr(shift_s),
            "pendsim_version": __version__,
            "mjcf": spec.mjcf_source,
            **dict(table.notes),
        },
        "pendsim/imu": {"sample_rate_hz": repr(1.0 / rate) if rate > 0 else "0", **BNO055_NDOF},
    }
    mjcf = spec.mjcf_xml if spec.mjcf_xml is not None else exact_mjcf(spec.params)
    with atomic_output(output, replace=replace) as tmp:
        sink = RecordingSink(
            tmp,
            nodes=tuple(per_node),
            groups=mapped[0].groups,
            params=spec.params,
            mjcf_xml=mjcf,
            metadata=metadata,
            start_time_ns=0,
            compression=spec.compression,
        )
        for node, (t, rows, _) in per_node.items():
            sink.add_samples(node, np.rint((t + shift_s) * 1e9).astype(np.int64), rows)
        sink.close()
    duration = max(float(t[-1] - t[0]) for t, _, _ in per_node.values())
    return ImportResult(
        output, source, fmt, {n: len(t) for n, (t, _, _) in per_node.items()}, duration, output.stat().st_size
    )
