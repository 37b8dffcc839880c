"""Rerun views of runs: the rig in 3D from the model's own geometry, measured against computed
time series, the phi1 error with cumulative IAE/ISE, and phase portraits.

All time-varying data go through ``rr.send_columns`` (one call per stream), on the timeline
"time" (seconds since the release). The 3D rig follows the computed trajectory: each pendulum
body turns about the pivot axis, its geoms (rods, disk, transverse rod), points and IMU axes
drawn from the compiled MjModel; the four springs are line strips whose colour runs from blue
(slack, the run's lowest tension) to red (its highest).
"""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import shutil
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb
from rerun.components import LineStrip3DBatch
from rerun.encodings import Vec3DBatch

from pendsim_mj.engines.dispatch import whole_steps_s
from pendsim_mj.engines.simulation import simulate_blocks
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.errors import ModelError
from pendsim_mj.estimation.quantities import BY_NAME, QUANTITIES
from pendsim_mj.estimation.timing import DEFAULT_MAX_GAP_S
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.mjcf_guard import compile_untrusted
from pendsim_mj.rig.model import BODIES, SPRING_ENDS, SPRING_POINT_OWNER, SPRINGS, build_model
from pendsim_mj.sensors import rotations

from ..errors import OutputError
from ..io.measured import align_recording, recorded_params, recording_drive
from ..io.outputs import atomic_output
from ..io.recording import read_recording
from ..io.recording_layout import DRIVE_TOPIC, NODES, imu_topic

if TYPE_CHECKING:
    from pendsim_mj.estimation.alignment import MeasuredRun

    from .validation_report import ValidationReport

TIMELINE = "time"
APPLICATION_ID = "pendsim"
VIEW_BLOCK_STEPS = 6000  # model steps simulated and logged at once (60 s at 0.01 s); rows sent at once


SERIES_STYLE: dict[str, tuple[str, tuple[int, int, int, int], float]] = {
    # series: (colour name for the view titles, RGBA, line width in points). The measurement is a
    # wide blue band, the model a narrow orange line over it (Rerun draws a plot's series in entity
    # order, "measured" before "model", and ignores alpha): where they agree, the orange line runs
    # inside the blue band; where they differ, each shows on its own.
    "measured": ("blue", (30, 90, 230, 255), 4.0),
    "model": ("orange", (255, 140, 0, 255), 1.5),
    "planar": ("blue", (30, 90, 230, 255), 4.0),
    "spatial": ("orange", (255, 140, 0, 255), 1.5),
    "delta": ("red", (210, 30, 30, 255), 1.5),
    "iae": ("green", (30, 150, 60, 255), 1.5),
    "ise": ("purple", (130, 60, 180, 255), 1.5),
}
PHASE_DRAW_ORDER = {"measured": 10.0, "planar": 10.0, "model": 20.0, "spatial": 20.0}
"""Higher is drawn on top: as in the plots, the model's narrow line over the measured band."""


def _key(series: tuple[str, ...]) -> str:
    """The colour key written into view titles (Rerun's legends would cover the data)."""
    return ", ".join(f"{name} {SERIES_STYLE[name][0]}" for name in series)


def blueprint(series: tuple[str, ...] = ("measured", "model")) -> rrb.Blueprint:
    """3D rig on the left, stacked plots on the right, phase portraits below them. The plots'
    legends are off (they cover the first seconds); each title says which colour is which."""
    key = _key(series)
    no_legend = rrb.PlotLegend(visible=False)
    plots = [
        rrb.TimeSeriesView(origin=f"/plots/{q.name}", name=f"{q.title}: {key}", plot_legend=no_legend)
        for q in QUANTITIES
    ]
    if "measured" in series:
        plots.append(
            rrb.TimeSeriesView(
                origin="/plots/error_phi1",
                name=f"phi1 error: {_key(('delta', 'iae', 'ise'))} (Delta rad, IAE rad s, ISE rad^2 s)",
                plot_legend=no_legend,
            )
        )
    if "spatial" in series:
        plots.append(rrb.TimeSeriesView(origin="/plots/tilt1", name="tilt of M1 (rad): spatial", plot_legend=no_legend))
        plots.append(rrb.TimeSeriesView(origin="/plots/tilt2", name="tilt of M2 (rad): spatial", plot_legend=no_legend))
    phase = [rrb.Spatial2DView(origin=f"/phase/m{k}", name=f"phase portrait M{k}: {key}") for k in (1, 2)]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/rig", name="rig (computed)"),
            rrb.Vertical(rrb.Vertical(*plots), rrb.Horizontal(*phase), row_shares=[3, 2]),
            column_shares=[2, 3],
        ),
        collapse_panels=True,
    )


