"""``pendsim nodes``: an emulator of the rig's two sensor nodes, sending UDP packets in real time.

What each node does, and how it is emulated:

- **The measurement** comes from the simulated rig (the MuJoCo model or the planar reference,
  ``run.record.simulate_for``) through pendsim's BNO055 model (``pendsim_mj.sensors.bno055``): the chip
  fuses at 100 Hz and the node reads the latest fused value (with its noise and quantisation)
  at each of its own sample instants. The pendulums are held still for ``hold_s`` before the
  release, as in a real recording.
- **The node's clock** runs at its own rate: device time D(t) = D0 + (1 + drift) t, t the true time
  since the stream started. The node samples when its clock reaches D0 + (1 + drift) phase + k/rate,
  so it samples at true instants t_k = phase + k / (rate (1 + drift)) and stamps them with D(t_k).
  D0 (the node's uptime at the start) and phase (0 to one period) are drawn from the seed unless
  given.
- **The network** (seeded, per packet): ``loss`` drops it; ``duplicate`` sends it twice;
  ``reorder`` holds it back until the packet ``reorder_depth`` places later has gone (after
  ``reorder_depth`` later packets, fewer if some of those were held back too); ``jitter_ms`` delays
  it by an exponentially distributed time of that mean, first in first out (a delayed packet holds
  back those behind it, none overtakes another); ``malformed`` sends an extra broken datagram
  (truncated, oversized, wrong CRC, wrong header, wrong node, non-finite, unparsable, as the
  format allows) before it.
- **Pacing**: every datagram has a due time on one schedule from the start (t_k plus its delays);
  the sender sleeps until each is due, so lateness never accumulates.
- **Scripted rig faults** (``rig_faults``, ``pendsim nodes --fault``): the rig's springs, hinge
  damping or dry friction change at an instant or along a ramp (the run simulated piece by piece,
  each from the state the one before ended in, ``pendsim_mj.engines.piecewise``); a node turns on its
  mount about the hinge axis (its samples from then on are those of the turned mount, the same
  noise); a node's clock jumps (its device times from then on). ``rig_faults.py`` has the grammar.
- **The log** (JSON lines or CSV, by the file's extension) lists every datagram sent, in order,
  with its actual send time, node, sequence number, device time, kind (data, duplicate,
  malformed), whether it was reordered and, for a malformed one, the reason the receiver should
  give; and every sample the network lost (``sent`` false). Tests compare it with what
  ``pendsim acquire`` counted.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import signal
import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.engines import dispatch as engines
from pendsim_mj.engines.piecewise import run_pieces, schedule_pieces
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.checks import check_step
from pendsim_mj.sensors import rotations
from pendsim_mj.sensors.bno055 import SAMPLE_RATE_HZ, ImuSamples, sample_imu

from ..io.outputs import atomic_output
from ..run.record import RecordSpec, simulate_for
from ..signals import signal_handlers
from .packets import GROUP_SLICES, ROW_FIELDS, CsvCodec, JsonCodec, StreamFormat, V1Codec
from .ports import DEFAULT_NODES, NodeSpec, check_nodes
from .rig_faults import RAMP_PIECE_S, PlayedFault, RigFault, resolve_faults

LOG_SUFFIXES = (".jsonl", ".csv")
LOG_COLUMNS = ("t_s", "node", "port", "seq", "device_time_us", "kind", "reordered", "reason", "bytes", "sent")
MALFORMED_KINDS = {
    "pendsim-v1": ("truncated", "oversized", "crc", "bad_header", "wrong_node"),
    "csv": ("truncated", "oversized", "non_finite", "unparsable", "wrong_node"),
    "json": ("truncated", "oversized", "non_finite", "unparsable", "wrong_node"),
}


@dataclasses.dataclass(frozen=True)
class Faults:
    """Seeded network faults, per packet (rates in [0, 1])."""

    loss: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    reorder_depth: int = 2
    jitter_ms: float = 0.0
    malformed: float = 0.0

    def __post_init__(self) -> None:
        for name in ("loss", "duplicate", "reorder", "malformed"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise ParameterError(f"{name} must be a rate in [0, 1], got {value!r}")
        if not 1 <= self.reorder_depth <= 1000:
            raise ParameterError(f"reorder_depth must be in [1, 1000] packets, got {self.reorder_depth!r}")
        if not (math.isfinite(self.jitter_ms) and 0.0 <= self.jitter_ms <= 10_000):
            raise ParameterError(f"jitter_ms must be in [0, 10000] ms, got {self.jitter_ms!r}")


@dataclasses.dataclass(frozen=True)
class NodeClock:
    """A node's clock: rate error (ppm, + runs fast), its reading at the stream's start (s) and
    the phase of its first sample (s after the start); None: drawn from the seed."""

    drift_ppm: float = 0.0
    offset_s: float | None = None
    phase_s: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.drift_ppm) and abs(self.drift_ppm) <= 1000):
            raise ParameterError(f"clock drift must be within +-1000 ppm, got {self.drift_ppm!r}")
        if self.offset_s is not None and not (math.isfinite(self.offset_s) and 0 <= self.offset_s < 1e9):
            raise ParameterError(f"clock offset must be in [0, 1e9) s, got {self.offset_s!r}")
        if self.phase_s is not None and not (math.isfinite(self.phase_s) and self.phase_s >= 0):
            raise ParameterError(f"clock phase must be >= 0 s, got {self.phase_s!r}")

    def resolved(self, rng: np.random.Generator, period_s: float) -> NodeClock:
        """This clock with its offset (10-600 s) and phase (within one period) drawn from ``rng``
        where not given (offset first)."""
        offset_s = self.offset_s if self.offset_s is not None else float(rng.uniform(10.0, 600.0))
        phase_s = self.phase_s if self.phase_s is not None else float(rng.uniform(0.0, period_s))
        return NodeClock(self.drift_ppm, offset_s, phase_s)

    def instants(self, k: NDArray[np.int64], period_s: float) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Samples k (n,) of a resolved clock: their true instants (s since the stream's start)
        and device times (us). The node samples when its clock reaches D0 + (1 + drift) phase + k
        period, at t_k = phase + k period / (1 + drift)."""
        assert self.offset_s is not None and self.phase_s is not None, "resolve the clock first"
        rate = 1.0 + self.drift_ppm * 1e-6
        t_s = np.asarray(self.phase_s + k * period_s / rate, dtype=np.float64)
        device_us = np.rint((self.offset_s + rate * self.phase_s + k * period_s) * 1e6).astype(np.int64)
        return t_s, device_us


