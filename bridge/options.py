"""What the command modules share: the parser class, argument types with checked ranges, the
options of a simulated run, and checks of input and output paths.

Every check here fails with ``UsageError`` (or argparse's own message through ``Parser.error``),
which ``pendsim_bridge.cli.main`` prints as one line ``pendsim: error: ...`` with exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import ipaddress
import json
import math
import os
import re
import stat
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NoReturn, TypeVar

from pendsim_mj.engines.dispatch import ENGINE_NAMES
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig import drives
from pendsim_mj.rig.checks import INPUT_RANGES, check_input, drive_amplitude_limit
from pendsim_mj.rig.params import (
    DEFAULT_PARAMS,
    FIELD_NAMES,
    PARAMETER_LIMITS,
    RigParams,
    check_field,
    far_from_paper,
    unknown_parameters,
)

from .errors import OutputError
from .io.mcap.records import MCAP_MAGIC, import_hint
from .io.outputs import atomic_output, check_file_target, check_folder_target, in_kernel_folder

MAX_JSON_BYTES = 1_000_000  # parameter files are a few hundred bytes
MAX_CSV_BYTES = 200_000_000  # a drive's time series: 1 kHz for hours is a few tens of MB
MAX_JSON_DEPTH = 1  # one object of numbers: {"b1_n_m_s": 0.0007}
MAX_LOG_TIME_S = 9.2e9  # MCAP log times are unsigned 64-bit nanoseconds; int64 arithmetic: 2^63 ns

T = TypeVar("T")


class UsageError(Exception):
    """Bad command-line input; reported in one line with exit code 2."""


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line and exit code 2 (no usage dump)."""

    def error(self, message: str) -> NoReturn:
        # argparse writes "argument --speed: MESSAGE"; our own messages already name the option
        head, sep, rest = message.partition(": ")
        if sep and head.startswith("argument "):
            option = head.removeprefix("argument ").split("/")[0]
            if rest.startswith((option, option.lstrip("-").replace("-", "_"))):
                message = rest
        raise UsageError(message)


# -- argument types --------------------------------------------------------------------------