@contextlib.contextmanager
def rrd_output(
    path: str | Path,
    *,
    replace: bool = False,
    series: tuple[str, ...] | None = ("measured", "model"),
    application_id: str = APPLICATION_ID,
) -> Iterator[None]:
    """Log to a new Rerun recording and publish it as the .rrd file ``path`` when the block
    completes: ``with rrd_output("run.rrd"): rr.log(...)``.

    The file is written while the block logs (``_streamed_rrd``: Rerun's file sink writes into a
    named pipe, and a thread here copies the pipe into the file): memory stays flat however long
    the recording is. The bytes are written by Python, so a full disk or a permission error is an
    ``OutputError`` here, never a warning on a background thread and a truncated file. The file is
    written under a temporary name and published atomically (``pendsim_bridge.io.outputs.atomic_output``):
    never over an existing file unless ``replace``, and nothing is left behind by a failure.
    Where named pipes do not exist (Windows), Rerun's in-memory stream is written once at the end.

    Args:
      path: the .rrd file.
      replace: replace an existing file (``--force``).
      series: the series the views show (``blueprint``); None: no blueprint (Rerun's own layout).
      application_id: Rerun's application id.
    """
    layout = blueprint(series) if series is not None else None
    with atomic_output(path, replace=replace) as tmp:
        rr.init(application_id, default_blueprint=layout)
        try:
            with _streamed_rrd(tmp) if hasattr(os, "mkfifo") else _buffered_rrd(tmp):
                if layout is not None:
                    rr.send_blueprint(layout, make_active=True, make_default=True)
                yield
        finally:
            rr.disconnect()


@contextlib.contextmanager
def _streamed_rrd(tmp: Path) -> Iterator[None]:
    """Rerun's file sink writes into a named pipe (in a private temporary folder) while the block
    logs; a thread copies the pipe into ``tmp``. A write error (full disk) is raised once the
    block ends (the thread keeps draining the pipe, so Rerun never blocks). Raises OSError (the
    copy failed) or OutputError (Rerun wrote nothing)."""
    folder = Path(tempfile.mkdtemp(prefix="pendsim-rrd-"))
    pipe = folder / "stream.rrd"
    try:
        os.mkfifo(pipe, 0o600)
    except OSError:  # a temporary folder without named pipes: the in-memory stream instead
        shutil.rmtree(folder, ignore_errors=True)
        with _buffered_rrd(tmp):
            yield
        return
    copier = _PipeCopier(pipe, tmp)
    copier.start()
    try:
        rr.save(pipe)
        yield
    finally:
        rr.disconnect()  # closes the file sink: the copier reads the end of the stream
        copier.finish()
        shutil.rmtree(folder, ignore_errors=True)
    if copier.error is not None:
        raise copier.error
    if not copier.bytes_written:
        raise OutputError(f"Rerun produced no data for {str(tmp)!r}")


class _PipeCopier(threading.Thread):
    """Copies a named pipe into a file until the writer closes it; keeps the first write error
    (``error``) and from then on only drains the pipe."""

    def __init__(self, pipe: Path, target: Path) -> None:
        super().__init__(name="rrd-copy", daemon=True)
        self.pipe, self.target = pipe, target
        self.error: OSError | None = None
        self.bytes_written = 0

    def run(self) -> None:
        with open(self.pipe, "rb") as src, open(self.target, "wb") as dst:  # waits for Rerun to open it
            while block := src.read(1 << 20):
                if self.error is None:
                    try:
                        dst.write(block)
                        self.bytes_written += len(block)
                    except OSError as exc:
                        self.error = exc
            if self.error is None:
                try:
                    dst.flush()
                except OSError as exc:
                    self.error = exc

    def finish(self, timeout_s: float = 60.0) -> None:
        """Wait for the copy to end; if Rerun never opened the pipe, open and close it here so
        that the thread ends."""
        self.join(timeout=0.5)
        if self.is_alive():
            with contextlib.suppress(OSError):
                os.close(os.open(self.pipe, os.O_WRONLY | os.O_NONBLOCK))
        self.join(timeout=timeout_s)


@contextlib.contextmanager
def _buffered_rrd(tmp: Path) -> Iterator[None]:
    """Rerun's in-memory stream, written to ``tmp`` once at the end (one read: each read is a whole
    RRD stream, and concatenated streams fail Rerun's CRC check)."""
    stream = rr.binary_stream()
    yield
    data = stream.read(flush=True)
    if not data:
        raise OutputError(f"Rerun produced no data for {str(tmp)!r}")
    tmp.write_bytes(data)


