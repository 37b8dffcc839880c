"""The emulated rig with motors, live (``pendsim nodes --motor``): the rig stepped in real time
with the torques its actuator node applies, both sensor nodes sending what they measure, and the
actuator listening for commands, so that a controller closes the loop over real sockets.

One loop, paced by one monotonic schedule from the start (every event has a due time; the loop
sleeps until the next one and catches up in time order when late, so lateness never accumulates;
commands are taken at their kernel arrival stamps, so the emulated time line is exact even when
the loop reads them late; the loop asks for real-time scheduling where permitted, ``realtime``):

- **The rig** (``pendsim_mj.control.plant``: MuJoCo or the fast engine's force law) is held still
  at its initial angles for ``hold_s``, then released and stepped in physics steps of
  ``physics_step_s`` (1 ms: a torque acts on the rig within 1 ms of the motor applying it), each
  with the motor's torque at its start held over it; the chip's fused output is the state at the
  10 ms ticks (``dt_s``) from the release.
- **The nodes** sample on their own clocks (``emulator.NodeClock``: offset, drift, phase; seeded
  as ``pendsim nodes`` does) at ``rate_hz``: each sample is the latest fused value (the state at
  the sample's own instant, to the physics step, without fusion timing) measured through the
  BNO055 model (``bno055.hinge_readings``, ``bno055.LiveImu``: mount, noise, quantisation) and
  sent in the stream's format (``packets``) with the emulator's network faults where they apply
  live (``Faults``: loss, duplicates, jitter first in first out; not reordering or malformed
  packets). A node given in ``silent_after_s`` stops sending then (a node going silent).
- **The actuator** (``actuator.Actuator``) takes the command packets on its port: latency, jitter,
  torque limit, watchdog; it answers every valid command with a status and sends one whenever
  its state changes.

The log (JSON lines, streamed into a temporary file and published at the end) holds a header
(the spec, the loop's start on the host's monotonic clock in ns, so that another process on
this host can compare its own records), then, in time order: each 10 ms ``step`` (state and the
motor's torques), each ``sample`` (sent or not, why), each actuator event (``command``, ``apply``,
``safe``, ``bad_packet``: ``actuator.Event``), each node going ``silent``, and an ``end`` row with
the counters. Times are s since the start; tests check timings from it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import heapq
import json
import math
import selectors
import signal
import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from pendsim_mj.control.plant import PLANT_ENGINES, FastPlant, MujocoPlant, make_plant
from pendsim_mj.engines.fast_planar.closed_form import accelerations, coefficients
from pendsim_mj.errors import ParameterError, SimulationDiverged
from pendsim_mj.sensors.bno055 import LiveImu, hinge_readings

from ...io.outputs import atomic_output
from ...signals import signal_handlers
from ..datagrams import listen_udp, read_stamped
from ..emulator import EmulatorSpec, NodeClock, sample_rows
from .actuator import DEFAULT_ACTUATOR_PORT, Actuator, ActuatorSpec, Event
from .packets import encode_status
from .realtime import realtime

PHYSICS_STEP_S = 0.001
BLOCK = 256  # node sample instants computed at a time
LOG_SUFFIX = ".jsonl"


@dataclasses.dataclass(frozen=True)
class MotorRigSpec:
    """The emulated rig with motors.

    Attributes:
      nodes: the rig's run (release state, duration after it, hold, rig, engine, BNO055 model) and
        its nodes (ports, host, format, rate, faults, clocks, seed), as ``pendsim nodes`` sends them.
      actuator: the actuator's model (limit, latency, jitter, watchdog).
      actuator_bind: the address the actuator listens on.
      actuator_port: its UDP port.
      silent_after_s: (node, s since the start) pairs: the node sends nothing from then on.
      physics_step_s: the rig's physics step (divides ``nodes.run.dt_s``), s.
      realtime: ask for real-time scheduling (``realtime.realtime``; granted where permitted).
    """

    nodes: EmulatorSpec = dataclasses.field(default_factory=EmulatorSpec)
    actuator: ActuatorSpec = dataclasses.field(default_factory=ActuatorSpec)
    actuator_bind: str = "127.0.0.1"
    actuator_port: int = DEFAULT_ACTUATOR_PORT
    silent_after_s: tuple[tuple[str, float], ...] = ()
    physics_step_s: float = PHYSICS_STEP_S
    realtime: bool = True

    def __post_init__(self) -> None:
        run = self.nodes.run
        if run.engine not in PLANT_ENGINES:
            raise ParameterError(
                f"the rig with motors runs on {' or '.join(PLANT_ENGINES)}, not {run.engine!r} (use --engine)"
            )
        if run.model != "planar" or run.drive is not None:
            raise ParameterError("the rig with motors is the planar model, driven by its motors only")
        faults = self.nodes.faults
        if faults.reorder or faults.malformed:
            raise ParameterError("reordered and malformed node packets are not emulated live (drop them with --motor)")
        if run.imu.imperfections.hold_wobble_rad:
            raise ParameterError("hand wobble during the hold is not emulated live (drop it with --motor)")
        LiveImu(run.imu, run.params.g_m_s2)  # refuses whole-run processes, in one line
        if not 1 <= self.actuator_port <= 65535:
            raise ParameterError(f"actuator port must be in [1, 65535], got {self.actuator_port}")
        names = {n.name for n in self.nodes.nodes}
        for name, at_s in self.silent_after_s:
            if name not in names:
                raise ParameterError(f"node {name!r} is to go silent but is not sent")
            if not (math.isfinite(at_s) and at_s >= 0):
                raise ParameterError(f"a node goes silent at a time >= 0 s, got {at_s!r}")
        substeps = run.dt_s / self.physics_step_s
        if not (0 < self.physics_step_s <= run.dt_s and abs(substeps - round(substeps)) < 1e-9):
            raise ParameterError(
                f"the physics step {self.physics_step_s:g} s must divide the step {run.dt_s:g} s into whole steps"
            )


@dataclasses.dataclass(frozen=True)
class MotorRigResult:
    """What the emulated rig did.

    Attributes:
      duration_s: how long it ran, s.
      completed: ran to its end (False: stopped by a signal).
      sent, lost, silenced: node datagrams sent, samples lost by the network, samples a silent
        node did not send, per node.
      commands: commands taken (applied or queued to be); stale_commands: reordered or repeated;
      bad_packets: datagrams on the actuator's port that were no valid command, per reason.
      safe_events: times the actuator went to zero torque, per reason.
      max_lateness_ms: the worst lateness of a scheduled event (physics step, sample, send), ms.
      log: the log file (None: none written).
    """

    duration_s: float
    completed: bool
    sent: dict[str, int]
    lost: dict[str, int]
    silenced: dict[str, int]
    commands: int
    stale_commands: int
    bad_packets: dict[str, int]
    safe_events: dict[str, int]
    max_lateness_ms: float
    log: Path | None


class _Node:
    """One node's sampling and sending."""

    def __init__(self, spec: MotorRigSpec, index: int, rng: np.random.Generator) -> None:
        emu = spec.nodes
        self.spec = emu.nodes[index]
        self.index = self.spec.node_id - 1  # m1 measures M1, m2 measures M2
        self.codec = emu.stream.codec(self.spec.name, self.spec.node_id)
        self.period_s = 1.0 / emu.rate_hz
        self.clock: NodeClock = emu.clock(self.spec.name).resolved(rng, self.period_s)
        self.silent_s = dict(spec.silent_after_s).get(self.spec.name, math.inf)
        self.k = 0  # the next sample
        self._block: tuple[np.ndarray, np.ndarray, np.ndarray] = (np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
        self.last_due_s = 0.0
        self.sent = self.lost = self.silenced = 0

    def take(self, before_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The samples whose instants fall before ``before_s``: their numbers (n,), true instants
        (n,) s and device times (n,) us (the next ones from here on). The instants come from the
        node's clock a block of ``BLOCK`` samples at a time."""
        k, t_s, device_us = self._block
        if not len(k) or t_s[-1] < before_s:
            k = np.arange(self.k, self.k + BLOCK, dtype=np.int64)
            t_s, device_us = self.clock.instants(k, self.period_s)
        n = int(np.searchsorted(t_s, before_s, side="left"))
        self._block = (k[n:], t_s[n:], device_us[n:])
        self.k += n
        return k[:n], t_s[:n], device_us[:n]


class MotorRig:
    """The live loop (module docstring): ``run`` it once."""

    def __init__(self, spec: MotorRigSpec, *, say: Callable[[str], None] = print) -> None:
        self.spec, self.say = spec, say
        run = spec.nodes.run
        self.params = run.params
        self.dt_s, self.h_s = run.dt_s, spec.physics_step_s
        self.release_s, self.end_s = run.hold_s, spec.nodes.total_s
        self.plant = make_plant(run.engine, run.params, dt_s=self.h_s)
        self.x0 = self.plant.reset(run.phi0_rad, run.omega0_rad_s)[0]
        self._step, self._state = _stepper(self.plant)
        self.log_steps = round(run.dt_s / spec.physics_step_s)  # physics steps per 10 ms log row
        self.coef = coefficients([run.params])
        self.fusion_timing = run.imu.fusion_timing
        # The nodes read the state at the instants of a grid from the release: the chip's fused
        # ticks (dt_s), or every physics step without fusion timing.
        self.grid_steps = round(run.dt_s / spec.physics_step_s) if self.fusion_timing else 1
        self.grid_s = self.grid_steps * self.h_s
        self.grid_i = math.floor(-self.release_s / self.grid_s + 1e-9)  # the next grid instant's number
        self.imu = LiveImu(run.imu, run.params.g_m_s2)
        rng = np.random.default_rng(spec.nodes.seed)
        self.nodes = [_Node(spec, i, rng) for i in range(len(spec.nodes.nodes))]
        self.net_rng = np.random.default_rng([spec.nodes.seed, 11])
        self.actuator = Actuator(spec.actuator)
        self.j = 0  # the next physics step
        self.values: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # physics steps done -> (x, alpha) at a grid instant
        self.sends: list[tuple[float, int, int, bytes, int, int, float]] = []  # (due, order, node, ...)
        self.order = 0
        self.out: TextIO | None = None  # the log being written (a temporary file until the end)
        self.safe_counts: dict[str, int] = {}
        self.lateness_s = 0.0
        self.controller: Any = None  # the address of the latest valid command (a socket address)
        self._was_safe = True
        self.sock: socket.socket | None = None
        self.node_socks: list[socket.socket] = []

    # -- the log ---------------------------------------------------------------------------------

    def _row(self, row: dict[str, object]) -> None:
        if self.out is not None:
            self.out.write(json.dumps(row) + "\n")

    def _events(self, events: list[Event]) -> None:
        for event in events:
            self._row(event.as_dict())
            if event.kind == "safe":
                self.safe_counts[event.reason] = self.safe_counts.get(event.reason, 0) + 1
                self.say(f"actuator: zero torque at {event.t_s:.3f} s ({event.reason})")

    # -- the loop ----------------------------------------------------------------------------------

    def run(self, log: str | Path | None = None, *, replace_log: bool = False) -> MotorRigResult:
        """Listen, run to the end (or a signal), write the log (streamed into a temporary file beside
        it, published when complete; removed if the run fails); sockets closed on every exit."""
        spec = self.spec
        family = socket.AF_INET6 if ":" in spec.nodes.host else socket.AF_INET
        selector = selectors.DefaultSelector()
        with contextlib.ExitStack() as stack:
            stack.callback(selector.close)
            self.sock = stack.enter_context(
                listen_udp(spec.actuator_bind, spec.actuator_port, what="the actuator", option="--actuator-port")
            )
            selector.register(self.sock, selectors.EVENT_READ)
            if log is not None:
                self.out = stack.enter_context(open(stack.enter_context(atomic_output(log, replace=replace_log)), "w"))
            self.node_socks = [stack.enter_context(socket.socket(family, socket.SOCK_DGRAM)) for _ in self.nodes]
            a = spec.actuator
            self.say(
                f"emulated rig with motors: sending {spec.nodes.stream.format} to "
                f"{', '.join(f'{n.spec.name} {spec.nodes.host}:{n.spec.port}' for n in self.nodes)}; "
                f"commands on {spec.actuator_bind}:{spec.actuator_port} (limit {a.torque_limit_n_m:g} N m, latency "
                f"{a.command_latency_s * 1e3:g} ms + {a.command_jitter_s * 1e3:g} ms jitter, watchdog "
                f"{a.watchdog_s * 1e3:g} ms); {self.end_s:g} s ({self.release_s:g} s held, then released)"
            )
            granted = stack.enter_context(realtime(spec.realtime))
            if spec.realtime and not granted:
                self.say("note: real-time scheduling not permitted (needs root or CAP_SYS_NICE): normal priority")
            completed, duration = self._loop(selector)
            result = self._result(duration, completed, log)
            self._row({"kind": "end", **{k: v for k, v in dataclasses.asdict(result).items() if k != "log"}})
            self.out = None
        return result

    def _loop(self, selector: selectors.BaseSelector) -> tuple[bool, float]:
        start_ns = time.monotonic_ns()
        self.start_ns = start_ns
        self._row(self._header())
        assert self.sock is not None
        with _stop_on_signals() as stop:
            while True:
                # Commands first, each at its arrival (the kernel's stamp): whatever fell due before
                # it (the watchdog's deadline, a physics step) happens before the command is taken.
                for datagram in sorted(read_stamped(self.sock), key=lambda d: d.arrival_ns):
                    arrival = (datagram.arrival_ns - start_ns) * 1e-9
                    self._catch_up(min(arrival, self.end_s))
                    self._command(datagram.data, arrival, datagram.address)
                now = (time.monotonic_ns() - start_ns) * 1e-9
                self._catch_up(now)
                if stop:
                    return False, now
                if now >= self.end_s:
                    return True, now
                selector.select(max(0.0, min(self._next_due(), self.end_s) - now))

    def _dues(self) -> tuple[float, float, float, float]:
        """The next instants of: the actuator, a physics step, a grid value for the nodes, a send."""
        physics = self._at(self.j)
        grid = self._at(self.grid_i * self.grid_steps - 1)  # the value is known one step before
        send = self.sends[0][0] if self.sends else math.inf
        return self.actuator.due_s(), physics, max(grid, 0.0), send

    def _at(self, step: int) -> float:
        """The instant of physics step ``step`` (its start), s since the start (one formula: equal
        instants compare equal)."""
        return self.release_s + step * self.h_s

    def _next_due(self) -> float:
        """When the loop must wake next: the actuator, a grid value, a send. Physics steps need no
        wake-up of their own: each is computed, in time order, when something after it is due
        (every command that arrived before then has been read: their kernel stamps order them)."""
        actuator, _, grid, send = self._dues()
        return min(actuator, grid, send)

    def _catch_up(self, now: float) -> None:
        """Everything due by ``now``, in time order (at one instant: the actuator, then the physics,
        the nodes' samples, the sends)."""
        while True:
            actuator, physics, grid, send = self._dues()
            due = min(actuator, physics, grid, send)
            if due > now or due > self.end_s:
                return
            self.lateness_s = max(self.lateness_s, now - due)
            if actuator == due:
                self._actuator_events(self.actuator.advance(due), due)
            elif physics == due:
                self._physics_step(physics)
            elif grid == due:
                self._samples()
            else:
                self._send(now)

    def _actuator_events(self, events: list[Event], now: float) -> None:
        self._events(events)
        if any(e.kind == "safe" for e in events) or (events and self._was_safe):
            self._status(now)
        self._was_safe = self.actuator.state == "safe"

    def _command(self, data: bytes, arrival_s: float, address: Any) -> None:
        read_s = (time.monotonic_ns() - self.start_ns) * 1e-9
        events, valid = self.actuator.receive(data, arrival_s, read_s)
        self._events(events)
        if valid:
            self.controller = address
            self._status(arrival_s)
        self._was_safe = self.actuator.state == "safe"

    def _status(self, now: float) -> None:
        if self.controller is None or self.sock is None:
            return
        with contextlib.suppress(OSError):  # the controller is gone: nobody to tell
            self.sock.sendto(encode_status(self.actuator.status(now)), self.controller)

    def _physics_step(self, t_s: float) -> None:
        """Physics step ``j`` (from ``t_s``) with the motor's torque held over it; the state is read
        where it is wanted only (each 10 ms step's log row, each grid value)."""
        tau = self.actuator.torques_n_m
        if self.j % self.log_steps == 0:
            x = self._state()
            if not np.all(np.isfinite(x)):
                raise SimulationDiverged(f"the emulated rig diverged at t = {t_s:.3f} s")
            self._row({"kind": "step", "t_s": round(t_s, 7), "phi1_rad": float(x[0]), "phi2_rad": float(x[1]),
                       "omega1_rad_s": float(x[2]), "omega2_rad_s": float(x[3]), "tau1_n_m": tau[0],
                       "tau2_n_m": tau[1]})  # fmt: skip
        self._step(tau)
        self.j += 1
        if self.j % self.grid_steps == 0:  # a grid instant: what the nodes read next
            x = self._state()
            u = np.array([[tau[0]], [tau[1]], [0.0], [0.0]])
            a1, a2 = accelerations(x[0:1], x[1:2], x[2:3], x[3:4], self.coef, u)
            self.values[self.j] = (x, np.array([a1[0], a2[0]]))
            self.values.pop(self.j - 4 * self.grid_steps, None)

    def _samples(self) -> None:
        """The samples of both nodes whose instants fall in the next grid interval [G, G + grid):
        each reads the value at G (the pendulums held still before the release), measured through
        the BNO055 model in one batch; each then goes to the network (faults applied)."""
        steps = self.grid_i * self.grid_steps  # physics steps from the release to G
        g = self._at(steps)
        self.grid_i += 1
        if steps < 0:
            x, alpha = np.concatenate([self.x0[:2], np.zeros(2)]), np.zeros(2)
        elif steps == 0:  # the release instant itself
            x, alpha = self.x0, np.zeros(2)
        else:
            x, alpha = self.values[steps]
        taken = [node.take(min(g + self.grid_s, self.end_s + 1e-9)) for node in self.nodes]
        m = sum(len(k) for k, _, _ in taken)
        if not m:
            return
        instants = np.concatenate([t for _, t, _ in taken])
        rows = np.broadcast_to(x, (m, 4))
        readings = hinge_readings(self.params, rows[:, :2], rows[:, 2:], np.broadcast_to(alpha, (m, 2)))
        measured = self.imu.measure(readings, instants)
        first = 0
        for node, (seqs, t_s, device_us) in zip(self.nodes, taken, strict=True):
            n = len(seqs)
            if n:
                values = sample_rows(measured, node.index, np.arange(first, first + n))
                for seq, t, us, row in zip(seqs, t_s, device_us, values, strict=True):
                    self._network(node, int(seq), float(t), int(us), node.codec.encode(int(seq), int(us), row))
            first += n

    def _network(self, node: _Node, seq: int, t_s: float, device_us: int, payload: bytes) -> None:
        """One sample's packet to the network: silent node, loss, jitter (first in first out),
        duplicate."""
        row: dict[str, object] = {"kind": "sample", "node": node.spec.name, "seq": seq, "device_time_us": device_us,
                                  "t_s": round(t_s, 7)}  # fmt: skip
        if t_s >= node.silent_s:
            if not node.silenced:
                self._row({"kind": "silent", "node": node.spec.name, "t_s": round(t_s, 7)})
                self.say(f"node {node.spec.name}: silent from {t_s:.3f} s")
            node.silenced += 1
            return
        faults = self.spec.nodes.faults
        if faults.loss and self.net_rng.random() < faults.loss:
            node.lost += 1
            self._row({**row, "sent": False})
            return
        delay = self.net_rng.exponential(faults.jitter_ms * 1e-3) if faults.jitter_ms > 0 else 0.0
        due = max(t_s + delay, node.last_due_s)  # first in first out
        node.last_due_s = due
        copies = 2 if faults.duplicate and self.net_rng.random() < faults.duplicate else 1
        for _ in range(copies):
            heapq.heappush(self.sends, (due, self.order, self.nodes.index(node), payload, seq, device_us, t_s))
            self.order += 1

    def _send(self, now: float) -> None:
        _, _, index, payload, seq, device_us, t_s = heapq.heappop(self.sends)
        node = self.nodes[index]
        with contextlib.suppress(OSError):  # nobody listening: the packet is simply gone
            self.node_socks[index].sendto(payload, (self.spec.nodes.host, node.spec.port))
        node.sent += 1
        self._row({"kind": "sample", "node": node.spec.name, "seq": seq, "device_time_us": device_us,
                   "t_s": round(t_s, 7), "sent": True, "sent_s": round(now, 7)})  # fmt: skip

    # -- the end -----------------------------------------------------------------------------------

    def _result(self, duration_s: float, completed: bool, log: str | Path | None) -> MotorRigResult:
        a = self.actuator
        return MotorRigResult(
            duration_s=duration_s,
            completed=completed,
            sent={n.spec.name: n.sent for n in self.nodes},
            lost={n.spec.name: n.lost for n in self.nodes},
            silenced={n.spec.name: n.silenced for n in self.nodes},
            commands=a.commands,
            stale_commands=a.stale_commands,
            bad_packets=dict(a.bad_reasons),
            safe_events=dict(self.safe_counts),
            max_lateness_ms=self.lateness_s * 1e3,
            log=Path(log) if log is not None else None,
        )

    def _header(self) -> dict[str, object]:
        """The log's first row: how the rig runs, its start on the host's monotonic clock."""
        spec = self.spec
        emu = spec.nodes
        header = {
            "kind": "header",
            "start_monotonic_ns": self.start_ns,
            "format": emu.stream.format,
            "rate_hz": emu.rate_hz,
            "seed": emu.seed,
            "engine": emu.run.engine,
            "phi0_rad": list(emu.run.phi0_rad),
            "omega0_rad_s": list(emu.run.omega0_rad_s),
            "hold_s": self.release_s,
            "end_s": self.end_s,
            "dt_s": self.dt_s,
            "physics_step_s": self.h_s,
            "fusion_timing": self.fusion_timing,
            "noise": emu.run.imu.noise,
            "faults": dataclasses.asdict(emu.faults),
            "actuator": {
                **dataclasses.asdict(spec.actuator),
                "watchdog_s": spec.actuator.watchdog_s,
                "age_limit_s": spec.actuator.age_limit_s,
                "bind": spec.actuator_bind,
                "port": spec.actuator_port,
            },
            "nodes": {n.spec.name: {"port": n.spec.port, **dataclasses.asdict(n.clock)} for n in self.nodes},
            "silent_after_s": dict(spec.silent_after_s),
        }
        return header


@contextlib.contextmanager
def _stop_on_signals() -> Iterator[list[int]]:
    stop: list[int] = []
    with signal_handlers(dict.fromkeys((signal.SIGINT, signal.SIGTERM), lambda signum, frame: stop.append(signum))):
        yield stop


def _stepper(
    plant: FastPlant | MujocoPlant,
) -> tuple[Callable[[tuple[float, float]], None], Callable[[], np.ndarray]]:
    """(step, state) of ``plant``: one physics step with the motors' torques held over it, and the
    state (4,) now. MuJoCo: ``mj_step`` on the plant's own model and data with ``ctrl`` set (the
    plant's ``step`` less its per-call argument checks and state copy, several times cheaper: the
    loop runs 1000 steps a second); the fast plant: its unchecked ``advance``."""
    if isinstance(plant, MujocoPlant):
        import mujoco  # start-up: loaded already by the plant

        model, data = plant.model, plant.data

        held: list[tuple[float, float]] = [(0.0, 0.0)]

        def step_mujoco(tau: tuple[float, float]) -> None:
            if tau != held[0]:  # the plant's actuators: torque on M1, torque on M2
                data.ctrl[:] = tau
                held[0] = tau
            mujoco.mj_step(model, data)

        return step_mujoco, lambda: plant.state[0]

    def step_fast(tau: tuple[float, float]) -> None:
        plant.advance(np.array([[tau[0]], [tau[1]], [0.0], [0.0]]))

    return step_fast, lambda: plant.columns[:, 0].copy()


def run_motor_rig(
    spec: MotorRigSpec,
    *,
    log: str | Path | None = None,
    replace_log: bool = False,
    say: Callable[[str], None] = print,
) -> MotorRigResult:
    """Run the emulated rig with motors in real time (module docstring) and write its log.

    Raises:
      ParameterError: the actuator's port cannot be bound (one line; nothing is written).
    """
    return MotorRig(spec, say=say).run(log, replace_log=replace_log)


def read_log(path: str | Path) -> tuple[dict[str, object], list[dict[str, object]]]:
    """A log written by the emulated rig: (header, the other rows in order)."""
    lines = Path(path).read_text().splitlines()
    return json.loads(lines[0]), [json.loads(line) for line in lines[1:]]


def summary(result: MotorRigResult) -> str:
    """The lines printed at the end."""
    lines = [
        f"{name}: {result.sent[name]} datagrams sent, {result.lost[name]} samples lost"
        + (f", silent for {result.silenced[name]} samples" if result.silenced[name] else "")
        for name in result.sent
    ]
    bad = sum(result.bad_packets.values())
    safe = ", ".join(f"{k} {v}" for k, v in sorted(result.safe_events.items())) or "none"
    lines.append(
        f"actuator: {result.commands} commands taken, {result.stale_commands} stale, {bad} bad packets"
        + (f" ({', '.join(f'{k} {v}' for k, v in sorted(result.bad_packets.items()))})" if bad else "")
        + f"; zero-torque events: {safe}"
    )
    state = "done" if result.completed else "stopped early"
    lines.append(f"{state} after {result.duration_s:.1f} s; worst lateness {result.max_lateness_ms:.2f} ms")
    if result.log is not None:
        lines.append(f"wrote {result.log}")
    return "\n".join(lines)


__all__ = ["LOG_SUFFIX", "MotorRig", "MotorRigResult", "MotorRigSpec", "read_log", "run_motor_rig", "summary"]
