"""The few exception types of pendsim; the CLI turns each into a one-line message and exit 2."""

import difflib
from collections.abc import Iterable


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


def did_you_mean(name: str, allowed: Iterable[str]) -> str:
    """`` (did you mean 'c1_n_m'?)`` for a misspelt ``name`` close to one of ``allowed``
    (``difflib``'s ratio >= 0.75, case aside), or the only one it begins (``b1`` for
    ``b1_n_m_s``: the unit left out), else "": the hint an unknown-name message carries."""
    names = list(allowed)
    lower = {n.lower(): n for n in names}
    close = difflib.get_close_matches(name.lower(), list(lower), n=1, cutoff=0.75)
    if close:
        return f" (did you mean {lower[close[0]]!r}?)"
    begun = [n for n in names if name and n.lower().startswith(name.lower() + "_")]
    return f" (did you mean {begun[0]!r}?)" if len(begun) == 1 else ""
