"""The twin's topics in its recording, beside the measured data (``pendsim twin -o``).

Each is a std_msgs/msg/Float64MultiArray whose one layout dimension's label lists the columns
(units in the names), CDR-encoded; log times are UTC ns on the recording's clock.

- ``/twin/estimate``: one message per node sample taken in, logged at the estimate's time after it
  (non-decreasing): ``ESTIMATE_COLUMNS`` (the instant its value stands for, s on the recording's
  clock: up to a fusion period before the log time when the other node's sample came first; the
  node, what it measured, the estimate after it with its standard deviations, the innovation with
  its predicted standard deviations, the normalised innovation squared; then the same for the
  node's accelerometer along its swing's tangent and toward the pivot, NaN where it was not taken in).
- ``/twin/parameters``: once a second, per tracked parameter ``NAME``: ``NAME``, ``NAME_sigma``,
  ``NAME_reference``, ``NAME_z`` (each parameter's unit: ``pendsim_mj.twin.TRACKABLE``).
- ``/twin/forecast``: each forecast, at the instant it was made: per point of its grid ``t_s``
  (from the instant), the four states' means and standard deviations (``forecast_columns``).
- ``/diagnostics``: the health status once a second and at each alarm (one status per tracked
  parameter: OK, WARN above 2 sigma, ERROR once alarmed with the alarm's text; one for the
  estimator).

Metadata ``pendsim/twin`` (how the twin ran) and, at the end, ``pendsim/twin_result`` (its
figures, its alarms as JSON, the samples that came too late to be taken in).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.twin.estimator import Forecast
from pendsim_mj.twin.outputs import STATE_NAMES, Estimates, ParameterCheck

from . import ros2

ESTIMATE_TOPIC = "/twin/estimate"
PARAMETERS_TOPIC = "/twin/parameters"
FORECAST_TOPIC = "/twin/forecast"
TWIN_METADATA = "pendsim/twin"
TWIN_RESULT_METADATA = "pendsim/twin_result"
SCHEMA = "std_msgs/msg/Float64MultiArray"

ESTIMATE_COLUMNS = (
    "t_value_s",
    "node",
    "phi_measured_rad",
    "omega_measured_rad_s",
    *STATE_NAMES,
    *(f"sigma_{n}" for n in STATE_NAMES),
    "innovation_phi_rad",
    "innovation_omega_rad_s",
    "innovation_sigma_phi_rad",
    "innovation_sigma_omega_rad_s",
    "nis",
    "accel_tangential_measured_m_s2",
    "accel_normal_measured_m_s2",
    "innovation_accel_tangential_m_s2",
    "innovation_accel_normal_m_s2",
    "innovation_sigma_accel_tangential_m_s2",
    "innovation_sigma_accel_normal_m_s2",
    "nis_accel",
)


def parameter_columns(names: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(f"{n}{suffix}" for n in names for suffix in ("", "_sigma", "_reference", "_z"))


def forecast_columns(points: int) -> tuple[str, ...]:
    per = ("t_s", *STATE_NAMES, *(f"sigma_{n}" for n in STATE_NAMES))
    return tuple(f"{c}[{k}]" for k in range(points) for c in per)


def layout(columns: tuple[str, ...]) -> ros2.FixedCdr:
    return ros2.float64_multiarray_layout(",".join(columns), len(columns))


def estimate_values(est: Estimates) -> NDArray[np.float64]:
    """(n, len(ESTIMATE_COLUMNS))."""
    return np.column_stack(
        [
            est.t_s,
            est.node.astype(float),
            est.measured,
            est.state,
            est.sigma,
            est.innovation,
            est.innovation_sigma,
            est.nis,
            est.accel_measured,
            est.accel_innovation,
            est.accel_innovation_sigma,
            est.accel_nis,
        ]
    )


def parameter_values(check: ParameterCheck) -> NDArray[np.float64]:
    """(4 k,)."""
    return np.column_stack([check.value, check.sigma, check.reference, check.z]).ravel()


def forecast_values(forecast: Forecast, points: int) -> NDArray[np.float64]:
    """(9 points,): the forecast on its own grid, padded with its last point (a horizon that is
    not a whole number of steps has one point fewer)."""
    k = len(forecast.t_s)
    idx = np.minimum(np.arange(points), k - 1)
    t = forecast.t_s[idx] - forecast.t_s[0]
    return np.column_stack([t, forecast.mean[idx], forecast.sigma[idx]]).ravel()


def encode(layout_: ros2.FixedCdr, values: NDArray[np.float64]) -> NDArray[np.uint8]:
    """(n, count) values as n payloads."""
    values = np.atleast_2d(values)
    n, count = values.shape
    return layout_.encode(n, size=np.full(n, count), stride=np.full(n, count), data_offset=np.zeros(n), data=values)


def decode(layout_: ros2.FixedCdr, payloads: NDArray[np.uint8]) -> NDArray[np.float64]:
    """Payloads (n, size) back to values (n, count)."""
    return np.asarray(layout_.decode(payloads)["data"])
