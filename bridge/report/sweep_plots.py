"""The pictures of a finished sweep (PNG, matplotlib Agg) and the sensitivity ranking.

One map per scalar feature, chosen by the shape of the sweep:

- a sensitivity sweep: a bar chart of the elasticity d ln f / d ln p of the feature to every
  parameter, ranked by size (largest at the top), positive and negative coloured apart;
- one varied input: the feature against it (a line with markers);
- two varied inputs: a heat map on a grid, or coloured points for random / lhs / csv cases;
- more: the feature against each input, one panel per input.

With the ``poincare`` feature and one varied input, ``poincare_phi2_rad.png`` plots every section
sample against the input (a bifurcation diagram). Diverged cases are left blank and counted in
the title. Each file is written atomically and replaces an older one of the same name.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pyarrow.parquet as pq
from numpy.typing import NDArray

from pendsim_mj.rig.params import RigParams
from pendsim_mj.sweep.features import FEATURE_GROUPS, LIST_GROUPS
from pendsim_mj.sweep.plan import CaseTable, SweepPlan, elasticities

from ..io.outputs import atomic_output
from . import figures

_UNITS = {name: unit for name, unit, _ in RigParams.describe()}
_SUFFIX_UNITS = (
    ("_deg_s", "deg/s"), ("_rad_s", "rad/s"), ("_deg", "deg"), ("_rad", "rad"), ("_hz", "Hz"),
    ("_per_s", "1/s"), ("_j", "J"), ("_s", "s"),
)  # fmt: skip
SCALAR_FEATURES = tuple(c for g, cols in FEATURE_GROUPS.items() if g not in LIST_GROUPS for c in cols)


def label(name: str) -> str:
    """An axis label with the unit: ``c1_n_m (N/m)``, ``freq1_hz (Hz)``."""
    if name in _UNITS:
        return f"{name} ({_UNITS[name]})"
    unit = next((u for suffix, u in _SUFFIX_UNITS if name.endswith(suffix)), "")
    return f"{name} ({unit})" if unit else name


def write_sensitivity(results: Path, table: CaseTable, *, out_dir: Path) -> Path:
    """``sensitivity.json``: for each feature, the parameters ranked by |elasticity|, with the
    feature's base value (d ln f / d ln p: +1 means f grows 1 % per 1 % of p)."""
    names, values = _feature_values(results)
    e = elasticities(table, values)
    base = values[np.array(table.varied) == ""][0]
    assert table.relative_change is not None
    out: dict[str, object] = {"relative_step": float(np.max(np.abs(table.relative_change)))}
    feats: dict[str, object] = {}
    for j, feature in enumerate(names):
        order = _ranking(e[:, j])
        feats[feature] = {
            "base_value": _number(base[j]),
            "ranking": [{"parameter": table.names[i], "elasticity": _number(e[i, j])} for i in order],
        }
    out["features"] = feats
    path = out_dir / "sensitivity.json"
    with atomic_output(path, replace=True) as tmp:
        tmp.write_text(json.dumps(out, indent=1) + "\n")
    return path