@dataclasses.dataclass(frozen=True)
class EmulatorSpec:
    """What the emulated nodes send.

    Attributes:
      run: the simulated run (release, duration after it, hold before it, rig, BNO055 model).
      nodes: names and destination ports.
      host: where to send.
      stream: the packet format.
      rate_hz: each node's sample rate on its own clock.
      faults: network faults.
      clocks: per node name, its clock (default: no drift, seeded offset and phase).
      seed: seeds the faults and the clocks (the BNO055 noise has run.imu.seed).
      rig_faults: scripted faults of the rig and the nodes (``rig_faults.parse_fault``), times
        after the release; drawn times follow ``seed``.
    """

    run: RecordSpec = dataclasses.field(default_factory=lambda: RecordSpec(hold_s=2.0))
    nodes: tuple[NodeSpec, ...] = DEFAULT_NODES
    host: str = "127.0.0.1"
    stream: StreamFormat = dataclasses.field(default_factory=StreamFormat)
    rate_hz: float = SAMPLE_RATE_HZ
    faults: Faults = Faults()
    clocks: tuple[tuple[str, NodeClock], ...] = ()
    seed: int = 0
    rig_faults: tuple[RigFault, ...] = ()

    def __post_init__(self) -> None:
        check_nodes(self.nodes)
        if not (math.isfinite(self.rate_hz) and 0 < self.rate_hz <= 100_000):
            raise ParameterError(f"rate_hz must be in (0, 100000] Hz, got {self.rate_hz!r}")
        if self.run.model == "static":
            raise ParameterError("the emulator sends a released run; the static model is not supported")
        known = {n.name for n in self.nodes}
        for name, _ in self.clocks:
            if name not in known:
                raise ParameterError(f"a clock is given for node {name!r}, which is not sent to")
        if any(f.physics for f in self.rig_faults) and (self.run.drive is not None or self.run.model != "planar"):
            raise ParameterError("rig faults of the physics are for a free run of the planar model")
        self.played_faults()  # every fault checked against the run

    def played_faults(self) -> tuple[PlayedFault, ...]:
        """The rig faults resolved against the run (drawn times drawn from ``seed``), in the order given."""
        if not self.rig_faults:
            return ()
        return resolve_faults(
            self.rig_faults, params=self.run.params, duration_s=self.run.duration_s, dt_s=self.run.dt_s,
            nodes=[n.name for n in self.nodes], seed=self.seed,
        )  # fmt: skip

    @property
    def total_s(self) -> float:
        """Streamed time: the hold and the run after the release, s."""
        return self.run.hold_s + self.run.duration_s

    def clock(self, name: str) -> NodeClock:
        return dict(self.clocks).get(name, NodeClock())


