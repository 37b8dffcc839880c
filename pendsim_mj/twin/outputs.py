"""What the live twin puts out, in batches: the records that its recording, its live views and its
tests share (``bridge`` writes them to MCAP, Rerun and Foxglove).

- ``Estimates``: the estimator's updates, one row per node sample taken in (time order): the
  sample as measured, the estimate after it with its standard deviations, and the innovation.
- ``ParameterCheck``: the tracked parameters once per health check, with their references and
  z-scores.
- ``estimator.Forecast`` (the motion predicted from an instant) and ``health.Alarm`` complete it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

Floats = NDArray[np.float64]
STATE_NAMES = ("phi1_rad", "phi2_rad", "omega1_rad_s", "omega2_rad_s")


@dataclasses.dataclass(frozen=True)
class Estimates:
    """n updates of the estimator, in time order.

    Attributes:
      t_s: (n,) each sample's instant (the instant its value stands for), s on the twin's clock.
      node: (n,) 0 (M1) or 1 (M2).
      measured: (n, 2) the node's swing angle (rad; its mount's offset, as estimated, taken out, so
        that it compares with the state's angle) and hinge rate (rad/s).
      state: (n, 4) the estimate after the update (``STATE_NAMES``).
      sigma: (n, 4) its standard deviations.
      innovation: (n, 2) measured minus predicted (rad, rad/s).
      innovation_sigma: (n, 2) the innovation's predicted standard deviations.
      nis: (n,) normalised innovation squared (chi^2 with 2 degrees of freedom on a healthy rig).
      accel_measured: (n, 2) the node's accelerometer along its swing's tangent and toward the
        pivot, gravity included, m/s^2.
      accel_innovation: (n, 2) its measured minus predicted, m/s^2 (NaN: not taken in).
      accel_innovation_sigma: (n, 2) their predicted standard deviations, m/s^2.
      accel_nis: (n,) its normalised innovation squared (chi^2 with 2 degrees of freedom).
    """

    t_s: Floats
    node: NDArray[np.int64]
    measured: Floats
    state: Floats
    sigma: Floats
    innovation: Floats
    innovation_sigma: Floats
    nis: Floats
    accel_measured: Floats
    accel_innovation: Floats
    accel_innovation_sigma: Floats
    accel_nis: Floats

    def __len__(self) -> int:
        return len(self.t_s)

    @staticmethod
    def empty() -> Estimates:
        z = np.zeros((0,))
        return Estimates(
            z,
            np.zeros(0, np.int64),
            z.reshape(0, 2),
            z.reshape(0, 4),
            z.reshape(0, 4),
            z.reshape(0, 2),
            z.reshape(0, 2),
            z,
            z.reshape(0, 2),
            z.reshape(0, 2),
            z.reshape(0, 2),
            z,
        )

    @staticmethod
    def concatenate(parts: list[Estimates]) -> Estimates:
        if not parts:
            return Estimates.empty()
        return Estimates(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(Estimates)))


@dataclasses.dataclass(frozen=True)
class ParameterCheck:
    """The tracked parameters at one health check.

    Attributes:
      t_s: the check's instant, s on the twin's clock.
      names: the parameters (``estimator.TRACKABLE``).
      value, sigma: (k,) their estimates and standard deviations (each parameter's unit).
      reference: (k,) their references (NaN before the baseline is taken).
      z: (k,) the monitor's change statistic (``HealthMonitor.statistics``: the likelihood ratio
        of that parameter alone changed, in sigmas; NaN before the baseline).
    """

    t_s: float
    names: tuple[str, ...]
    value: Floats
    sigma: Floats
    reference: Floats
    z: Floats
