"""Allan-deviation analysis of a static recording: the paper's table, noise terms, plots, JSON."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from pendsim_mj.allan.deviation import (
    MIN_MOTION_RAD_S,
    MOTION_MARGIN_S,
    AllanCurve,
    NoiseTerms,
    SamplingReport,
    adev_of_phase,
    check_sampling,
    curves_of_deviations,
    gyro_motion,
    load_kernels,
    longest_uniform_segment,
    motion_intervals_s,
    noise_terms,
    phase,
    still_samples,
    tau_grid,
)
from pendsim_mj.errors import RecordingError
from pendsim_mj.estimation.timing import nominal_rate_hz
from pendsim_mj.units import seconds

from ..io.outputs import atomic_directory
from ..io.recording import ImuTopic, read_recording
from ..io.recording_layout import NODES, imu_topic
from ..signals import interrupts_deferred

SENSORS = (("accel", "m/s^2", "accelerometer"), ("gyro", "rad/s", "gyroscope"))
NOT_PROVIDED = -1.0
"""REP-145: covariance element 0 = -1 says a message does not carry that quantity (its values are
placeholders: a lab file imported without an accelerometer column, ``acquire.sink``)."""
# Units of the noise terms per sensor: N, B, K.
TERM_UNITS = {"accel": ("m/s/sqrt(s)", "m/s^2", "m/s^2/sqrt(s)"), "gyro": ("rad/sqrt(s)", "rad/s", "rad/s/sqrt(s)")}


@dataclasses.dataclass(frozen=True)
class AxisResult:
    """One sensor axis: the paper's table row, its curve and its noise terms. An axis the
    recording does not provide (``provided`` False: its messages mark the quantity not provided)
    has NaN numbers, no curve values and no terms; the table and JSON say "not provided"."""

    node: str
    sensor: str  # "accel" or "gyro"
    axis: str  # "x", "y", "z"
    unit: str
    sigma: float  # Allan deviation at tau = 1/fs (the paper's one-sample sigma)
    std: float  # plain sample standard deviation, for comparison
    mean: float
    cv_percent: float  # sigma / |mean| * 100
    curve: AllanCurve
    terms: NoiseTerms
    provided: bool = True


@dataclasses.dataclass(frozen=True)
class AllanReport:
    path: Path
    rate_hz: float
    duration_s: float
    n_samples: dict[str, int]
    sampling: dict[str, SamplingReport]
    segment: dict[str, tuple[float, float]]  # node -> analysed (start, end) s
    axes: list[AxisResult]
    largest_motion_rad_s: dict[str, float] = dataclasses.field(default_factory=dict)  # node -> turning rate
    clocks: dict[str, SampleClock] = dataclasses.field(default_factory=dict)  # node -> its sampling's clock
    absent: dict[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)  # node -> sensors not provided

    def moved(self, node: str) -> bool:
        """The node turned (somewhere outside the analysed stretch: ``pendsim_mj.allan.deviation.gyro_motion``)."""
        return self.largest_motion_rad_s.get(node, 0.0) > MIN_MOTION_RAD_S


def analyse(
    path: str | Path,
    *,
    longest_segment: bool = False,
    progress: Callable[[int], None] | None = None,
    while_computing: Callable[[], object] | None = None,
) -> AllanReport:
    """Read the IMU topics of a recording and analyse every accelerometer and gyro axis.

    Each node's phase (``pendsim_mj.allan.deviation.phase``) is built from the recording's own arrays (no
    joined copy of the data) once the rest of the decoded topics (orientations, stamps) is
    dropped, one node at a time. With ``longest_segment``, a node's samples count as static only
    farther than ``MOTION_MARGIN_S`` from the motion of every node (``still_samples``): a stretch
    held before a release ends before the earliest motion onset, whichever node moves first.

    Time on a 2-core machine (a 6 h recording): numba is loaded first (0.3-0.5 s) and the chunks'
    message indexes are checked compiled (``McapFile.chunks``); the deviations are computed on
    other threads (compiled, without the GIL) while this one imports scipy.special and calls
    ``while_computing`` (the caller's own imports, e.g. the plotting modules).

    Raises:
      RecordingError: unreadable file, no IMU topic, or (without ``longest_segment``, which
        analyses the longest static, uniformly sampled stretch) a node that turns
        (``pendsim_mj.allan.deviation.gyro_motion``), gaps or irregular timestamps, which Allan deviation
        cannot take.
    """
    from ..io.mcap import chunk_kernel  # start-up: numba, for the analysis only

    path = Path(path)
    chunk_kernel.warm_up()  # numba's first call in this process: the chunks are then parsed compiled
    stretches = _static_stretches(path, longest_segment, progress)
    with interrupts_deferred():  # numba loads its compiled code: Ctrl-C held back, not swallowed
        load_kernels()
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="allan") as pool:
        computing = pool.submit(_deviations, stretches.columns)  # compiled, without the GIL
        import scipy.special  # noqa: F401  (start-up: loaded meanwhile, for the confidence intervals)

        if while_computing is not None:
            while_computing()
        moments = {
            node: [(float(c.mean()), float(c.std())) for block in columns for c in block.T]
            for node, columns in stretches.columns.items()
        }
        deviations = computing.result()
    axes = []
    for node, (accel, _) in stretches.columns.items():
        curves = curves_of_deviations(deviations[node], len(accel), stretches.rates[node])
        axes += _axis_results(node, moments[node], curves, stretches.absent.get(node, ()))
    found = stretches
    counts = {node: len(accel) for node, (accel, _) in found.columns.items()}
    duration = max(end - start for start, end in found.segments.values())
    rate = found.rates[next(iter(found.rates))]
    return AllanReport(
        path, rate, duration, counts, found.sampling, found.segments, axes, found.largest, found.clocks, found.absent
    )


def _deviations(columns: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, np.ndarray]:
    """Each node's overlapping Allan deviations (k, 6) on ``tau_grid`` of its (accelerometer,
    gyro) samples: one node's phase (``phase``, (n + 1, 6)) in memory at a time."""
    out = {}
    for node, (accel, gyro) in columns.items():
        x = phase(accel, gyro)
        out[node] = adev_of_phase(x, tau_grid(len(accel)))
        del x
    return out