def finite_float(text: str) -> float:
    """A finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def non_negative_float(text: str) -> float:
    """A finite number >= 0."""
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def float_in(
    low: float, high: float, unit: str = "", *, low_open: bool = False, name: str = ""
) -> Callable[[str], float]:
    """An argument type: a finite number in [low, high] (or (low, high] with ``low_open``); the
    messages name the quantity as ``name`` (e.g. "duration_s") when given."""
    where = f"{'(' if low_open else '['}{low:g}, {high:g}]{' ' + unit if unit else ''}"
    u = f" {unit}" if unit else ""

    def parse(text: str) -> float:
        try:
            value = finite_float(text)
        except argparse.ArgumentTypeError:
            if not name:
                raise
            raise argparse.ArgumentTypeError(f"{name} must be a finite number, got {text!r}") from None
        if value < low or (low_open and value == low):
            bound = f"> {low:g}" if low_open else f">= {low:g}"
            raise argparse.ArgumentTypeError(
                f"{name} must be a finite number {bound}{u}, got {value!r}"
                if name
                else f"must be in {where}, got {text!r}"
            )
        if value > high:
            raise argparse.ArgumentTypeError(
                f"{name} must be at most {high:g}{u}, got {value!r}" if name else f"must be in {where}, got {text!r}"
            )
        return value

    parse.__name__ = f"number in {where}"
    parse.low, parse.high, parse.low_open = low, high, low_open  # type: ignore[attr-defined]
    return parse


def ranged(name: str, flag: str) -> Callable[[str], float]:
    """An argument type for the input ``name`` of the one table of ranges
    (``pendsim_mj.rig.checks.INPUT_RANGES``), its messages naming the option ``flag``."""
    r = INPUT_RANGES[name]
    return float_in(r.low, r.high, r.unit, low_open=r.low_open, name=flag)


def int_in(low: int, high: int) -> Callable[[str], int]:
    """An argument type: an integer in [low, high] (decimal digits only, at most 20)."""

    def parse(text: str) -> int:
        digits = text.strip().removeprefix("-").removeprefix("+")
        if not digits.isdecimal() or len(digits) > 20:
            raise argparse.ArgumentTypeError(f"must be an integer in [{low}, {high}], got {text!r}")
        value = int(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be an integer in [{low}, {high}], got {text!r}")
        return value

    parse.__name__ = f"integer in [{low}, {high}]"
    parse.low, parse.high, parse.low_open = low, high, False  # type: ignore[attr-defined]
    return parse


def bind_address(text: str) -> str:
    """An IP address to listen on (IPv4 or IPv6, no host names)."""
    try:
        return str(ipaddress.ip_address(text))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--bind must be an IP address such as 127.0.0.1 (this machine only) or 0.0.0.0 (every network), "
            f"got {text!r}"
        ) from None


def choice(allowed: tuple[str, ...], message: str) -> Callable[[str], str]:
    """An argument type for a closed set (use with ``choices=allowed`` so help lists them);
    ``message`` is formatted with the bad ``value`` and the ``allowed`` list, e.g.
    "unknown engine {value!r}; allowed: {allowed}"."""

    def parse(text: str) -> str:
        if text not in allowed:
            raise argparse.ArgumentTypeError(message.format(value=text, allowed=", ".join(allowed)))
        return text

    parse.__name__ = "choice"
    return parse


def argument(parse: Callable[[str], T], name: str) -> Callable[[str], T]:
    """An argparse type from a parser that raises ParameterError."""

    def convert(text: str) -> T:
        try:
            return parse(text)
        except ParameterError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    convert.__name__ = name
    return convert


def assignment(text: str) -> tuple[str, float]:
    """NAME=VALUE with a finite number in the range of NAME (a rig parameter's, ``RigParams``, or
    an input's, ``pendsim_mj.rig.checks.INPUT_RANGES``); an unknown NAME is left to the command,
    whatever its value (NaN where it is not a number: every command refuses an unknown name
    before it reads a value, and says the option it may be: --set engine=fast, "this command's
    --engine")."""
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    name = name.strip()
    try:
        number = finite_float(value)
    except argparse.ArgumentTypeError as exc:
        if name not in INPUT_RANGES and name not in PARAMETER_LIMITS:
            return name, math.nan
        raise argparse.ArgumentTypeError(f"{name}: {exc}") from None
    try:
        check_input(name, number)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return name, number


def input_file(text: str) -> Path:
    """An existing regular file (not a folder, FIFO, device or a kernel file under /proc, /sys or
    /dev, whose reads can block or never end)."""
    path = Path(text)
    try:
        mode = path.stat().st_mode
    except OSError as exc:
        reason = "no such file" if isinstance(exc, FileNotFoundError) else (exc.strerror or "cannot read")
        raise argparse.ArgumentTypeError(f"{text}: {reason}") from None
    except ValueError:  # e.g. a NUL byte in the name
        raise argparse.ArgumentTypeError(f"{text!r}: not a valid file name") from None
    if stat.S_ISDIR(mode):
        raise argparse.ArgumentTypeError(f"{text}: is a folder; give a file")
    if not stat.S_ISREG(mode):
        raise argparse.ArgumentTypeError(f"{text}: not a regular file (FIFOs and devices are refused)")
    kernel = in_kernel_folder(path)
    if kernel is not None:
        raise argparse.ArgumentTypeError(f"{text}: a kernel file under {kernel}, not a data file")
    if not os.access(path, os.R_OK):
        raise argparse.ArgumentTypeError(f"{text}: permission denied")
    return path


def mcap_file(text: str) -> Path:
    """An existing regular file (``input_file``) that starts with the MCAP magic: checked while
    parsing, so that a wrong input is named before anything else (e.g. an output that exists)."""
    path = input_file(text)
    try:
        with open(path, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"{text}: cannot read: {exc.strerror}") from None
    if head != MCAP_MAGIC:
        raise argparse.ArgumentTypeError(f"{text}: not an MCAP file (no MCAP magic at the start){import_hint(path)}")
    return path


# -- options of a simulated run --------------------------------------------------------------


def add_run_options(p: argparse.ArgumentParser) -> None:
    """Initial conditions, duration, step, engine and parameter overrides (``run_from_args``)."""
    p.add_argument("--phi1-deg", type=ranged("phi1_deg", "--phi1-deg"), default=30.0,
                   help="initial angle of M1, deg (default 30)")  # fmt: skip
    p.add_argument("--phi2-deg", type=ranged("phi2_deg", "--phi2-deg"), default=0.0,
                   help="initial angle of M2, deg (default 0)")  # fmt: skip
    p.add_argument("--omega1-deg-s", type=ranged("omega1_deg_s", "--omega1-deg-s"), default=0.0,
                   help="initial rate of M1, deg/s (default 0)")  # fmt: skip
    p.add_argument("--omega2-deg-s", type=ranged("omega2_deg_s", "--omega2-deg-s"), default=0.0,
                   help="initial rate of M2, deg/s (default 0)")  # fmt: skip
    p.add_argument(
        "--duration-s",
        type=ranged("duration_s", "--duration-s"),
        default=120.0,
        help="simulated time, s (default 120, at most 1 day)",
    )
    p.add_argument(
        "--dt-s",
        type=ranged("dt_s", "--dt-s"),
        default=0.01,
        help="integration step, s (default 0.01)",
    )
    p.add_argument(
        "--engine",
        type=choice(ENGINE_NAMES, "unknown engine {value!r}; allowed: {allowed}"),
        choices=ENGINE_NAMES,
        default="mujoco",
        help="mujoco (the MJCF model), reference (planar Newtonian RK4) or fast (the same planar equations, "
        "compiled); default mujoco",
    )
    for n in (1, 2):
        default_b = getattr(DEFAULT_PARAMS, f"b{n}_n_m_s")
        _, b_max = PARAMETER_LIMITS[f"b{n}_n_m_s"]
        p.add_argument(
            f"--b{n}",
            type=float_in(0.0, b_max, "N m s/rad", name=f"--b{n}"),
            help=f"hinge damping of M{n}, N m s/rad (default {default_b:.4g})",
        )
    add_parameter_options(p)


def add_parameter_options(p: argparse.ArgumentParser, *, what: str = "the rig") -> None:
    """--params-file and --set (``overrides_from``)."""
    p.add_argument(
        "--params-file",
        type=input_file,
        help=f"JSON object of parameter overrides for {what} (SI names as in 'pendsim info'), "
        "e.g. from 'pendsim identify --write'",
    )
    p.add_argument(
        "--set",
        dest="overrides",
        type=assignment,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help=f"override a parameter of {what} in SI units, e.g. --set c1_n_m=6.0 (see 'pendsim info'); repeatable",
    )


def add_mjcf_option(p: argparse.ArgumentParser) -> None:
    """``--mjcf FILE.xml``: the rig's model to attach to a recording (``mjcf_from``)."""
    p.add_argument(
        "--mjcf",
        type=input_file,
        metavar="FILE.xml",
        help="the rig's MJCF model to attach (default: pendsim's, with the --set/--params-file parameters)",
    )


def mjcf_from(args: argparse.Namespace) -> tuple[str | None, str]:
    """(the MJCF text or None, where it came from), checked by compiling it with MuJoCo."""
    if args.mjcf is None:
        return None, "built by pendsim from the rig parameters"
    import mujoco  # start-up: loaded only to check a given model

    try:
        text = args.mjcf.read_text()
        mujoco.MjModel.from_xml_string(text)
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"{args.mjcf}: cannot read: {exc}") from None
    except ValueError as exc:
        raise UsageError(f"{args.mjcf}: not a valid MJCF model: {' '.join(str(exc).split())}") from None
    return text, str(args.mjcf.resolve())


def add_alignment_options(p: argparse.ArgumentParser) -> None:
    """--release-s and --max-gap-s (how a recording is aligned; ``pendsim_mj.estimation.alignment``)."""
    p.add_argument(
        "--release-s",
        type=float_in(0.0, MAX_LOG_TIME_S, "s"),
        metavar="T",
        help="the release (start) on the recording's clock, s (the log time replay uses), instead of finding it",
    )
    p.add_argument(
        "--max-gap-s",
        type=float_in(0.0, 10.0, "s", low_open=True),
        default=0.1,
        metavar="S",
        help="never interpolate or integrate across a gap between samples longer than this, s (default 0.1)",
    )


def print_warnings(lines: tuple[str, ...] | list[str]) -> None:
    """Each warning as one line ``pendsim: warning: ...`` on standard error."""
    for line in lines:
        print(f"pendsim: warning: {' '.join(line.split())}", file=sys.stderr)


def add_rerun_option(p: argparse.ArgumentParser, default: str, what: str) -> None:
    """``--rerun [FILE.rrd]``."""
    help_text = f"{what} (default file {default})"
    p.add_argument("--rerun", type=Path, nargs="?", const=Path(default), metavar="FILE.rrd", help=help_text)


def _json_depth(text: str) -> int:
    """The deepest nesting of brackets outside strings (checked before parsing, so a deeply
    nested file cannot exhaust the parser's recursion)."""
    depth = deepest = 0
    in_string = escaped = False
    for char in text:
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth -= 1
    return deepest


def _duplicate_keys(pairs: list[tuple[str, object]]) -> dict[str, object]:
    seen: dict[str, object] = {}
    for key, value in pairs:
        if key in seen:
            raise UsageError(f"the parameter file names {key!r} twice")
        seen[key] = value
    return seen


def read_params_file(path: Path) -> dict[str, float]:
    """A JSON object of parameter names to numbers: at most ``MAX_JSON_BYTES``, UTF-8, one level
    deep, each value a finite number (booleans, strings, null, arrays, objects and duplicate
    names refused), each name a RigParams field (the file named in the error, with the likely
    spelling). Ranges are the parameters' own (``RigParams``); a value more than 10 times from the
    paper's rig is used but warned about on standard error (``far_from_paper``: a unit slip?)."""
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_JSON_BYTES + 1)
    except OSError as exc:
        raise UsageError(f"cannot read {path}: {exc.strerror}") from None
    if raw.startswith(b"\x89MCAP"):  # a recording given for its rig: the one command that reads it so
        raise UsageError(
            f"{path} is a recording, not a parameter file; its rig as one: pendsim info {path} --json > rig.json"
        )
    if len(raw) > MAX_JSON_BYTES:
        raise UsageError(f"{path} is over {MAX_JSON_BYTES} bytes; a parameter file is a small JSON object")
    example = '{"b1_n_m_s": 0.0007}'
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise UsageError(f"{path} is not UTF-8 text") from None
    if _json_depth(text) > MAX_JSON_DEPTH:
        raise UsageError(f"{path} is nested; a parameter file is one JSON object of numbers, e.g. {example}")
    try:
        loaded = json.loads(text, object_pairs_hook=_duplicate_keys, parse_constant=lambda name: name)
    except json.JSONDecodeError as exc:
        raise UsageError(f"{path} is not JSON: {exc.msg} at line {exc.lineno}") from None
    except (ValueError, RecursionError) as exc:  # e.g. an integer of thousands of digits
        raise UsageError(f"{path} is not a parameter file: {str(exc).split(';')[0]}") from None
    if not isinstance(loaded, dict):
        raise UsageError(f"{path} must hold a JSON object of numbers, e.g. {example}")
    values: dict[str, float] = {}
    for name, value in loaded.items():
        try:
            number = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan
        except OverflowError:  # an integer beyond the float range
            number = math.inf
        if not math.isfinite(number):
            raise UsageError(f"{path}: {name!r} must be a finite number, got {json.dumps(value)[:40]}")
        values[str(name)] = number
    unknown = [name for name in values if name not in FIELD_NAMES]
    if unknown:
        raise UsageError(f"{path}: {unknown_parameters(unknown)}")
    for name, number in values.items():  # each value's own range first: a bad file is one line, no warning
        try:
            check_field(name, number)
        except ParameterError as exc:
            raise UsageError(f"{path}: {exc}") from None
    print_warnings([f"{path}: {line}: a unit slip? (used as given)" for line in far_from_paper(values)])
    return values


