"""A closed loop in simulation, measured against the open loop and recorded.

    result = run_control(ControlSpec("lqr"), "run.mcap")
    result.metrics.decay_s, result.open_loop.decay_s

The loop runs on the chosen engine (``pendsim_mj.control.loop.closed_loop``); the open loop (no
torque) runs from the same release long enough to decay (three linear decay times, at most
20 min) on the MuJoCo model in one rollout (the fast force law agrees with it to 1e-14 rad). The
recording is the loop's held inputs replayed on the MuJoCo model (``/drive``: the same states to
rounding, on either engine: the fast force law and MuJoCo agree to 1e-14 rad under held inputs),
sampled by the BNO055 model as ``pendsim record`` does, with the ``/control`` topic (what the
controller saw and did at each step) and ``pendsim/control`` metadata: so ``validate``, ``view``
and ``replay`` open it as any driven recording.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pendsim_mj.control.controllers import (
    CONTROLLERS,
    LQR,
    BeatingSuppressor,
    Controller,
    EnergyRegulator,
    OpenLoop,
    ScheduledLQR,
)
from pendsim_mj.control.linear import linearise
from pendsim_mj.control.loop import ClosedLoop, LoopMetrics, closed_loop
from pendsim_mj.control.names import OBSERVERS
from pendsim_mj.control.observe import NodeObserver, StateObserver
from pendsim_mj.control.plant import PLANT_ENGINES, replay_drive
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import Bno055

from ..io.recording_layout import ControlTopic
from .record import RecordResult, RecordSpec, record

OPEN_LOOP_LONGEST_S = 1200.0
LONGEST_PERIOD_S = 0.02  # s: RK4 at 20 ms damps the faster mode by under 1e-3 over its open-loop decay


@dataclasses.dataclass(frozen=True)
class ControlSpec:
    """A closed loop to run.

    Attributes:
      controller: a name of ``CONTROLLERS`` (lqr, scheduled-lqr, energy, beating, none).
      params: the simulated rig (the truth).
      design_params: the rig the controller is designed for (None: ``params``; e.g. the stated
        rig while ``params`` is a calibrated one, to see what a wrong model costs).
      phi0_rad, omega0_rad_s: the release, rad and rad/s.
      duration_s: the closed loop's length, s.
      dt_s: the control period (= the engine's step), s.
      engine: "mujoco" or "fast".
      motors: the motors the controller uses ("m1", "m2").
      torque_limit_n_m: each motor's limit, N m.
      input_weight: LQR's R = input_weight I (None: 10; only for the LQR controllers without
        ``gain``).
      gain: (len(motors), 4) LQR gains to use instead of the design (checked to stabilise).
      target_amplitudes_rad: the energy regulator's mode amplitudes to hold, rad.
      observe: "state" (exact) or "nodes" (what the BNO055 nodes deliver: ``imu``'s noise, loss,
        latency).
      imu: the node model (the controller's view with observe="nodes", and the recording's IMUs).
      open_loop: also run the open loop for the comparison.
    """

    controller: str = "lqr"
    params: RigParams = DEFAULT_PARAMS
    design_params: RigParams | None = None
    phi0_rad: tuple[float, float] = (math.pi / 6, 0.0)
    omega0_rad_s: tuple[float, float] = (0.0, 0.0)
    duration_s: float = 30.0
    dt_s: float = 0.01
    engine: str = "mujoco"
    motors: tuple[str, ...] = ("m1", "m2")
    torque_limit_n_m: float = 0.05
    input_weight: float | None = None
    gain: tuple[tuple[float, ...], ...] | None = None
    target_amplitudes_rad: tuple[float, float] = (0.0, 0.0)
    observe: str = "state"
    imu: Bno055 = dataclasses.field(default_factory=Bno055)
    open_loop: bool = True

    def __post_init__(self) -> None:
        if self.controller not in CONTROLLERS:
            raise ParameterError(f"unknown controller {self.controller!r}; allowed: {', '.join(CONTROLLERS)}")
        if self.engine not in PLANT_ENGINES:
            raise ParameterError(f"unknown engine {self.engine!r} for a closed loop; allowed: mujoco, fast")
        if self.observe not in OBSERVERS:
            raise ParameterError(f"unknown observation {self.observe!r}; allowed: {', '.join(OBSERVERS)}")
        lqr = self.controller in ("lqr", "scheduled-lqr")
        if self.gain is not None and not lqr:
            raise ParameterError("gains are for the lqr and scheduled-lqr controllers")
        if self.input_weight is not None and (not lqr or self.gain is not None):
            raise ParameterError("an input weight is for the lqr design (not with given gains or other controllers)")
        if not (0 < self.dt_s <= LONGEST_PERIOD_S):
            raise ParameterError(
                f"the control period (--dt-s) must be in (0, {LONGEST_PERIOD_S}] s, got {self.dt_s:g} s: longer "
                "steps damp the rig numerically and skew the comparison with the open loop"
            )
        if any(self.target_amplitudes_rad) and self.controller != "energy":
            raise ParameterError("a target amplitude is for the energy controller")


def make_controller(spec: ControlSpec) -> Controller:
    """The controller a spec names, designed for its design rig (gains checked to stabilise)."""
    design = spec.design_params or spec.params
    motors, limit, dt = spec.motors, spec.torque_limit_n_m, spec.dt_s
    cls = CONTROLLERS[spec.controller]
    if cls is EnergyRegulator:
        return EnergyRegulator(
            design, target_amplitudes_rad=spec.target_amplitudes_rad, motors=motors, torque_limit_n_m=limit, dt_s=dt
        )
    if cls is LQR or cls is ScheduledLQR:
        gain = None if spec.gain is None else np.asarray(spec.gain, dtype=float)
        weight = 10.0 if spec.input_weight is None else spec.input_weight
        return cls(design, input_weight=weight, gain=gain, motors=motors, torque_limit_n_m=limit, dt_s=dt)
    if cls is BeatingSuppressor:
        if spec.motors != ("m1", "m2"):
            raise ParameterError("the beating suppressor needs both motors (m1, m2)")
        return BeatingSuppressor(design, torque_limit_n_m=limit, dt_s=dt)
    return OpenLoop(design, motors=motors, torque_limit_n_m=limit, dt_s=dt)


@dataclasses.dataclass(frozen=True)
class ControlResult:
    """A closed loop run.

    Attributes:
      loop: the closed loop. metrics: its metrics.
      open_loop: the open loop's metrics from the same release (None when not run).
      open_loop_s: how long the open loop ran, s.
      recording: the written recording, or None.
      target_amplitude_rad: the energy controller's mode-1 target (0: none).
      held_amplitude_rad: mode 1's mean amplitude over the last 5 s where a target was held, rad.
    """

    loop: ClosedLoop
    metrics: LoopMetrics
    open_loop: LoopMetrics | None
    open_loop_s: float
    recording: RecordResult | None
    target_amplitude_rad: float = 0.0
    held_amplitude_rad: float | None = None

    def speedup(self) -> tuple[float, float]:
        """Open-loop decay time over closed-loop decay time, per mode (nan where not measured)."""
        if self.open_loop is None:
            return (math.nan, math.nan)
        out = []
        for i in range(2):
            closed, open_ = float(self.metrics.decay_s[i]), float(self.open_loop.decay_s[i])
            out.append(open_ / closed if closed > 0 and math.isfinite(closed) and math.isfinite(open_) else math.nan)
        return (out[0], out[1])


def _open_loop(spec: ControlSpec) -> tuple[LoopMetrics, float]:
    """The free run's metrics from the same release, on the same equations, long enough to decay."""
    from pendsim_mj.engines.dispatch import run  # start-up: the engines load on use

    rates = linearise(spec.params).decay_rates_1_s()
    slowest = float(np.min(rates))
    duration = min(OPEN_LOOP_LONGEST_S, max(spec.duration_s, 3.0 / slowest if slowest > 0 else OPEN_LOOP_LONGEST_S))
    duration = math.floor(duration / spec.dt_s) * spec.dt_s
    traj = run("mujoco", spec.params, spec.phi0_rad, spec.omega0_rad_s, duration, spec.dt_s)
    states = np.hstack([traj.phi_rad, traj.omega_rad_s])
    free = ClosedLoop(
        t_s=traj.t_s, states=states, inputs=np.zeros((len(states) - 1, 4)), observed=states[:-1],
        age_s=np.zeros((len(states) - 1, 2)), log=np.zeros((len(states) - 1, 0)), log_names=(), controller="none",
        motors=spec.motors, torque_limit_n_m=spec.torque_limit_n_m, engine=spec.engine, params=spec.params,
        dt_s=spec.dt_s, observer="state",
    )  # fmt: skip
    return free.metrics(), duration


