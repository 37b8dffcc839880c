"""Files of the nonlinear analyses (``pendsim analyze``): a JSON of every number, a CSV of the main
table and a PNG plot a person can read (axes with units, stable branches solid and unstable dashed,
bifurcations marked, the legend outside the data), published together into one folder.

Each ``write_*`` takes the frozen result of ``pendsim_mj.nonlinear`` and returns the written paths.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from pendsim_mj.nonlinear import (
    Agreement,
    Backbone,
    Lyapunov,
    PoincareDiagram,
    ResponseBranch,
    SteppedSweep,
    Tongues,
)
from pendsim_mj.rig.drives import Drive

from ..io.outputs import atomic_directory
from . import figures

BIFURCATION_STYLE = {
    "fold": ("D", "tab:red", "fold"),
    "period_doubling": ("s", "tab:purple", "period doubling"),
    "neimark_sacker": ("o", "tab:green", "Neimark-Sacker"),
    "branch_point": ("P", "tab:brown", "branch point"),
}
MODE_COLOURS = ("tab:blue", "tab:orange")


def jsonable(value: Any) -> Any:
    """Dataclasses, numpy arrays and scalars, complex numbers and tuples as JSON values (complex
    as {"real": ..., "imag": ...}; NaN and infinity as null)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        if np.iscomplexobj(value):
            return {"real": jsonable(value.real), "imag": jsonable(value.imag)}
        return jsonable(value.tolist())
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (complex, np.complexfloating)):
        return {"real": jsonable(float(value.real)), "imag": jsonable(float(value.imag))}
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) else None
    return value


def _write_json(path: Path, payload: dict[str, Any]) -> None:
    path.write_text(json.dumps(jsonable(payload), indent=1) + "\n")