def overrides_from(args: argparse.Namespace) -> dict[str, float]:
    """Parameter overrides from --params-file, then --set, then --b1/--b2 (later ones win). Where
    each came from is kept on ``args`` (``parameter_sources``) for ``explained``."""
    overrides: dict[str, float] = {}
    sources: dict[str, str] = {}
    if getattr(args, "params_file", None) is not None:
        from_file = read_params_file(args.params_file)
        overrides.update(from_file)
        sources.update(dict.fromkeys(from_file, str(args.params_file)))
    given = dict(getattr(args, "overrides", []))
    overrides.update(given)
    sources.update(dict.fromkeys(given, "--set"))
    for n in (1, 2):
        if getattr(args, f"b{n}", None) is not None:
            overrides[f"b{n}_n_m_s"] = getattr(args, f"b{n}")
            sources[f"b{n}_n_m_s"] = f"--b{n}"
    args.parameter_sources = sources
    return overrides


def explained(message: str, args: argparse.Namespace | None, command: argparse.ArgumentParser | None) -> str:
    """A parameter error's ``message`` with where the values it names were given ("j1_kg_m2 = ...
    must exceed m1_kg * oc1_m^2 = ... (m1_kg from rig.json; the others are the rig's own)": a value
    the rig's other values make impossible), or, for an unknown name that is an option of the
    ``command`` (--set phi1_deg=10), that option ("unknown parameter(s) phi1_deg (this command's
    --phi1-deg, not a rig parameter); allowed: ..."). ``parameter_sources``: ``overrides_from``."""
    if args is None:
        return message
    drive = re.search(r"the (\w+) drive reaches", message)  # a drive faster than the step: by its option
    if drive is not None and command is not None:
        flag = next((f for f, target, _ in DRIVE_OPTIONS if target == drive.group(1)), None)
        if flag is not None and flag in command._option_string_actions:
            return message.replace(f"the {drive.group(1)} drive", f"the {drive.group(1)} drive ({flag})", 1)
    unknown = re.search(r"unknown (?:parameter\(s\) ([^;]*)|input '([a-z0-9_]+)')", message)
    if unknown is not None and command is not None:
        head, sep, rest = message.partition("; allowed:")
        entries = (unknown.group(1) or unknown.group(2) or "").split(", ")
        names = [e.strip() for e in entries if e.strip() and "did you mean" not in e]  # a misspelling: its own hint
        flags = [f"--{name.replace('_', '-')}" for name in dict.fromkeys(names)]
        found = [flag for flag in flags if flag in command._option_string_actions]
        if found:
            return f"{head} (this command's {', '.join(found)}, not a rig parameter){sep}{rest}"
        inputs = [name for name in names if name in INPUT_RANGES]
        if inputs and "--vary" in command._option_string_actions and "unknown parameter" in head:
            what = "a sweep's input" + ("s" if len(inputs) > 1 else "")
            return f"{head} ({what}, not a rig parameter: --set or --vary){sep}{rest}"
        drives = [  # a sweep's drive input (torque_m1_frequency_hz) on a command that takes a drive as a signal
            flag
            for flag, target, _ in DRIVE_OPTIONS
            if flag in command._option_string_actions and any(name.startswith(f"{target}_") for name in names)
        ]
        if drives and "unknown parameter" in head:
            return (
                f"{head} (a sweep's drive input; here a drive is one option and a signal: {drives[0]} "
                f"sine:AMP,FREQ_HZ, docs/excitation.md){sep}{rest}"
            )
        return message
    sources: dict[str, str] = getattr(args, "parameter_sources", {})
    named = [name for name in sources if re.search(rf"\b{re.escape(name)}\b", message)]
    if not named:
        return message
    return f"{message} ({', '.join(f'{name} from {sources[name]}' for name in named)}; the others are the rig's own)"


