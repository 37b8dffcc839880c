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

import array
import dataclasses
import datetime
import hashlib
import itertools
import logging
import math
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pendsim_mj import __version__
from pendsim_mj.errors import ParameterError, RecordingError
from pendsim_mj.estimation.timing import nominal_rate_hz
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import ACCEL_LSB_M_S2
from pendsim_mj.units import nanoseconds

from ..io.outputs import atomic_output
from ..io.recording_layout import IMPORT_METADATA, UNIX_2000_S, utc_iso
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
from .tdms_check import NptdmsWarnings, check_tdms_segments
from .unit_check import check_units

IMPORT_FORMATS = ("csv", "lvm", "tdms")
SUFFIXES = {".csv": "csv", ".txt": "csv", ".lvm": "lvm", ".tdms": "tdms"}
MAX_TIME_S = 4.0e9
"""The largest time (s, either sign) a file may hold: Unix time in the year 2096; recordings keep
int64 nanoseconds, which end at 9.2e9 s."""


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


MAX_LINE_CHARS = 1 << 16
"""The longest line of a text file import reads (a row of a few dozen numbers is a few hundred
characters): a longer one (a file of zeros, a binary file) is refused when met, not read whole."""
MAX_LINES_BEFORE_DATA = 10_000
"""Lines of boot messages or comments allowed before the first line of numbers."""
SNIFF_BYTES = 1 << 16


def text_head(path: Path, what: str) -> bytes:
    """The first ``SNIFF_BYTES`` of a file that must be text; a NUL byte there refuses it (a
    binary file, or a file of zeros) before anything else is read."""
    try:
        with open(path, "rb") as f:
            head = f.read(SNIFF_BYTES)
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None
    nul = head.find(0)
    if nul >= 0:
        raise RecordingError(f"{path}: not a text file (a NUL byte at byte {nul}); is it a {what}?")
    return head