@dataclasses.dataclass
class _Stretches:
    """What ``_static_stretches`` found per node: the rate (Hz), the sampling report, the analysed
    stretch's (start, end) s and its (accelerometer, gyro) samples ((n, 3) views each), and the
    largest turning rate (rad/s)."""

    rates: dict[str, float]
    sampling: dict[str, SamplingReport]
    segments: dict[str, tuple[float, float]]
    columns: dict[str, tuple[np.ndarray, np.ndarray]]
    largest: dict[str, float]
    clocks: dict[str, SampleClock]
    absent: dict[str, tuple[str, ...]]  # node -> the sensors its messages mark not provided


@dataclasses.dataclass(frozen=True)
class SampleClock:
    """The instants a node's sampling was checked on.

    name: "log times" (when the writer logged each message) or "header stamps" (the sensor's own
      time of each sample, ``header.stamp``).
    other: the other clock's sampling, in words, where it was not uniform and the chosen one is
      (e.g. a ROS bag's log times, the instants the messages arrived, with the transport's
      jitter); "" otherwise.
    """

    name: str
    other: str = ""


def sample_instants(
    t_ns: np.ndarray, stamp_ns: np.ndarray | None, rate_hz: float
) -> tuple[np.ndarray, float, SampleClock, SamplingReport]:
    """The instants (ns, (n,)) to check a node's sampling on, the rate (Hz: ``rate_hz`` if given,
    else estimated from them), which clock they are and their sampling report: the header stamps
    (None: not read) where they increase throughout and break uniform sampling less often (gaps
    and irregular intervals) than the log times, which keep the choice otherwise (pendsim's own
    recordings: uniform)."""
    log_rate = rate_hz or nominal_rate_hz(t_ns * 1e-9)
    by_log = check_sampling(t_ns, log_rate)
    if by_log.uniform or stamp_ns is None or len(stamp_ns) != len(t_ns) or not np.all(np.diff(stamp_ns) > 0):
        return t_ns, log_rate, SampleClock("log times"), by_log
    stamp_rate = rate_hz or nominal_rate_hz(stamp_ns * 1e-9)
    by_stamp = check_sampling(stamp_ns, stamp_rate)
    if len(by_stamp.gaps) + by_stamp.irregular < len(by_log.gaps) + by_log.irregular:
        return stamp_ns, stamp_rate, SampleClock("header stamps", by_log.describe()), by_stamp
    return t_ns, log_rate, SampleClock("log times"), by_log


