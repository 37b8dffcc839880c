"""Nonlinear-dynamics analyses of the driven rig on the MuJoCo model (planar variant).

- ``backbone``: backbone curves of both nonlinear normal modes of the undamped rig (shooting on
  brake orbits, pseudo-arclength continuation), checked against the linearised modes and free
  simulations, with periodicity residuals and Floquet multipliers.
- ``response``: frequency-response curves by stepped sine (up and down) and by continuation of
  periodic orbits with Floquet multipliers, folds, period doubling and Neimark-Sacker points.
- ``bifurcation``: stroboscopic (Poincare) samples against drive frequency or level.
- ``lyapunov``: the largest Lyapunov exponent with its convergence.
- ``tongues``: instability tongues of parametric (vertical pivot) excitation, with the
  Mathieu-type first-order boundary.
- ``sync``: phase-locking index and frequency ratio of the two pendulums.

Shared parts: ``flow`` (batched ``mujoco.rollout`` of the state), ``periodic`` (shooting for
forced orbits, Floquet multipliers), ``continuation`` (pseudo-arclength); the linearised rig
(``linear_modes``) lives with the engines (``pendsim_mj.engines.linearised``), below every room
that uses it. Every result is a frozen dataclass;
the command line (``pendsim analyze``) writes them as JSON/CSV and plots. The state is
x = (phi1, phi2, omega1, omega2) in rad and rad/s throughout.
"""

from pendsim_mj.engines.linearised import LinearModes, linear_modes
from pendsim_mj.nonlinear.backbone import Backbone, backbone
from pendsim_mj.nonlinear.bifurcation import PoincareDiagram, PoincareSweep, poincare_sweep
from pendsim_mj.nonlinear.lyapunov import Lyapunov, largest_lyapunov
from pendsim_mj.nonlinear.response import (
    Agreement,
    Bifurcation,
    ResponseBranch,
    SteppedSweep,
    compare_with_branch,
    continue_response,
    orbit_at,
    stepped_sine,
)
from pendsim_mj.nonlinear.sync import PhaseLocking, phase_locking
from pendsim_mj.nonlinear.tongues import Tongues, mathieu_boundary_m_s2, tongues

__all__ = [
    "Agreement",
    "Backbone",
    "Bifurcation",
    "LinearModes",
    "Lyapunov",
    "PhaseLocking",
    "PoincareDiagram",
    "PoincareSweep",
    "ResponseBranch",
    "SteppedSweep",
    "Tongues",
    "backbone",
    "compare_with_branch",
    "continue_response",
    "largest_lyapunov",
    "linear_modes",
    "mathieu_boundary_m_s2",
    "orbit_at",
    "phase_locking",
    "poincare_sweep",
    "stepped_sine",
    "tongues",
]