def control_topic(loop: ClosedLoop, spec: ControlSpec, controller: Controller, metrics: LoopMetrics) -> ControlTopic:
    """The recording's /control topic and pendsim/control metadata for a loop."""
    names = (
        "seen_phi1_rad", "seen_phi2_rad", "seen_omega1_rad_s", "seen_omega2_rad_s", "age_m1_s", "age_m2_s",
        *loop.log_names,
    )  # fmt: skip
    values = np.hstack([loop.observed, loop.age_s, loop.log])
    meta = {
        "controller": controller.name,
        "motors": json.dumps(list(loop.motors)),
        "torque_limit_n_m": repr(loop.torque_limit_n_m),
        "loop_engine": loop.engine,
        "observer": loop.observer,
        "control_period_s": repr(loop.dt_s),
        "design_params": json.dumps(dataclasses.asdict(spec.design_params or spec.params)),
        "metrics": json.dumps(metrics.as_dict()),
        "replay": "the /drive topic holds the loop's inputs; replayed on the MuJoCo model they give its states",
    }
    gain = getattr(controller, "gain", None)
    if gain is not None:
        meta["gain"] = json.dumps(np.asarray(gain).tolist())
    return ControlTopic(names=names, t_s=loop.t_s[:-1], values=values, metadata=meta)


