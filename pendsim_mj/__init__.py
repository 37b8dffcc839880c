"""pendsim_mj: physics of the spring-coupled two-pendulum rig (Ganev et al., Machines 2025).

What a script needs is exported here (``__all__``; reference with examples: docs/api.md)::

    from pendsim_mj import DEFAULT_PARAMS, Drive, Sine, simulate, solve

    traj = simulate(DEFAULT_PARAMS, phi0_rad=(0.5, 0.0), duration_s=10.0)  # MuJoCo
    traj.phi_rad  # (1001, 2) phi1, phi2, rad, at traj.t_s (1001,) s

SI units and radians throughout; arrays are numpy, shapes in each docstring. The rooms:

- ``rig``: the parameters (``RigParams``, ``DEFAULT_PARAMS``), the drives (``Drive``, the
  signals ``Sine``, ``SteppedSine``, ``Chirp``, ``TimeSeries``, and ``Sampling``), the MuJoCo model (``build_model``);
- ``engines``: MuJoCo (``simulate``, ``simulate_batch``), the independent planar reference
  (``solve``, ``solve_batch``), the compiled planar engine, and the ``Trajectory`` they return;
- ``sensors``: the BNO055 node model (``Bno055``, ``sample_imu``);
- ``estimation``: signal analysis (``summarize``), alignment of recorded nodes (``align``),
  validation metrics (``compare``), damping identification (``planar_damping``, ``log_decrement``);
- ``allan``: Allan deviation and noise terms (``allan_curves``, ``noise_terms``);
- ``sweep``: sweep definitions and their cases (``SweepPlan``), one task of cases (``run_task``);
- ``nonlinear``: backbones, frequency responses, bifurcations, Lyapunov exponents, instability
  tongues, synchronisation (``pendsim_mj.nonlinear``, a facade of its own).

Importing the package imports no physics engine, no compiled kernel and no plotting: the
parameters, drives and errors are imported with it, every other name when it is first used
(``pendsim_mj.lazy``). Files, recordings and the command line are in ``pendsim_bridge``, which
imports this package; this package never imports it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy
from pendsim_mj.errors import ModelError, ParameterError, PendsimError, RecordingError, SimulationDiverged
from pendsim_mj.rig.drives import (
    Chirp,
    Drive,
    Sampling,
    Sine,
    SteppedSine,
    Target,
    TimeSeries,
    read_time_series_csv,
)
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams

__version__ = "0.1.0"

_LAZY = {
    "PLANAR": "pendsim_mj.rig.model",
    "SPATIAL": "pendsim_mj.rig.model",
    "Clamp": "pendsim_mj.rig.model",
    "Variant": "pendsim_mj.rig.model",
    "build_model": "pendsim_mj.rig.model",
    "Trajectory": "pendsim_mj.engines.trajectory",
    "simulate": "pendsim_mj.engines.simulation",
    "simulate_batch": "pendsim_mj.engines.simulation",
    "solve": "pendsim_mj.engines.reference",
    "solve_batch": "pendsim_mj.engines.reference",
    "Bno055": "pendsim_mj.sensors.bno055",
    "ImuNoise": "pendsim_mj.sensors.bno055",
    "ImuSamples": "pendsim_mj.sensors.bno055",
    "sample_imu": "pendsim_mj.sensors.bno055",
    "Imperfections": "pendsim_mj.sensors.imperfections",
    "RunSummary": "pendsim_mj.estimation.analysis",
    "summarize": "pendsim_mj.estimation.analysis",
    "MeasuredRun": "pendsim_mj.estimation.alignment",
    "NodeSamples": "pendsim_mj.estimation.alignment",
    "align": "pendsim_mj.estimation.alignment",
    "Comparison": "pendsim_mj.estimation.validation",
    "compare": "pendsim_mj.estimation.validation",
    "DampingFit": "pendsim_mj.estimation.identification",
    "LogDecrement": "pendsim_mj.estimation.identification",
    "log_decrement": "pendsim_mj.estimation.identification",
    "planar_damping": "pendsim_mj.estimation.identification",
    "AllanCurve": "pendsim_mj.allan.deviation",
    "NoiseTerms": "pendsim_mj.allan.deviation",
    "allan_curves": "pendsim_mj.allan.deviation",
    "noise_terms": "pendsim_mj.allan.deviation",
    "CaseTable": "pendsim_mj.sweep.plan",
    "SweepPlan": "pendsim_mj.sweep.plan",
    "TaskResult": "pendsim_mj.sweep.run",
    "run_task": "pendsim_mj.sweep.run",
    "nonlinear": "pendsim_mj.nonlinear",
}

if TYPE_CHECKING:
    from pendsim_mj import nonlinear
    from pendsim_mj.allan.deviation import AllanCurve, NoiseTerms, allan_curves, noise_terms
    from pendsim_mj.engines.reference import solve, solve_batch
    from pendsim_mj.engines.simulation import simulate, simulate_batch
    from pendsim_mj.engines.trajectory import Trajectory
    from pendsim_mj.estimation.alignment import MeasuredRun, NodeSamples, align
    from pendsim_mj.estimation.analysis import RunSummary, summarize
    from pendsim_mj.estimation.identification import DampingFit, LogDecrement, log_decrement, planar_damping
    from pendsim_mj.estimation.validation import Comparison, compare
    from pendsim_mj.rig.model import PLANAR, SPATIAL, Clamp, Variant, build_model
    from pendsim_mj.sensors.bno055 import Bno055, ImuNoise, ImuSamples, sample_imu
    from pendsim_mj.sensors.imperfections import Imperfections
    from pendsim_mj.sweep.plan import CaseTable, SweepPlan
    from pendsim_mj.sweep.run import TaskResult, run_task
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = [
    "DEFAULT_PARAMS",
    "PLANAR",
    "SPATIAL",
    "AllanCurve",
    "Bno055",
    "CaseTable",
    "Chirp",
    "Clamp",
    "Comparison",
    "DampingFit",
    "Drive",
    "Imperfections",
    "ImuNoise",
    "ImuSamples",
    "LogDecrement",
    "MeasuredRun",
    "ModelError",
    "NodeSamples",
    "NoiseTerms",
    "ParameterError",
    "PendsimError",
    "RecordingError",
    "RigParams",
    "RunSummary",
    "Sampling",
    "SimulationDiverged",
    "Sine",
    "SteppedSine",
    "SweepPlan",
    "Target",
    "TaskResult",
    "TimeSeries",
    "Trajectory",
    "Variant",
    "__version__",
    "align",
    "allan_curves",
    "build_model",
    "compare",
    "log_decrement",
    "noise_terms",
    "nonlinear",
    "planar_damping",
    "read_time_series_csv",
    "run_task",
    "sample_imu",
    "simulate",
    "simulate_batch",
    "solve",
    "solve_batch",
    "summarize",
]