def draw_maps(results: Path, plan: SweepPlan, table: CaseTable, directory: Path) -> list[Path]:
    """Every map of the module docstring into ``directory`` (created); returns the files."""
    directory.mkdir(parents=True, exist_ok=True)
    names, values = _feature_values(results)
    diverged = pq.read_table(results, columns=["diverged"]).column("diverged").to_numpy(zero_copy_only=False)
    head = f"{plan.engine} engine, {plan.duration_s:g} s at {plan.dt_s:g} s"
    written = []
    if plan.method == "sensitivity":
        e = elasticities(table, values)
        step = 100 * plan.relative_step
        for j, feature in enumerate(names):
            title = f"Sensitivity of {feature} (+/-{step:g} % per parameter)\n{head}"
            written.append(_bars(directory / f"sensitivity_{feature}.png", e[:, j], table.names, feature, title))
        return written
    x = table.values
    logs = log_inputs(plan, table)
    note = f", {int(diverged.sum())} diverged" if diverged.any() else ""
    columns = pq.read_schema(results).names
    for j, feature in enumerate(names):
        marks = _ambiguous(results, feature, columns)
        count = f", {int(marks.sum())} ambiguous: ringed" if marks is not None and marks.any() else ""
        title = f"{feature}: {len(table)} cases ({plan.method}{note}{count})\n{head}"
        path = directory / f"{feature}.png"
        if len(table.names) == 1:
            written.append(_line(path, x[:, 0], values[:, j], table.names[0], feature, title, logs, marks))
        elif len(table.names) == 2 and plan.method == "grid":
            shape = tuple(len(a.grid_values()) for a in plan.axes)
            written.append(_heat(path, x, values[:, j], shape, table.names, feature, title, logs, marks))
        elif len(table.names) == 2:
            written.append(_scatter(path, x, values[:, j], table.names, feature, title, logs, marks, diverged))
        else:
            written.append(_panels(path, x, values[:, j], table.names, feature, title, logs, marks))
    if len(table.names) == 1 and "poincare_phi2_rad" in columns:
        samples = pq.read_table(results, columns=["poincare_phi2_rad"]).column("poincare_phi2_rad").to_pylist()
        title = f"Poincare section phi1 = 0 (rising): phi2 against {table.names[0]}\n{head}"
        bifurcation = directory / "poincare_phi2_rad.png"
        written.append(_bifurcation(bifurcation, x[:, 0], samples, table.names[0], title, logs))
    return written


LOG_LIST_SPAN = 100.0
"""A list of values (``--vary NAME=V1,V2,...``), all positive, whose largest is at least this many
times its smallest is drawn on a log axis too (1e-4,1e-3,1e-2 squeezed two of three together)."""


def log_inputs(plan: SweepPlan, table: CaseTable) -> tuple[bool, ...]:
    """Per input of ``table``: whether it is drawn on a log axis: varied on a log scale, or a list
    of positive values spanning ``LOG_LIST_SPAN`` or more (a case file's inputs: never)."""
    scaled = {a.name for a in plan.axes if a.log}
    for a in plan.axes:
        values = np.asarray(a.values if a.values is not None else [], dtype=float)
        if len(values) > 1 and np.all(values > 0) and values.max() >= LOG_LIST_SPAN * values.min():
            scaled.add(a.name)
    return tuple(name in scaled for name in table.names)


def _ambiguous(results: Path, feature: str, columns: list[str]) -> NDArray[np.bool_] | None:
    """A frequency feature's ``freqN_ambiguous`` column, ordered by case_id; None for another
    feature or when the file has no such column."""
    flag = feature.removesuffix("_hz") + "_ambiguous"
    if not feature.endswith("_hz") or flag not in columns:
        return None
    data = pq.read_table(results, columns=["case_id", flag]).sort_by("case_id")
    return np.asarray(data.column(flag).to_numpy(zero_copy_only=False), dtype=bool)


AMBIGUOUS_LABEL = "ambiguous: two modes'\npeaks within 20 %"


def _ring(
    ax: plt.Axes,
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    marks: NDArray[np.bool_] | None,
    legend_at: float | None,
) -> None:
    """Ring the ambiguous cases (``marks``) at (x, y) in red; with ``legend_at``, a legend to the
    right of the axes, its left edge there (in axes widths: beyond a colour bar for 1.25)."""
    if marks is None or not marks.any():
        return
    ax.plot(x[marks], y[marks], "o", mfc="none", mec="tab:red", ms=7, mew=1.2, label=AMBIGUOUS_LABEL)
    if legend_at is not None:
        ax.legend(loc="upper left", bbox_to_anchor=(legend_at, 1.0), fontsize=8)


def _cell_edges(centres: NDArray[np.float64], log: bool) -> NDArray[np.float64]:
    """The edges of a heat map's cells around sorted grid values: midway between neighbours
    (geometrically on a log axis), the outer edges as far out as the inner ones."""
    c = np.log(centres) if log else np.asarray(centres, dtype=float)
    if len(c) == 1:  # one value: a cell half a unit wide each way (of ln x on a log axis, of x or |x| else)
        half = 0.5 if log or c[0] == 0 else 0.5 * abs(c[0])
        edges = np.array([c[0] - half, c[0] + half])
    else:
        mid = (c[1:] + c[:-1]) / 2
        edges = np.concatenate([[2 * c[0] - mid[0]], mid, [2 * c[-1] - mid[-1]]])
    return np.exp(edges) if log else edges