@dataclasses.dataclass(frozen=True)
class Datagram:
    """One planned datagram (or a lost sample: ``sent`` False)."""

    due_s: float  # send time after the start
    node: str
    port: int
    seq: int
    device_time_us: int
    kind: str  # "data", "duplicate", "malformed"
    reordered: bool
    reason: str  # for malformed ones: what the receiver should count
    payload: bytes
    sent: bool = True


@dataclasses.dataclass(frozen=True)
class NodeStreamPlan:
    """One node's samples as sent: sequence numbers, device times, true instants, rows."""

    name: str
    seq: NDArray[np.int64]  # (K,)
    device_time_us: NDArray[np.int64]  # (K,)
    t_s: NDArray[np.float64]  # (K,) true sample instants since the start
    rows: NDArray[np.float64]  # (K, len(ROW_FIELDS)) SI
    clock: NodeClock  # with offset and phase resolved


@dataclasses.dataclass(frozen=True)
class Plan:
    """Everything the emulator will send, in order."""

    spec: EmulatorSpec
    streams: tuple[NodeStreamPlan, ...]
    datagrams: tuple[Datagram, ...]  # sorted by due time; lost samples included (sent False)
    rig_faults: tuple[PlayedFault, ...] = ()  # as resolved, in the order given

    def sent_in_time_order(self) -> list[tuple[float, int, int]]:
        """Every data sample that is sent (not lost), as (true instant s, stream index, sample index),
        in time order: what a receiver with perfect clocks would take in (offline benchmarks and
        tests feed ``TwinSession`` with it)."""
        sent = {(d.node, d.seq) for d in self.datagrams if d.sent and d.kind == "data"}
        return sorted(
            (float(st.t_s[i]), k, i)
            for k, st in enumerate(self.streams)
            for i in range(len(st.t_s))
            if (st.name, int(st.seq[i])) in sent
        )


def node_rows(samples: ImuSamples, node_index: int, t_s: NDArray[np.float64]) -> NDArray[np.float64]:
    """The node's readings at true instants t_s (s since the start of the samples): the latest
    fused value at or before each, from 100 Hz ``samples``; (K, len(ROW_FIELDS))."""
    j = np.clip(np.floor(t_s * samples.config.sample_rate_hz + 1e-9).astype(np.int64), 0, len(samples.t_s) - 1)
    return sample_rows(samples, node_index, j)


