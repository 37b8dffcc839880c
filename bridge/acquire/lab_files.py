"""Lab files read into a ``Table`` of named columns: CSV (and .txt), LabVIEW measurement files
(.lvm) and NI TDMS, each refused in one line where it is not what it says, cut short or damaged
(``tdms_check`` checks a TDMS file's segments first). What the columns mean and how they become a
recording is ``importers``.

Memory: a text file is sniffed from its first ``SNIFF_BYTES`` (a NUL byte refuses it) and read
line by line into arrays of numbers, never whole.
"""

from __future__ import annotations

import array
import dataclasses
import itertools
import logging
import math
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.errors import RecordingError

from .tdms_check import NptdmsWarnings, check_tdms_segments

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
