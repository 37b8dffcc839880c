"""Files: MCAP reading and writing (mcap), the ROS 2 codec, recordings, lab-file importers, atomic
publication of outputs.

- ``recording``: one MCAP file per run; ``read_recording`` gives a ``Recording`` (arrays per
  topic: ``ImuTopic``, ``JointStates``; times in ns since its ``start_time_ns``);
- ``mcap``: any MCAP file, every CRC checked: ``read_mcap`` (-> ``McapContents``), ``scan_mcap``
  (-> ``McapFile``, chunk by chunk), the streaming ``BulkMcapWriter``;
- ``trajectory_file``: ``save_trajectory``, a simulated run to ``.npz`` or ``.csv``;
- ``importers``: lab files (CSV, LabVIEW ``.lvm``, TDMS) to recordings: ``import_file``;
- ``outputs``: ``atomic_output``, ``atomic_directory``: a file or folder appears only complete;
- ``ros2``: the CDR layouts of the messages pendsim writes; ``recording_writer``: a recording
  written block by block.

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
    "ImportResult": ".importers",
    "ImportSpec": ".importers",
    "import_file": ".importers",
    "atomic_directory": ".outputs",
    "atomic_output": ".outputs",
}

if TYPE_CHECKING:
    from .importers import ImportResult, ImportSpec, import_file
    from .mcap.reader import McapContents, McapFile, read_mcap, scan_mcap
    from .mcap.writer import BulkMcapWriter
    from .outputs import atomic_directory, atomic_output
    from .recording import ImuTopic, JointStates, Recording, read_recording
    from .trajectory_file import save_trajectory
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = [
    "BulkMcapWriter",
    "ImportResult",
    "ImportSpec",
    "ImuTopic",
    "JointStates",
    "McapContents",
    "McapFile",
    "Recording",
    "atomic_directory",
    "atomic_output",
    "import_file",
    "read_mcap",
    "read_recording",
    "save_trajectory",
    "scan_mcap",
]