def params_from(args: argparse.Namespace) -> RigParams:
    """The default rig with the command line's overrides."""
    return DEFAULT_PARAMS.with_mapping(overrides_from(args))


def initial_state_from(args: argparse.Namespace) -> tuple[tuple[float, float], tuple[float, float]]:
    """(phi0_rad, omega0_rad_s) from the degree options."""
    phi0 = (math.radians(args.phi1_deg), math.radians(args.phi2_deg))
    omega0 = (math.radians(args.omega1_deg_s), math.radians(args.omega2_deg_s))
    return phi0, omega0


# -- drives ----------------------------------------------------------------------------------

# One option per drivable input (pendsim_mj.rig.drives.Target), its unit in the name.
DRIVE_OPTIONS = (
    ("--torque1-n-m", "torque_m1", "motor torque at the hinge of M1, N m (positive raises phi1)"),
    ("--torque2-n-m", "torque_m2", "motor torque at the hinge of M2, N m"),
    ("--support-x-m-s2", "support_x", "horizontal acceleration of the support (frame and pivot), m/s^2"),
    ("--pivot-z-m-s2", "pivot_z", "vertical acceleration of the support, upward, m/s^2 (parametric excitation)"),
)
SIGNAL_FORMS = (
    "sine:AMP,FREQ_HZ[,PHASE_DEG]",
    "stepped:AMP,F0_HZ,F1_HZ,STEPS,DWELL_S",
    "chirp:AMP,F0_HZ,F1_HZ,DURATION_S",
    "logchirp:AMP,F0_HZ,F1_HZ,DURATION_S",
    "csv:FILE[:COLUMN]",
)
_SIGNAL_ARITY = {"sine": (2, 3), "stepped": (5, 5), "chirp": (4, 4), "logchirp": (4, 4)}
DRIVE_LIMITS = {t.value: (drive_amplitude_limit(t), t.unit) for t in drives.Target}
"""Largest drive amplitude per input (from ``pendsim_mj.rig.checks.INPUT_RANGES``)."""
MAX_DRIVE_FREQUENCY_HZ = INPUT_RANGES["torque_m1_frequency_hz"].high
MAX_DRIVE_TIME_S = 86400.0


