"""The few exception types of pendsim; the CLI turns each into a one-line message and exit 2."""


class PendsimError(Exception):
    """Base class: an error the user can fix, reported in one line."""


class ParameterError(PendsimError, ValueError):
    """A rig parameter, initial condition or option is out of its allowed range."""


class SimulationDiverged(PendsimError, ArithmeticError):
    """The integration produced non-finite or runaway values (step too large for the stiffness)."""


class ModelError(PendsimError):
    """The MJCF model could not be loaded or compiled, or MuJoCo warned while stepping."""


class RecordingError(PendsimError):
    """A recording file is missing, truncated, corrupted or not what was expected."""
