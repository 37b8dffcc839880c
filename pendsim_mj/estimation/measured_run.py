"""What alignment takes and gives: each node's samples as recorded (``NodeSamples``) in, the
measured run from the start on (``MeasuredRun``: a ``NodeRun`` per node and the ``StartState``)
out. ``pendsim_mj.estimation.alignment.align`` makes them; this module only holds them.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.estimation.quantities import BY_NAME, Quantity
from pendsim_mj.estimation.swing_frame import SwingFrame
from pendsim_mj.estimation.timing import ClockRelation, Coverage

Floats = NDArray[np.float64]
StartKind = Literal["release", "in motion", "given"]

UNEXPLAINED_POOR = 0.03  # above this share the start fit is reported as poor (a 5 % frequency error gives 0.02)


@dataclasses.dataclass(frozen=True)
class NodeSamples:
    """One node's samples as recorded: n of them, any spacing, gaps allowed.

    Attributes:
      log_t_s: (n,) when the recorder logged each sample, s on its clock.
      quat_wxyz: (n, 4) fused orientation (this and the two below float64, or float32 to save
        memory: ``bridge.recording.read_recording(sensor_float32=True)``).
      gyro_rad_s: (n, 3) angular velocity, sensor axes.
      accel_m_s2: (n, 3) acceleration with gravity (specific force), sensor axes.
      stamp_s: (n,) the node's own time stamps, s (None: use log_t_s).
      gyro_covariance: (3, 3) of the gyro noise, (rad/s)^2 (None or zeros: the BNO055's).
    """

    log_t_s: Floats
    quat_wxyz: Floats
    gyro_rad_s: Floats
    accel_m_s2: Floats
    stamp_s: Floats | None = None
    gyro_covariance: Floats | None = None


@dataclasses.dataclass(frozen=True)
class NodeRun:
    """One node's measured series from the start on (m samples, the node's own instants).

    Attributes:
      t_s: (m,) sample instants since the start, s (the recorder's clock).
      value_t_s: (m,) instants the values belong to (fused values are older than their
        samples), s since the start: where the model is evaluated.
      phi_rad, omega_rad_s: (m,) the pendulum's angle and rate in its swing frame.
      tangential_m_s2, normal_m_s2: (m,) accelerometer along the swing frame's tangential and
        toward-pivot directions (gravity included).
      frame: the node's swing frame (hinge axis, mounting).
      clock: its stamps' relation to the recorder's clock (None: its stamps were unusable and
        log times were used).
      fusion_phase_s: where its chip's fusion ticks fall on its clock (mod one fusion period), s;
        None without fusion timing.
      coverage: how much of the run its samples cover.
      gyro_sigma_rad_s: noise sigma of its rate, rad/s.
      off_hinge_gyro_rad_s: (m, 2) gyro along the swing frame's tangential and toward-pivot
        directions, rad/s: zero for a planar swing; the tilt rate of a spatial one (what
        ``pendsim_mj.estimation.spatial_identification`` fits).
      before_start: the node's samples left out as before the start: a hold before a release,
        or, for a start in motion or a given one, samples whose (fused) values are older than
        the start (the first sample of a recording that starts in motion: its value is up to one
        fusion period old).
    """

    t_s: Floats
    value_t_s: Floats
    phi_rad: Floats
    omega_rad_s: Floats
    tangential_m_s2: Floats
    normal_m_s2: Floats
    frame: SwingFrame
    clock: ClockRelation | None
    fusion_phase_s: float | None
    coverage: Coverage
    gyro_sigma_rad_s: float
    off_hinge_gyro_rad_s: Floats | None = None
    before_start: int = 0


@dataclasses.dataclass(frozen=True)
class StartState:
    """Where the run starts and the model with it.

    Attributes:
      kind: "release" (from rest, found in the data), "in motion" (the recording starts
        moving; the state at its first samples) or "given" (the caller's start instant).
      time_s: the start on the recorder's clock, s.
      phi_rad, omega_rad_s: (phi1, phi2) and (omega1, omega2) there (rates 0 for a release).
      fit_rms: rms of the start fit's residuals in units of their sigmas.
      unexplained: how much of the motion over the start fit's window after the start the model
        leaves unexplained: rms of the angle residuals over the rms of the angles' change since
        the start (both nodes); 0 is a perfect fit, 1 is no better than "nothing moves".
      fit_window_s: the start fit's window after the start, s.
    """

    kind: StartKind
    time_s: float
    phi_rad: tuple[float, float]
    omega_rad_s: tuple[float, float]
    fit_rms: float
    unexplained: float = 0.0
    fit_window_s: float = 1.0

    @property
    def poor_fit(self) -> bool:
        """The model does not explain the first seconds after the start (UNEXPLAINED_POOR)."""
        return not self.unexplained <= UNEXPLAINED_POOR

    def fit_note(self) -> str:
        """A warning when the fit is poor, else "" (one sentence)."""
        if not self.poor_fit:
            return ""
        return (
            f"poor start fit: the model leaves {100 * self.unexplained:.0f} % of the motion over the first "
            f"{self.fit_window_s:g} s unexplained; check the start (give --release-s) or the rig parameters"
        )


@dataclasses.dataclass(frozen=True)
class MeasuredRun:
    """Both nodes' measured series from the start (t = 0) on, and how they were aligned.

    ``relative_timing_range_s``: (lo_s < 0, hi_s > 0), the shifts of M2's value instants against
    M1's that the nodes' fusion timing still allows (their fusion phases are known only within a
    stretch each): a fit through the whole run (``planar_fit``) refines the timing within it;
    None where the timing is pinned or the nodes have no fusion timing and trusted times.

    ``relative_timing_s``: how far alignment moved M2's value instants against M1's from where
    the nodes' own data (fusion phases, time columns) put them, s (the start fit's choice).

    ``timing_open_s``: how far the nodes' times were allowed off against each other beyond their
    fusion timing, s (a lab file's time columns; 0: a recorder's clocks, trusted).

    ``warnings``: one-line warnings about choices the data did not make clear or corrections
    made to the times (a clock step removed, M2's sense, a timing held at its room's edge)."""

    nodes: tuple[NodeRun, NodeRun]
    start: StartState
    fusion_rate_hz: float | None
    max_gap_s: float
    relative_timing_range_s: tuple[float, float] | None = None
    relative_timing_s: float = 0.0
    timing_open_s: float = 0.0
    warnings: tuple[str, ...] = ()

    def series(self, quantity: Quantity | str) -> tuple[Floats, Floats, Floats]:
        """(t_s, values, value_t_s) of a quantity (see ``pendsim_mj.estimation.quantities``), each (m,)."""
        q = BY_NAME[quantity] if isinstance(quantity, str) else quantity
        node = self.nodes[q.node]
        return node.t_s, getattr(node, q.attribute), node.value_t_s

    def both_nodes(self, field: str) -> Floats:
        """One per-node field (a ``NodeRun`` attribute of shape (m_k,), e.g. ``value_t_s``,
        ``omega_rad_s``) of both nodes as (m, 2) float64, NaN where a node has fewer samples."""
        m = max(len(n.t_s) for n in self.nodes)
        out = np.full((m, 2), np.nan)
        for k, node in enumerate(self.nodes):
            values = getattr(node, field)
            out[: len(values), k] = values
        return out

    @property
    def duration_s(self) -> float:
        """From the start to the later node's last sample, s."""
        return max(float(n.t_s[-1]) for n in self.nodes)

    @property
    def release_time_s(self) -> float:
        return self.start.time_s

    @property
    def release_angle_rad(self) -> tuple[float, float]:
        return self.start.phi_rad

    @property
    def gyro_sigma_rad_s(self) -> tuple[float, float]:
        return (self.nodes[0].gyro_sigma_rad_s, self.nodes[1].gyro_sigma_rad_s)
