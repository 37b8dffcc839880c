"""The engines that run the rig, each returning the same ``Trajectory``.

- ``simulation``: the MuJoCo model (``simulate``, ``simulate_batch``; the planar and spatial
  variants, clamps, drives; ``simulate_blocks`` for long runs).
- ``reference``: the independent planar Newtonian RK4 of the paper's equations (``solve``,
  ``solve_batch``), the check the other engines are tested against; imports no MuJoCo.
- ``fast_planar``: the same planar equations in closed form, compiled by numba (the sweeps'
  engine; also ``integrate``, ``lyapunov`` and the damping fit's ``rates_at``).
- ``protocol``: ``Engine``, the one signature of a batch of runs the three share.
- ``dispatch``: ``run`` / ``run_batch`` / ``run_blocks`` by engine name, ``ENGINES`` (name ->
  batch entry point, as the command line names them).
- ``trajectory``: ``Trajectory``, the result: arrays (nbatch, n, ...) or (n, ...) in SI units.
- ``linearised``: the rig linearised about rest from the reference's equations (``linear_modes``:
  M, C, K, the normal modes), for the nonlinear analyses, the identification and control design.

Importing this package imports neither MuJoCo nor numba (each takes seconds): a name is imported
from its module when first used.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pendsim_mj.engines.dispatch import ENGINES, run, run_batch
    from pendsim_mj.engines.protocol import Engine
    from pendsim_mj.engines.reference import solve, solve_batch
    from pendsim_mj.engines.simulation import simulate, simulate_batch
    from pendsim_mj.engines.trajectory import Trajectory

_MODULE = {
    "ENGINES": "dispatch",
    "Engine": "protocol",
    "Trajectory": "trajectory",
    "run": "dispatch",
    "run_batch": "dispatch",
    "simulate": "simulation",
    "simulate_batch": "simulation",
    "solve": "reference",
    "solve_batch": "reference",
}

__all__ = [
    "ENGINES",
    "Engine",
    "Trajectory",
    "run",
    "run_batch",
    "simulate",
    "simulate_batch",
    "solve",
    "solve_batch",
]


def __getattr__(name: str) -> object:
    """A name of ``__all__``, imported from its module on first use (PEP 562)."""
    if name not in _MODULE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_MODULE[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
