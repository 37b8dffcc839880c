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
name below is imported from its module on first use (``pendsim_mj.lazy``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy

_LAZY = {
    "FEATURE_GROUPS": "pendsim_mj.sweep.features",
    "Features": "pendsim_mj.sweep.features",
    "Axis": "pendsim_mj.sweep.plan",
    "CaseTable": "pendsim_mj.sweep.plan",
    "SweepPlan": "pendsim_mj.sweep.plan",
    "elasticities": "pendsim_mj.sweep.plan",
    "parse_vary": "pendsim_mj.sweep.plan",
    "read_cases_csv": "pendsim_mj.sweep.plan",
    "TaskResult": "pendsim_mj.sweep.run",
    "run_task": "pendsim_mj.sweep.run",
}

if TYPE_CHECKING:
    from pendsim_mj.sweep.features import FEATURE_GROUPS, Features
    from pendsim_mj.sweep.plan import Axis, CaseTable, SweepPlan, elasticities, parse_vary, read_cases_csv
    from pendsim_mj.sweep.run import TaskResult, run_task
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

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