def sample_rows(samples: ImuSamples, node_index: int, j: NDArray[np.int64]) -> NDArray[np.float64]:
    """The node's samples number j (K,) as packet rows (K, len(ROW_FIELDS)), SI."""
    rows = np.empty((len(j), len(ROW_FIELDS)))
    rows[:, GROUP_SLICES["quat"]] = samples.quat_wxyz[j, node_index]
    rows[:, GROUP_SLICES["gyro"]] = samples.gyro_rad_s[j, node_index]
    rows[:, GROUP_SLICES["accel"]] = samples.accel_m_s2[j, node_index]
    rows[:, GROUP_SLICES["linear"]] = samples.linear_accel_m_s2[j, node_index]
    rows[:, GROUP_SLICES["gravity"]] = samples.gravity_m_s2[j, node_index]
    rows[:, GROUP_SLICES["calib"]] = samples.calibration[j, node_index]
    return rows


def simulated(run: RecordSpec, faults: tuple[PlayedFault, ...] = ()) -> Trajectory:
    """The run (``simulate_for``), or, with physics faults, the run in pieces (each from the state
    the one before ended in, with its own parameters; a ramp in pieces of ``RAMP_PIECE_S`` at its
    midpoint value), on the same engine."""
    changes = [f.change(run.dt_s) for f in faults if f.fault.physics]
    if not changes:
        return simulate_for(run)
    nstep = check_step(run.duration_s, run.dt_s)
    every = max(1, round(RAMP_PIECE_S / run.dt_s))
    pieces = [p for p in schedule_pieces(run.params, changes, ramp_every=every) if p[0] < nstep]
    engine = engines.FAST_PATH.get(run.engine, run.engine)
    return run_pieces(engine, pieces, run.phi0_rad, run.omega0_rad_s, run.duration_s, run.dt_s)


def fused_samples(run: RecordSpec, faults: tuple[PlayedFault, ...] = ()) -> ImuSamples:
    """Both nodes' BNO055 outputs at the chip's fusion rate over the hold and the run, with the
    rig faults ``faults`` (``EmulatorSpec.played_faults``; clock jumps act later, in ``plan``).

    A node's mount turn by theta about the hinge axis (sensor z): from the first fused sample at
    or after the fault on, the node's samples are those of the mount q_z(theta) q_mount (every
    output turned with it; the noise and quantisation the same draws)."""
    traj = simulated(run, faults)
    chip = dataclasses.replace(run.imu, sample_rate_hz=run.imu.fusion_rate_hz, fusion_timing=True)
    samples = sample_imu(traj, chip, hold_s=run.hold_s)
    for f in sorted((f for f in faults if f.fault.kind == "mount"), key=lambda f: f.start_s):
        n = int(f.fault.target[1]) - 1  # m1 is pendulum M1
        mounts = np.array(chip.mount_quat_wxyz, dtype=float)  # (2, 4)
        mounts[n] = rotations.multiply(rotations.from_rotvec(np.array([0.0, 0.0, math.radians(f.after)])), mounts[n])
        quats = tuple((float(w), float(x), float(y), float(z)) for w, x, y, z in mounts)
        turned = sample_imu(traj, dataclasses.replace(chip, mount_quat_wxyz=quats), hold_s=run.hold_s)
        first = math.ceil((run.hold_s + f.start_s) * chip.sample_rate_hz - 1e-9)
        samples = _spliced(samples, turned, n, first)
    return samples


def _spliced(samples: ImuSamples, turned: ImuSamples, node: int, first: int) -> ImuSamples:
    """``samples`` with node ``node``'s outputs from sample ``first`` on taken from ``turned``."""
    out = {}
    for name in ("quat_wxyz", "gyro_rad_s", "accel_m_s2", "linear_accel_m_s2", "gravity_m_s2"):
        value = getattr(samples, name).copy()
        value[first:, node] = getattr(turned, name)[first:, node]
        out[name] = value
    return dataclasses.replace(samples, **out)