def _text_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(line number, line) of each line that is neither empty nor a comment (#), read one at a
    time, each at most ``MAX_LINE_CHARS`` long."""
    text_head(path, "CSV file")
    try:
        with open(path, encoding="utf-8-sig") as f:
            number = 0
            while True:
                text = f.readline(MAX_LINE_CHARS + 1)
                if not text:
                    return
                number += 1
                if len(text) > MAX_LINE_CHARS:
                    raise RecordingError(
                        f"{path}: line {number} is over {MAX_LINE_CHARS} characters; is it a CSV file of numbers?"
                    )
                line = text.rstrip("\r\n")
                if line.strip() and not line.startswith("#"):
                    yield number, line
    except UnicodeDecodeError:
        raise RecordingError(f"{path}: not UTF-8 text; is it a CSV file?") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None


def read_csv(path: Path) -> Table:
    """A CSV file as a Table: a header row optional; lines before the header that are not data
    (a node's boot messages) skipped, an empty field after the last delimiter of a line ignored, a
    last line cut short (a logger stopped mid-line) dropped, each with a note. Read line by line
    into an array: memory grows with the numbers, not with the file's text."""
    lines = _text_lines(path)
    before: list[tuple[int, str]] = []  # up to and including the first line of numbers
    found = None
    for number, line in lines:
        before.append((number, line))
        found = _first_data_line([(number, line)])
        if found is not None:
            break
        if len(before) > MAX_LINES_BEFORE_DATA:
            raise RecordingError(f"{path}: no line of numbers in the first {MAX_LINES_BEFORE_DATA} lines")
    if not before:
        raise RecordingError(f"{path}: no data lines")
    if found is None:
        raise RecordingError(f"{path}: no data lines (no line of numbers separated by commas, semicolons or tabs)")
    first, delimiter = len(before) - 1, found[1]
    notes: list[str] = []
    start = first
    if first > 0 and delimiter in before[first - 1][1]:
        start = first - 1  # the header
    if start > 0:
        numbers = f"line {before[0][0]}" if start == 1 else f"lines {before[0][0]}-{before[start - 1][0]}"
        notes.append(f"skipped {numbers} before the {'header' if start < first else 'data'}: not data")
    trailing = 0

    def fields(line: str, *, count: bool = True) -> list[str]:
        nonlocal trailing
        body = line.rstrip()
        if body.endswith(delimiter) and delimiter.strip():
            body, trailing = body[: -len(delimiter)], trailing + count
        return _fields(body, delimiter)

    header = start < first
    head = fields(before[start][1], count=header)  # without a header, the line is counted as data below
    names = tuple(head) if header else tuple(f"column{i + 1}" for i in range(len(head)))
    values = array.array("d")
    numbers_of_lines = array.array("q")

    def keep(number: int, parts: list[str]) -> None:
        if len(parts) != len(names):
            first_line = "header" if header else "first line"
            raise RecordingError(f"{path}: line {number} has {len(parts)} fields, the {first_line} {len(names)}")
        try:
            values.extend(float(p) for p in parts)
        except ValueError:
            del values[len(numbers_of_lines) * len(names) :]
            k = next(i for i, p in enumerate(parts) if not _is_number(p))
            what = f"column {k + 1} ({names[k]!r})" if header else f"column {k + 1}"
            raise RecordingError(f"{path}: line {number}, {what}: {parts[k]!r} is not a number") from None
        numbers_of_lines.append(number)

    pending: tuple[int, list[str]] | None = None  # the last line is kept only once known to be whole
    for number, line in itertools.chain([before[first]], lines):
        if pending is not None:
            keep(*pending)
        pending = (number, fields(line))
    if trailing:
        notes.append(f"{trailing} line(s) end in {delimiter!r}: the empty field after it is not a column")
    if pending is not None:  # a last line cut short: fewer fields, or its last field not (yet) a number
        number, parts = pending
        short = len(parts) < len(names) or (
            len(parts) == len(names) and not _is_number(parts[-1]) and all(_is_number(p) for p in parts[:-1])
        )
        if short:
            why = f"{len(parts)} of {len(names)} fields" if len(parts) < len(names) else f"ends in {parts[-1]!r}"
            if not numbers_of_lines:
                raise RecordingError(f"{path}: no complete data line (line {number} is cut short: {why})")
            notes.append(f"dropped the last line {number}: cut short ({why})")
        else:
            keep(number, parts)
    if not numbers_of_lines:
        raise RecordingError(f"{path}: a header but no data lines")
    data = np.frombuffer(values, dtype=float).reshape(-1, len(names)).copy()
    return Table(names, data, skipped=tuple(notes), lines=tuple(numbers_of_lines))


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


def _lvm_line_end(path: Path) -> None:
    """LabVIEW ends every line of an .lvm file: a file whose last line has no line end was cut
    while it was written or copied (its last number may be cut short, e.g. 0.6046 to 0.60).

    Raises:
      RecordingError: the file does not end in a line end.
    """
    try:
        with open(path, "rb") as f:
            f.seek(0, 2)
            size = f.tell()
            f.seek(max(0, size - 1))
            last = f.read(1)
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None
    if size and last not in (b"\n", b"\r"):
        with open(path, "rb") as f:
            count = sum(block.count(b"\n") for block in iter(lambda: f.read(1 << 20), b"")) + 1
        raise RecordingError(
            f"{path}: truncated LVM file: its last line ({count}) has no line end, as LabVIEW writes every line: the "
            "file was cut while it was written or copied, and its last values may be cut short"
        )


def read_lvm(path: Path) -> Table:
    """A LabVIEW measurement file's first segment as a Table; a file cut short (its last line
    without a line end, or fewer rows than its header's Samples) is refused."""
    import lvm_read  # only for .lvm files

    head = text_head(path, "LabVIEW measurement file")
    if not head.removeprefix(b"\xef\xbb\xbf").lstrip().startswith(b"LabVIEW Measurement"):
        raise RecordingError(
            f"{path}: not a LabVIEW measurement file (it does not start with 'LabVIEW Measurement'); import reads "
            ".lvm files as LabVIEW writes them: a 'LabVIEW Measurement' header whose Separator (Tab or Comma) splits "
            "the data; a plain table is --format csv"
        )
    _lvm_line_end(path)
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
    declared = [n for n in segment.get("Samples", []) if isinstance(n, (int, float)) and math.isfinite(n) and n > 0]
    if declared and len(data) < min(declared):  # a header written with its data declares at least those rows
        raise RecordingError(
            f"{path}: truncated LVM file: the header declares {int(min(declared))} samples per channel, the file "
            f"holds {len(data)} rows (cut short, or rows removed by hand)"
        )
    notes = tuple((f"lvm_{key.lower()}", str(lvm[key])) for key in ("Date", "Time", "Operator") if key in lvm)
    segments = lvm.get("Segments", 1)
    skipped = (
        (f"imported the first of the file's {segments} segments",) if isinstance(segments, int) and segments > 1 else ()
    )
    return Table(tuple(names), data, timing, notes, skipped, lines=_lvm_data_lines(path, len(data)))


def read_tdms(path: Path) -> Table:
    """Every channel of a TDMS file (``GROUP/CHANNEL``) as a Table; little- or big-endian, every
    segment checked whole first (``check_tdms_segments``), and anything npTDMS warns about (data
    it would crop or guess) refused."""
    from nptdms import TdmsFile  # only for .tdms files

    check_tdms_segments(path)
    caught = NptdmsWarnings()
    # npTDMS logs per module (nptdms.reader, ...), each logger with its own console handler: ours
    # replaces them while it reads, so nothing reaches stderr and every warning is seen
    loggers = [logging.getLogger(name) for name in list(logging.root.manager.loggerDict) if name.startswith("nptdms")]
    saved = [(log, log.handlers[:], log.propagate, log.level) for log in loggers]
    for log in loggers:
        log.handlers, log.propagate = [caught], False
        log.setLevel(logging.WARNING)
    try:
        tdms = TdmsFile.read(str(path))
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except Exception as exc:  # npTDMS raises ValueError, KeyError, struct.error ... on foreign input
        raise RecordingError(f"{path}: not a TDMS file npTDMS can read ({type(exc).__name__}: {exc})") from None
    finally:
        for log, handlers, propagate, level in saved:
            log.handlers, log.propagate = handlers, propagate
            log.setLevel(level)
    if caught.messages:
        said = re.sub(r"[.,]?\s*will attempt .*$", "", caught.messages[0], flags=re.I | re.S)  # we do not guess
        raise RecordingError(
            f"{path}: damaged TDMS file: its data do not match what its metadata declares (npTDMS: {said!r})"
        )
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
                timing = _waveform_timing(path, f"{group.name}/{channel.name}", channel.properties)
    if not columns:
        raise RecordingError(f"{path}: a TDMS file with no channels")
    lengths = {len(c) for c in columns}
    if len(lengths) != 1:
        raise RecordingError(f"{path}: channels have different lengths ({', '.join(map(str, sorted(lengths)))})")
    notes = tuple(
        (f"tdms_{k}", str(v)) for k, v in tdms.properties.items() if isinstance(v, (str, int, float, np.datetime64))
    )
    return Table(tuple(names), np.stack(columns, axis=1), timing, notes)


def _waveform_timing(path: Path, name: str, properties: dict[str, object]) -> tuple[float, float]:
    """(wf_increment, wf_start_offset) of a TDMS channel, s, checked: a step > 0 and a start that
    place every sample within the times pendsim keeps (``MAX_TIME_S``)."""
    try:
        step, start = float(properties["wf_increment"]), float(properties.get("wf_start_offset", 0.0))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise RecordingError(f"{path}: channel {name}: wf_increment and wf_start_offset must be numbers") from None
    if not (math.isfinite(step) and 0 < step <= MAX_TIME_S and math.isfinite(start) and abs(start) <= MAX_TIME_S):
        raise RecordingError(
            f"{path}: channel {name}: waveform timing wf_increment = {step!r} s, wf_start_offset = {start!r} s; "
            f"allowed: a step in (0, {MAX_TIME_S:g}] s and a start within +-{MAX_TIME_S:g} s"
        )
    return step, start


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
