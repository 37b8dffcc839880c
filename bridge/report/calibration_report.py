"""calibrate's outputs: the report's contents (``CalibrationReport``), its JSON and text forms,
and the files (the parameter file, both reports and one figure: what the calibration changed,
with intervals, and each recording's validation before and after)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

from pendsim_mj.calibration import Calibration
from pendsim_mj.calibration.design import Suggestion

from ..io.outputs import atomic_directory


@dataclasses.dataclass(frozen=True)
class Metrics:
    """A recording validated with one rig (MuJoCo from the estimated start, the whole run)."""

    path: str
    rig: str  # "stated", "calibrated", "left out"
    max_abs_phi1_rad: float
    max_abs_omega2_rad_s: float  # (phi2 is not validated: M2's angle is integrated from its gyro)
    iae_phi1_rad_s: float
    delta_f_phi1: float  # relative frequency error of phi1


@dataclasses.dataclass(frozen=True)
class CalibrationReport:
    """What ``calibrate_recordings`` found: the calibration, the held directions in words, the
    validations before and after (and left out), the model-error findings and the suggested
    experiments."""

    calibration: Calibration
    paths: tuple[str, ...]
    held_words: tuple[str, ...]
    before: tuple[Metrics, ...]
    after: tuple[Metrics, ...]
    left_out: tuple[Metrics, ...]
    model_error: tuple[str, ...]
    suggestions: tuple[Suggestion, ...]
    fixed: tuple[tuple[str, float], ...] = ()  # held at given values (--fix)


def _clean(v: float) -> float | None:
    return v if math.isfinite(v) else None


def report_json(report: CalibrationReport) -> dict[str, Any]:
    """calibration.json: everything the text report says, for machines."""
    cal = report.calibration
    return {
        "recordings": list(report.paths),
        "model": cal.model,
        "law": cal.law,
        "fixed": dict(report.fixed),
        "free": list(cal.free),
        "parameters": cal.overrides(),
        "stated": {name: cal.stated.as_dict()[name] for name in cal.free},
        "quantities": [
            {**dataclasses.asdict(q), "half_width95": _clean(q.half_width95) if q.determined else None}
            for q in cal.quantities
        ],
        "directions": [
            {
                "components": dict(zip(cal.free, map(float, d.vector), strict=True)),
                "half_width95_relative": _clean(d.half_width95),
                "determined": d.determined,
            }
            for d in cal.directions
        ],
        "not_determined": list(report.held_words),
        "runs": [dataclasses.asdict(r) for r in cal.runs],
        "residual_rms_sigma": cal.residual_rms_sigma,
        "iterations": cal.iterations,
        "seconds": cal.seconds,
        "validation": {
            "before": [dataclasses.asdict(m) for m in report.before],
            "after": [dataclasses.asdict(m) for m in report.after],
            "left_out": [dataclasses.asdict(m) for m in report.left_out],
        },
        "model_error": list(report.model_error),
        "suggested_experiments": [s.to_json() for s in report.suggestions],
    }


WORSE_BY = 1.2  # a calibrated rig whose IAE of phi1 exceeds the stated rig's by this factor is said to be worse


def _worse(before: Metrics, after: Metrics) -> str:
    """A line where the calibrated rig validates a recording worse than the stated one (a stated rig
    that was already right: a simulated recording's own, calibrated from it), else ""."""
    if not after.iae_phi1_rad_s > WORSE_BY * before.iae_phi1_rad_s:
        return ""
    return (
        f"\n{Path(before.path).name}: the calibrated rig validates worse than the stated one (IAE phi1 "
        f"{after.iae_phi1_rad_s:.4f} against {before.iae_phi1_rad_s:.4f} rad s, max abs dphi1 "
        f"{after.max_abs_phi1_rad:.4f} against {before.max_abs_phi1_rad:.4f} rad): the stated rig already fits "
        "it; keep the stated rig unless other recordings need the calibration"
    )


def report_text(report: CalibrationReport) -> str:
    """The plain-words report (printed, and calibration.md)."""
    cal = report.calibration
    out = [f"# Calibration of {len(report.paths)} recording(s), {cal.model} model, {cal.law} damping", ""]
    out.append(
        f"Residual after calibration: {cal.residual_rms_sigma:.2f} gyro noise sigmas rms"
        + (" (all three axes of both gyros)" if cal.model == "spatial" else "")
        + " "
        f"({cal.iterations} iterations, {cal.seconds:.1f} s)."
    )
    out += ["", "## Determined (95 % intervals)", ""]
    for q in cal.quantities:
        if q.determined:
            change = 100 * (q.value / q.stated - 1) if q.stated else math.nan
            shown = f"{change:+.2f} % from stated" if math.isfinite(change) else f"stated {q.stated:.6g}"
            out.append(f"- {q.label} = {q.value:.6g} +- {q.half_width95:.2g} {q.unit} ({shown})")
    out.append(
        "Stated rig (where the fit starts, and what it holds where the recordings say nothing): the paper's, with "
        "--params-file/--set"
        + (": held by --fix: " + ", ".join(f"{n} = {v:g}" for n, v in report.fixed) if report.fixed else "")
        + "."
    )
    out += ["", "## Not determined by these recordings (held near the stated values)", ""]
    out += [f"- {w}" for w in report.held_words] or ["- nothing: every free parameter is determined"]
    undetermined = [q for q in cal.quantities if not q.determined]
    if undetermined:
        out.append(
            "- so these are not determined alone (params.json holds one rig with every determined quantity; "
            "its values of these carry the held directions): " + ", ".join(q.label for q in undetermined)
        )
    if report.suggestions:
        out += ["", "## Which recording would determine more", ""]
        out += [f"- {s.describe()}" for s in report.suggestions]
    if report.before:
        model = "the spatial MuJoCo model" if cal.model == "spatial" else "MuJoCo"
        out += ["", f"## Validation ({model} from the estimated start, whole run)", ""]
        out.append(
            "| recording | rig | max abs dphi1 (rad) | max abs domega2 (rad/s) | IAE phi1 (rad s) | df phi1 (%) |"
        )
        out.append("|---|---|---|---|---|---|")
        for m in (*report.before, *report.after, *report.left_out):
            out.append(
                f"| {Path(m.path).name} | {m.rig} | {m.max_abs_phi1_rad:.4f} | {m.max_abs_omega2_rad_s:.4f} | "
                f"{m.iae_phi1_rad_s:.4f} | {100 * m.delta_f_phi1:+.3f} |"
            )
        out += [line for b, a in zip(report.before, report.after, strict=True) if (line := _worse(b, a))]
    if report.model_error:
        out += ["", "## Model error", ""]
        out += [f"- {line}" for line in report.model_error]
    return "\n".join(out) + "\n"


def write_outputs(report: CalibrationReport, out_dir: str | Path, *, replace: bool = False) -> list[Path]:
    """params.json, calibration.json, calibration.md and calibration.png into ``out_dir``, published
    together (``atomic_directory``). Returns the paths written."""
    out = Path(out_dir)
    with atomic_directory(out, replace=replace) as tmp:
        (tmp / "params.json").write_text(json.dumps(report.calibration.parameter_file(), indent=1) + "\n")
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
