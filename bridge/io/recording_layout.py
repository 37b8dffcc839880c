"""The names and layouts of a pendsim recording: its nodes, topics, frames and joints, the MJCF
attachment, the fixed CDR layouts of its /tf and /drive messages, ``RunInfo`` (how the run was
made) and how its log times read as UTC (``UNIX_2000_S``, ``utc_iso``). The reader
(``recording``) and the writer (``recording_writer``) both follow it; the topics are described in
``recording``'s docstring.
"""

from __future__ import annotations

import dataclasses
import datetime

from pendsim_mj.rig.drives import CHANNEL_LABELS, NCHANNEL
from pendsim_mj.sensors import rotations

from . import ros2

NODES = ("m1", "m2")
JOINT_NAMES = ("hinge_phi1", "hinge_phi2")
SPATIAL_JOINT_NAMES = ("tilt_m1", "tilt_m2")  # pendsim_mj.rig.model.TILTS: the spatial variant's extra joints
WORLD_FRAME = "world"
MJCF_ATTACHMENT = "pendulums.xml"
IMPORT_METADATA = "pendsim/import"  # what ``pendsim import`` writes: the times are a lab file's columns
SITE_QUAT_WXYZ = rotations.IMU_SITE_QUAT_WXYZ  # the IMU site's axes in its body at rest
TF_LAYOUT = ros2.tf_layout(((WORLD_FRAME, "m1"), (WORLD_FRAME, "m2")))
STATIC_TF_LAYOUT = ros2.tf_layout((("m1", "imu_m1"), ("m2", "imu_m2")))
STATIC_WORLD_TF_LAYOUT = ros2.tf_layout(
    ((WORLD_FRAME, "m1"), (WORLD_FRAME, "m2"), ("m1", "imu_m1"), ("m2", "imu_m2"))
)  # a static recording: the pendulums at rest under the world root, then the mounts
UNIX_2000_S = 946_684_800.0  # 2000-01-01T00:00:00Z: file times from here on are taken as Unix (UTC) times
DEFAULT_START_NS = 1_735_689_600_000_000_000  # 2025-01-01T00:00:00Z: a fixed UTC start for files made in memory


DRIVE_TOPIC = "/drive"
DRIVE_LABEL = ",".join(CHANNEL_LABELS)
DRIVE_LAYOUT = ros2.float64_multiarray_layout(DRIVE_LABEL, NCHANNEL)


CONTROL_TOPIC = "/control"
CONTROL_METADATA = "pendsim/control"


@dataclasses.dataclass(frozen=True)
class ControlTopic:
    """A closed loop's ``/control`` topic: what the controller saw and did at each control step
    (log time = the step's start), one Float64MultiArray per step whose layout label lists
    ``names`` (units in the names), and the loop's description for ``pendsim/control``.

    Attributes:
      names: the columns.
      t_s: (n,) each step's start from the release, s.
      values: (n, len(names)).
      metadata: JSON-able text per key (controller, gains, limits, metrics).
    """

    names: tuple[str, ...]
    t_s: object
    values: object
    metadata: dict[str, str]


def control_layout(names: tuple[str, ...]) -> ros2.FixedCdr:
    """The /control message layout for these columns."""
    return ros2.float64_multiarray_layout(",".join(names), len(names))


def imu_topic(node: str) -> str:
    return f"/imu/{node}"


@dataclasses.dataclass(frozen=True)
class RunInfo:
    """How a run was made: enough, with the MJCF, to re-simulate it."""

    engine: str
    phi0_rad: tuple[float, float]
    omega0_rad_s: tuple[float, float]
    duration_s: float
    dt_s: float
    model: str = "planar"
    release_time_s: float = 0.0  # when the pendulums were let go, on the recording's clock


def utc_iso(t_ns: int) -> str:
    """ns since 1970 as ISO 8601 UTC with a Z, to the microsecond."""
    moment = datetime.datetime(1970, 1, 1, tzinfo=datetime.UTC) + datetime.timedelta(microseconds=t_ns // 1000)
    return moment.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
