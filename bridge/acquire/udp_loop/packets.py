"""The actuator's two packets: the controller's command and the actuator's status, each with an
encoder and a strict decoder (docs/control.md, "The loop over UDP", has the byte tables).

Both are little endian and end in a CRC-32 (zlib's, IEEE 802.3) of the bytes before it. A CRC
says only that the bytes arrived as sent, not who sent them: every field is range-checked as
well (magic, version, reserved bits and bytes zero, flags and reason codes known, times below
``MAX_TIME_US``, torques finite and within ``MAX_TORQUE_N_M``), and anything else raises
``ActuatorPacketError`` with one of ``BAD_PACKET_REASONS``; no input makes a decoder raise
anything else. Whether a valid command is fresh, in order and within the motor's limit is the
actuator's question (``actuator``).

- **Command** (controller -> actuator, ``COMMAND_SIZE`` = 32 bytes): magic ``PSCM``, version,
  flags (bit 0: stop, zero torque now), the stop's reason, sequence number (uint32), the
  controller's time stamp (uint64 us, its own monotonic clock), the torque of each motor (float32,
  N m), CRC-32.
- **Status** (actuator -> controller, ``STATUS_SIZE`` = 48 bytes): magic ``PSST``, version, state
  (ok or safe), the reason for a safe state, the sequence number of the newest command it took,
  the actuator's time stamp (uint64 us), the torque each motor applies now (float32, N m), and its
  counters of bad packets, stale commands (reordered or repeated), safe events and commands taken
  (uint32 each), CRC-32.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import zlib

COMMAND_MAGIC = b"PSCM"
STATUS_MAGIC = b"PSST"
VERSION = 1
MAX_TIME_US = 2**52  # as the node packets: a float64 holds it exactly (142 years of microseconds)
MAX_TORQUE_N_M = 10.0  # no motor on this rig gives more: a larger number is no command, N m
MOTORS = 2
FLAG_STOP = 0x01  # zero torque now (the controller's safe state)
FLAGS_KNOWN = FLAG_STOP
SEQ_MODULUS = 2**32

# Why the actuator applies zero torque (the status's reason; a command's stop reason is one of
# STOP_REASONS). Codes are the index.
REASONS = ("none", "timeout", "late", "limit", "node_silent", "waiting", "shutdown", "stop")
REASON_CODE = {name: code for code, name in enumerate(REASONS)}
STOP_REASONS = ("node_silent", "waiting", "shutdown", "stop")
"""Why a controller sends a stop: a node went silent, it has no state yet (waiting for the nodes),
it is ending (shutdown), or it was told to (stop)."""
SAFETY_REASONS = ("timeout", "late", "limit")
"""What the actuator finds itself: no fresh valid command for longer than its watchdog (timeout), a
command that arrived too old (late), a torque above its limit (limit)."""
STATES = ("ok", "safe")
BAD_PACKET_REASONS = (
    "truncated", "oversized", "bad_header", "crc", "bad_flags", "bad_time", "non_finite", "out_of_range",
)  # fmt: skip

# Command: magic, version, flags, stop reason, reserved, seq, controller time (us), tau1, tau2, CRC.
_COMMAND = struct.Struct("<4sBBBBIQffI")
COMMAND_SIZE = _COMMAND.size  # 32
# Status: magic, version, state, reason, reserved, seq, actuator time (us), tau1, tau2, bad packets,
# stale commands, safe events, commands taken (uint32 each), CRC.
_STATUS = struct.Struct("<4sBBBBIQffIIIII")
STATUS_SIZE = _STATUS.size  # 48


class ActuatorPacketError(Exception):
    """A datagram that is no valid actuator packet; ``reason`` is one of ``BAD_PACKET_REASONS``."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


@dataclasses.dataclass(frozen=True)
class Command:
    """A controller's command.

    Attributes:
      seq: sequence number, 0 to 2^32 - 1 (wraps).
      time_us: when it was sent on the controller's monotonic clock, us.
      torques_n_m: (tau1, tau2), N m (0, 0 with ``stop``).
      stop: zero torque now, for ``stop_reason`` (one of ``STOP_REASONS``).
      stop_reason: "none" unless ``stop``.
    """

    seq: int
    time_us: int
    torques_n_m: tuple[float, float]
    stop: bool = False
    stop_reason: str = "none"


@dataclasses.dataclass(frozen=True)
class Status:
    """The actuator's status, sent in answer to each valid command and whenever its state changes.

    Attributes:
      seq: the newest command it took (0 before any).
      time_us: when it was sent on the actuator's clock, us.
      state: "ok" (applying commands) or "safe" (zero torque).
      reason: why it is safe (one of ``REASONS``; "none" when ok).
      torques_n_m: (tau1, tau2) applied now, N m.
      bad_packets, stale_commands, safe_events, commands: its counters since it started.
    """

    seq: int
    time_us: int
    state: str
    reason: str
    torques_n_m: tuple[float, float]
    bad_packets: int = 0
    stale_commands: int = 0
    safe_events: int = 0
    commands: int = 0


def _check_size(data: bytes, size: int, what: str) -> None:
    if len(data) != size:
        reason = "truncated" if len(data) < size else "oversized"
        raise ActuatorPacketError(reason, f"{len(data)} bytes, a {what} has {size}")


def _check_crc(data: bytes, crc: int) -> None:
    if zlib.crc32(memoryview(data)[:-4]) != crc:
        raise ActuatorPacketError("crc", "CRC-32 does not match")