def log_series_styles(series: tuple[str, ...]) -> None:
    """Colour, width and name of each plotted series (static)."""
    styled = [(f"/plots/{q.name}/{s}", s) for q in QUANTITIES for s in series]
    if "spatial" in series:
        styled += [(f"/plots/tilt{k}/spatial", "spatial") for k in (1, 2)]
    if "measured" in series:
        styled += [(f"/plots/error_phi1/{s}", s) for s in ("delta", "iae", "ise")]
    for entity, s in styled:
        _, rgba, width = SERIES_STYLE[s]
        rr.log(entity, rr.SeriesLines(colors=[rgba], widths=[width], names=[s]), static=True)


def _geom_rgba(model: mujoco.MjModel, geoms: list[int]) -> np.ndarray:
    """Each geom's colour: its material's where it has one."""
    matid = model.geom_matid[geoms]
    return np.where((matid >= 0)[:, None], model.mat_rgba[np.maximum(matid, 0)], model.geom_rgba[geoms])


def log_rig_geometry(
    model: mujoco.MjModel, *, root: str = "/rig", x_offset_m: float = 0.0, moving_frame: bool = False
) -> None:
    """Static geometry: the frame in the world, each pendulum's geoms and points in its body
    (a rig drawn ``x_offset_m`` to the side, under ``root``). With ``moving_frame`` (a run that
    moves the support) the frame's pose is left to ``log_trajectory``."""
    if not moving_frame:
        rr.log(f"{root}/frame", rr.Transform3D(translation=[x_offset_m, 0.0, 0.0]), static=True)
    for body_id in range(model.nbody):
        name = model.body(body_id).name or "frame"
        entity = f"{root}/{name}" if name in BODIES else f"{root}/frame"
        geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body_id]
        round_types = (int(mujoco.mjtGeom.mjGEOM_CYLINDER), int(mujoco.mjtGeom.mjGEOM_CAPSULE))
        cylinders = [g for g in geoms if int(model.geom_type[g]) in round_types]  # numpy int vs pybind enum
        if cylinders:
            quat = model.geom_quat[cylinders]
            rr.log(
                f"{entity}/geoms",
                rr.Cylinders3D(
                    lengths=2 * model.geom_size[cylinders, 1],
                    radii=model.geom_size[cylinders, 0],
                    centers=model.geom_pos[cylinders],
                    quaternions=[rr.Quaternion(xyzw=[q[1], q[2], q[3], q[0]]) for q in quat],
                    colors=(_geom_rgba(model, cylinders) * 255).astype(np.uint8),
                    labels=[model.geom(g).name for g in cylinders],
                ),
                static=True,
            )
        sites = [s for s in range(model.nsite) if model.site_bodyid[s] == body_id]
        points = [s for s in sites if model.site(s).name.startswith("point_")]
        if points:
            rr.log(
                f"{entity}/points",
                rr.Points3D(
                    model.site_pos[points],
                    radii=0.006,
                    colors=[230, 230, 50],
                    labels=[model.site(s).name.replace("point_", "") for s in points],
                    show_labels=True,
                ),
                static=True,
            )
        for s in (s for s in sites if model.site(s).name.startswith("imu_")):
            axes = np.zeros((3, 3))
            mujoco.mju_quat2Mat(axes.ravel(), model.site_quat[s])
            rr.log(
                f"{entity}/{model.site(s).name}",
                rr.Arrows3D(
                    origins=np.repeat(model.site_pos[s][None], 3, axis=0),
                    vectors=0.05 * axes.T,  # the site's x, y, z axes in the body frame
                    colors=[[220, 40, 40], [40, 200, 40], [40, 80, 230]],
                    labels=["x tangential", "y to pivot", "z pivot axis"],
                ),
                static=True,
            )


def log_trajectory(
    traj: Trajectory,
    model: mujoco.MjModel,
    *,
    time_offset_s: float = 0.0,
    root: str = "/rig",
    x_offset_m: float = 0.0,
    series: str = "model",
    springs: bool = True,
) -> None:
    """The computed run: body poses, springs coloured by tension (``log_springs``; not with
    ``springs=False``), and every plotted quantity (under /plots/<quantity>/<series>). A long run
    can be logged block by block: consecutive calls append to the same entities."""
    times = rr.TimeColumn(TIMELINE, duration=traj.t_s + time_offset_s)
    n = len(traj.t_s)
    # the support's displacement (a driven run; zero otherwise) moves the frame and both pendulums
    support = np.zeros((n, 3))
    support[:, 0], support[:, 2] = traj.support_m[:, 0], traj.support_m[:, 1]
    frame = support + np.array([x_offset_m, 0.0, 0.0])
    if np.any(support):
        rr.send_columns(f"{root}/frame", indexes=[times], columns=rr.Transform3D.columns(translation=frame))
    for k, body in enumerate(BODIES):
        quat = traj.body_quat_wxyz()[:, k]
        position = model.body(body).pos + frame
        rr.send_columns(
            f"{root}/{body}",
            indexes=[times],
            columns=rr.Transform3D.columns(quaternion=rotations.wxyz_to_xyzw(quat), translation=position),
        )
    if springs:
        force = traj.spring_force_n
        log_springs(
            model, traj.t_s + time_offset_s, traj.phi_rad, traj.tilt_rad, traj.support_m, force,
            (float(force.min()), float(force.max())), root=root, x_offset_m=x_offset_m,
        )  # fmt: skip
    for q in QUANTITIES:
        values = rr.Scalars.columns(scalars=q.computed(traj))
        rr.send_columns(f"/plots/{q.name}/{series}", indexes=[times], columns=values)