@dataclasses.dataclass(frozen=True)
class SignalSpec:
    """A drive signal as written on the command line (a CSV file is read by ``drive_from``)."""

    kind: str
    numbers: tuple[float, ...] = ()
    path: str = ""
    column: str | None = None


def signal_spec(text: str) -> SignalSpec:
    """Parse SIGNAL (one of SIGNAL_FORMS); amplitudes in the option's unit, frequencies in Hz."""
    kind, sep, rest = text.partition(":")
    forms = "; ".join(SIGNAL_FORMS)
    if not sep or kind not in (*_SIGNAL_ARITY, "csv"):
        raise argparse.ArgumentTypeError(f"expected a signal {forms}; got {text!r}")
    if kind == "csv":
        if not rest:
            raise argparse.ArgumentTypeError(f"csv needs a file: csv:FILE[:COLUMN], got {text!r}")
        path, colon, column = rest.rpartition(":")
        if colon and path and not Path(rest).exists():
            return SignalSpec("csv", path=path, column=column)
        return SignalSpec("csv", path=rest)
    low, high = _SIGNAL_ARITY[kind]
    parts = [x.strip() for x in rest.split(",")]
    if not low <= len(parts) <= high:
        form = next(f for f in SIGNAL_FORMS if f.startswith(f"{kind}:"))
        raise argparse.ArgumentTypeError(f"{kind} takes {form}, got {text!r}")
    numbers = tuple(finite_float(x) for x in parts)
    try:
        _signal(SignalSpec(kind, numbers))  # checks the values (positive frequencies, ...) now
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None
    return SignalSpec(kind, numbers)


