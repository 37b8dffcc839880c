"""A recording turned into what the physics layer aligns and compares: each node's IMU samples
as arrays on the recorder's clock (``node_samples``), the measured run aligned on them
(``align_recording``, ``pendsim_mj.estimation.alignment``), and the rig and drive the recording
holds (``recorded_params``, ``recording_drive``). A recording made by ``pendsim acquire`` keeps
each node's clock relation in its metadata (``recorded_stamp_clock``).

Validation, identification and the Rerun view all start here.
"""

from __future__ import annotations

import json
import math

import numpy as np

from pendsim_mj.errors import RecordingError
from pendsim_mj.estimation.alignment import MeasuredRun, NodeSamples, align
from pendsim_mj.estimation.timing import DEFAULT_MAX_GAP_S, MAX_DRIFT_PPM, ClockRelation
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.units import seconds

from .recording import Recording
from .recording_layout import IMPORT_METADATA, NODES, imu_topic


def recorded_stamp_clock(metadata: dict[str, dict[str, str]], node: str, start_time_ns: int) -> ClockRelation | None:
    """The clock relation ``pendsim acquire`` fitted over every packet's arrival, from a node's
    header stamps to its log times (both s since the recording's ``start_time_ns``), as its
    metadata keeps it (``pendsim/acquisition_result``, ``NODE.stamp_clock``); None when absent or
    unreadable (another recorder, a restarted node): then the stamps are fitted to the log times."""
    text = metadata.get("pendsim/acquisition_result", {}).get(f"{node}.stamp_clock")
    start = metadata.get("pendsim/acquisition", {}).get("start_time_ns", "")
    if text is None or not start.isdigit():
        return None
    try:
        value = json.loads(text)
        offset_s, rate, stamp0_s = (float(value[k]) for k in ("offset_s", "rate", "stamp0_s"))
    except (ValueError, TypeError, KeyError):
        return None
    if not all(map(math.isfinite, (offset_s, rate, stamp0_s))) or abs(rate - 1.0) > MAX_DRIFT_PPM * 2e-6:
        return None
    shift_s = seconds(int(start) - start_time_ns)  # acquisition start on the recording's time axis
    return ClockRelation(offset_s + shift_s, rate, stamp0_s + shift_s)


def node_samples(rec: Recording) -> tuple[NodeSamples, NodeSamples]:
    """Both nodes' /imu/mN samples as arrays (log times and header stamps in s)."""
    missing = [imu_topic(n) for n in NODES if n not in rec.imu]
    if missing:
        raise RecordingError(
            f"{rec.path}: needs both /imu/m1 and /imu/m2 (M1's and M2's IMU); {', '.join(missing)} missing; "
            "a one-node recording is for 'pendsim inspect' and 'pendsim allan' (docs/acquisition.md)"
        )
    out = []
    for n in NODES:
        topic = rec.imu[n]
        stamps = topic.stamp_ns
        clock = recorded_stamp_clock(rec.metadata, n, rec.start_time_ns)  # acquire's fit over the arrivals
        out.append(
            NodeSamples(
                log_t_s=seconds(topic.t_ns) if clock is None else clock.to_recorder_in_place(seconds(stamps)),
                quat_wxyz=topic.quat_wxyz,
                gyro_rad_s=topic.gyro_rad_s,
                accel_m_s2=topic.accel_m_s2,
                stamp_s=seconds(stamps) if np.any(stamps != stamps[0]) else None,  # constant stamps: none
                gyro_covariance=topic.gyro_covariance[0] if len(topic.gyro_covariance) else None,
            )
        )
    return out[0], out[1]


def fusion_rate_of(rec: Recording) -> float | None:
    """The nodes' fusion rate from the recording's metadata (a recording from elsewhere: a BNO055
    in NDOF mode, 100 Hz)."""
    imu_meta = rec.metadata.get("pendsim/imu", {})
    if imu_meta.get("fusion_timing", "true") != "true":
        return None
    return float(imu_meta.get("fusion_rate_hz", "100"))


def align_recording(
    rec: Recording,
    params: RigParams,
    *,
    release_s: float | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    samples: tuple[NodeSamples, NodeSamples] | None = None,
    off_hinge: bool = True,
    float32_values: bool = False,
) -> MeasuredRun:
    """The measured run of a recording (``pendsim_mj.estimation.alignment.align`` on its IMU topics, and on
    its /drive topic for a driven run); ``samples``: its ``node_samples`` if the caller has them;
    ``off_hinge``: keep the gyros off the hinge axes (for a spatial fit); ``float32_values``: the
    run's values as float32 (``align``)."""
    if samples is None:
        samples = node_samples(rec)  # its errors name the file already
    try:
        return align(
            samples,
            params,
            fusion_rate_hz=fusion_rate_of(rec),
            release_s=release_s,
            max_gap_s=max_gap_s,
            drive_input=rec.drive_input_s,
            off_hinge=off_hinge,
            float32_values=float32_values,
            file_times=IMPORT_METADATA in rec.metadata,
        )
    except RecordingError as exc:
        raise RecordingError(f"{rec.path}: {exc}") from None


def recording_drive(rec: Recording, run: MeasuredRun) -> Drive | None:
    """The recording's drive from the aligned run's start on (drive time 0 there), covering the
    whole run; None for a free run."""
    return rec.drive_from(run.start.time_s, until_s=run.duration_s + 0.1)


def recorded_params(rec: Recording) -> RigParams:
    try:
        return rec.params()
    except RecordingError:
        return DEFAULT_PARAMS  # a recording from elsewhere: the paper's rig
