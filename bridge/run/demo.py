"""``pendsim demo``: the whole chain on built-in defaults, as a library function.

Simulate the rig from 30 deg, record both BNO055 nodes with 2 s held before the release, identify
the damping and validate the recording against the MuJoCo model and the planar reference, write
the report and the paper's Figures 9-15, and a Rerun view built from the validation's own aligned
runs (nothing is read, aligned or simulated twice).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from pendsim_mj.errors import ParameterError

from ..io.outputs import atomic_directory
from ..report.rerun_view import view_report
from ..report.validation_report import ValidationReport, table, write_outputs
from .record import RecordSpec, record
from .validate import validate

HOLD_S = 2.0  # held before the release, as a real recording starts
DEMO_FILES = ("run.mcap", "report.json", "run.rrd")
"""The demo's main files (checked before the work; the figures too when publishing)."""


@dataclasses.dataclass(frozen=True)
class DemoResult:
    """Where everything went."""

    recording: Path
    report_json: Path
    figures: list[Path]
    rrd: Path
    report: ValidationReport


def run_demo(
    out_dir: str | Path, *, duration_s: float = 120.0, replace: bool = False, say: Callable[[str], None] = print
) -> DemoResult:
    """Run the chain into ``out_dir``: everything is written to a temporary folder and published
    together at the end (``atomic_directory``), so a failure or Ctrl-C leaves nothing behind.

    Args:
      out_dir: output folder (created; other files there are left alone).
      duration_s: simulated time after the release, s (10 to 3600).
      replace: replace files of the same names in ``out_dir`` (otherwise they are an error).
      say: receives one progress line per stage and the validation table.
    """
    if not 10 <= duration_s <= 3600:
        raise ParameterError(f"duration_s must be between 10 and 3600 s, got {duration_s:g}")
    out = Path(out_dir)
    recording = out / "run.mcap"
    with atomic_directory(out, replace=replace) as tmp:
        say(f"1/4 simulating the rig from 30 deg for {duration_s:g} s and recording both IMUs to {recording}")
        record(RecordSpec(duration_s=duration_s, hold_s=HOLD_S), tmp / recording.name)
        say("2/4 identifying the damping and validating against the MuJoCo model and the planar reference")
        report = dataclasses.replace(validate(tmp / recording.name), path=recording)
        say(table(report))
        say("3/4 drawing the paper's Figures 9-15")
        written = [out / p.name for p in write_outputs(report, tmp, replace=True)]
        say("4/4 writing the Rerun view")
        view_report(report, tmp / "run.rrd")
    return DemoResult(recording, written[0], written[1:], out / "run.rrd", report)
