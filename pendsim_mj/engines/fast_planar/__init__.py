"""The fast planar engine: the rig's planar equations in closed form, classical RK4, compiled by numba.

Same equations, same fixed-step RK4 and the same Trajectory as ``reference`` (which stays the
paper-faithful check and is what this package is tested against), many times faster: the batch is
split into chunks that run on every core (``prange``) and, inside a chunk, the members are
integrated side by side so the compiler vectorises the step (SIMD). Imports no MuJoCo.

Modules, one seam each:

- ``closed_form``: the force law's constants (``COEFFICIENTS``, ``coefficients``) and its closed
  forms in numpy (moments, accelerations, spring lengths, energies, ``diverged``); its docstring
  derives the equations of motion.
- ``kernel``: every compiled function: the inlined sin/cos, the RK4 step, the batch kernel, and the
  rates-at-instants kernel with its exact sensitivities. One file on purpose: the kernels inline
  the same helpers (the rates kernel repeats the RK4 step's order of operations), and numba's
  ``cache=True`` notices edits only in the file a cached function is defined in.
- ``batch``: ``integrate``, the batch driver (chunks over threads, held inputs).
- ``lyapunov_exponent``: ``lyapunov`` (Benettin's two-trajectory method).
- ``rates``: ``rates_at`` and ``normal_equations_at``, the model of the damping fit
  (``pendsim_mj.estimation.planar_fit``).
- ``trajectories``: ``solve``, ``solve_batch``, ``solve_blocks``, the reference's arguments and its
  Trajectory.

A member that diverges (non-finite state) keeps NaN; ``integrate`` never raises for it,
``solve_batch`` does (as the reference).

Public entry points: ``solve`` / ``solve_batch`` (the reference's arguments, drives included, and
its Trajectory), ``integrate`` (states only, optionally every k-th step), ``summarise`` (the same pass reduced on
the fly to a sweep's features: no stored trajectory),
``lyapunov`` (largest Lyapunov exponent, Benettin's two-trajectory method), ``diverged``,
``rates_at`` (one run's rates at given instants with exact sensitivities) and
``normal_equations_at`` (the same pass summing a fit's J^T J, J^T r, r.r), and the closed
forms ``spring_moments``, ``accelerations``, ``spring_lengths``, ``potential_energy``.

To extend the force law (e.g. hinge friction): add its constants to ``COEFFICIENTS`` and
``coefficients`` (``closed_form``), load them in ``_chunk_coefficients`` / ``_member``, use them
in ``_accel`` (and in the power of ``_rk4`` if they dissipate) (``kernel``), mirror it in
``accelerations``, and test one step against ``reference`` to 1e-12 rad.
"""

from pendsim_mj.engines.fast_planar.batch import CHUNK, SUMMARY_ROWS, integrate, summarise
from pendsim_mj.engines.fast_planar.closed_form import (
    COEFFICIENTS,
    NCOEF,
    NINPUT,
    accelerations,
    coefficients,
    diverged,
    kinetic_energy,
    potential_energy,
    spring_lengths,
    spring_moments,
)
from pendsim_mj.engines.fast_planar.kernel import sincos
from pendsim_mj.engines.fast_planar.lyapunov_exponent import lyapunov
from pendsim_mj.engines.fast_planar.rates import COEF_SENSITIVITIES, SENSITIVITY_NAMES, normal_equations_at, rates_at
from pendsim_mj.engines.fast_planar.trajectories import solve, solve_batch, solve_blocks

__all__ = [
    "CHUNK",
    "COEFFICIENTS",
    "COEF_SENSITIVITIES",
    "NCOEF",
    "NINPUT",
    "SENSITIVITY_NAMES",
    "SUMMARY_ROWS",
    "accelerations",
    "coefficients",
    "diverged",
    "integrate",
    "kinetic_energy",
    "lyapunov",
    "normal_equations_at",
    "potential_energy",
    "rates_at",
    "sincos",
    "solve",
    "solve_batch",
    "solve_blocks",
    "spring_lengths",
    "spring_moments",
    "summarise",
]