def _signal(spec: SignalSpec) -> drives.Signal:
    n = spec.numbers
    if spec.kind == "sine":
        return drives.Sine(n[0], n[1], math.radians(n[2]) if len(n) > 2 else 0.0)
    if spec.kind == "stepped":
        if n[3] != int(n[3]) or n[3] < 1:
            raise ParameterError(f"STEPS must be a whole number >= 1, got {n[3]:g}")
        return drives.SteppedSine.linear(n[0], n[1], n[2], int(n[3]), n[4])
    if spec.kind in ("chirp", "logchirp"):
        return drives.Chirp(n[0], n[1], n[2], n[3], "linear" if spec.kind == "chirp" else "log")
    try:
        path = input_file(spec.path)  # a FIFO or a device would block or never end
    except argparse.ArgumentTypeError as exc:
        raise ParameterError(f"csv drive file {exc}") from None
    if path.stat().st_size > MAX_CSV_BYTES:
        raise ParameterError(f"csv drive file {path} is over {MAX_CSV_BYTES // 1_000_000} MB")
    return drives.read_time_series_csv(path, spec.column)


def add_drive_options(p: argparse.ArgumentParser, *, what: str = "the run") -> None:
    """One option per drivable input, each taking a SIGNAL (``drive_from``); any combination."""
    group = p.add_argument_group(
        "drives",
        f"inputs that drive {what} (any combination), each a SIGNAL: {'; '.join(SIGNAL_FORMS)}. A csv file has "
        "a header, a time column (t_s or time, s) and values in the option's unit. Each input is held over a "
        "step at its value at the step's midpoint.",
    )
    for flag, target, help_text in DRIVE_OPTIONS:
        limit, unit = DRIVE_LIMITS[target]
        group.add_argument(
            flag,
            dest=f"drive_{target}",
            type=bounded_signal_spec(flag, limit, unit),
            metavar="SIGNAL",
            help=f"{help_text}; amplitude at most {limit:g} {unit}",
        )


