"""Record a simulated run (or a static noise test) to one MCAP file, block by block: simulate a
block from the previous block's final state, sample both BNO055 nodes over it, write and flush
its messages; the file is written under a temporary name and published when complete (or, when
interrupted, published holding what was recorded, marked as such).

    from .record import RecordSpec, record
    result = record(RecordSpec(duration_s=30.0), "run.mcap")
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Literal

import numpy as np

from pendsim_mj import __version__
from pendsim_mj.engines import dispatch as engines
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.errors import ParameterError
from pendsim_mj.estimation.analysis import BlockBalance
from pendsim_mj.rig.checks import check_step
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.model import PLANAR, SPATIAL, exact_mjcf
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import Bno055, ImuSampler, sample_imu, static_imu, streamable
from pendsim_mj.units import NS_PER_S

from ..io.mcap.writer import BulkMcapWriter
from ..io.outputs import atomic_output
from ..io.recording_layout import ControlTopic, RunInfo
from ..io.recording_writer import RecordingWriter
from ..signals import signal_handlers

Model = Literal["planar", "spatial", "static"]
MODELS: tuple[Model, ...] = ("planar", "spatial", "static")


@dataclasses.dataclass(frozen=True)
class RecordSpec:
    """What to record.

    Attributes:
      params: the rig (for "spatial", its plane_offset_m sets the distance between the planes).
      phi0_rad, omega0_rad_s: release state, rad and rad/s.
      duration_s: simulated time after the release (the whole static test for "static"), s.
      dt_s: integration step, s.
      engine: "mujoco" or "reference" (planar only).
      model: "planar", "spatial" (tilt freedoms, MuJoCo) or "static" (both nodes at rest, IMU
        topics only).
      hold_s: recorded time before the release with the pendulums held still, s.
      imu: the BNO055 node model (noise, timing, seed).
      compression: chunk compression of the MCAP file.
      drive: torques and support motion from the release on (``pendsim_mj.rig.drives``), recorded
        as the /drive topic and the pendsim/drive metadata; None for a free run.
      control: a closed loop's /control topic (``pendsim control``: the drive is then the loop's
        inputs replayed), or None.
    """

    params: RigParams = DEFAULT_PARAMS
    phi0_rad: tuple[float, float] = (math.pi / 6, 0.0)
    omega0_rad_s: tuple[float, float] = (0.0, 0.0)
    duration_s: float = 120.0
    dt_s: float = 0.01
    engine: str = "mujoco"
    model: Model = "planar"
    hold_s: float = 0.0
    imu: Bno055 = dataclasses.field(default_factory=Bno055)
    compression: str = "zstd"
    drive: Drive | None = None
    control: ControlTopic | None = None

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ParameterError(f"unknown model {self.model!r}; allowed: {', '.join(MODELS)}")
        if self.model == "spatial" and self.engine != "mujoco":
            raise ParameterError("the spatial model runs in MuJoCo only; use the mujoco engine")
        if not (math.isfinite(self.hold_s) and self.hold_s >= 0):
            raise ParameterError(f"hold_s must be a finite number >= 0 s, got {self.hold_s!r}")
        if self.model == "static" and self.drive:
            raise ParameterError("a static noise test has no drive; drop the drive options or --static")


@dataclasses.dataclass(frozen=True)
class RecordResult:
    """A written recording.

    Attributes:
      path: the file.
      samples: IMU sample instants per node (lost packets included: they set ``recorded_s``).
      recorded_s: recording time written (hold included), s.
      requested_s: recording time asked for (hold included), s.
      size_bytes: file size.
      start_time_ns: UTC log time of the recording's t = 0.
      interrupted: the run was stopped early (Ctrl-C, SIGTERM): the file holds the first
        ``recorded_s`` and says so in its ``pendsim/interrupted`` metadata.
      written_per_node: IMU messages written per node (lost packets are not).
      warnings: what the user must know about the run (its step does not resolve it:
        ``analysis.unresolved_warning``; also in the file's ``pendsim/unresolved`` metadata).
    """

    path: Path
    samples: int
    recorded_s: float
    requested_s: float
    size_bytes: int
    start_time_ns: int
    interrupted: bool = False
    written_per_node: tuple[int, int] | None = None
    warnings: tuple[str, ...] = ()

    @property
    def written(self) -> tuple[int, int]:
        """IMU messages written per node (M1, M2): ``samples`` less the lost packets."""
        return self.written_per_node if self.written_per_node is not None else (self.samples, self.samples)

    def samples_text(self) -> str:
        """ "N IMU samples per node", or, where packets were lost, both counts and the share lost."""
        m1, m2 = self.written
        if m1 == m2 == self.samples:
            return f"{self.samples} IMU samples per node"
        lost = 100 * (1 - (m1 + m2) / (2 * self.samples)) if self.samples else 0.0
        return f"{m1} (M1) and {m2} (M2) IMU samples of {self.samples}, {lost:.1f} % lost"


class RecordInterrupted(Exception):
    """``record`` was interrupted (KeyboardInterrupt: Ctrl-C, or SIGTERM turned into one); the
    part recorded so far was published as a complete file, ``result.path``."""

    def __init__(self, result: RecordResult) -> None:
        super().__init__(
            f"interrupted after {result.recorded_s:.3f} s of {result.requested_s:g} s; "
            f"{result.path} holds the first {result.recorded_s:.3f} s (a complete recording)"
        )
        self.result = result


def _engine(spec: RecordSpec) -> str:
    """The engine that runs a spec's simulation: the planar reference on its compiled kernel
    (``engines.FAST_PATH``); the recording still names the engine asked for."""
    return engines.FAST_PATH.get(spec.engine, spec.engine)


def simulate_for(spec: RecordSpec) -> Trajectory:
    """The simulated run a (non-static) spec describes (in memory: for views, not recording)."""
    return engines.run(
        _engine(spec), spec.params, spec.phi0_rad, spec.omega0_rad_s, spec.duration_s, spec.dt_s,
        spatial=spec.model == "spatial", drive=spec.drive,
    )  # fmt: skip


def record(
    spec: RecordSpec,
    output: str | Path,
    *,
    replace: bool = False,
    progress: Callable[[float], None] | None = None,
    start_time_ns: int | None = None,
    block_s: float = 30.0,
    stop: threading.Event | None = None,
) -> RecordResult:
    """Simulate, sample and write one recording block by block (memory independent of the
    duration; each block's chunks flushed as written); the file appears only when complete.

    Args:
      spec: what to record.
      output: the .mcap file.
      replace: replace an existing file (otherwise that is an OutputError and it stays untouched).
      progress: called with the recording seconds written after each block.
      start_time_ns: UTC log time of the recording's t = 0 (default: now).
      block_s: simulated seconds per block.
      stop: set it (from another thread) to end the recording after the block in progress: the
        file then holds every complete block. Called from the main thread, ``record`` also sets
        it on SIGINT (Ctrl-C) and SIGTERM while it runs (the previous handlers come back after).

    Raises:
      ParameterError, SimulationDiverged: a bad spec or a diverging run (nothing written).
      OutputError: the output exists, or writing failed (nothing left behind).
      RecordInterrupted: ``stop`` was set, or KeyboardInterrupt came during the run: the
        complete blocks recorded so far are published at ``output`` as a complete recording
        marked ``pendsim/interrupted``.
    """
    output = Path(output)
    start = time.time_ns() if start_time_ns is None else int(start_time_ns)
    if not (0 <= start < 2**31 * NS_PER_S):
        raise ParameterError(f"start_time_ns must be a UTC time in ns between 1970 and 2038, got {start}")
    if not (math.isfinite(block_s) and block_s > 0):
        raise ParameterError(f"block_s must be a finite number > 0 s, got {block_s!r}")
    static = spec.model == "static"
    rate = spec.imu.sample_rate_hz
    end_t_s = spec.duration_s if static else check_step(spec.duration_s, spec.dt_s) * spec.dt_s
    held = 0 if static else round(spec.hold_s * rate)
    requested = (held + math.floor(end_t_s * rate + 1e-9)) / rate
    # Node models with whole-run processes (fusion error, packet loss, latency) are sampled whole.
    sampler = (
        ImuSampler(spec.imu, spec.params, end_t_s=end_t_s, hold_s=spec.hold_s, static=static)
        if streamable(spec.imu)
        else None
    )
    if static:
        run = RunInfo("static", (0.0, 0.0), (0.0, 0.0), spec.duration_s, 1 / rate, model="static")
        blocks = None
    else:
        release = held / rate
        run = RunInfo(
            spec.engine, spec.phi0_rad, spec.omega0_rad_s, spec.duration_s, spec.dt_s,
            model=spec.model, release_time_s=release,
        )  # fmt: skip
        block_steps = max(1, round(block_s / spec.dt_s))
        blocks = engines.run_blocks(
            _engine(spec), spec.params, spec.phi0_rad, spec.omega0_rad_s, spec.duration_s, spec.dt_s,
            block_steps=block_steps, spatial=spec.model == "spatial", drive=spec.drive,
        )  # fmt: skip
    variant = SPATIAL if spec.model == "spatial" else PLANAR
    targets = spec.drive.targets if spec.drive else ()
    mjcf = exact_mjcf(spec.params, timestep_s=spec.dt_s, variant=variant, drive_targets=targets)
    written = _Progress(spec.imu.sample_rate_hz, progress)
    interrupted = False
    stop = stop if stop is not None else threading.Event()
    library = f"pendsim {__version__}"
    with (
        atomic_output(output, replace=replace) as tmp,
        BulkMcapWriter(tmp, compression=spec.compression, library=library) as w,
    ):
        rw = RecordingWriter(
            w, params=spec.params, config=spec.imu, run=run, mjcf_xml=mjcf, start_time_ns=start,
            compression=spec.compression, static=static, spatial=spec.model == "spatial", drive=spec.drive,
            control=spec.control,
        )  # fmt: skip
        given = 0  # samples of a block handed to the writer in full, not yet counted
        balance = BlockBalance()
        per_node = np.zeros(2, dtype=int)  # messages written per node (lost packets are not)
        pieces = _blocks(sampler, blocks, spec, block_s)
        try:
            with _signals_set(stop):
                for samples, traj, first, last in pieces:
                    rw.write_imu(samples)
                    per_node += len(samples.t_s) if samples.received is None else samples.received.sum(axis=0)
                    if traj is not None:
                        rw.write_steps(traj, first, last)
                        balance.add(traj, first)
                    given = len(samples.t_s)
                    rw.flush(None if last or not len(samples.t_s) else float(samples.t_s[-1]) - FLUSH_MARGIN_S)
                    written.add(given)
                    given = 0
                    if stop is not None and stop.is_set():
                        interrupted = sampler is not None and not sampler.done
                        break
        except KeyboardInterrupt:
            interrupted = True
        if interrupted and given:  # the block was given in full: finishing writes it out
            written.add(given)
        warning = None if interrupted else balance.warning(spec.params, spec.dt_s, planar=spec.model != "spatial")
        if warning is not None:
            w.add_metadata("pendsim/unresolved", {"warning": warning, "energy_residual_j": repr(balance.residual_j)})
        if interrupted:
            recorded = max(written.samples - 1, 0) / spec.imu.sample_rate_hz
            w.add_metadata(
                "pendsim/interrupted",
                {"recorded_s": repr(recorded), "requested_s": repr(requested), "reason": "interrupted by the user"},
            )
    result = RecordResult(
        output, written.samples, max(written.samples - 1, 0) / spec.imu.sample_rate_hz, requested,
        output.stat().st_size, start, interrupted, (int(per_node[0]), int(per_node[1])),
        () if warning is None else (warning,),
    )  # fmt: skip
    if interrupted:
        raise RecordInterrupted(result)
    return result


@contextlib.contextmanager
def _signals_set(stop: threading.Event) -> Iterator[None]:
    """SIGINT (Ctrl-C) and SIGTERM set ``stop`` while recording (main thread only): the
    recording ends after the block in progress, between writes, and keeps what it recorded."""

    def handler(signum: int, frame: object) -> None:
        stop.set()

    with signal_handlers(dict.fromkeys((signal.SIGINT, signal.SIGTERM), handler)):
        yield


FLUSH_MARGIN_S = 1.0  # messages of the last second of a block wait for the next flush (clock skew)


def _blocks(sampler: ImuSampler | None, blocks, spec: RecordSpec, block_s: float):
    """(samples, trajectory block or None, first row, last) for each block of the recording
    (one block holding the whole run for a node model that is not sampled block by block)."""
    if sampler is None:
        if blocks is None:
            yield static_imu(spec.params, spec.duration_s, spec.imu), None, 0, True
        else:
            traj = simulate_for(spec)
            yield sample_imu(traj, spec.imu, hold_s=spec.hold_s), traj, 0, True
        return
    if blocks is None:
        per_block = max(1, round(block_s * spec.imu.sample_rate_hz))
        while not sampler.done:
            yield sampler.static_block(per_block), None, 0, False
        return
    total_steps = check_step(spec.duration_s, spec.dt_s)
    for first, traj in blocks:
        last = first + len(traj.t_s) - 1 == total_steps
        yield sampler.block(traj, first_row=first, last=last), traj, first, last


class _Progress:
    def __init__(self, rate_hz: float, callback: Callable[[float], None] | None) -> None:
        self.rate_hz, self.callback, self.samples = rate_hz, callback, 0

    def add(self, samples: int) -> None:
        self.samples += samples
        if self.callback is not None:
            self.callback(samples / self.rate_hz)