def plan(spec: EmulatorSpec, samples: ImuSamples | None = None) -> Plan:
    """Simulate, sample and lay out every datagram (deterministic for a given spec). ``samples``
    given: ``fused_samples(spec.run, spec.played_faults())`` (clock jumps are applied here)."""
    played = spec.played_faults()
    samples = samples if samples is not None else fused_samples(spec.run, played)
    rng = np.random.default_rng(spec.seed)
    period_s = 1.0 / spec.rate_hz
    streams, datagrams = [], []
    for node in spec.nodes:
        clock = spec.clock(node.name).resolved(rng, period_s)
        assert clock.phase_s is not None
        rate = 1.0 + clock.drift_ppm * 1e-6
        count = math.floor((spec.total_s - clock.phase_s) * rate / period_s + 1e-9) + 1
        k = np.arange(max(count, 0), dtype=np.int64)
        t_s, device_us = clock.instants(k, period_s)
        device_us = _clock_jumps(
            device_us, t_s, spec.run.hold_s, [f for f in played if f.fault.kind == "clock" and f.node == node.name]
        )
        rows = node_rows(samples, node.node_id - 1, t_s)  # m1 is pendulum M1, m2 is M2
        stream = NodeStreamPlan(node.name, k, device_us, t_s, rows, clock)
        streams.append(stream)
        datagrams += _node_datagrams(spec, node, stream, rng)
    ordered = sorted(enumerate(datagrams), key=lambda item: (item[1].due_s, item[0]))
    return Plan(spec, tuple(streams), tuple(d for _, d in ordered), played)


def _clock_jumps(
    device_us: NDArray[np.int64], t_s: NDArray[np.float64], hold_s: float, jumps: list[PlayedFault]
) -> NDArray[np.int64]:
    """Device times (K,) with each clock jump added from the first sample at or after it (true
    instants t_s, s since the start; the sample instants stay: the node's timer runs on)."""
    out = device_us.copy()
    for f in jumps:
        later = t_s >= hold_s + f.start_s - 1e-12
        out[later] += round(f.fault.amount * 1e6)
        if np.any(out < 0):
            raise ParameterError(
                f"--fault {f.fault.label!r}: the node's clock would read {out.min() * 1e-6:.6g} s (< 0); "
                "give a smaller backward jump or a larger --clock-offset-s"
            )
    return out


def _node_datagrams(
    spec: EmulatorSpec, node: NodeSpec, stream: NodeStreamPlan, rng: np.random.Generator
) -> list[Datagram]:
    """One node's datagrams with the faults applied, each with its due time (not yet sorted)."""
    f = spec.faults
    codec = spec.stream.codec(node.name, node.node_id)
    n = len(stream.seq)
    lost = rng.random(n) < f.loss
    duplicate = (rng.random(n) < f.duplicate) & ~lost
    reorder = (rng.random(n) < f.reorder) & ~lost
    malformed = rng.random(n) < f.malformed
    delay = rng.exponential(f.jitter_ms * 1e-3, n) if f.jitter_ms > 0 else np.zeros(n)
    kinds: tuple[str, ...] = MALFORMED_KINDS[spec.stream.format]
    if not isinstance(codec, V1Codec) and "node" not in codec.names:  # no node field: cannot be wrong
        kinds = tuple(k for k in kinds if k != "wrong_node")
    kind_of = rng.integers(0, len(kinds), n)
    # First in, first out: a packet leaves when it is due or when the one before it has left.
    sent = np.flatnonzero(~lost)
    due = np.full(n, np.nan)
    due[sent] = np.maximum.accumulate(stream.t_s[sent] + delay[sent])
    # A reordered packet leaves right after the packet reorder_depth places later (or last).
    position = {int(i): p for p, i in enumerate(sent)}
    final_due = due.copy()
    for j in np.flatnonzero(reorder):
        later = position[int(j)] + f.reorder_depth
        final_due[j] = due[sent[later]] + 1e-9 if later < len(sent) else due[sent[-1]] + 1e-6
    payloads = codec.encode_many(stream.seq, stream.device_time_us, stream.rows)
    out = []
    for i in range(n):
        seq, t_us = int(stream.seq[i]), int(stream.device_time_us[i])
        payload = payloads[i]
        who = (node.name, node.port, seq, t_us)
        if malformed[i]:
            bad, reason = _malformed(kinds[int(kind_of[i])], payload, codec, seq, t_us, stream.rows[i], rng)
            out.append(Datagram(float(stream.t_s[i]), *who, "malformed", False, reason, bad))
        if lost[i]:  # not sent: the network lost it
            out.append(Datagram(float(stream.t_s[i]), *who, "data", False, "", b"", sent=False))
            continue
        out.append(Datagram(float(final_due[i]), *who, "data", bool(reorder[i]), "", payload))
        if duplicate[i]:
            out.append(Datagram(float(final_due[i]), *who, "duplicate", False, "", payload))
    return out