def _segments_arrow(ends: np.ndarray) -> pa.Array:
    """Line strips of two points each, ends (m, 2, 3) m, as the Arrow array Rerun makes of them
    (``LineStrip3DBatch``: the same offsets and float32 points), without its offset loop in
    Python (one call per strip: about 0.7 s per hour of springs)."""
    offsets = np.arange(0, 2 * len(ends) + 1, 2, dtype=np.int32)
    points = Vec3DBatch(ends.reshape(-1)).as_arrow_array()
    return pa.ListArray.from_arrays(offsets, points, type=LineStrip3DBatch._ARROW_DATATYPE)


def log_springs(
    model: mujoco.MjModel,
    t_s: np.ndarray,
    phi_rad: np.ndarray,
    tilt_rad: np.ndarray,
    support_m: np.ndarray,
    force_n: np.ndarray | None,
    force_range_n: tuple[float, float],
    *,
    root: str = "/rig",
    x_offset_m: float = 0.0,
) -> None:
    """The four springs as line strips between their anchor points, coloured from blue (the
    lowest tension of ``force_range_n``, N) to red (the highest), at n instants t_s (s) of a run
    given by its angles phi_rad and tilt_rad (n, 2), its support displacement support_m (n, 2)
    and spring tensions force_n (n, 4); ``force_n`` None: the strips only (their colours sent
    later, as ``_log_spring_colours`` does). Consecutive calls append (a long run in windows)."""
    times = rr.TimeColumn(TIMELINE, duration=t_s)
    n = len(t_s)
    frame = np.zeros((n, 3))
    frame[:, 0], frame[:, 2] = support_m[:, 0] + x_offset_m, support_m[:, 1]
    quat = rotations.pendulum_quat_wxyz(phi_rad, tilt_rad)  # (n, 2, 4)
    poses = {k: (rotations.to_matrix(quat[:, k]), model.body(body).pos + frame) for k, body in enumerate(BODIES)}
    # Spring end points in the world: each body's pose applied to the model's site positions.
    site = {name: model.site(name).pos.copy() for pair in SPRING_ENDS for name in pair}
    owner = SPRING_POINT_OWNER

    def world(name: str) -> np.ndarray:
        p = site[name]
        if name not in owner:
            return p + frame
        matrix, position = poses[owner[name]]
        return position + matrix @ p

    ends = np.stack([np.stack([world(a), world(b)], axis=1) for a, b in SPRING_ENDS], axis=1)  # (n, 4, 2, 3)
    colours = None if force_n is None else _tension_colours(force_n, *force_range_n).reshape(n * 4, 3)
    rr.send_columns(
        f"{root}/springs",
        indexes=[times],
        columns=rr.LineStrips3D.columns(strips=_segments_arrow(ends.reshape(n * 4, 2, 3)), colors=colours).partition(
            [4] * n
        ),
    )
    rr.log(f"{root}/springs", rr.LineStrips3D.from_fields(labels=list(SPRINGS), radii=0.002), static=True)


def log_measured(run: MeasuredRun) -> None:
    """Measured series (seconds since the start, each node at its own instants; gaps stay gaps)
    beside the model's."""
    for q in QUANTITIES:
        t, values, _ = run.series(q)
        for t_w, values_w in _in_windows(t, values):
            times = rr.TimeColumn(TIMELINE, duration=t_w)
            rr.send_columns(f"/plots/{q.name}/measured", indexes=[times], columns=rr.Scalars.columns(scalars=values_w))


def log_error(t_s: np.ndarray, delta: np.ndarray, iae: np.ndarray, ise: np.ndarray) -> None:
    """Delta phi1 = computed - measured and its cumulative IAE and ISE."""
    for name, values in (("delta", delta), ("iae", iae), ("ise", ise)):
        for t_w, values_w in _in_windows(t_s, values):
            times = rr.TimeColumn(TIMELINE, duration=t_w)
            rr.send_columns(f"/plots/error_phi1/{name}", indexes=[times], columns=rr.Scalars.columns(scalars=values_w))


