"""calibrate's outputs: the parameter file, the JSON and text reports, and one figure (what the
calibration changed, with intervals, and each recording's validation before and after)."""

from __future__ import annotations

import json
from pathlib import Path

from ..io.outputs import atomic_directory
from ..run.calibrate import CalibrationReport, report_json, report_text


def write_outputs(report: CalibrationReport, out_dir: str | Path, *, replace: bool = False) -> list[Path]:
    """params.json, calibration.json, calibration.md and calibration.png into ``out_dir``, published
    together (``atomic_directory``). Returns the paths written."""
    out = Path(out_dir)
    with atomic_directory(out, replace=replace) as tmp:
        (tmp / "params.json").write_text(json.dumps(report.calibration.overrides(), indent=1) + "\n")
        (tmp / "calibration.json").write_text(json.dumps(report_json(report), indent=1) + "\n")
        (tmp / "calibration.md").write_text(report_text(report))
        figure(report, tmp / "calibration.png")
    return [out / name for name in ("params.json", "calibration.json", "calibration.md", "calibration.png")]


def figure(report: CalibrationReport, path: Path) -> Path:
    """Left: each determined quantity's change from the stated rig, %, with its 95 % interval.
    Right: each recording's max |Delta phi1| with the stated and the calibrated rig (and left out)."""
    import matplotlib  # start-up: only when the figure is drawn

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    from .figures import save_figure

    cal = report.calibration
    shown = [q for q in cal.quantities if q.determined and q.stated]
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, max(3.5, 0.35 * len(shown) + 1.5)))
    y = list(range(len(shown)))
    change = [100 * (q.value / q.stated - 1) for q in shown]
    err = [100 * q.half_width95 / abs(q.stated) for q in shown]
    left.errorbar(change, y, xerr=err, fmt="o", color="C0", capsize=3)
    left.axvline(0.0, color="0.5", lw=0.8)
    left.set_yticks(y, [q.label for q in shown], fontsize=8)
    left.set_xlabel("change from the stated rig (%), 95 % interval")
    left.set_title("determined quantities")
    left.grid(alpha=0.3)
    if report.before:
        names = [Path(m.path).name for m in report.before]
        x = range(len(names))
        width = 0.27
        right.bar([i - width for i in x], [m.max_abs_phi1_rad for m in report.before], width, label="stated rig")
        right.bar(list(x), [m.max_abs_phi1_rad for m in report.after], width, label="calibrated")
        if report.left_out:
            right.bar([i + width for i in x], [m.max_abs_phi1_rad for m in report.left_out], width, label="left out")
        right.set_xticks(list(x), names, rotation=20, fontsize=8)
        right.set_yscale("log")
        right.set_ylabel("max |Delta phi1| over the run (rad)")
        right.set_title("validation (MuJoCo, estimated start)")
        right.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        right.grid(alpha=0.3, axis="y")
    else:
        right.axis("off")
        right.text(0.5, 0.5, "no validation (--no-checks)", ha="center", va="center")
    rms = cal.residual_rms_sigma
    fig.suptitle(f"calibration: residual {rms:.2f} noise sigmas rms")
    fig.tight_layout()
    return save_figure(fig, path, replace=True)
