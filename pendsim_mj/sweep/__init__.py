"""Sweeps of the rig over its inputs (parameters, release state, sine drives). No I/O: the
bridge's sweep command reads the definition, distributes the tasks and writes the table.

Modules and their jobs:

- ``plan``: what a sweep runs: its definition (``SweepPlan``, from TOML, JSON or options:
  ``SweepPlan.load``, ``parse_vary``; one ``Axis`` per varied input) and the table of cases it
  expands to (``SweepPlan.cases``, ``CaseTable``; ``read_cases_csv`` for a CSV of cases), and the
  elasticities of a sensitivity sweep (``elasticities``).
- ``run``: one task of cases through an engine to their features (``run_task``, ``TaskResult``):
  what a Dask worker and the serial path both call.
- ``features``: the features of a batch of runs (``Features``; the groups and their columns:
  ``FEATURE_GROUPS``), whichever engine ran them.

Importing this package imports none of them (``run`` imports the compiled kernel, numba): each
name below is imported from its module on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pendsim_mj.sweep.features import FEATURE_GROUPS, Features
    from pendsim_mj.sweep.plan import Axis, CaseTable, SweepPlan, elasticities, parse_vary, read_cases_csv
    from pendsim_mj.sweep.run import TaskResult, run_task

_HOME = {
    "FEATURE_GROUPS": "features",
    "Features": "features",
    "Axis": "plan",
    "CaseTable": "plan",
    "SweepPlan": "plan",
    "elasticities": "plan",
    "parse_vary": "plan",
    "read_cases_csv": "plan",
    "TaskResult": "run",
    "run_task": "run",
}

__all__ = [
    "FEATURE_GROUPS",
    "Axis",
    "CaseTable",
    "Features",
    "SweepPlan",
    "TaskResult",
    "elasticities",
    "parse_vary",
    "read_cases_csv",
    "run_task",
]


def __getattr__(name: str) -> Any:
    """A public name, imported from its module on first use (PEP 562) and kept here."""
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_HOME[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
