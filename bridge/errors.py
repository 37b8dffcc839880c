"""The errors of the outside world: files that cannot be written, helper processes that fail.

Both are ``PendsimError``s: the CLI turns each into a one-line message and exit 2.
"""

from pendsim_mj.errors import PendsimError


class OutputError(PendsimError):
    """An output file or folder could not be written or published (exists, full disk, permissions)."""


class ProcessError(PendsimError):
    """A helper process (the Rerun viewer) could not be started, or stopped unexpectedly."""