def error_in_windows(
    t_s: np.ndarray, measured: np.ndarray, computed: np.ndarray, *, max_gap_s: float, window: int = VIEW_BLOCK_STEPS
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """(t_s, delta, iae, ise) of computed - measured at the instants t_s (s), window by window
    (``validation.compare`` on ``window`` samples at a time, consecutive windows sharing their
    boundary sample so that every interval is integrated once, each window's cumulative IAE and
    ISE continued from the previous window's end): memory of one window, whatever the duration.
    The curves equal one whole-run ``compare``'s to the integration rule's difference at the
    window boundaries (Simpson's pairing restarts there; tested to 1e-6 of the total)."""
    from pendsim_mj.estimation.validation import compare  # scipy: not for the live view

    n = len(t_s)
    starts = list(range(0, max(n - 1, 1), window))
    if len(starts) > 1 and n - 1 - starts[-1] < 8:  # no window of fewer than 8 samples: join the last two
        starts.pop()
    iae0 = ise0 = 0.0
    for k, lo in enumerate(starts):
        hi = starts[k + 1] + 1 if k + 1 < len(starts) else n  # shares its last sample with the next window
        part = compare(t_s[lo:hi], measured[lo:hi], computed[lo:hi], max_gap_s=max_gap_s)
        first = 1 if k else 0  # the shared sample was logged with the previous window
        yield (
            part.t_s[first:],
            part.delta[first:],
            part.iae_curve[first:] + iae0,
            part.ise_curve[first:] + ise0,
        )
        iae0 += float(part.iae_curve[-1])
        ise0 += float(part.ise_curve[-1])


def nice_ticks(low: float, high: float, *, count: int = 5) -> np.ndarray:
    """About ``count`` round tick values (1, 2 or 5 times a power of ten apart) within [low, high]."""
    span = high - low
    if not (math.isfinite(span) and span > 0):
        return np.array([low]) if math.isfinite(low) else np.zeros(0)
    raw = span / max(1, count - 1)
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1.0, 2.0, 5.0, 10.0) if m * power >= raw)
    first = math.ceil(low / step) * step
    ticks = np.arange(first, high + step * 1e-9, step)
    return np.where(np.abs(ticks) < step * 1e-9, 0.0, ticks)


def log_phase_portraits(curves: dict[str, list[tuple[np.ndarray, np.ndarray]]]) -> None:
    """Phase portraits (omega over phi) of each pendulum with drawn, labelled axes.

    Args:
      curves: series name (a key of SERIES_STYLE) -> per pendulum (M1, M2) its (phi_rad (n,),
        omega_rad_s (n,)); the lengths may differ (each node has its own instants).

    Rerun's 2D view keeps one scale for both directions, so omega is drawn scaled by
    (phi span / omega span) to fill a square; the tick labels give the real omega in rad/s. The
    view's y grows downward, so omega is drawn negated (up is positive). Entities:
    ``/phase/m{k}/{series}`` (the traces), ``/phase/m{k}/axes`` (lines, ticks, labels).
    """
    for k in range(2):
        phi_range = _finite_range([c[k][0] for c in curves.values()])
        omega_range = _finite_range([c[k][1] for c in curves.values()])
        if phi_range is None or omega_range is None:
            continue
        p_low, p_high = min(phi_range[0], 0.0), max(phi_range[1], 0.0)
        w_low, w_high = min(omega_range[0], 0.0), max(omega_range[1], 0.0)
        p_span, w_span = max(p_high - p_low, 1e-9), max(w_high - w_low, 1e-9)
        scale = p_span / w_span  # display units per rad/s
        size = p_span  # the square's side, display units
        root = f"/phase/m{k + 1}"
        for name, pendulums in curves.items():
            _, rgba, width = SERIES_STYLE[name]
            phi_rad, omega_rad_s = pendulums[k]
            strip = np.empty((len(phi_rad), 2), np.float32)  # Rerun's 2D positions are float32
            strip[:, 0] = phi_rad
            np.multiply(omega_rad_s, -scale, out=strip[:, 1], casting="unsafe")
            finite = np.isfinite(strip).all(axis=1)
            if not finite.all():
                strip = strip[finite]
            rr.log(
                f"{root}/{name}",
                rr.LineStrips2D(
                    [strip], colors=[rgba], radii=[0.002 * width * size], draw_order=PHASE_DRAW_ORDER.get(name, 15.0)
                ),
                static=True,
            )
        pad = 0.06 * size
        tick = 0.015 * size
        x0, x1, y0, y1 = p_low - pad, p_high + pad, -scale * w_high - pad, -scale * w_low + pad
        p_ticks, w_ticks = nice_ticks(p_low, p_high), nice_ticks(w_low, w_high)
        lines = [[[x0, 0.0], [x1, 0.0]], [[0.0, y0], [0.0, y1]]]
        lines += [[[p, -tick], [p, tick]] for p in p_ticks]
        lines += [[[-tick, -scale * w], [tick, -scale * w]] for w in w_ticks]
        grey = (110, 110, 110, 255)
        rr.log(f"{root}/axes/lines", rr.LineStrips2D(lines, colors=[grey], radii=[0.002 * size]), static=True)
        labels = [f"{p:g}" for p in p_ticks] + [f"{w:g}" for w in w_ticks if w != 0]
        positions = [[p, 3 * tick] for p in p_ticks] + [[-4 * tick, -scale * w] for w in w_ticks if w != 0]
        labels += [f"phi{k + 1} (rad)", f"omega{k + 1} (rad/s)"]
        positions += [[x1 + 0.1 * size, 0.0], [0.0, y0 - 0.05 * size]]  # beyond the axes' ends
        rr.log(
            f"{root}/axes/labels",
            rr.Points2D(positions, radii=[0.0005 * size], colors=[grey], labels=labels, show_labels=True),
            static=True,
        )