def _write_csv(path: Path, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        for row in rows:
            writer.writerow([_cell(v) for v in row])


def _cell(value: Any) -> Any:
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return repr(float(value)) if math.isfinite(float(value)) else ""
    return value


def _finish(fig: Any, ax_legend: Any, path: Path) -> None:
    """Legend outside the data (right of the axes), tight layout, save, close."""
    handles, labels = ax_legend.get_legend_handles_labels()
    if handles:
        ax_legend.legend(handles, labels, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.tight_layout()
    figures.save_figure(fig, path, replace=True)


def _segments(x: np.ndarray, y: np.ndarray, stable: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """Runs of equal stability, each sharing its end point with the next so the line is unbroken."""
    out = []
    start = 0
    for i in range(1, len(x) + 1):
        if i == len(x) or stable[i] != stable[start]:
            stop = min(i + 1, len(x))
            out.append((x[start:stop], y[start:stop], bool(stable[start])))
            start = i
    return out


def _plot_branch(ax: Any, x: np.ndarray, y: np.ndarray, stable: np.ndarray, colour: str, label: str) -> None:
    labelled = {True: False, False: False}
    for xs, ys, is_stable in _segments(x, y, stable):
        name = f"{label}, {'stable' if is_stable else 'unstable'}"
        ax.plot(
            xs,
            ys,
            color=colour,
            linestyle="-" if is_stable else "--",
            linewidth=1.6 if is_stable else 1.1,
            label=None if labelled[is_stable] else name,
        )
        labelled[is_stable] = True


# -- backbone ---------------------------------------------------------------------------------


def write_backbone(
    backbones: Sequence[Backbone], out_dir: Path, *, settings: dict[str, Any], replace: bool = False
) -> list[Path]:
    """backbone.json, backbone.csv and backbone.png."""
    with atomic_directory(out_dir, replace=replace) as tmp:
        _write_json(tmp / "backbone.json", {"settings": settings, "backbones": list(backbones)})
        rows = []
        for b in backbones:
            for i in range(len(b.frequency_hz)):
                rows.append(
                    [
                        b.mode, b.frequency_hz[i], math.degrees(b.amplitude_rad[i, 0]),
                        math.degrees(b.amplitude_rad[i, 1]), b.phi0_rad[i, 0], b.phi0_rad[i, 1],
                        b.free_frequency_hz[i], b.free_relative_difference[i], b.periodicity_residual[i],
                        float(np.max(np.abs(b.multipliers[i]))), b.stable[i],
                    ]
                )  # fmt: skip
        header = [
            "mode", "frequency_hz", "amplitude_phi1_deg", "amplitude_phi2_deg", "phi1_0_rad", "phi2_0_rad",
            "free_simulation_frequency_hz", "relative_difference", "periodicity_residual", "max_abs_multiplier",
            "stable",
        ]  # fmt: skip
        _write_csv(tmp / "backbone.csv", header, rows)
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.8), dpi=110, sharey=True)
        for ax, k in zip(axes, (0, 1), strict=True):
            for b in backbones:
                colour = MODE_COLOURS[b.mode - 1]
                _plot_branch(ax, b.frequency_hz, np.degrees(b.amplitude_rad[:, k]), b.stable, colour, f"mode {b.mode}")
                ax.plot(
                    b.free_frequency_hz,
                    np.degrees(b.amplitude_rad[:, k]),
                    "x",
                    color=colour,
                    markersize=4,
                    label=f"mode {b.mode}, free simulation",
                )
                linear = f"mode {b.mode}, linear"
                ax.axvline(b.linear_frequency_hz, color=colour, linestyle=":", linewidth=1, label=linear)
            ax.set_xlabel("frequency (Hz)")
            ax.set_title(f"amplitude of phi{k + 1}")
            ax.grid(True, alpha=0.3)
        axes[0].set_ylabel("amplitude (deg)")
        fig.suptitle("Backbone curves of the undamped rig (nonlinear normal modes)")
        _finish(fig, axes[1], tmp / "backbone.png")
    return [out_dir / n for n in ("backbone.json", "backbone.csv", "backbone.png")]


# -- response ---------------------------------------------------------------------------------


def _mark_bifurcations(ax: Any, branch: ResponseBranch, k: int) -> None:
    shown = set()
    for b in branch.bifurcations:
        marker, colour, name = BIFURCATION_STYLE[b.kind]
        label = None if b.kind in shown else f"{name}"
        shown.add(b.kind)
        ax.plot(b.frequency_hz, math.degrees(b.amplitude_rad[k]), marker, color=colour, markersize=7,
                markeredgecolor="black", label=label, zorder=5)  # fmt: skip


def write_response(
    drive: Drive,
    branch: ResponseBranch | None,
    sweeps: Sequence[SteppedSweep],
    agreements: Sequence[Agreement],
    out_dir: Path,
    *,
    settings: dict[str, Any],
    replace: bool = False,
) -> list[Path]:
    """response.json, response_continuation.csv, response_stepped.csv and response.png."""
    names = ["response.json", "response_stepped.csv", "response.png"]
    with atomic_directory(out_dir, replace=replace) as tmp:
        payload: dict[str, Any] = {
            "settings": settings,
            "drive": drive.describe(),
            "stepped_sine": list(sweeps),
            "continuation": branch,
            "agreement": [{**jsonable(a), "max_relative_difference": a.max_relative_difference} for a in agreements],
        }
        _write_json(tmp / "response.json", payload)
        header = [
            "direction", "frequency_hz", "amplitude_phi1_deg", "amplitude_phi2_deg", "phase_phi1_deg",
            "phase_phi2_deg", "periods", "settled", "periodicity_residual", "locking_index", "frequency_ratio",
        ]  # fmt: skip
        rows = [
            [s.direction, s.frequency_hz[i], math.degrees(s.amplitude_rad[i, 0]), math.degrees(s.amplitude_rad[i, 1]),
             s.phase_deg[i, 0], s.phase_deg[i, 1], s.periods[i], s.settled[i], s.periodicity_residual[i],
             s.locking_index[i], s.frequency_ratio[i]]
            for s in sweeps
            for i in range(len(s.frequency_hz))
        ]  # fmt: skip
        _write_csv(tmp / "response_stepped.csv", header, rows)
        if branch is not None:
            names.insert(1, "response_continuation.csv")
            header = [
                "frequency_hz", "amplitude_phi1_deg", "amplitude_phi2_deg", "phase_phi1_deg", "phase_phi2_deg",
                "stable", "max_abs_multiplier", "residual",
            ]  # fmt: skip
            rows = [
                [branch.frequency_hz[i], math.degrees(branch.amplitude_rad[i, 0]),
                 math.degrees(branch.amplitude_rad[i, 1]), branch.phase_deg[i, 0], branch.phase_deg[i, 1],
                 branch.stable[i], float(np.max(np.abs(branch.multipliers[i]))), branch.residual[i]]
                for i in range(len(branch.frequency_hz))
            ]  # fmt: skip
            _write_csv(tmp / "response_continuation.csv", header, rows)
        fig, axes = plt.subplots(3, 1, figsize=(10, 9.5), dpi=110, sharex=True)
        panels = [(axes[0], "amp", 0, "amplitude of phi1 (deg)"), (axes[1], "amp", 1, "amplitude of phi2 (deg)"),
                  (axes[2], "phase", 0, "phase of phi1 (deg)")]  # fmt: skip
        for ax, what, k, ylabel in panels:
            if branch is not None:
                y = np.degrees(branch.amplitude_rad[:, k]) if what == "amp" else branch.phase_deg[:, k]
                _plot_branch(ax, branch.frequency_hz, y, branch.stable, "tab:blue", "continuation")
                if what == "amp":
                    _mark_bifurcations(ax, branch, k)
            for s in sweeps:
                y = np.degrees(s.amplitude_rad[:, k]) if what == "amp" else s.phase_deg[:, k]
                marker = "^" if s.direction == "up" else "v"
                colour = "tab:orange" if s.direction == "up" else "tab:green"
                ax.plot(s.frequency_hz, y, marker, color=colour, markersize=5, fillstyle="none",
                        label=f"stepped sine, {s.direction}")  # fmt: skip
            ax.set_ylabel(ylabel)
            ax.grid(True, alpha=0.3)
        axes[2].set_xlabel("drive frequency (Hz)")
        what = ", ".join(f"{t}: {v['amplitude']:g} {v['unit']}" for t, v in drive.describe().items())
        axes[0].set_title(f"Frequency response, drive {what}")
        _finish(fig, axes[0], tmp / "response.png")
    return [out_dir / n for n in names]


# -- bifurcation diagram ----------------------------------------------------------------------


def write_bifurcation(
    diagram: PoincareDiagram, drive: Drive, out_dir: Path, *, settings: dict[str, Any], replace: bool = False
) -> list[Path]:
    """bifurcation.json, bifurcation.csv and bifurcation.png."""
    with atomic_directory(out_dir, replace=replace) as tmp:
        _write_json(tmp / "bifurcation.json", {"settings": settings, "drive": drive.describe(), "diagram": diagram})
        header = ["direction", diagram.parameter, "period", "sample", "phi1_rad", "phi2_rad", "omega1_rad_s",
                  "omega2_rad_s"]  # fmt: skip
        rows = [
            [s.direction, s.values[i], s.period[i], j, *s.samples[i, j]]
            for s in diagram.sweeps
            for i in range(len(s.values))
            for j in range(s.samples.shape[1])
        ]
        _write_csv(tmp / "bifurcation.csv", header, rows)
        fig, axes = plt.subplots(2, 1, figsize=(10, 7.5), dpi=110, sharex=True)
        for k, ax in enumerate(axes):
            for s, colour in zip(diagram.sweeps, ("tab:orange", "tab:green"), strict=False):
                x = np.repeat(s.values, s.samples.shape[1])
                ax.plot(x, np.degrees(s.samples[:, :, k].ravel()), ".", color=colour, markersize=2, alpha=0.7,
                        label=f"sweep {s.direction}")  # fmt: skip
            ax.set_ylabel(f"phi{k + 1} once per drive period (deg)")
            ax.grid(True, alpha=0.3)
        xlabel = "drive frequency (Hz)" if diagram.parameter == "frequency" else f"drive level ({diagram.unit})"
        axes[1].set_xlabel(xlabel)
        axes[0].set_title(
            f"Bifurcation diagram: stroboscopic samples after {diagram.transient_periods} periods "
            f"({diagram.sample_periods} per value)"
        )
        _finish(fig, axes[0], tmp / "bifurcation.png")
    return [out_dir / n for n in ("bifurcation.json", "bifurcation.csv", "bifurcation.png")]


# -- Lyapunov -----------------------------------------------------------------------------------


def write_lyapunov(
    result: Lyapunov, drive: Drive | None, out_dir: Path, *, settings: dict[str, Any], replace: bool = False
) -> list[Path]:
    """lyapunov.json, lyapunov.csv and lyapunov.png (the convergence)."""
    with atomic_directory(out_dir, replace=replace) as tmp:
        described = drive.describe() if drive else {}
        _write_json(tmp / "lyapunov.json", {"settings": settings, "drive": described, "result": result})
        _write_csv(
            tmp / "lyapunov.csv",
            ["t_s", "running_estimate_per_s", "log_stretch"],
            zip(result.t_s, result.running_per_s, result.stretch, strict=True),
        )
        fig, (ax, ax2) = plt.subplots(2, 1, figsize=(10, 7.5), dpi=110, sharex=True)
        ax.plot(result.t_s, result.running_per_s, color="tab:blue", linewidth=1.2,
                label="first run's running estimate: sum of ln(d/d0) / t")  # fmt: skip
        low, high = result.exponent_per_s - result.uncertainty_per_s, result.exponent_per_s + result.uncertainty_per_s
        ax.axhspan(low, high, color="tab:red", alpha=0.15, label="ensemble estimate +- uncertainty (95 %)")
        ax.axhline(result.exponent_per_s, color="tab:red", linestyle="--", linewidth=1.2,
                   label=f"ensemble estimate {result.exponent_per_s:.4g} 1/s "
                   f"({len(result.member_exponents_per_s)} runs)")  # fmt: skip
        ax.plot(np.full(len(result.member_exponents_per_s), result.t_s[-1]), result.member_exponents_per_s, "_",
                color="black", markersize=12, label="each run's exponent (last three quarters)")  # fmt: skip
        ax.axhline(0.0, color="black", linewidth=0.8)
        ax.set_ylabel("largest Lyapunov exponent (1/s)")
        verdict = "chaotic" if low > 0 else ("not chaotic" if high < max(0.01, result.tolerance_per_s) else "undecided")
        state = "converged" if result.converged else "NOT converged"
        ax.set_title(f"Convergence of the largest Lyapunov exponent ({verdict}; {state})")
        total = np.cumsum(result.stretch)
        first = len(total) // 4
        ax2.plot(result.t_s, total, color="tab:blue", linewidth=1.2, label="sum of ln(d/d0), first run")
        ax2.plot(result.t_s[first:], total[first] + result.exponent_per_s * (result.t_s[first:] - result.t_s[first]),
                 "--", color="tab:red", linewidth=1.2, label="slope of the ensemble estimate")  # fmt: skip
        ax2.set_xlabel(f"time after {result.transient_s:g} s of transient (s)")
        ax2.set_ylabel("cumulative log stretch")
        for a in (ax, ax2):
            a.grid(True, alpha=0.3)
        ax2.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        _finish(fig, ax, tmp / "lyapunov.png")
    return [out_dir / n for n in ("lyapunov.json", "lyapunov.csv", "lyapunov.png")]


# -- tongues ------------------------------------------------------------------------------------


def write_tongues(result: Tongues, out_dir: Path, *, settings: dict[str, Any], replace: bool = False) -> list[Path]:
    """tongues.json, tongues.csv and tongues.png."""
    with atomic_directory(out_dir, replace=replace) as tmp:
        _write_json(tmp / "tongues.json", {"settings": settings, "tongues": result})
        _write_csv(
            tmp / "tongues.csv",
            ["frequency_hz", "boundary_m_s2", "mathieu_mode1_m_s2", "mathieu_mode2_m_s2"],
            zip(result.frequency_hz, result.boundary_m_s2, *result.analytic_m_s2, strict=True),
        )
        fig, ax = plt.subplots(figsize=(10, 5.5), dpi=110)
        growth = np.clip(result.growth, 0.0, None)
        mesh = ax.pcolormesh(result.frequency_hz, result.level_m_s2, growth, shading="nearest", cmap="Reds")
        fig.colorbar(mesh, ax=ax, pad=0.01).set_label("growth of a perturbation, ln|mu| per period")
        ax.plot(result.frequency_hz, result.boundary_m_s2, color="black", linewidth=1.6, label="boundary (Floquet)")
        if result.tips:
            ax.plot([t.frequency_hz for t in result.tips], [t.level_m_s2 for t in result.tips], "v", color="black",
                    markersize=7, label="tongue tips (refined between the grid's frequencies)")  # fmt: skip
        top = result.level_m_s2[-1]
        for m in (0, 1):
            a = np.where(result.analytic_m_s2[m] <= top * 1.05, result.analytic_m_s2[m], np.nan)
            ax.plot(result.frequency_hz, a, "--", color=MODE_COLOURS[m], linewidth=1.3,
                    label=f"Mathieu limit, mode {m + 1}")  # fmt: skip
        f1, f2 = result.linear_frequency_hz
        for x, name in ((2 * f1, "2 f1"), (2 * f2, "2 f2"), (f1 + f2, "f1 + f2")):
            if result.frequency_hz[0] <= x <= result.frequency_hz[-1]:
                ax.axvline(x, color="grey", linestyle=":", linewidth=1)
                ax.annotate(name, (x, top), xytext=(2, -10), textcoords="offset points", fontsize=8)
        ax.set_xlim(result.frequency_hz[0], result.frequency_hz[-1])
        ax.set_ylim(0, top)
        ax.set_xlabel("pivot drive frequency (Hz)")
        ax.set_ylabel("pivot acceleration amplitude (m/s^2)")
        ax.set_title("Instability tongues of rest under vertical pivot motion (parametric excitation)")
        handles, labels = ax.get_legend_handles_labels()
        fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=3, bbox_to_anchor=(0.5, -0.02))
        fig.tight_layout(rect=(0, 0.06, 1, 1))
        figures.save_figure(fig, tmp / "tongues.png", replace=True)
    return [out_dir / n for n in ("tongues.json", "tongues.csv", "tongues.png")]


