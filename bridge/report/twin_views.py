"""The live twin's views: what both live views (``twin_rerun.TwinRerunView``,
``twin_foxglove.TwinFoxgloveView``) take in, and what they share.

The twin's runner feeds a view in time order with ``add_*`` (estimator updates in batches, a
forecast and a parameter check about once a second, alarms, /diagnostics statuses) and calls
``send`` about 5 times a second: a view buffers what was added and puts it out in ``send``, in
one go per stream (never one call per sample where its sink takes columns). ``close`` sends what
is left and ends everything the view started (its servers, its viewer's process group, its file);
it is idempotent and belongs in a ``finally``.

Times are seconds on the twin's clock; the twin started at ``start_utc_ns`` (UTC, ns), so a
sample at ``t_s`` carries the timestamp ``start_utc_ns + round(t_s * 1e9)`` where a view needs one.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Protocol, runtime_checkable

import numpy as np

from pendsim_mj.twin.estimator import Forecast
from pendsim_mj.twin.health import Alarm
from pendsim_mj.twin.outputs import Estimates, ParameterCheck

from ..io.ros2 import DiagnosticStatus

SIGMA_BAND = 3.0
"""The bands the views draw: estimate +- SIGMA_BAND standard deviations."""
NIS_LIMIT_95 = -2.0 * math.log(0.05)
"""The NIS a healthy rig stays under 95 % of the time (chi^2 with 2 degrees of freedom: 5.99)."""
FOXGLOVE_PORT = 8765
"""The Foxglove view's default port (the Foxglove app's default for a WebSocket connection)."""


@runtime_checkable
class TwinView(Protocol):
    """What the twin's runner calls on a live view (see the module docstring)."""

    def add_estimates(self, est: Estimates) -> None: ...
    def add_forecast(self, made_at_s: float, forecast: Forecast) -> None: ...
    def add_parameters(self, check: ParameterCheck) -> None: ...
    def add_alarm(self, alarm: Alarm) -> None: ...
    def add_diagnostics(self, t_s: float, statuses: list[DiagnosticStatus]) -> None: ...
    def send(self) -> None: ...
    def close(self) -> None: ...


@dataclasses.dataclass
class Pending:
    """What was added since the last ``send`` (in the order it was added)."""

    estimates: list[Estimates] = dataclasses.field(default_factory=list)
    forecasts: list[tuple[float, Forecast]] = dataclasses.field(default_factory=list)
    parameters: list[ParameterCheck] = dataclasses.field(default_factory=list)
    alarms: list[Alarm] = dataclasses.field(default_factory=list)
    diagnostics: list[tuple[float, list[DiagnosticStatus]]] = dataclasses.field(default_factory=list)

    def take(self) -> Pending:
        """Everything pending, leaving this empty."""
        taken = Pending(self.estimates, self.forecasts, self.parameters, self.alarms, self.diagnostics)
        self.estimates, self.forecasts, self.parameters, self.alarms, self.diagnostics = [], [], [], [], []
        return taken

    def __bool__(self) -> bool:
        return bool(self.estimates or self.forecasts or self.parameters or self.alarms or self.diagnostics)


class BufferedView:
    """The ``add_*`` half of a ``TwinView``: each call files its record in ``pending``."""

    def __init__(self, start_utc_ns: int, nodes: tuple[str, ...]) -> None:
        if not nodes or len(nodes) > 2 or len(set(nodes)) != len(nodes):
            raise ValueError(f"nodes must be one or two distinct names, got {nodes!r}")
        self.start_utc_ns = int(start_utc_ns)
        self.nodes = nodes
        self.pending = Pending()
        self.sends = 0
        self.closed = False

    def add_estimates(self, est: Estimates) -> None:
        if len(est):
            self.pending.estimates.append(est)

    def add_forecast(self, made_at_s: float, forecast: Forecast) -> None:
        self.pending.forecasts.append((float(made_at_s), forecast))

    def add_parameters(self, check: ParameterCheck) -> None:
        self.pending.parameters.append(check)

    def add_alarm(self, alarm: Alarm) -> None:
        self.pending.alarms.append(alarm)

    def add_diagnostics(self, t_s: float, statuses: list[DiagnosticStatus]) -> None:
        self.pending.diagnostics.append((float(t_s), list(statuses)))

    def utc_ns(self, t_s: float) -> int:
        """The UTC timestamp (ns) of an instant on the twin's clock (s)."""
        return self.start_utc_ns + round(t_s * 1e9)

    def utc_ns_array(self, t_s: np.ndarray) -> np.ndarray:
        """(n,) int64 UTC timestamps (ns) of instants (n,) s on the twin's clock."""
        return self.start_utc_ns + np.round(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)


class TwinViews:
    """Several views fed as one: each call goes to every view; ``close`` closes them all, even
    when one fails (the first error is raised once all are closed)."""

    def __init__(self, views: list[TwinView]) -> None:
        self.views = list(views)

    def add_estimates(self, est: Estimates) -> None:
        for view in self.views:
            view.add_estimates(est)

    def add_forecast(self, made_at_s: float, forecast: Forecast) -> None:
        for view in self.views:
            view.add_forecast(made_at_s, forecast)

    def add_parameters(self, check: ParameterCheck) -> None:
        for view in self.views:
            view.add_parameters(check)

    def add_alarm(self, alarm: Alarm) -> None:
        for view in self.views:
            view.add_alarm(alarm)

    def add_diagnostics(self, t_s: float, statuses: list[DiagnosticStatus]) -> None:
        for view in self.views:
            view.add_diagnostics(t_s, statuses)

    def send(self) -> None:
        for view in self.views:
            view.send()

    def close(self) -> None:
        error: BaseException | None = None
        for view in self.views:
            try:
                view.close()
            except BaseException as exc:  # close the others first
                error = error or exc
        if error is not None:
            raise error
