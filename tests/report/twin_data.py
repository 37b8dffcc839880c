"""Made-up twin outputs for the live views' tests: two nodes at 80 Hz swinging, in 50 ms batches,
a forecast and a parameter check each second, an alarm and /diagnostics statuses."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np

from pendsim_bridge.io.ros2 import DiagnosticStatus
from pendsim_mj.twin.estimator import Forecast
from pendsim_mj.twin.health import Alarm
from pendsim_mj.twin.outputs import Estimates, ParameterCheck

START_UTC_NS = 1_780_000_000_123_456_789
NODES = ("m1", "m2")


@dataclasses.dataclass
class TwinRun:
    batches: list[Estimates]
    forecasts: list[tuple[float, Forecast]]
    checks: list[ParameterCheck]
    alarms: list[Alarm]
    diagnostics: list[tuple[float, list[DiagnosticStatus]]]

    @property
    def estimates(self) -> Estimates:
        return Estimates.concatenate(self.batches)


def estimates(t_s: np.ndarray, node: np.ndarray, rng: np.random.Generator) -> Estimates:
    n = len(t_s)
    w = 2 * np.pi * 0.9
    phi = np.stack([0.3 * np.cos(w * t_s), 0.25 * np.cos(w * t_s + 0.4)], axis=1)
    omega = np.stack([-0.3 * w * np.sin(w * t_s), -0.25 * w * np.sin(w * t_s + 0.4)], axis=1)
    state = np.concatenate([phi, omega], axis=1)
    sigma = np.abs(rng.normal(0.01, 0.002, (n, 4)))
    innovation = rng.normal(0.0, 0.01, (n, 2))
    innovation_sigma = np.abs(rng.normal(0.01, 0.001, (n, 2)))
    rows = np.arange(n)
    measured = np.stack([phi[rows, node], omega[rows, node]], axis=1) + innovation
    nis = np.sum((innovation / innovation_sigma) ** 2, axis=1)
    accel = np.stack([9.81 * np.sin(phi[rows, node]), 9.81 * np.cos(phi[rows, node])], axis=1)
    accel_innovation = rng.normal(0.0, 0.011, (n, 2))
    accel_sigma = np.full((n, 2), 0.011)
    accel_nis = np.sum((accel_innovation / accel_sigma) ** 2, axis=1)
    return Estimates(t_s, node.astype(np.int64), measured, state, sigma, innovation, innovation_sigma, nis,
                     accel + accel_innovation, accel_innovation, accel_sigma, accel_nis)  # fmt: skip


def twin_run(duration_s: float, *, rate_hz: float = 80.0, batch_s: float = 0.05, seed: int = 1) -> TwinRun:
    rng = np.random.default_rng(seed)
    k = np.arange(round(duration_s * rate_hz))
    t = np.concatenate([k / rate_hz, k / rate_hz + 0.5 / rate_hz])
    node = np.concatenate([np.zeros(len(k), np.int64), np.ones(len(k), np.int64)])
    order = np.argsort(t, kind="stable")
    est = estimates(t[order], node[order], rng)
    edges = np.searchsorted(est.t_s, np.arange(0.0, duration_s + batch_s, batch_s))
    batches = [
        Estimates(*(getattr(est, f.name)[a:b] for f in dataclasses.fields(Estimates)))
        for a, b in itertools.pairwise(edges)
        if b > a
    ]
    forecasts = []
    checks = []
    names = ("b1_n_m_s", "coupling_sin_n_m")
    for second in range(1, int(duration_s) + 1):
        made = float(second)
        ft = made + np.arange(0, 241) * 0.0125
        mean = np.stack([0.3 * np.cos(5.65 * ft), 0.25 * np.cos(5.65 * ft + 0.4), ft * 0, ft * 0], axis=1)
        forecasts.append((made, Forecast(ft, mean, np.full((len(ft), 4), 0.01) * (1 + ft - made)[:, None])))
        value = np.array([1.2e-4 + 1e-6 * second, 0.05])
        reference = np.array([np.nan, np.nan]) if second == 1 else np.array([1.2e-4, 0.05])
        sigma = np.array([2e-6, 1e-3])
        checks.append(ParameterCheck(made, names, value, sigma, reference, (value - reference) / sigma))
    alarms = [Alarm("b1_n_m_s", "damping of M1", duration_s * 0.8, duration_s * 0.5, 1.2e-4, 1.5e-4, 4e-6)]
    diagnostics = [
        (float(s), [
            DiagnosticStatus(0 if s < 2 else 1, "twin: b1_n_m_s", "ok" if s < 2 else "changing", "pendsim",
                             (("z", f"{s:.1f}"),)),
            DiagnosticStatus(0, "twin: node m1", "ok", "m1", ()),
        ])
        for s in range(1, int(duration_s) + 1)
    ]  # fmt: skip
    return TwinRun(batches, forecasts, checks, alarms, diagnostics)


def feed(view, run: TwinRun) -> None:
    """Feed a view in time order as the runner does: a send after each batch."""
    events: list[tuple[float, int, object]] = []
    events += [(float(b.t_s[-1]), 0, b) for b in run.batches]
    events += [(t, 1, ("forecast", t, f)) for t, f in run.forecasts]
    events += [(c.t_s, 2, ("check", c)) for c in run.checks]
    events += [(a.t_s, 3, ("alarm", a)) for a in run.alarms]
    events += [(t, 4, ("diagnostics", t, s)) for t, s in run.diagnostics]
    for _, _, item in sorted(events, key=lambda e: (e[0], e[1])):
        if isinstance(item, Estimates):
            view.add_estimates(item)
            view.send()
        elif item[0] == "forecast":
            view.add_forecast(item[1], item[2])
        elif item[0] == "check":
            view.add_parameters(item[1])
        elif item[0] == "alarm":
            view.add_alarm(item[1])
        else:
            view.add_diagnostics(item[1], item[2])
    view.send()