def _finite_range(arrays: list[np.ndarray]) -> tuple[float, float] | None:
    """(lowest, highest) finite value over the arrays (no joined copy); None if there is none."""
    lows, highs = [], []
    for a in arrays:
        finite = a[np.isfinite(a)] if not np.isfinite(a).all() else a
        if len(finite):
            lows.append(float(finite.min()))
            highs.append(float(finite.max()))
    return (min(lows), max(highs)) if lows else None


def _warn_stderr(message: str) -> None:
    print(f"pendsim: warning: {' '.join(message.split())}", file=sys.stderr)


def _pendulums(traj: Trajectory) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(traj.phi_rad[:, k], traj.omega_rad_s[:, k]) for k in range(2)]


def view_recording(
    path: str | Path,
    rrd_path: str | Path,
    *,
    release_s: float | None = None,
    max_gap_s: float | None = None,
    drive: Drive | None = None,
    replace: bool = False,
    warn: Callable[[str], None] = _warn_stderr,
    overrides: Mapping[str, float] | None = None,
) -> Path:
    """A recording and the model's prediction (re-simulated from the recording's parameters, from
    the estimated start) to an .rrd file, the rig drawn from its MJCF attachment where that is
    safe (``rig_model``).

    Args:
      release_s, max_gap_s: as ``measured.align_recording`` (the start on the recording's clock
        instead of finding it; the longest gap interpolated across).
      drive: the drive of the re-simulation, from the start on; by default the one the recording
        holds on its /drive topic from the start on (none for a free run;
        ``measured.recording_drive``). The start is found by the model, driven by it, over its
        first second (``pendsim_mj.estimation.alignment``).
      replace: replace an existing .rrd file (``--force``).
      warn: receives a warning line (an MJCF attachment ignored).
      overrides: parameter changes on the recording's rig (``--params-file``, e.g. calibrate's).
    """
    # a truncated or damaged file fails here, before Rerun sees it (only the topics shown are decoded)
    rec = read_recording(path, topics=[*(imu_topic(n) for n in NODES), DRIVE_TOPIC])
    params = recorded_params(rec).with_mapping(overrides or {})
    gap = DEFAULT_MAX_GAP_S if max_gap_s is None else max_gap_s
    run = align_recording(rec, params, release_s=release_s, max_gap_s=gap)
    duration = whole_steps_s(run.duration_s + 0.02)
    if drive is None:
        drive = recording_drive(rec, run)  # the recording's /drive from the start on (None: a free run)
    start = (params, run.start.phi_rad, run.start.omega_rad_s, duration)

    def blocks() -> Iterator[tuple[int, Trajectory]]:
        return simulate_blocks(*start, block_steps=VIEW_BLOCK_STEPS, drive=drive)

    mjcf_xml = rec.mjcf_xml
    del rec  # the decoded topics: the aligned run holds what is shown
    return view_aligned(run, blocks, mjcf_xml, rrd_path, replace=replace, warn=warn)


def view_report(
    report: ValidationReport, rrd_path: str | Path, *, replace: bool = False, warn: Callable[[str], None] = _warn_stderr
) -> Path:
    """A validation's measured run and its MuJoCo run (no second read, alignment or simulation)."""
    traj = report.model_run
    return view_aligned(report.run, lambda: iter([(0, traj)]), report.mjcf_xml, rrd_path, replace=replace, warn=warn)


def rig_model(mjcf_xml: str | None, traj: Trajectory, *, warn: Callable[[str], None] = _warn_stderr) -> mujoco.MjModel:
    """The model to draw: the recording's MJCF attachment if ``pendsim_mj.rig.mjcf_guard`` accepts it
    (no file references, within size limits) and it compiles, else the run's parameters (with a
    warning naming the reason)."""
    if mjcf_xml:
        try:
            return compile_untrusted(mjcf_xml)
        except ModelError as exc:
            warn(f"ignoring the recording's MJCF attachment ({exc}); drawing the rig from the recorded parameters")
    targets = traj.drive.targets if isinstance(traj.drive, Drive) else ()
    return build_model(traj.single_params, drive_targets=targets)


