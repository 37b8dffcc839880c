"""pendsim_mj: physics of the spring-coupled two-pendulum rig (Ganev et al., Machines 2025).

Modules: ``params`` (RigParams), ``model`` (MJCF -> MjModel via MjSpec), ``simulation``
(MuJoCo runs), ``reference`` (independent planar RK4, no MuJoCo), ``trajectory`` (the result
container), ``analysis`` (frequencies, log decrement), ``errors``.

Importing the package imports no physics engine; import ``pendsim_mj.engines.simulation`` for MuJoCo.
"""

from pendsim_mj.errors import ModelError, ParameterError, PendsimError, SimulationDiverged
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams

__version__ = "0.1.0"

__all__ = [
    "DEFAULT_PARAMS",
    "ModelError",
    "ParameterError",
    "PendsimError",
    "RigParams",
    "SimulationDiverged",
    "__version__",
]
