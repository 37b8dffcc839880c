"""The quantities that are validated and plotted: one table for validation, figures and Rerun.

Each is one node's phi, omega, or its accelerometer reading along the swing frame's tangential
or normal direction (what the sensor reads, gravity included: the paper's computed normal
acceleration has the projection of g added to match it). The same attribute name picks the
measured series from a ``pendsim_mj.estimation.alignment.NodeRun`` and, with the node index, the computed
one from a ``Trajectory``.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.engines.trajectory import Trajectory

Kind = Literal["phi", "omega", "tangential", "normal"]


@dataclasses.dataclass(frozen=True)
class Quantity:
    """One measured-against-computed quantity.

    Attributes:
      name: key in reports ("phi1", "tangential_m1", ...).
      label: short label for tables and axes ("a_t M1").
      unit: SI unit.
      description: what it is, for titles.
      node: 0 for M1's node, 1 for M2's.
      kind: which reading of that node.
      validated: compared with the paper's metrics (phi2 is only plotted).
    """

    name: str
    label: str
    unit: str
    description: str
    node: int
    kind: Kind
    validated: bool = True

    @property
    def attribute(self) -> str:
        """The NodeRun attribute holding the measured series."""
        return {
            "phi": "phi_rad",
            "omega": "omega_rad_s",
            "tangential": "tangential_m_s2",
            "normal": "normal_m_s2",
        }[self.kind]

    def computed(self, traj: Trajectory) -> NDArray[np.float64]:
        """The model's series (..., n) from a trajectory (the IMU model's accelerometer for
        accelerations)."""
        if self.kind == "phi":
            return traj.phi_rad[..., self.node]
        if self.kind == "omega":
            return traj.omega_rad_s[..., self.node]
        axis = 0 if self.kind == "tangential" else 1
        return traj.imu_accel_m_s2[..., self.node, axis]

    @property
    def title(self) -> str:
        return f"{self.description} ({self.unit})"


QUANTITIES: tuple[Quantity, ...] = (
    Quantity("phi1", "phi1", "rad", "angle of M1", 0, "phi"),
    Quantity("phi2", "phi2", "rad", "angle of M2", 1, "phi", validated=False),
    Quantity("omega1", "omega1", "rad/s", "angular velocity of M1", 0, "omega"),
    Quantity("omega2", "omega2", "rad/s", "angular velocity of M2", 1, "omega"),
    Quantity("tangential_m1", "a_t M1", "m/s^2", "tangential acceleration of M1 (accelerometer)", 0, "tangential"),
    Quantity("normal_m1", "a_n M1", "m/s^2", "normal acceleration of M1 (accelerometer)", 0, "normal"),
)
BY_NAME = {q.name: q for q in QUANTITIES}
VALIDATED: tuple[Quantity, ...] = tuple(q for q in QUANTITIES if q.validated)