SPLINE_MARGIN_ROWS = 64
"""Model rows each side of a block that the phi1 error's cubic spline sees (``_ModelAtInstants``):
a not-a-knot spline's dependence on a knot falls by about 3.7x per knot, so at 64 rows the
blocks' values equal one spline through the whole run to rounding."""


class _ModelAtInstants:
    """The model's phi1 (cubic spline, as ``validation.resample``) at given increasing instants,
    gathered block by block: each block is interpolated once the next one's first rows are known,
    from a spline over the block and SPLINE_MARGIN_ROWS rows each side."""

    def __init__(self, at_s: np.ndarray) -> None:
        self.at_s = at_s
        self.values = np.full(len(at_s), np.nan)
        self.done = 0  # instants before this index are interpolated
        self.t_s = np.zeros(0)
        self.phi_rad = np.zeros(0)
        self.pending_from = 0  # rows of (t_s, phi_rad) before this are only the left margin

    def add(self, t_s: np.ndarray, phi_rad: np.ndarray) -> None:
        self.t_s, self.phi_rad = np.concatenate([self.t_s, t_s]), np.concatenate([self.phi_rad, phi_rad])
        ready = len(self.t_s) - SPLINE_MARGIN_ROWS  # rows before this have their right margin
        if ready > self.pending_from:
            self._interpolate(until_s=float(self.t_s[ready - 1]))
            keep = max(0, ready - SPLINE_MARGIN_ROWS)
            self.t_s, self.phi_rad = self.t_s[keep:], self.phi_rad[keep:]
            self.pending_from = ready - keep

    def finish(self) -> np.ndarray:
        """The values at every instant up to the run's end (NaN past it)."""
        if len(self.t_s):
            self._interpolate(until_s=float(self.t_s[-1]))
        return self.values

    def _interpolate(self, *, until_s: float) -> None:
        from pendsim_mj.estimation.validation import resample  # scipy: not for the live view

        stop = int(np.searchsorted(self.at_s, until_s, side="right"))
        if stop > self.done:
            self.values[self.done : stop] = resample(self.t_s, self.phi_rad, self.at_s[self.done : stop])
            self.done = stop


def _log_blocks(
    blocks: Iterator[tuple[int, Trajectory]], model: mujoco.MjModel, phi1_at: _ModelAtInstants
) -> tuple[dict[str, np.ndarray], bool]:
    """Log each block's poses, series and spring geometry (colours follow once the whole run's
    tension range is known: ``_log_spring_colours``), interpolate phi1 at the measured instants,
    and keep per step only what the end needs, in float32: the spring tensions (4) and the phase
    portraits' angles and rates (2 + 2), 32 bytes per step. Returns those (with t_s) and whether
    the support moves."""
    parts: dict[str, list[np.ndarray]] = {"t_s": [], "force_n": [], "phi_rad": [], "omega_rad_s": []}
    moving_frame = False
    for start, block in blocks:
        if start:  # consecutive blocks share their boundary row: logged with the previous one
            block = block.rows(slice(1, None))
        log_trajectory(block, model, springs=False)
        log_springs(model, block.t_s, block.phi_rad, block.tilt_rad, block.support_m, None, (0.0, 0.0))
        phi1_at.add(block.t_s, block.phi_rad[:, 0])
        moving_frame = moving_frame or bool(np.any(block.support_m))
        parts["t_s"].append(block.t_s)
        parts["force_n"].append(block.spring_force_n.astype(np.float32))
        parts["phi_rad"].append(block.phi_rad.astype(np.float32))
        parts["omega_rad_s"].append(block.omega_rad_s.astype(np.float32))
    return {name: np.concatenate(p) for name, p in parts.items()}, moving_frame


def _log_spring_colours(t_s: np.ndarray, force_n: np.ndarray, *, root: str = "/rig") -> None:
    """The springs' colours (``log_springs``) over the whole run's tension range, in windows."""
    low, high = float(force_n.min()), float(force_n.max())
    for lo in range(0, len(t_s), VIEW_BLOCK_STEPS):
        rows = slice(lo, lo + VIEW_BLOCK_STEPS)
        n = len(t_s[rows])
        colours = _tension_colours(force_n[rows], low, high).reshape(n * 4, 3)
        rr.send_columns(
            f"{root}/springs",
            indexes=[rr.TimeColumn(TIMELINE, duration=t_s[rows])],
            columns=rr.LineStrips3D.columns(colors=colours).partition([4] * n),
        )