def _header_stamps(path: Path, nodes: list[str]) -> dict[str, np.ndarray]:
    """The header stamps (ns) of these nodes (those whose log times are not uniform), read in a
    second pass over their topics only when there are any (a ROS bag's; pendsim's own recordings
    skip it: 0.3-0.4 s of a 6 h run)."""
    if not nodes:
        return {}
    again = read_recording(path, topics=[imu_topic(n) for n in nodes], imu_fields=("stamp_ns",), compiled=True)
    return {node: again.imu[node].stamp_ns for node in nodes if node in again.imu}


def _static_stretches(path: Path, longest_segment: bool, progress: Callable[[int], None] | None) -> _Stretches:
    """Read the IMU topics and choose each node's static, uniformly sampled stretch (``analyse``)."""
    # only what the analysis uses: the log times, gyros and accelerometers (no orientations, stamps)
    # and their covariances (constant: kept once), which say whether a sensor is provided at all
    topics = [imu_topic(n) for n in NODES]
    fields = ("gyro_rad_s", "accel_m_s2", "gyro_covariance", "accel_covariance")
    rec = read_recording(path, topics=topics, progress=progress, imu_fields=fields, compiled=True)
    if not rec.imu:
        raise RecordingError(f"{path}: no /imu/m1 or /imu/m2 topic to analyse")
    absent = {node: not_provided(topic) for node, topic in rec.imu.items()}
    if all(len(a) == len(SENSORS) for a in absent.values()):
        raise RecordingError(
            f"{path}: no accelerometer or gyro to analyse: every IMU message marks both as not provided "
            "(covariance -1, REP-145); e.g. a lab file imported with orientation columns only"
        )
    rate = float(rec.metadata.get("pendsim/imu", {}).get("sample_rate_hz", "0") or 0)
    rates, motions, instants, clocks, sampling = {}, {}, {}, {}, {}
    for node, topic in rec.imu.items():
        if len(topic.t_ns) < 2:
            raise RecordingError(f"{path}: {imu_topic(node)} has {len(topic.t_ns)} message(s); need at least 20")
        instants[node], rates[node], clocks[node], sampling[node] = sample_instants(topic.t_ns, None, rate)
    uneven = [node for node, report in sampling.items() if not report.uniform]
    for node, stamp_ns in _header_stamps(path, uneven).items():
        t_ns = rec.imu[node].t_ns
        instants[node], rates[node], clocks[node], sampling[node] = sample_instants(t_ns, stamp_ns, rate)
    for node, topic in rec.imu.items():
        motions[node] = motion = gyro_motion(topic.gyro_rad_s, rates[node])
        if not motion.static and not longest_segment:
            at_s = seconds(int(topic.t_ns[motion.largest_index] - topic.t_ns[0]))
            raise RecordingError(
                f"{path}: {imu_topic(node)} is not static: it turns at up to {motion.largest_rad_s:.3g} rad/s "
                f"({at_s:.1f} s into the recording; a node at rest stays below {MIN_MOTION_RAD_S} rad/s); Allan "
                "deviation needs a static recording ('pendsim record --static'), or '--longest-segment' analyses "
                "the longest static, uniformly sampled stretch"
            )
    # every node's motion, on the recording's clock: no node is static while another one moves
    moving_s = np.concatenate(
        [motion_intervals_s(seconds(rec.imu[node].t_ns), m.moving) for node, m in motions.items()]
    ).reshape(-1, 2)
    segments, columns, largest = {}, {}, {}
    for node in list(rec.imu):
        topic = rec.imu.pop(node)  # the node's orientations go with it
        report = sampling[node]
        largest[node] = motions[node].largest_rad_s
        if not report.uniform and not longest_segment:
            raise RecordingError(
                f"{path}: {imu_topic(node)} is not uniformly sampled ({report.describe()}, by its "
                f"{clocks[node].name}); Allan deviation needs uniform sampling. '--longest-segment' analyses the "
                "longest uniform stretch"
            )
        part = slice(None)
        if not report.uniform or len(moving_s):
            still = still_samples(seconds(topic.t_ns), moving_s)
            part = longest_uniform_segment(instants[node], rates[node], usable=still)
            if part.stop - part.start < 20:
                raise RecordingError(f"{path}: {imu_topic(node)} has no static, uniformly sampled stretch to analyse")
        t = topic.t_ns[part]
        segments[node] = (float(t[0]) * 1e-9, float(t[-1]) * 1e-9)
        columns[node] = (topic.accel_m_s2[part], topic.gyro_rad_s[part])  # views: (n, 3) each
        del topic, t
        del instants[node]
    del rec
    return _Stretches(rates, sampling, segments, columns, largest, clocks, {n: a for n, a in absent.items() if a})


