"""pendsim_bridge (the folder ``bridge/``): everything between the physics (``pendsim_mj``) and
the outside world: the ``pendsim`` command line, ROS 2 CDR codec, MCAP files, recordings,
validation runs, Rerun views and replay.

Installed under the distinctive name ``pendsim_bridge`` so that it can neither shadow nor be
shadowed by another package called ``bridge``. Imports pendsim_mj; pendsim_mj never imports it.

What a script does with recordings is exported here (``__all__``; reference with examples:
docs/api.md)::

    from pendsim_bridge import RecordSpec, identify, read_recording, record, validate

    record(RecordSpec(duration_s=20.0), "run.mcap")  # simulate and write both IMU nodes
    rec = read_recording("run.mcap")  # rec.imu["m1"].gyro_rad_s: (n, 3) rad/s
    report = validate("run.mcap")  # the paper's metrics against MuJoCo and the reference

- record: ``RecordSpec``, ``record`` (-> ``RecordResult``); a trajectory to a file:
  ``save_trajectory``;
- read: ``read_recording`` (-> ``Recording``, arrays per topic, times in ns since its start),
  any MCAP file: ``read_mcap`` (-> ``McapContents``), write one: ``BulkMcapWriter``;
- validate and identify: ``validate`` (-> ``ValidationReport``), ``identify`` (->
  ``Identification``);
- calibrate: ``calibrate_recordings`` (-> ``CalibrationReport``: the rig's parameters fitted to
  recordings, what they determine, before and after);
- replay: ``replay`` (messages in log-time order), ``replay_to_mcap`` (a cut to a new file);
- sweep: ``run_sweep`` (a ``pendsim_mj.SweepPlan`` into a results folder), ``read_results``;
- the whole chain: ``run_demo``.

Importing the package imports none of them (nor MuJoCo, numba, matplotlib or Rerun): each is
imported when first used (``pendsim_mj.lazy``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy

from .errors import OutputError, ProcessError

_LAZY = {
    "ImuTopic": ".io.recording",
    "JointStates": ".io.recording",
    "Recording": ".io.recording",
    "read_recording": ".io.recording",
    "McapContents": ".io.mcap.reader",
    "read_mcap": ".io.mcap.reader",
    "BulkMcapWriter": ".io.mcap.writer",
    "save_trajectory": ".io.trajectory_file",
    "RecordInterrupted": ".run.record",
    "RecordResult": ".run.record",
    "RecordSpec": ".run.record",
    "record": ".run.record",
    "Identification": ".run.validate",
    "ValidationReport": ".run.validate",
    "identify": ".run.validate",
    "validate": ".run.validate",
    "CalibrationReport": ".report.calibration_report",
    "calibrate_recordings": ".run.calibrate",
    "ReplayMessage": ".run.replay",
    "replay": ".run.replay",
    "replay_to_mcap": ".run.replay",
    "SweepSummary": ".run.sweep",
    "read_results": ".run.sweep",
    "run_sweep": ".run.sweep",
    "DemoResult": ".run.demo",
    "run_demo": ".run.demo",
}

if TYPE_CHECKING:
    from .io.mcap.reader import McapContents, read_mcap
    from .io.mcap.writer import BulkMcapWriter
    from .io.recording import ImuTopic, JointStates, Recording, read_recording
    from .io.trajectory_file import save_trajectory
    from .report.calibration_report import CalibrationReport
    from .run.calibrate import calibrate_recordings
    from .run.demo import DemoResult, run_demo
    from .run.record import RecordInterrupted, RecordResult, RecordSpec, record
    from .run.replay import ReplayMessage, replay, replay_to_mcap
    from .run.sweep import SweepSummary, read_results, run_sweep
    from .run.validate import Identification, ValidationReport, identify, validate
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = [
    "BulkMcapWriter",
    "CalibrationReport",
    "DemoResult",
    "Identification",
    "ImuTopic",
    "JointStates",
    "McapContents",
    "OutputError",
    "ProcessError",
    "RecordInterrupted",
    "RecordResult",
    "RecordSpec",
    "Recording",
    "ReplayMessage",
    "SweepSummary",
    "ValidationReport",
    "calibrate_recordings",
    "identify",
    "read_mcap",
    "read_recording",
    "read_results",
    "record",
    "replay",
    "replay_to_mcap",
    "run_demo",
    "run_sweep",
    "save_trajectory",
    "validate",
]