def _tension_colours(force_n: np.ndarray, low: float, high: float) -> np.ndarray:
    """(n, 4, 3) uint8 RGB of spring tensions force_n (n, 4), N: blue at ``low``, red at ``high``."""
    share = (force_n - low) / (high - low) if high > low else np.zeros_like(force_n)
    return np.stack([255 * share, 60 + 0 * share, 255 * (1 - share)], axis=-1).astype(np.uint8)


def _in_windows(t_s: np.ndarray, *columns: np.ndarray) -> Iterator[tuple[np.ndarray, ...]]:
    """(t_s, columns...) in windows of VIEW_BLOCK_STEPS rows: Rerun converts one window at a time."""
    for lo in range(0, max(len(t_s), 1), VIEW_BLOCK_STEPS):
        yield (t_s[lo : lo + VIEW_BLOCK_STEPS], *(c[lo : lo + VIEW_BLOCK_STEPS] for c in columns))


def view_aligned(
    run: MeasuredRun,
    blocks: Callable[[], Iterator[tuple[int, Trajectory]]],
    mjcf_xml: str | None,
    rrd_path: str | Path,
    *,
    replace: bool = False,
    warn: Callable[[str], None] = _warn_stderr,
) -> Path:
    """Measured series (t = 0 at the start) beside a model run, the rig drawn by ``rig_model``,
    published as the .rrd file ``rrd_path`` (``rrd_output``, written while it is logged).

    ``blocks()`` yields the model run as (first row, block) pairs sharing their boundary rows
    (``simulation.simulate_blocks``; a whole trajectory is one block): the run is logged block by
    block and never held whole (32 bytes per step are kept: ``_log_blocks``); the phi1 error is
    interpolated block by block, and every series goes to Rerun in windows of VIEW_BLOCK_STEPS
    rows, so that memory beyond the measured run grows by 32 bytes per model step."""
    it = blocks()
    first = next(it)
    model = rig_model(mjcf_xml, first[1], warn=warn)
    t, phi1, at = run.series(BY_NAME["phi1"])
    phi1_at = _ModelAtInstants(np.clip(at, 0.0, None))
    with rrd_output(rrd_path, replace=replace, series=("measured", "model")):
        log_series_styles(("measured", "model"))
        kept, moving_frame = _log_blocks(itertools.chain([first], it), model, phi1_at)
        del first
        log_rig_geometry(model, moving_frame=moving_frame)
        _log_spring_colours(kept["t_s"], kept["force_n"])
        log_measured(run)
        inside = at <= kept["t_s"][-1]
        computed = phi1_at.finish()[inside]
        for window in error_in_windows(t[inside], phi1[inside], computed, max_gap_s=run.max_gap_s):
            log_error(*window)
        del computed
        measured = [(node.phi_rad, node.omega_rad_s) for node in run.nodes]
        model_curves = [(kept["phi_rad"][:, k], kept["omega_rad_s"][:, k]) for k in range(2)]
        log_phase_portraits({"measured": measured, "model": model_curves})
    return Path(rrd_path)


def view_comparison(comparison, params, variant, rrd_path: str | Path, *, replace: bool = False) -> Path:
    """Planar and spatial rigs side by side (0.8 m apart) and their angles on shared plots."""
    planar_model = build_model(params.with_overrides(plane_offset_m=0.0))
    spatial_model = build_model(params, variant=variant)
    with rrd_output(rrd_path, replace=replace, series=("planar", "spatial")):
        log_series_styles(("planar", "spatial"))
        for root, model, traj, x, series in (
            ("/rig/planar", planar_model, comparison.planar, -0.4, "planar"),
            ("/rig/spatial", spatial_model, comparison.spatial, 0.4, "spatial"),
        ):
            log_rig_geometry(model, root=root, x_offset_m=x, moving_frame=bool(np.any(traj.support_m)))
            log_trajectory(traj, model, root=root, x_offset_m=x, series=series)
        times = rr.TimeColumn(TIMELINE, duration=comparison.spatial.t_s)
        for k in range(2):
            rr.send_columns(
                f"/plots/tilt{k + 1}/spatial",
                indexes=[times],
                columns=rr.Scalars.columns(scalars=comparison.spatial.tilt_rad[:, k]),
            )
        log_phase_portraits({"planar": _pendulums(comparison.planar), "spatial": _pendulums(comparison.spatial)})
    return Path(rrd_path)


def view_trajectory(traj: Trajectory, model: mujoco.MjModel, rrd_path: str | Path, *, replace: bool = False) -> Path:
    """A simulated run (no measurement) to an .rrd file."""
    with rrd_output(rrd_path, replace=replace, series=("model",)):
        log_series_styles(("model",))
        log_rig_geometry(model, moving_frame=bool(np.any(traj.support_m)))
        log_trajectory(traj, model)
        log_phase_portraits({"model": _pendulums(traj)})
    return Path(rrd_path)
