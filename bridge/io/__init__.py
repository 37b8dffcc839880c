"""Files: MCAP reading and writing (mcap), the ROS 2 codec, recordings (their layout, reader and
writer), the measured arrays a recording gives, atomic publication of outputs.

- ``recording``: one MCAP file per run; ``read_recording`` gives a ``Recording`` (arrays per
  topic: ``ImuTopic``, ``JointStates``; times in ns since its ``start_time_ns``);
- ``mcap``: any MCAP file, every CRC checked: ``read_mcap`` (-> ``McapContents``), ``scan_mcap``
  (-> ``McapFile``, chunk by chunk), the streaming ``BulkMcapWriter``;
- ``trajectory_file``: ``save_trajectory``, a simulated run to ``.npz`` or ``.csv``;
- ``measured``: a recording turned into what the physics takes: ``align_recording`` (-> a
  ``MeasuredRun``), ``recorded_params``, ``recording_drive``;
- ``outputs``: ``atomic_output``, ``atomic_directory``: a file or folder appears only complete;
- ``ros2``: the CDR layouts of the messages pendsim writes; ``recording_layout``: the topics and
  metadata a recording holds; ``recording_writer``: a recording written block by block;
- ``twin_topics``: the live twin's topics beside the measured data (``pendsim twin``).

Importing this package imports none of them: the names above are imported when first used
(``pendsim_mj.lazy``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy

_LAZY = {
    "ImuTopic": ".recording",
    "JointStates": ".recording",
    "Recording": ".recording",
    "read_recording": ".recording",
    "McapContents": ".mcap.reader",
    "McapFile": ".mcap.reader",
    "read_mcap": ".mcap.reader",
    "scan_mcap": ".mcap.reader",
    "BulkMcapWriter": ".mcap.writer",
    "save_trajectory": ".trajectory_file",
    "align_recording": ".measured",
    "recorded_params": ".measured",
    "recording_drive": ".measured",
    "atomic_directory": ".outputs",
    "atomic_output": ".outputs",
}

if TYPE_CHECKING:
    from .mcap.reader import McapContents, McapFile, read_mcap, scan_mcap
    from .mcap.writer import BulkMcapWriter
    from .measured import align_recording, recorded_params, recording_drive
    from .outputs import atomic_directory, atomic_output
    from .recording import ImuTopic, JointStates, Recording, read_recording
    from .trajectory_file import save_trajectory
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = [
    "BulkMcapWriter",
    "ImuTopic",
    "JointStates",
    "McapContents",
    "McapFile",
    "Recording",
    "align_recording",
    "atomic_directory",
    "atomic_output",
    "read_mcap",
    "read_recording",
    "recorded_params",
    "recording_drive",
    "save_trajectory",
    "scan_mcap",
]