def _sensor_name(codec: V1Codec | CsvCodec | JsonCodec) -> str:
    """A name of the map that holds a sensor value (not time, sequence or node)."""
    assert not isinstance(codec, V1Codec), "binary packets have no names"
    return next(name for name in codec.names if name in ROW_FIELDS or name == "calib")


def _replaced(codec: V1Codec | CsvCodec | JsonCodec, payload: bytes, name: str, value: object) -> bytes:
    """A text packet with one named value replaced."""
    if isinstance(codec, JsonCodec):
        obj = json.loads(payload)
        node = obj
        path = codec.paths[name]
        for key in path[:-1]:
            node = node[int(key)] if isinstance(node, list) else node[key]
        if isinstance(node, list):
            node[int(path[-1])] = value
        else:
            node[path[-1]] = value
        return json.dumps(obj).encode()
    assert isinstance(codec, CsvCodec)
    fields = payload.rstrip(b"\n").split(b",")
    fields[codec.names.index(name)] = str(value).encode()
    return b",".join(fields) + b"\n"


def _malformed(
    kind: str,
    payload: bytes,
    codec: V1Codec | CsvCodec | JsonCodec,
    seq: int,
    t_us: int,
    row: NDArray[np.float64],
    rng: np.random.Generator,
) -> tuple[bytes, str]:
    """A broken datagram of the given kind and the reason the receiver should count."""
    if kind == "truncated":
        if isinstance(codec, JsonCodec):
            obj = json.loads(payload)
            obj.pop(next(iter(obj)))  # a field is missing
            return json.dumps(obj).encode(), "truncated"
        if isinstance(codec, CsvCodec):
            return payload.rstrip(b"\n").rsplit(b",", 1)[0] + b"\n", "truncated"
        return payload[: int(rng.integers(1, len(payload)))], "truncated"
    if kind == "oversized":
        limit = codec.max_bytes if not isinstance(codec, V1Codec) else len(payload)
        extra = int(rng.integers(1, 64))
        if isinstance(codec, JsonCodec):
            obj = json.loads(payload)
            obj["padding"] = "x" * (limit + extra)
            return json.dumps(obj).encode(), "oversized"
        if isinstance(codec, CsvCodec):
            return b" " * (limit + extra) + payload, "oversized"
        return payload + bytes(extra), "oversized"
    if kind == "crc":
        i = int(rng.integers(8, len(payload) - 4))
        return payload[:i] + bytes([payload[i] ^ 0x10]) + payload[i + 1 :], "crc"
    if kind == "bad_header":
        return b"XSIM" + payload[4:], "bad_header"
    if kind == "wrong_node":
        other = 2 if codec.node_id == 1 else 1
        if isinstance(codec, V1Codec):
            return codec.encode(seq, t_us, row, node_id=other), "wrong_node"
        return _replaced(codec, payload, "node", f"m{other}"), "wrong_node"
    if kind == "non_finite":
        return _replaced(codec, payload, _sensor_name(codec), math.nan), "non_finite"
    if kind == "unparsable":
        if isinstance(codec, JsonCodec):
            return payload[: len(payload) // 2], "unparsable"
        return _replaced(codec, payload, _sensor_name(codec), "1.2.3"), "unparsable"
    raise ValueError(kind)


@dataclasses.dataclass(frozen=True)
class EmulatorResult:
    """What was sent: counts per node and kind, the log file, whether it ran to the end."""

    sent: dict[str, int]  # datagrams per node
    lost: dict[str, int]
    duplicated: dict[str, int]
    reordered: dict[str, int]
    malformed: dict[str, int]
    duration_s: float
    max_lateness_ms: float  # worst (actual - due) send time
    completed: bool
    log: Path | None
    faults_played: tuple[str, ...] = ()  # rig faults whose start was reached, described
    faults_missed: tuple[str, ...] = ()  # rig faults the run stopped before


@contextlib.contextmanager
def _stop_on_signals() -> Iterator[list[int]]:
    stop: list[int] = []
    with signal_handlers(dict.fromkeys((signal.SIGINT, signal.SIGTERM), lambda signum, frame: stop.append(signum))):
        yield stop


def run(
    spec: EmulatorSpec,
    *,
    log: str | Path | None = None,
    replace_log: bool = False,
    say: Callable[[str], None] = print,
    prepared: Plan | None = None,
) -> EmulatorResult:
    """Send everything ``plan(spec)`` lays out, in real time, and write the log.

    Stops early (and still writes the log of what was sent) on SIGINT or SIGTERM.
    """
    the_plan = prepared if prepared is not None else plan(spec)
    family = socket.AF_INET6 if ":" in spec.host else socket.AF_INET
    sockets = {n.name: socket.socket(family, socket.SOCK_DGRAM) for n in spec.nodes}
    records: list[tuple[float, Datagram]] = []
    say(
        f"sending {spec.stream.format} to {', '.join(f'{n.name} {spec.host}:{n.port}' for n in spec.nodes)}: "
        f"{spec.total_s:g} s ({spec.run.hold_s:g} s held, then released), {spec.rate_hz:g} Hz"
    )
    lateness = 0.0
    completed = True
    try:
        with _stop_on_signals() as stop:
            start = time.monotonic()
            for d in the_plan.datagrams:
                if stop:
                    completed = False
                    break
                now = time.monotonic() - start
                if d.due_s > now:
                    time.sleep(d.due_s - now)
                    now = time.monotonic() - start
                if d.sent:
                    with contextlib.suppress(OSError):  # nobody listening: the packet is simply gone
                        sockets[d.node].sendto(d.payload, (spec.host, d.port))
                    lateness = max(lateness, now - d.due_s)
                records.append((now if d.sent else d.due_s, d))
            duration = time.monotonic() - start
    finally:
        for s in sockets.values():
            s.close()
    if log is not None:
        write_log(log, spec, the_plan, records, replace=replace_log)
    count = {n.name: 0 for n in spec.nodes}
    result = EmulatorResult(
        sent={**count, **_count(records, lambda d: d.sent)},
        lost={**count, **_count(records, lambda d: not d.sent)},
        duplicated={**count, **_count(records, lambda d: d.kind == "duplicate")},
        reordered={**count, **_count(records, lambda d: d.reordered)},
        malformed={**count, **_count(records, lambda d: d.kind == "malformed")},
        duration_s=duration,
        max_lateness_ms=lateness * 1e3,
        completed=completed,
        log=Path(log) if log is not None else None,
        faults_played=tuple(f.describe() for f in the_plan.rig_faults if completed or _reached(f, spec, duration)),
        faults_missed=tuple(
            f.describe() for f in the_plan.rig_faults if not (completed or _reached(f, spec, duration))
        ),
    )
    return result


def _reached(fault: PlayedFault, spec: EmulatorSpec, sent_s: float) -> bool:
    return spec.run.hold_s + fault.start_s <= sent_s


def _count(records: list[tuple[float, Datagram]], which: Callable[[Datagram], bool]) -> dict[str, int]:
    out: dict[str, int] = {}
    for _, d in records:
        if which(d):
            out[d.node] = out.get(d.node, 0) + 1
    return out


def write_log(
    path: str | Path, spec: EmulatorSpec, the_plan: Plan, records: list[tuple[float, Datagram]], *, replace: bool
) -> None:
    """The log: a header (JSON lines: the first line; CSV: comment lines) and one row per datagram
    in the order sent (lost samples at their due time, ``sent`` false)."""
    path = Path(path)
    header = {
        "kind": "header",
        "format": spec.stream.format,
        "rate_hz": spec.rate_hz,
        "seed": spec.seed,
        "faults": dataclasses.asdict(spec.faults),
        "rig_faults": [f.as_dict() for f in the_plan.rig_faults],
        "ramp_piece_s": RAMP_PIECE_S,
        "nodes": {
            s.name: {"port": n.port, **dataclasses.asdict(s.clock)}
            for s, n in zip(the_plan.streams, spec.nodes, strict=True)
        },
    }
    rows = [
        {
            "t_s": round(t, 6), "node": d.node, "port": d.port, "seq": d.seq, "device_time_us": d.device_time_us,
            "kind": d.kind, "reordered": d.reordered, "reason": d.reason, "bytes": len(d.payload), "sent": d.sent,
        }
        for t, d in records
    ]  # fmt: skip
    with atomic_output(path, replace=replace) as tmp, open(tmp, "w") as f:
        if path.suffix == ".csv":
            f.write(f"# {json.dumps(header)}\n")
            f.write(",".join(LOG_COLUMNS) + "\n")
            for r in rows:
                f.write(
                    ",".join(str(r[c]).lower() if isinstance(r[c], bool) else str(r[c]) for c in LOG_COLUMNS) + "\n"
                )
        else:
            f.write(json.dumps(header) + "\n")
            for r in rows:
                f.write(json.dumps(r) + "\n")


def read_log(path: str | Path) -> tuple[dict, list[dict]]:
    """A log written by ``write_log``: (header, rows), rows with typed values."""
    path = Path(path)
    lines = path.read_text().splitlines()
    if path.suffix == ".csv":
        header = json.loads(lines[0][2:])
        names = lines[1].split(",")
        rows = []
        for line in lines[2:]:
            raw = dict(zip(names, line.split(","), strict=True))
            rows.append(
                {
                    "t_s": float(raw["t_s"]), "node": raw["node"], "port": int(raw["port"]), "seq": int(raw["seq"]),
                    "device_time_us": int(raw["device_time_us"]), "kind": raw["kind"],
                    "reordered": raw["reordered"] == "true", "reason": raw["reason"], "bytes": int(raw["bytes"]),
                    "sent": raw["sent"] == "true",
                }
            )  # fmt: skip
        return header, rows
    return json.loads(lines[0]), [json.loads(line) for line in lines[1:]]


def summary(result: EmulatorResult) -> str:
    lines = []
    for node in result.sent:
        lines.append(
            f"{node}: {result.sent[node]} datagrams sent, {result.lost[node]} samples lost, "
            f"{result.duplicated[node]} duplicated, {result.reordered[node]} reordered, "
            f"{result.malformed[node]} malformed"
        )
    if result.faults_played:
        lines.append(f"rig faults played (s after the release): {'; '.join(result.faults_played)}")
    if result.faults_missed:
        lines.append(f"rig faults not reached: {'; '.join(result.faults_missed)}")
    state = "done" if result.completed else "stopped early"
    lines.append(f"{state} after {result.duration_s:.1f} s; worst send lateness {result.max_lateness_ms:.2f} ms")
    if result.log is not None:
        lines.append(f"wrote {result.log}")
    return "\n".join(lines)