def bounded_signal_spec(flag: str, limit: float, unit: str) -> Callable[[str], SignalSpec]:
    """``signal_spec`` with checked ranges: |AMP| <= ``limit``, frequencies <= 1000 Hz, durations
    and dwells <= 1 day, STEPS <= 10000, PHASE within +-360 deg (a CSV's values: ``drive_from``)."""

    def parse(text: str) -> SignalSpec:
        spec = signal_spec(text)
        n = spec.numbers
        if not n:
            return spec
        if abs(n[0]) > limit:
            raise argparse.ArgumentTypeError(f"{flag} amplitude must be at most {limit:g} {unit}, got {n[0]:g}")
        frequencies = {"sine": n[1:2], "stepped": n[1:3], "chirp": n[1:3], "logchirp": n[1:3]}[spec.kind]
        if any(f > MAX_DRIVE_FREQUENCY_HZ for f in frequencies):
            raise argparse.ArgumentTypeError(f"{flag} frequencies must be at most {MAX_DRIVE_FREQUENCY_HZ:g} Hz")
        times = {"stepped": n[4:5], "chirp": n[3:4], "logchirp": n[3:4]}.get(spec.kind, ())
        if any(t > MAX_DRIVE_TIME_S for t in times):
            raise argparse.ArgumentTypeError(f"{flag} durations must be at most {MAX_DRIVE_TIME_S:g} s")
        if spec.kind == "stepped" and n[3] > 10000:
            raise argparse.ArgumentTypeError(f"{flag} STEPS must be at most 10000, got {n[3]:g}")
        if spec.kind == "sine" and len(n) > 2 and abs(n[2]) > 360:
            raise argparse.ArgumentTypeError(f"{flag} PHASE_DEG must be within +-360, got {n[2]:g}")
        return spec

    parse.__name__ = "signal"
    return parse