# -- synchronisation ----------------------------------------------------------------------------


def write_sync(
    drive: Drive, sweeps: Sequence[SteppedSweep], out_dir: Path, *, settings: dict[str, Any], replace: bool = False
) -> list[Path]:
    """sync.json, sync.csv and sync.png: phase locking of the two pendulums against the drive
    frequency."""
    with atomic_directory(out_dir, replace=replace) as tmp:
        _write_json(tmp / "sync.json", {"settings": settings, "drive": drive.describe(), "sweeps": list(sweeps)})
        rows = [
            [s.direction, s.frequency_hz[i], s.locking_index[i], s.frequency_ratio[i],
             math.degrees(s.amplitude_rad[i, 0]), math.degrees(s.amplitude_rad[i, 1]), s.periodicity_residual[i]]
            for s in sweeps
            for i in range(len(s.frequency_hz))
        ]  # fmt: skip
        header = ["direction", "frequency_hz", "locking_index", "frequency_ratio_f1_f2", "amplitude_phi1_deg",
                  "amplitude_phi2_deg", "periodicity_residual"]  # fmt: skip
        _write_csv(tmp / "sync.csv", header, rows)
        fig, axes = plt.subplots(3, 1, figsize=(10, 8.5), dpi=110, sharex=True)
        for s in sweeps:
            marker, colour = ("^", "tab:orange") if s.direction == "up" else ("v", "tab:green")
            style = {"marker": marker, "color": colour, "markersize": 5, "linewidth": 0.8}
            style["label"] = f"sweep {s.direction}"
            axes[0].plot(s.frequency_hz, s.locking_index, **style)
            axes[1].plot(s.frequency_hz, s.frequency_ratio, **style)
            for k, ls in ((0, "-"), (1, ":")):
                axes[2].plot(s.frequency_hz, np.degrees(s.amplitude_rad[:, k]), marker=marker, color=colour,
                             linestyle=ls, markersize=4, linewidth=0.8, label=f"phi{k + 1}, {s.direction}")  # fmt: skip
        axes[0].set_ylabel("1:1 phase-locking index")
        axes[0].set_ylim(-0.02, 1.02)
        axes[1].set_ylabel("frequency ratio f(phi1) / f(phi2)")
        axes[2].set_ylabel("amplitude (deg)")
        axes[2].set_xlabel("drive frequency (Hz)")
        for ax in axes:
            ax.grid(True, alpha=0.3)
        what = ", ".join(f"{t}: {v['amplitude']:g} {v['unit']}" for t, v in drive.describe().items())
        axes[0].set_title(f"Synchronisation of the two pendulums, drive {what}")
        axes[2].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        _finish(fig, axes[0], tmp / "sync.png")
    return [out_dir / n for n in ("sync.json", "sync.csv", "sync.png")]