def run_control(
    spec: ControlSpec,
    output: str | Path | None = None,
    *,
    replace: bool = False,
    progress: Callable[[float], None] | None = None,
) -> ControlResult:
    """Run the closed loop (and the open loop), and record it to ``output`` if given.

    Raises:
      ParameterError: a bad spec or gains that destabilise the linearised rig (before any run).
      SimulationDiverged: the plant diverged. OutputError: the output exists or writing failed.
    """
    controller = make_controller(spec)
    if isinstance(controller, EnergyRegulator):
        start = linearise(spec.params).mode_amplitudes_rad(np.array([*spec.phi0_rad, *spec.omega0_rad_s]))
        if spec.target_amplitudes_rad[0] > 0 and start[0] < math.radians(0.5):
            raise ParameterError(
                "the energy controller holds a mode's amplitude by pushing along its motion, and mode 1 starts "
                f"still ({math.degrees(start[0]):.2f} deg): release it, e.g. --phi1-deg 5"
            )
    observer = NodeObserver(spec.imu, dt_s=spec.dt_s, seed=spec.imu.seed) if spec.observe == "nodes" else None
    loop = closed_loop(
        controller, engine=spec.engine, params=spec.params, phi0_rad=spec.phi0_rad,
        omega0_rad_s=spec.omega0_rad_s, duration_s=spec.duration_s, dt_s=spec.dt_s,
        observer=observer or StateObserver(), progress=progress,
    )  # fmt: skip
    metrics = loop.metrics()
    open_metrics, open_s = _open_loop(spec) if spec.open_loop else (None, 0.0)
    recorded = None
    if output is not None:
        drive = replay_drive(loop.inputs, spec.dt_s)
        rec = RecordSpec(
            spec.params, spec.phi0_rad, spec.omega0_rad_s, spec.duration_s, spec.dt_s, "mujoco", "planar",
            imu=spec.imu, drive=drive if drive else None, control=control_topic(loop, spec, controller, metrics),
        )  # fmt: skip
        recorded = record(rec, output, replace=replace)
    target = spec.target_amplitudes_rad[0] if isinstance(controller, EnergyRegulator) else 0.0
    held: float | None = None
    if target > 0:
        last = loop.states[-max(2, round(5.0 / spec.dt_s)) :]
        held = float(np.mean(linearise(spec.params).mode_amplitudes_rad(last)[:, 0]))
    return ControlResult(loop, metrics, open_metrics, open_s, recorded, target, held)
