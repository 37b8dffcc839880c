"""A closed loop in simulation: a controller drives a plant one control period at a time from
what an observer shows it, and the run's metrics (decay of each mode, energy used, peak torque).

    loop = closed_loop(LQR(params), engine="mujoco", phi0_rad=(0.52, 0.0), duration_s=30.0)
    loop.metrics().decay_s        # (2,) time to 1/e of each normal mode's amplitude, s
    loop.trajectory()             # the run replayed open loop through its inputs (a Trajectory)

The command at instant t_k is computed from the observation at t_k and held over the step
[t_k, t_k+1] (a controller that computes instantly; a real loop's delay enters through the
observer's latency). ``ClosedLoop.trajectory`` replays the held inputs on the same engine
(``plant.replay_drive``): the states equal the loop's to rounding (tested), so a closed loop can
be recorded, validated and viewed as any driven run.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pendsim_mj.control.controllers import Controller
from pendsim_mj.control.linear import decay_time_s, linearise
from pendsim_mj.control.observe import NodeObserver, StateObserver
from pendsim_mj.control.plant import make_plant, replay_drive
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.checks import check_step
from pendsim_mj.rig.drives import NCHANNEL, Sampling
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams

if TYPE_CHECKING:
    from pendsim_mj.engines.trajectory import Trajectory

Floats = NDArray[np.float64]
Observer = StateObserver | NodeObserver


@dataclasses.dataclass(frozen=True)
class LoopMetrics:
    """What a closed loop achieved.

    Attributes:
      decay_s: (2,) time for each normal mode's amplitude to fall for good below 1/e of its
        start, s (inf: not within the run; nan: the mode was not excited, start below 0.1 deg).
      start_amplitudes_rad: (2,) each mode's amplitude at the start, rad.
      final_amplitudes_rad: (2,) at the end, rad.
      energy_used_j: sum over motors of the absolute mechanical work |tau omega| dt, J.
      peak_torque_n_m: (2,) largest |tau| per motor, N m.
      saturated_share: share of steps in which a motor was at its limit.
      largest_ratio_m2_m1: largest ratio of M2's to M1's swing amplitude over 1 s windows
        while M1 swings (beating: energy moving from M1 to M2).
      final_swing_rad: (2,) each pendulum's largest |phi| over the last second, rad.
    """

    decay_s: Floats
    start_amplitudes_rad: Floats
    final_amplitudes_rad: Floats
    energy_used_j: float
    peak_torque_n_m: Floats
    saturated_share: float
    largest_ratio_m2_m1: float
    final_swing_rad: Floats

    def as_dict(self) -> dict[str, object]:
        return {
            "decay_mode1_s": _num(self.decay_s[0]),
            "decay_mode2_s": _num(self.decay_s[1]),
            "start_amplitude_mode1_deg": math.degrees(self.start_amplitudes_rad[0]),
            "start_amplitude_mode2_deg": math.degrees(self.start_amplitudes_rad[1]),
            "final_amplitude_mode1_deg": math.degrees(self.final_amplitudes_rad[0]),
            "final_amplitude_mode2_deg": math.degrees(self.final_amplitudes_rad[1]),
            "energy_used_j": self.energy_used_j,
            "peak_torque_m1_n_m": float(self.peak_torque_n_m[0]),
            "peak_torque_m2_n_m": float(self.peak_torque_n_m[1]),
            "saturated_share": self.saturated_share,
            "largest_ratio_m2_m1": _num(self.largest_ratio_m2_m1),
            "final_swing_m1_deg": math.degrees(self.final_swing_rad[0]),
            "final_swing_m2_deg": math.degrees(self.final_swing_rad[1]),
        }


def _num(value: float) -> float | str:
    return value if math.isfinite(value) else str(value)


@dataclasses.dataclass(frozen=True)
class ClosedLoop:
    """One closed-loop run.

    Attributes:
      t_s: (n + 1,) control instants, s.
      states: (n + 1, 4) the plant's state at each instant (phi1, phi2 rad; omega1, omega2 rad/s).
      inputs: (n, 4) the inputs held over each step (drive channels: tau1, tau2 N m, 0, 0).
      observed: (n, 4) the state the controller was shown at each step's start.
      age_s: (n, 2) age of each node's newest sample at each step's start, s.
      log: (n, len(log_names)) the controller's log after each command.
      log_names: the log's columns.
      controller: its name; motors: the motors it used; torque_limit_n_m: their limit.
      engine, params, dt_s, observer: how it ran.
    """

    t_s: Floats
    states: Floats
    inputs: Floats
    observed: Floats
    age_s: Floats
    log: Floats
    log_names: tuple[str, ...]
    controller: str
    motors: tuple[str, ...]
    torque_limit_n_m: float
    engine: str
    params: RigParams
    dt_s: float
    observer: str

    def trajectory(self) -> Trajectory:
        """The run replayed open loop through its held inputs on its engine (a full Trajectory:
        sensors, springs, energies), equal to ``states`` to rounding."""
        from pendsim_mj.engines.dispatch import run  # start-up: the engines load on use
        from pendsim_mj.engines.fast_planar import solve

        phi0, omega0 = tuple(self.states[0, :2].tolist()), tuple(self.states[0, 2:].tolist())
        duration = (len(self.t_s) - 1) * self.dt_s
        drive = replay_drive(self.inputs, self.dt_s)
        if self.engine == "fast":
            return solve(self.params, phi0, omega0, duration, self.dt_s, drive=drive, sampling=Sampling.HELD)
        return run(self.engine, self.params, phi0, omega0, duration, self.dt_s, drive=drive)

    def metrics(self) -> LoopMetrics:
        """The run's metrics (``LoopMetrics``), the modes those of the loop's rig."""
        linear = linearise(self.params)
        amplitudes = linear.mode_amplitudes_rad(self.states)
        decay = np.array(
            [
                decay_time_s(self.t_s, amplitudes[:, i]) if amplitudes[0, i] >= math.radians(0.1) else math.nan
                for i in range(2)
            ]
        )
        torque = self.inputs[:, :2]
        omega = self.states[:-1, 2:]
        work = float(np.sum(np.abs(torque * omega)) * self.dt_s)
        at_limit = np.abs(torque) >= self.torque_limit_n_m * (1 - 1e-12)
        return LoopMetrics(
            decay_s=decay,
            start_amplitudes_rad=amplitudes[0],
            final_amplitudes_rad=amplitudes[-1],
            energy_used_j=work,
            peak_torque_n_m=np.max(np.abs(torque), axis=0) if len(torque) else np.zeros(2),
            saturated_share=float(np.mean(np.any(at_limit, axis=1))) if len(torque) else 0.0,
            largest_ratio_m2_m1=_largest_ratio(self.t_s, self.states),
            final_swing_rad=np.max(np.abs(self.states[-max(1, round(1.0 / self.dt_s)) - 1 :, :2]), axis=0),
        )


def _largest_ratio(t_s: Floats, states: Floats, window_s: float = 1.0, swinging: float = 0.1) -> float:
    """Largest ratio of M2's to M1's peak |phi| over whole windows of ``window_s`` in which M1
    still swings (its peak at least ``swinging`` of its largest: once both are damped to the
    noise, their ratio says nothing about beating)."""
    per = max(1, round(window_s / float(t_s[1] - t_s[0]))) if len(t_s) > 1 else 1
    n = (len(states) // per) * per
    if n == 0:
        return math.nan
    peaks = np.abs(states[:n, :2]).reshape(-1, per, 2).max(axis=1)
    peaks = peaks[peaks[:, 0] >= swinging * np.max(peaks[:, 0])]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = peaks[:, 1] / peaks[:, 0]
    return float(np.nanmax(ratio)) if np.any(np.isfinite(ratio)) else math.nan


def closed_loop(
    controller: Controller,
    *,
    engine: str = "fast",
    params: RigParams = DEFAULT_PARAMS,
    phi0_rad: ArrayLike = (math.pi / 6, 0.0),
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 30.0,
    dt_s: float = 0.01,
    observer: Observer | None = None,
    progress: Callable[[float], None] | None = None,
) -> ClosedLoop:
    """Run ``controller`` against the rig ``params`` on ``engine`` (module docstring).

    Args:
      controller: any ``Controller`` (its design may assume another rig: ``params`` is the truth).
      engine: "fast" or "mujoco".
      params: the simulated rig.
      phi0_rad, omega0_rad_s: (2,) start state, rad and rad/s.
      duration_s: simulated time, s (whole control periods).
      dt_s: the control period (= the engine's step), s.
      observer: what the controller sees (default: the exact state).
      progress: called with the simulated seconds done, about once per simulated second.

    Raises:
      ParameterError: bad arguments. SimulationDiverged: the plant diverged.
    """
    nstep = check_step(duration_s, dt_s)
    plant = make_plant(engine, params, dt_s=dt_s)
    observer = observer if observer is not None else StateObserver()
    controller.reset()
    x = plant.reset(phi0_rad, omega0_rad_s)[0]
    states = np.empty((nstep + 1, 4))
    inputs = np.zeros((nstep, NCHANNEL))
    observed = np.empty((nstep, 4))
    ages = np.empty((nstep, 2))
    log = np.empty((nstep, len(controller.log_names)))
    states[0] = x
    seen = observer.reset(x)
    every = max(1, round(1.0 / dt_s))
    for k in range(nstep):
        observed[k], ages[k] = seen.state, seen.age_s
        shown = np.where(np.isfinite(seen.state), seen.state, 0.0)  # no sample yet: rest
        inputs[k, :2] = controller(shown)
        log[k] = controller.log()
        x_next = plant.step(inputs[k])[0]
        states[k + 1] = x_next
        seen = observer.observe((k + 1) * dt_s, x, x_next)
        x = x_next
        if progress is not None and (k + 1) % every == 0:
            progress((k + 1) * dt_s)
    if not np.all(np.isfinite(states)):
        raise ParameterError("the closed loop produced non-finite states")
    return ClosedLoop(
        t_s=np.arange(nstep + 1, dtype=np.float64) * dt_s,
        states=states,
        inputs=inputs,
        observed=observed,
        age_s=ages,
        log=log,
        log_names=tuple(controller.log_names),
        controller=controller.name,
        motors=tuple(controller.motors),
        torque_limit_n_m=controller.torque_limit_n_m,
        engine=engine,
        params=params,
        dt_s=dt_s,
        observer=observer.name,
    )
