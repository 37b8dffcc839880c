"""The actuator node of the emulated rig: what it does with the commands it receives, in time
(seeded; no sockets here, times are given: the emulated rig's loop and the tests drive it).

- **Commands take effect late**: a valid, fresh command within the limit is applied
  ``command_latency_s`` plus an exponentially distributed delay of mean ``command_jitter_s`` after
  it arrived, first in first out (a command never takes effect before an earlier one).
- **Safety first, at once**: each of these zeroes the torque the moment it is found (pending
  commands are dropped) and says why (``Status.reason``), until a later valid command takes effect:

  - ``timeout``: no valid fresh command arrived for ``watchdog_s`` = the control period plus
    ``watchdog_margin_s`` (the controller stopped, or its commands are lost);
  - ``late``: a command arrived more than ``max_command_age_s`` (default one control period) after
    it was sent, measured on the controller's time stamps through the lower-envelope clock fit
    of the commands taken so far (``ClockFit``: the delay beyond the fastest command seen; the
    clocks need not agree);
  - ``limit``: a command asks a motor for more than ``torque_limit_n_m`` (with 1e-6 relative
    slack for the float32 rounding of a torque at the limit);
  - a stop (the command's stop flag): the controller asks for zero torque (a node went silent, it
    has no state yet, it is ending), with its reason; taken however late it arrives.

- **Stray datagrams change nothing**: a bad packet (``packets.BAD_PACKET_REASONS``) or a stale
  command (its sequence number not newer than the newest taken: reordered or repeated) is
  counted and otherwise ignored, so that no single datagram can move or stop the motor; a stream
  of them ends in the watchdog's timeout.
- **Sessions**: a valid command more than ``SESSION_GAP_S`` after the previous one, with the motors
  at zero, starts a new session: its sequence numbers and clock are learnt afresh (a controller
  run again numbers its commands from 0).

Every valid command gets a status in answer; every change of state is a status too.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from pendsim_mj.errors import ParameterError

from ..clock import ClockFit
from .packets import (
    ActuatorPacketError,
    Command,
    Status,
    decode_command,
    newer,
)

LIMIT_SLACK = 1e-6  # relative: a float32 torque at the limit rounds up by at most 6e-8
DEFAULT_ACTUATOR_PORT = 5603


@dataclasses.dataclass(frozen=True)
class ActuatorSpec:
    """The actuator's model.

    Attributes:
      torque_limit_n_m: each motor's limit, N m (a command above it: safe zero torque).
      command_latency_s: from a command's arrival to its effect, s.
      command_jitter_s: mean of the exponential delay added to the latency, s.
      command_period_s: the controller's period the watchdog expects, s.
      watchdog_margin_s: the watchdog's slack beyond one period, s.
      max_command_age_s: the oldest a command may arrive (its delay beyond the fastest command
        seen), s; None: one control period.
      seed: the jitter's draws.
    """

    torque_limit_n_m: float = 0.05
    command_latency_s: float = 0.002
    command_jitter_s: float = 0.0005
    command_period_s: float = 0.01
    watchdog_margin_s: float = 0.01
    max_command_age_s: float | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        checks = (
            ("torque_limit_n_m", self.torque_limit_n_m, 0.0, 10.0, True),
            ("command_latency_s", self.command_latency_s, 0.0, 1.0, False),
            ("command_jitter_s", self.command_jitter_s, 0.0, 1.0, False),
            ("command_period_s", self.command_period_s, 0.0, 0.1, True),
            ("watchdog_margin_s", self.watchdog_margin_s, 0.0, 1.0, False),
        )
        for name, value, low, high, low_open in checks:
            if not (math.isfinite(value) and (value > low if low_open else value >= low) and value <= high):
                bound = f"({low:g}, {high:g}]" if low_open else f"[{low:g}, {high:g}]"
                raise ParameterError(f"{name} must be in {bound}, got {value!r}")
        age = self.max_command_age_s
        if age is not None and not (math.isfinite(age) and 0 < age <= 1.0):
            raise ParameterError(f"max_command_age_s must be in (0, 1] s, got {age!r}")

    @property
    def watchdog_s(self) -> float:
        """No valid fresh command for this long: safe zero torque, s."""
        return self.command_period_s + self.watchdog_margin_s

    @property
    def age_limit_s(self) -> float:
        return self.max_command_age_s if self.max_command_age_s is not None else self.command_period_s


@dataclasses.dataclass(frozen=True)
class Event:
    """Something the actuator did, for the log.

    Attributes:
      kind: "command" (a valid command arrived; ``decision``: queued, stop, late, limit or stale),
        "apply" (a command's torques became the motor's), "safe" (zero torque, ``reason``),
        "bad_packet" (``reason``: one of ``packets.BAD_PACKET_REASONS``).
      t_s: when it happened on the actuator's (emulated) time line, s on the emulator's clock: a
        command's arrival (the kernel's stamp), a command's effect instant, the watchdog's deadline.
      seq: the command's sequence number (-1: none).
      torques_n_m: the command's (command) or the motor's (apply, safe) torques, N m.
      reason: why (safe, bad_packet); the decision (command).
      detected_s: when the fault was found (safe: the watchdog's deadline, or the arrival of the
        command that showed it), s.
      arrival_s: the command's arrival (command, apply, safe from a command), s.
      age_s: the command's delay beyond the fastest command seen (command), s.
      read_s: when the emulator's loop read the command (command; its lateness is read_s - t_s), s.
    """

    kind: str
    t_s: float
    seq: int = -1
    torques_n_m: tuple[float, float] = (0.0, 0.0)
    reason: str = ""
    detected_s: float = math.nan
    arrival_s: float = math.nan
    age_s: float = math.nan
    read_s: float = math.nan

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {"kind": self.kind, "t_s": round(self.t_s, 7)}
        if self.seq >= 0:
            out["seq"] = self.seq
        if self.kind != "bad_packet":
            out["tau1_n_m"], out["tau2_n_m"] = self.torques_n_m
        if self.reason:
            out["reason"] = self.reason
        for name in ("detected_s", "arrival_s", "age_s", "read_s"):
            value = getattr(self, name)
            if math.isfinite(value):
                out[name] = round(value, 7)
        return out


SESSION_GAP_S = 0.5
"""s: a valid command this long after the previous one, the motors at zero, starts a new session
(a controller restarted numbers its commands from 0 again: otherwise all would be stale)."""


class Actuator:
    """The actuator's state machine (module docstring); times are s on one monotonic clock."""

    def __init__(self, spec: ActuatorSpec) -> None:
        self.spec = spec
        self._rng = np.random.default_rng([spec.seed, 7])
        self.torques_n_m = (0.0, 0.0)
        self.state, self.reason = "safe", "waiting"
        self.last_seq: int | None = None
        self.last_valid_s: float | None = None  # arrival of the latest valid fresh command (a stop too)
        self._pending: list[tuple[float, int, tuple[float, float], float]] = []  # (effect, seq, torques, arrival)
        self._clock = ClockFit()
        self.bad_packets = 0
        self.bad_reasons: dict[str, int] = {}
        self.stale_commands = 0
        self.safe_events = 0
        self.commands = 0

    def status(self, now_s: float) -> Status:
        """The status to send now (the actuator's time stamp: ``now_s`` in us)."""
        return Status(
            seq=self.last_seq if self.last_seq is not None else 0,
            time_us=max(0, round(now_s * 1e6)),
            state=self.state,
            reason=self.reason,
            torques_n_m=self.torques_n_m,
            bad_packets=self.bad_packets,
            stale_commands=self.stale_commands,
            safe_events=self.safe_events,
            commands=self.commands,
        )

    def receive(self, data: bytes, arrival_s: float, read_s: float) -> tuple[list[Event], bool]:
        """A datagram that arrived at ``arrival_s`` (read at ``read_s``), taken at its arrival (what
        was due before it must have been ``advance``d): the events, and whether it was a valid
        command (to be answered with a status)."""
        try:
            command = decode_command(data)
        except ActuatorPacketError as exc:
            self.bad_packets += 1
            self.bad_reasons[exc.reason] = self.bad_reasons.get(exc.reason, 0) + 1
            return [Event("bad_packet", arrival_s, reason=exc.reason, arrival_s=arrival_s, read_s=read_s)], False
        return self._take(command, arrival_s, read_s), True

    def _take(self, command: Command, arrival_s: float, read_s: float) -> list[Event]:
        sent_s = command.time_us * 1e-6
        now_s = arrival_s

        def noted(decision: str, age_s: float = math.nan) -> Event:
            return Event("command", arrival_s, command.seq, command.torques_n_m, decision, arrival_s=arrival_s,
                         age_s=age_s, read_s=read_s)  # fmt: skip

        if self.state == "safe" and self.last_valid_s is not None and arrival_s - self.last_valid_s > SESSION_GAP_S:
            # a new controller (or the same one after a long silence): its sequence and clock start
            # afresh; within a session a sequence number not newer than the last is stale
            self.last_seq, self._clock = None, ClockFit()
        if self.last_seq is not None and not newer(command.seq, self.last_seq):
            self.stale_commands += 1
            return [noted("stale")]
        self.last_seq = command.seq
        age_s = arrival_s - float(self._clock.relation().to_recorder(sent_s)) if self._clock.count else 0.0
        late = age_s > self.spec.age_limit_s
        if command.stop:  # zero torque is always safe: a stop is taken however late
            if not late:
                self._clock.add(sent_s, arrival_s)
                self.last_valid_s = arrival_s
            return [noted("stop", age_s), *self._safe(command.stop_reason, now_s, arrival_s, command.seq)]
        if late:
            return [noted("late", age_s), *self._safe("late", now_s, arrival_s, command.seq)]
        self._clock.add(sent_s, arrival_s)
        self.last_valid_s = arrival_s
        limit = self.spec.torque_limit_n_m * (1.0 + LIMIT_SLACK)
        if any(abs(t) > limit for t in command.torques_n_m):
            return [noted("limit", age_s), *self._safe("limit", now_s, arrival_s, command.seq)]
        self.commands += 1
        jitter = self._rng.exponential(self.spec.command_jitter_s) if self.spec.command_jitter_s > 0 else 0.0
        effect = arrival_s + self.spec.command_latency_s + jitter
        if self._pending:
            effect = max(effect, self._pending[-1][0])
        self._pending.append((effect, command.seq, command.torques_n_m, arrival_s))
        return [noted("queued", age_s)]

    def _safe(self, reason: str, now_s: float, detected_s: float, seq: int = -1) -> list[Event]:
        """Zero torque now, pending commands dropped; one event unless already safe for this reason."""
        self._pending.clear()
        if self.state == "safe" and self.reason == reason:
            return []
        self.state, self.reason, self.torques_n_m = "safe", reason, (0.0, 0.0)
        self.safe_events += 1
        return [Event("safe", now_s, seq, (0.0, 0.0), reason, detected_s=detected_s, arrival_s=detected_s)]

    def watchdog_deadline_s(self) -> float:
        """When the watchdog fires if no valid command arrives (inf: not armed: no command yet, or
        already safe for a timeout)."""
        if self.last_valid_s is None or (self.state == "safe" and self.reason == "timeout"):
            return math.inf
        return self.last_valid_s + self.spec.watchdog_s

    def due_s(self) -> float:
        """The next instant ``advance`` has something to do (inf: nothing pending)."""
        effect = self._pending[0][0] if self._pending else math.inf
        return min(effect, self.watchdog_deadline_s())

    def advance(self, now_s: float) -> list[Event]:
        """Everything due by ``now_s``, in time order, each at its own instant: commands taking
        effect, the watchdog's deadline."""
        events: list[Event] = []
        while True:
            deadline = self.watchdog_deadline_s()
            effect = self._pending[0][0] if self._pending else math.inf
            if min(deadline, effect) > now_s:
                return events
            if deadline <= effect:
                events += self._safe("timeout", deadline, deadline)
                continue
            _, seq, torques, arrival = self._pending.pop(0)
            self.state, self.reason, self.torques_n_m = "ok", "none", torques
            events.append(Event("apply", effect, seq, torques, arrival_s=arrival))


__all__ = ["DEFAULT_ACTUATOR_PORT", "Actuator", "ActuatorSpec", "Event"]