def not_provided(topic: ImuTopic) -> tuple[str, ...]:
    """The sensors ("accel", "gyro") that messages of this topic mark as not provided (REP-145:
    covariance element 0 = -1 in any message): their values are placeholders, never data."""
    covariances = {"accel": topic.accel_covariance, "gyro": topic.gyro_covariance}
    return tuple(
        sensor
        for sensor, _, _ in SENSORS
        if len(covariances[sensor]) and bool(np.any(covariances[sensor][:, 0, 0] == NOT_PROVIDED))
    )


def _axis_results(
    node: str, moments: list[tuple[float, float]], curves: list[AllanCurve], absent: tuple[str, ...] = ()
) -> list[AxisResult]:
    """The six rows of one node (accelerometer x, y, z, then gyro x, y, z) from each column's
    (mean, standard deviation) and its curve; the sensors in ``absent`` (not provided) get NaN
    numbers, an empty curve and no terms."""
    axes = []
    for j, ((mean, std), curve) in enumerate(zip(moments, curves, strict=True)):
        sensor, unit, _ = SENSORS[j // 3]
        if sensor in absent:
            nan, none = math.nan, np.empty(0)
            empty = dataclasses.replace(curve, tau_s=none, adev=none, low=none, high=none, edf=none, alpha=none)
            terms = NoiseTerms(None, None, None, None)
            axes.append(AxisResult(node, sensor, "xyz"[j % 3], unit, nan, nan, nan, nan, empty, terms, False))
            continue
        sigma = float(curve.adev[0])
        axes.append(
            AxisResult(
                node=node,
                sensor=sensor,
                axis="xyz"[j % 3],
                unit=unit,
                sigma=sigma,
                std=std,
                mean=mean,
                cv_percent=cv_percent(sigma, mean),
                curve=curve,
                terms=noise_terms(curve),
            )
        )
    return axes


def duration_text(duration_s: float) -> str:
    """A duration in a readable unit: "45.2 s", "12.5 min", "6.00 h"."""
    if duration_s < 120:
        return f"{duration_s:.1f} s"
    if duration_s < 2 * 3600:
        return f"{duration_s / 60:.1f} min"
    return f"{duration_s / 3600:.2f} h"


CV_LARGEST_PERCENT = 100.0
"""The largest CV given: above it an axis' mean is smaller than its one-sample noise (a gyro at
rest reads its small bias, an accelerometer axis across gravity nearly 0), and sigma / |mean| is
a ratio to what is mostly noise (thousands of percent that say nothing); such a CV is "-"."""


def cv_percent(sigma: float, mean: float) -> float:
    """The paper's coefficient of variation sigma / |mean| x 100 %, or NaN where the mean is
    below the one-sample noise (``CV_LARGEST_PERCENT``)."""
    if not abs(mean) * CV_LARGEST_PERCENT > sigma * 100.0:
        return math.nan
    return sigma / abs(mean) * 100.0


def table(report: AllanReport) -> str:
    """The paper's table (sigma, mean, CV per axis) and the noise terms, as text."""
    spans = {n: end - start for n, (start, end) in report.segment.items()}
    if max(spans.values()) - min(spans.values()) > 1.5 / report.rate_hz:  # the nodes' stretches differ
        each = "; ".join(f"{n}: {c} samples, {duration_text(spans[n])}" for n, c in report.n_samples.items())
        lines = [f"{report.path}: at {report.rate_hz:g} Hz ({each})"]
    else:
        lines = [
            f"{report.path}: {duration_text(report.duration_s)} at {report.rate_hz:g} Hz "
            f"({', '.join(f'{n}: {c} samples' for n, c in report.n_samples.items())})"
        ]
    for node, clock in report.clocks.items():
        if clock.name != "log times":
            lines.append(f"{node}: sampled by its {clock.name} (by its log times: {clock.other})")
    any_moved = any(report.moved(node) for node in report.sampling)
    for node, s in report.sampling.items():
        start, end = report.segment[node]
        if any_moved:  # every node's stretch keeps clear of every node's motion
            turns = f"turns at up to {report.largest_motion_rad_s[node]:.3g} rad/s" if report.moved(node) else "still"
            lines.append(
                f"{node}: {s.describe()}, {turns}; analysed the longest static, uniform stretch "
                f"{start:.3f}-{end:.3f} s (no node turning within {MOTION_MARGIN_S:g} s)"
            )
        elif not s.uniform:
            lines.append(f"{node}: {s.describe()}; analysed the longest uniform stretch {start:.3f}-{end:.3f} s")
    for node, sensors in report.absent.items():
        names = " and ".join(name for key, _, name in SENSORS if key in sensors)
        unchecked = "; whether it was static cannot be checked without a gyro" if "gyro" in sensors else ""
        lines.append(f"{node}: no {names} in the recording (its messages say not provided){unchecked}")
    lines.append("")
    head = f"{'node':4} {'sensor':13} {'axis':4}"
    lines.append(f"{head} {'sigma (tau=1/fs)':>17} {'mean':>12} {'CV %':>9} {'std':>11}  unit")
    for a in report.axes:
        sensor = dict((k, name) for k, _, name in SENSORS)[a.sensor]
        if not a.provided:
            lines.append(
                f"{a.node:4} {sensor:13} {a.axis:4} {'not provided':>17} {'-':>12} {'-':>9} {'-':>11}  {a.unit}"
            )
            continue
        cv = f"{a.cv_percent:9.3g}" if math.isfinite(a.cv_percent) else f"{'-':>9}"
        lines.append(f"{a.node:4} {sensor:13} {a.axis:4} {a.sigma:17.5g} {a.mean:12.5g} {cv} {a.std:11.5g}  {a.unit}")
    if any(a.provided and not math.isfinite(a.cv_percent) for a in report.axes):
        lines.append(
            "CV '-': the axis' mean is below its one-sample noise (a gyro at rest, an axis across gravity), "
            "so sigma / |mean| would say nothing"
        )
    lines.append("")
    lines.append(f"{head} {'N (white)':>12} {'B (bias inst.)':>15} {'at tau (s)':>10} {'K (rate RW)':>12}")
    for a in report.axes:
        sensor = dict((k, name) for k, _, name in SENSORS)[a.sensor]
        t = a.terms

        def fmt(v: float | None, width: int) -> str:
            return f"{v:{width}.4g}" if v is not None else f"{'-':>{width}}"

        if not a.provided:
            lines.append(f"{a.node:4} {sensor:13} {a.axis:4} {'not provided':>12}")
            continue
        lines.append(
            f"{a.node:4} {sensor:13} {a.axis:4} {fmt(t.white, 12)} {fmt(t.bias_instability, 15)} "
            f"{fmt(t.bias_instability_tau_s, 10)} {fmt(t.rate_random_walk, 12)}" + ("  B or K?" if t.unresolved else "")
        )
    if any(a.provided and a.terms.unresolved for a in report.axes):
        lines.append(
            "B or K?: the curve rises above its white noise at long tau, but this record cannot tell bias "
            "instability from a rate random walk (each fits the rise alike); a longer record can"
        )
    lines.append(
        "units: N "
        + "; ".join(f"{s}: {u[0]}" for s, u in TERM_UNITS.items())
        + "; B: the sensor's unit; K: unit/sqrt(s)"
    )
    return "\n".join(lines)


ABSENT_KEYS = (
    *("sigma", "mean", "cv_percent", "std", "white_N", "bias_instability_B", "bias_instability_tau_s"),
    *("rate_random_walk_K", "curve"),
)


def as_json(report: AllanReport) -> dict:
    """Everything in the report, curves included, as plain JSON types."""

    def num(v):
        return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v

    return {
        "file": str(report.path),
        "rate_hz": report.rate_hz,
        "duration_s": report.duration_s,
        "n_samples": report.n_samples,
        "sampling": {
            n: {
                "uniform": s.uniform,
                "gaps": s.gaps,
                "irregular": s.irregular,
                "analysed_s": list(report.segment[n]),
                "largest_motion_rad_s": report.largest_motion_rad_s.get(n),
                "clock": report.clocks[n].name if n in report.clocks else "log times",
                "not_provided": list(report.absent.get(n, ())),
            }
            for n, s in report.sampling.items()
        },
        "axes": [
            {"node": a.node, "sensor": a.sensor, "axis": a.axis, "unit": a.unit, "provided": False}
            | dict.fromkeys(ABSENT_KEYS)  # never a number for what the recording does not carry
            if not a.provided
            else {
                "node": a.node,
                "sensor": a.sensor,
                "axis": a.axis,
                "unit": a.unit,
                "provided": True,
                "sigma": a.sigma,
                "mean": a.mean,
                "cv_percent": num(a.cv_percent),
                "std": a.std,
                "white_N": num(a.terms.white),
                "bias_instability_B": num(a.terms.bias_instability),
                "bias_instability_tau_s": num(a.terms.bias_instability_tau_s),
                "rate_random_walk_K": num(a.terms.rate_random_walk),
                "terms_unresolved": a.terms.unresolved,
                "curve": {
                    "tau_s": a.curve.tau_s.tolist(),
                    "adev": a.curve.adev.tolist(),
                    "low": a.curve.low.tolist(),
                    "high": a.curve.high.tolist(),
                    "edf": [num(float(e)) for e in a.curve.edf],
                    "confidence": a.curve.confidence,
                },
            }
            for a in report.axes
        ],
    }


def plots(report: AllanReport, directory: str | Path, *, replace: bool = False) -> list[Path]:
    """One log-log plot per node and sensor (x, y, z together), rendered in this process (no
    forked workers: a fork of a process with threads can deadlock) and published together into
    ``directory`` (``atomic_directory``: never over
    plots of the same names unless ``replace``); returns the PNG paths."""
    directory = Path(directory)
    duration = duration_text(report.duration_s)
    names = []
    with atomic_directory(directory, replace=replace) as tmp:
        jobs = []
        for node in report.n_samples:
            for sensor, unit, name in SENSORS:
                chosen = [a for a in report.axes if a.node == node and a.sensor == sensor and a.provided]
                if not chosen:  # not provided: no plot
                    continue
                names.append(f"allan_{node}_{sensor}.png")
                jobs.append(
                    (
                        [a.curve for a in chosen],
                        [a.terms for a in chosen],
                        [a.axis for a in chosen],
                        f"{report.path.name}: {node} {name}, {duration} at {report.rate_hz:g} Hz",
                        unit,
                        TERM_UNITS[sensor],
                        tmp / names[-1],
                    )
                )
        for job in jobs:
            _render(job)
    return [directory / name for name in names]


def _render(job) -> Path:
    from .plots import allan_plot  # start-up: matplotlib, only when the plots are drawn

    curves, terms, labels, title, unit, term_units, path = job
    return allan_plot(curves, terms, labels, title=title, unit=unit, term_units=term_units, path=path)