def drive_from(args: argparse.Namespace) -> drives.Drive | None:
    """The Drive the drive options describe (None if none is given); reads CSV files.

    Raises:
      UsageError: a CSV file cannot be read or is not a time series.
    """
    given = {target: getattr(args, f"drive_{target}", None) for _, target, _ in DRIVE_OPTIONS}
    signals = {}
    for target, spec in given.items():
        if spec is None:
            continue
        try:
            signals[target] = _signal(spec)
        except ParameterError as exc:
            raise UsageError(str(exc)) from None
        limit, unit = DRIVE_LIMITS[target]
        values = getattr(signals[target], "values", ())
        if values and max(abs(v) for v in values) > limit:
            raise UsageError(f"{spec.path}: drive values must be at most {limit:g} {unit} in size")
    return drives.Drive(**signals) if signals else None


# -- paths -----------------------------------------------------------------------------------


def check_output(path: Path | None, suffixes: tuple[str, ...], *, force: bool = False) -> None:
    """An output file name: the right suffix, in a writable existing folder, not a folder, FIFO,
    device or kernel file, and (without ``force``) not an existing file. Checked before any work
    so that a bad name costs nothing; ``pendsim_bridge.io.outputs`` checks again when publishing."""
    if path is None:
        return
    if path.suffix.lower() not in suffixes:
        raise UsageError(f"output {str(path)!r} must end in {' or '.join(suffixes)}")
    try:
        check_file_target(path, replace=force)
    except OutputError as exc:
        raise UsageError(str(exc)) from None
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.exists():
        raise UsageError(f"output directory {str(parent)!r} does not exist")
    if not parent.is_dir():
        raise UsageError(f"output directory {str(parent)!r} is not a directory")
    _check_writable(parent)


def _check_writable(folder: Path) -> None:
    if os.access(folder, os.W_OK):
        return
    with contextlib.suppress(OSError):
        if os.statvfs(folder).f_flag & os.ST_RDONLY:
            raise UsageError(f"output directory {str(folder)!r} is on a read-only file system")
    raise UsageError(f"output directory {str(folder)!r} is not writable (permission denied)")


def check_output_dir(path: Path, names: tuple[str, ...] = (), *, force: bool = False) -> None:
    """An output folder: absent (it is created) or a folder, not under /proc, /sys or /dev, and
    (without ``force``) holding none of ``names``, the files the command will write there."""
    try:
        check_folder_target(path)
    except OutputError as exc:
        raise UsageError(str(exc)) from None
    if force or not path.is_dir():
        return
    taken = [name for name in names if (path / name).exists() or (path / name).is_symlink()]
    if taken:
        raise UsageError(f"output {str(path / taken[0])!r} exists; choose another folder or pass --force to replace")
    _check_writable(path)


def add_force_option(p: argparse.ArgumentParser, what: str = "the output file") -> None:
    """``--force``: replace existing outputs."""
    p.add_argument("--force", action="store_true", help=f"replace {what} if it exists")


def check_not_input(output: Path | None, input_path: Path) -> None:
    """Refuse an output that is the input file itself (even with --force)."""
    if output is None:
        return
    with contextlib.suppress(OSError):
        if output.exists() and os.path.samefile(output, input_path):
            raise UsageError(f"output {str(output)!r} is the input file; write to another name")


@contextlib.contextmanager
def replacing(path: Path, *, force: bool) -> Iterator[Path]:
    """The name to hand a library writer that never replaces a file (``mcap_tools.rewrite``):
    without ``force`` the output itself; with ``force`` a fresh, absent name beside it, published
    over ``path`` atomically once the writer has finished (``pendsim_bridge.io.outputs``)."""
    if not force:
        yield path
        return
    with atomic_output(path, replace=True) as tmp:
        tmp.unlink()  # the writer creates it anew, under its own temporary name first
        try:
            yield tmp
        except OutputError as exc:  # name the file the user gave, not the temporary one
            raise OutputError(str(exc).replace(str(tmp), str(path))) from None