def _check_torques(values: tuple[float, float]) -> tuple[float, float]:
    if not all(math.isfinite(v) for v in values):
        raise ActuatorPacketError("non_finite", "a torque is NaN or infinite")
    if not all(abs(v) <= MAX_TORQUE_N_M for v in values):
        raise ActuatorPacketError("out_of_range", f"a torque beyond +-{MAX_TORQUE_N_M:g} N m")
    return values


def _check_time(time_us: int) -> None:
    if time_us >= MAX_TIME_US:
        raise ActuatorPacketError("bad_time", f"time {time_us} us, at most {MAX_TIME_US - 1}")


def encode_command(command: Command) -> bytes:
    """The 32-byte packet of a command (its fields checked as the decoder checks them: an
    ``ActuatorPacketError`` for a command no actuator would take)."""
    stop_code = REASON_CODE[command.stop_reason] if command.stop else 0
    if command.stop and command.stop_reason not in STOP_REASONS:
        raise ActuatorPacketError("bad_flags", f"stop reason {command.stop_reason!r}; allowed: {STOP_REASONS}")
    if not 0 <= command.seq < SEQ_MODULUS or not 0 <= command.time_us < MAX_TIME_US:
        raise ActuatorPacketError("out_of_range", "sequence number or time outside the packet's range")
    torques = (0.0, 0.0) if command.stop else _check_torques(command.torques_n_m)
    head = _COMMAND.pack(
        COMMAND_MAGIC, VERSION, FLAG_STOP if command.stop else 0, stop_code, 0, command.seq, command.time_us,
        *torques, 0,
    )  # fmt: skip
    return head[:-4] + struct.pack("<I", zlib.crc32(head[:-4]))


def decode_command(data: bytes) -> Command:
    """A command from a datagram, every field checked (module docstring)."""
    _check_size(data, COMMAND_SIZE, "command")
    magic, version, flags, stop_code, reserved, seq, time_us, tau1, tau2, crc = _COMMAND.unpack(data)
    if magic != COMMAND_MAGIC or version != VERSION or reserved:
        raise ActuatorPacketError("bad_header", f"magic {magic!r} version {version} reserved {reserved}")
    _check_crc(data, crc)
    if flags & ~FLAGS_KNOWN:
        raise ActuatorPacketError("bad_flags", f"flags {flags:#04x} has unknown bits set")
    stop = bool(flags & FLAG_STOP)
    if stop != (stop_code != 0) or (stop and not (stop_code < len(REASONS) and REASONS[stop_code] in STOP_REASONS)):
        raise ActuatorPacketError("bad_flags", f"stop flag {int(stop)} with stop reason code {stop_code}")
    _check_time(time_us)
    torques = _check_torques((tau1, tau2))
    if stop and torques != (0.0, 0.0):
        raise ActuatorPacketError("out_of_range", "a stop carries zero torque")
    return Command(seq, time_us, torques, stop, REASONS[stop_code] if stop else "none")


def encode_status(status: Status) -> bytes:
    """The 48-byte packet of a status."""
    counters = (status.bad_packets, status.stale_commands, status.safe_events, status.commands)
    packed = _STATUS.pack(
        STATUS_MAGIC, VERSION, STATES.index(status.state), REASON_CODE[status.reason], 0, status.seq % SEQ_MODULUS,
        status.time_us, *_check_torques(status.torques_n_m), *(c % SEQ_MODULUS for c in counters), 0,
    )  # fmt: skip
    return packed[:-4] + struct.pack("<I", zlib.crc32(packed[:-4]))


def decode_status(data: bytes) -> Status:
    """A status from a datagram, every field checked (module docstring): a known state, a reason
    that fits it (none when ok, another when safe), zero torque when safe."""
    _check_size(data, STATUS_SIZE, "status")
    fields = _STATUS.unpack(data)
    magic, version, state, reason, reserved, seq, time_us, tau1, tau2 = fields[:9]
    bad, stale, events, taken, crc = fields[9:]
    if magic != STATUS_MAGIC or version != VERSION or reserved:
        raise ActuatorPacketError("bad_header", f"magic {magic!r} version {version}")
    _check_crc(data, crc)
    if state >= len(STATES) or reason >= len(REASONS) or (state == 0) != (reason == 0):
        raise ActuatorPacketError("bad_flags", f"state {state} with reason code {reason}")
    _check_time(time_us)
    torques = _check_torques((tau1, tau2))
    if state == 1 and torques != (0.0, 0.0):
        raise ActuatorPacketError("out_of_range", "a safe actuator applies zero torque")
    return Status(seq, time_us, STATES[state], REASONS[reason], torques, bad, stale, events, taken)


def newer(seq: int, than: int) -> bool:
    """Whether sequence number ``seq`` comes after ``than`` (modulo 2^32, the nearer way)."""
    step = (seq - than) % SEQ_MODULUS
    return 0 < step < SEQ_MODULUS // 2


__all__ = [
    "BAD_PACKET_REASONS",
    "COMMAND_SIZE",
    "MAX_TORQUE_N_M",
    "REASONS",
    "SAFETY_REASONS",
    "STATUS_SIZE",
    "STOP_REASONS",
    "ActuatorPacketError",
    "Command",
    "Status",
    "decode_command",
    "decode_status",
    "encode_command",
    "encode_status",
    "newer",
]