def _feature_values(results: Path) -> tuple[list[str], NDArray[np.float64]]:
    """The scalar feature columns of a results file, (ncases, k), ordered by case_id."""
    schema = pq.read_schema(results).names
    names = [c for c in SCALAR_FEATURES if c in schema]
    data = pq.read_table(results, columns=["case_id", *names]).sort_by("case_id")
    values = np.stack([data.column(c).to_numpy(zero_copy_only=False) for c in names], axis=1) if names else None
    return names, values if values is not None else np.zeros((data.num_rows, 0))


def _ranking(values: NDArray[np.float64]) -> list[int]:
    """Indices by |value|, largest first; NaN last."""
    key = np.where(np.isfinite(values), -np.abs(values), np.inf)
    return [int(i) for i in np.argsort(key, kind="stable")]


def _number(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def _bars(path: Path, e: NDArray[np.float64], params: tuple[str, ...], feature: str, title: str) -> Path:
    order = _ranking(e)[::-1]  # matplotlib draws the first bar at the bottom: largest on top
    shown = np.nan_to_num(e[order])
    fig, ax = plt.subplots(figsize=(8, 0.28 * len(order) + 1.6), dpi=110)
    colours = ["tab:red" if v < 0 else "tab:blue" for v in shown]
    ax.barh(np.arange(len(order)), shown, color=colours)
    span = float(np.max(np.abs(shown))) if len(shown) and np.any(shown) else 1.0
    for row, (i, v) in enumerate(zip(order, shown, strict=True)):
        text = f"{v:+.3g}" if np.isfinite(e[i]) else "n/a"
        ax.annotate(
            text,
            (v, row),
            xytext=(3 if v >= 0 else -3, 0),
            textcoords="offset points",
            ha="left" if v >= 0 else "right",
            va="center",
            fontsize=7,
        )
    ax.set_xlim(-1.25 * span if np.any(shown < 0) else -0.05 * span, 1.25 * span if np.any(shown > 0) else 0.05 * span)
    ax.set_yticks(
        np.arange(len(order)), [params[i] + ("" if np.isfinite(e[i]) else " (n/a)") for i in order], fontsize=8
    )
    ax.axvline(0, color="black", linewidth=0.8)
    ax.set_xlabel(f"elasticity d ln({feature}) / d ln(parameter)  (blue: grows with it, red: falls)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, axis="x", alpha=0.3)
    fig.tight_layout()
    return figures.save_figure(fig, path, replace=True, crop=False)


def _line(
    path: Path,
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    xname: str,
    yname: str,
    title: str,
    logs: tuple[bool, ...],
    marks: NDArray[np.bool_] | None = None,
) -> Path:
    order = np.argsort(x, kind="stable")
    fig, ax = plt.subplots(figsize=(7.5, 4.8), dpi=110)
    ax.plot(x[order], y[order], "o-", markersize=3, linewidth=1.2)
    _ring(ax, x, y, marks, 1.02)
    if logs[0]:
        ax.set_xscale("log")
    ax.set_xlabel(label(xname))
    ax.set_ylabel(label(yname))
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    return figures.save_figure(fig, path, replace=True, crop=False)


def _heat(
    path: Path,
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    shape: tuple[int, ...],
    names: tuple[str, ...],
    feature: str,
    title: str,
    logs: tuple[bool, ...],
    marks: NDArray[np.bool_] | None = None,
) -> Path:
    grid = y.reshape(shape)  # the grid's first input is the slowest: rows
    a = x[:, 0].reshape(shape)[:, 0]
    b = x[:, 1].reshape(shape)[0, :]
    rows, cols = np.argsort(a, kind="stable"), np.argsort(b, kind="stable")  # a list of values may be unsorted
    grid = grid[rows][:, cols]
    fig, ax = plt.subplots(figsize=(7.5, 5.5), dpi=110)
    a_edges, b_edges = _cell_edges(a[rows], logs[0]), _cell_edges(b[cols], logs[1])
    mesh = ax.pcolormesh(b_edges, a_edges, np.ma.masked_invalid(grid), shading="flat", cmap="viridis")
    fig.colorbar(mesh, ax=ax, label=label(feature))
    _ring(ax, x[:, 1], x[:, 0], marks, 1.25)
    return _two_inputs_drawn(fig, ax, path, names, title, logs)


def _two_inputs_drawn(
    fig: Any, ax: Any, path: Path, names: tuple[str, ...], title: str, logs: tuple[bool, ...]
) -> Path:
    """A map over two inputs finished and written: the first input up the side, the second along
    the bottom, each on a log axis where ``logs`` says."""
    if logs[0]:
        ax.set_yscale("log")
    if logs[1]:
        ax.set_xscale("log")
    ax.set_xlabel(label(names[1]))
    ax.set_ylabel(label(names[0]))
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return figures.save_figure(fig, path, replace=True, crop=False)


NO_VALUE = {
    **dict.fromkeys(("freq1_hz", "freq2_hz"), "no swing frequency (turned over, or < 1 cycle)"),
    **dict.fromkeys(("decay1_per_s", "decay2_per_s"), "no decay (at rest)"),
}
"""The legend of a scatter map's cases without a value that did not diverge, by feature."""


def _scatter(
    path: Path,
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    names: tuple[str, ...],
    feature: str,
    title: str,
    logs: tuple[bool, ...],
    marks: NDArray[np.bool_] | None = None,
    diverged: NDArray[np.bool_] | None = None,
) -> Path:
    fig, ax = plt.subplots(figsize=(7.5, 5.5), dpi=110)
    ok = np.isfinite(y)
    points = ax.scatter(x[ok, 1], x[ok, 0], c=y[ok], s=12, cmap="viridis")
    broke = ~ok & (diverged if diverged is not None else True)
    blank = ~ok & ~broke  # a value the feature does not have (a turned-over pendulum's frequency), not a failure
    if blank.any():
        ax.scatter(x[blank, 1], x[blank, 0], marker=".", color="0.7", s=8, label=NO_VALUE.get(feature, "no value"))
    if broke.any():
        ax.scatter(x[broke, 1], x[broke, 0], marker="x", color="tab:red", s=14, label="diverged")
    if (~ok).any():
        ax.legend(loc="upper left", bbox_to_anchor=(1.25, 1.0), fontsize=8)
    _ring(ax, x[:, 1], x[:, 0], marks, 1.25)
    fig.colorbar(points, ax=ax, label=label(feature))
    return _two_inputs_drawn(fig, ax, path, names, title, logs)


def _panels(
    path: Path,
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    names: tuple[str, ...],
    feature: str,
    title: str,
    logs: tuple[bool, ...],
    marks: NDArray[np.bool_] | None = None,
) -> Path:
    cols = min(3, len(names))
    rows = -(-len(names) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows + 0.8), dpi=110, squeeze=False)
    for k, ax in enumerate(axes.flat):
        if k >= len(names):
            ax.axis("off")
            continue
        ax.plot(x[:, k], y, ".", markersize=3)
        _ring(ax, x[:, k], y, marks, None)  # the title says what the rings are
        if logs[k]:
            ax.set_xscale("log")
        ax.set_xlabel(label(names[k]))
        ax.set_ylabel(label(feature))
        ax.grid(True, alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return figures.save_figure(fig, path, replace=True, crop=False)


def _bifurcation(
    path: Path, x: NDArray[np.float64], samples: list[list[float]], xname: str, title: str, logs: tuple[bool, ...]
) -> Path:
    xs = np.concatenate([np.full(len(s), v) for v, s in zip(x, samples, strict=True)]) if samples else np.zeros(0)
    ys = np.concatenate([np.asarray(s, dtype=float) for s in samples]) if samples else np.zeros(0)
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=110)
    ax.plot(xs, ys, ",", color="black", alpha=0.6)
    if logs[0]:
        ax.set_xscale("log")
    ax.set_xlabel(label(xname))
    ax.set_ylabel(label("poincare_phi2_rad"))
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    return figures.save_figure(fig, path, replace=True, crop=False)
