"""PNG plots (matplotlib, no display needed)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib import ticker

from pendsim_mj.allan.deviation import AllanCurve, NoiseTerms
from pendsim_mj.estimation.analysis import carrier_envelope
from pendsim_mj.estimation.quantities import BY_NAME

from ..io.outputs import atomic_directory
from . import figures
from .figure_lines import FIGURES, broken, drawn_lines
from .figures import legend_outside

AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")


def allan_plot(
    curves: Sequence[AllanCurve],
    terms: Sequence[NoiseTerms],
    labels: Sequence[str],
    *,
    title: str,
    unit: str,
    term_units: tuple[str, str, str],
    path: str | Path,
) -> Path:
    """Log-log Allan deviation of several axes with confidence bands; tau = 1/fs marked.

    Args:
      curves, terms, labels: one per axis.
      title: figure title.
      unit: the data's unit, for the y label (e.g. "m/s^2").
      term_units: the noise terms' units (N, B, K), for the legend (``allan_report.TERM_UNITS``).
      path: output .png.
    """
    fig, ax = plt.subplots(figsize=(7.5, 5.5), dpi=110)
    for curve, term, label, colour in zip(curves, terms, labels, AXIS_COLOURS, strict=False):
        pct = round(100 * curve.confidence)
        ax.fill_between(
            curve.tau_s, curve.low, curve.high, color=colour, alpha=0.2, linewidth=0, label=f"{label} {pct} % CI"
        )
        ax.loglog(curve.tau_s, curve.adev, color=colour, linewidth=1.4, label=label)
        ax.plot(curve.tau_s[0], curve.adev[0], "o", color=colour, markersize=6, markeredgecolor="black")
        parts = []
        n_unit, b_unit, k_unit = term_units
        if term.white is not None:
            parts.append(f"N={term.white:.3g} {n_unit}")
        if term.bias_instability is not None:
            parts.append(f"B={term.bias_instability:.3g} {b_unit}")
        if term.rate_random_walk is not None:
            parts.append(f"K={term.rate_random_walk:.3g} {k_unit}")
        if parts:
            ax.plot([], [], " ", label=f"  {label}: " + ", ".join(parts))
    tau0 = curves[0].tau_s[0]
    ax.axvline(tau0, color="grey", linestyle=":", linewidth=1)
    ax.annotate(
        f"tau = 1/{curves[0].rate_hz:g} s",
        (tau0, ax.get_ylim()[0]),
        xytext=(4, 6),
        textcoords="offset points",
        fontsize=8,
    )
    ax.set_xlabel("averaging time tau (s)")
    ax.set_ylabel(f"overlapping Allan deviation ({unit})")
    ax.set_title(title, y=1.0, pad=6)  # a fixed place: no search for overlapping tick labels
    ax.grid(True, which="major", alpha=0.3)
    # decades only: a log axis' minor ticks cost a third of the drawing (0.06 s per plot)
    ax.minorticks_off()
    ax.xaxis.set_major_formatter(ticker.LogFormatter())
    ax.yaxis.set_major_formatter(ticker.LogFormatter())
    legend_outside(ax)
    return figures.save_figure(fig, path, replace=True)  # cropped to what is drawn: no tight_layout pass needed


def validation_figures(report, directory: str | Path) -> list[Path]:
    """The paper's Figures 9-15 for a ValidationReport: measured against computed (MuJoCo and
    the planar reference, from the estimated start; the reference from the nominal 30 deg, the
    paper's simulation, dashed when the run starts from rest). Lines break at gaps in the
    samples; a long run's lines are drawn as their envelopes (``figure_lines.envelope``; the
    whole run's as ``validate`` kept them: ``ValidationReport.lines``)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    short = next(c.window for c in report.cases if c.window != "whole")
    gap = report.run.max_gap_s

    wanted = [(stem, quantity, short if window == "short" else window) for stem, quantity, window in FIGURES]
    out = []
    for stem, quantity, window in wanted:
        m = report.case("mujoco", "estimated", window).comparisons[quantity]
        r = report.case("reference", "estimated", window).comparisons[quantity]
        q = BY_NAME[quantity]
        if window == "whole":  # a long overlay hides the measured line: the differences below it
            fig, (ax, low) = plt.subplots(
                2, 1, figsize=(9, 6), dpi=100, sharex=True, gridspec_kw={"height_ratios": [2.2, 1]}
            )
        else:
            fig, ax = plt.subplots(figsize=(9, 4.2), dpi=100)
        if window == "whole":  # the whole run's lines, reduced when compared (ValidationReport.lines)
            m_lines = report.lines[("mujoco", "estimated", quantity)]
            r_lines = report.lines[("reference", "estimated", quantity)]
        else:
            m_lines = drawn_lines(m.t_s, m.measured, m.computed, gap, with_measured=True)
            r_lines = drawn_lines(r.t_s, r.measured, r.computed, gap)
        assert m_lines.measured is not None
        ax.plot(*m_lines.measured, color="black", linewidth=1.0, label="measured (IMU)")
        label = "computed: MuJoCo, estimated start"
        ax.plot(*m_lines.computed, color="tab:orange", linewidth=1.0, label=label)
        label = "computed: planar reference, estimated start"
        ax.plot(*r_lines.computed, color="tab:blue", linewidth=0.8, linestyle=":", label=label)
        if report.has_nominal:
            if window == "whole":
                n_line = report.lines[("reference", "nominal", quantity)].computed
            else:
                n = report.case("reference", "nominal", window).comparisons[quantity]
                n_line = drawn_lines(n.t_s, n.measured, n.computed, gap).computed
            label = "computed: planar reference, nominal 30 deg"
            ax.plot(*n_line, color="tab:green", linewidth=0.8, linestyle="--", label=label)
        ax.set_ylabel(f"{q.label} ({q.unit})")
        ax.set_title(f"{q.description}, {'first ' + window if window != 'whole' else 'whole run'}")
        ax.grid(True, alpha=0.3)
        legend_outside(ax)
        if window == "whole":
            assert m_lines.difference is not None and r_lines.difference is not None
            label = "MuJoCo, estimated start"
            low.plot(*m_lines.difference, color="tab:orange", linewidth=0.8, label=label)
            label = "planar reference, estimated start"
            low.plot(*r_lines.difference, color="tab:blue", linewidth=0.6, linestyle=":", label=label)
            low.axhline(0.0, color="black", linewidth=0.6)
            low.set_ylabel(f"computed - measured ({q.unit})", fontsize=8)
            low.grid(True, alpha=0.3)
            legend_outside(low)
            ax = low
        ax.set_xlabel("time since the start t (s)")
        fig.tight_layout()
        name = f"{stem}_{'whole' if window == 'whole' else window.replace(' ', '')}.png"
        out.append(figures.save_figure(fig, directory / name, replace=True))
    # Figure 14: Delta, IAE and ISE of phi1 over the short window.
    m = report.case("mujoco", "estimated", short).comparisons["phi1"]
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), dpi=100, sharex=True)
    t, delta, iae, ise = broken(m.t_s, m.delta, m.iae_curve, m.ise_curve, max_gap_s=gap)
    for ax, values, ylabel in (
        (axes[0], delta, "Delta phi1 = computed - measured (rad)"),
        (axes[1], iae, "IAE (rad s)"),
        (axes[2], ise, "ISE (rad^2 s)"),
    ):
        ax.plot(t, values, color="tab:red", linewidth=1.0)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[0].set_title(f"phi1 error, MuJoCo from the estimated start, first {short}")
    axes[2].set_xlabel("time since the start t (s)")
    fig.tight_layout()
    out.append(figures.save_figure(fig, directory / f"fig14_error_phi1_{short.replace(' ', '')}.png", replace=True))
    return sorted(out)


def comparison_figures(comparison, directory: str | Path) -> list[Path]:
    """Planar against spatial: angles, in-plane difference, tilt, envelopes, spectra near f0."""
    from pendsim_mj.estimation.comparison import spectrum_near  # start-up: scipy and MuJoCo, for comparisons only

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    planar, spatial = comparison.planar, comparison.spatial
    t = planar.t_s
    f0 = comparison.main_frequency_hz
    offset_mm = 1000 * comparison.plane_offset_m
    out = []

    def save(fig, name):
        fig.tight_layout()
        out.append(figures.save_figure(fig, directory / name, replace=True))

    fig, axes = plt.subplots(2, 1, figsize=(10, 6), dpi=100, sharex=True)
    for k, ax in enumerate(axes):
        ax.plot(t, planar.phi_rad[:, k], color="tab:blue", linewidth=0.7, label="planar")
        ax.plot(t, spatial.phi_rad[:, k], color="tab:orange", linewidth=0.7, label=f"spatial ({offset_mm:g} mm, tilt)")
        ax.set_ylabel(f"phi{k + 1} (rad)")
        ax.grid(True, alpha=0.3)
        legend_outside(ax, fontsize=8)
    axes[0].set_title("in-plane angles, planar and spatial, same release")
    axes[1].set_xlabel("t (s)")
    save(fig, "compare_angles.png")

    fig, axes = plt.subplots(2, 1, figsize=(10, 5.5), dpi=100, sharex=True)
    for k in range(2):
        axes[0].plot(t, spatial.phi_rad[:, k] - planar.phi_rad[:, k], linewidth=0.8, label=f"phi{k + 1}")
        axes[1].plot(t, spatial.tilt_rad[:, k], linewidth=0.8, label=f"tilt of M{k + 1}")
    axes[0].set_ylabel("spatial - planar (rad)")
    axes[0].set_title("in-plane angle difference")
    axes[1].set_ylabel("out-of-plane tilt (rad)")
    axes[1].set_title("out-of-plane motion (spatial)")
    axes[1].set_xlabel("t (s)")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        legend_outside(ax, fontsize=8)
    save(fig, "compare_difference_and_tilt.png")

    fig, axes = plt.subplots(2, 2, figsize=(11, 6), dpi=100)
    for k in range(2):
        for name, tr, colour in (("planar", planar, "tab:blue"), ("spatial", spatial, "tab:orange")):
            axes[k, 0].plot(t, carrier_envelope(t, tr.phi_rad[:, k]), color=colour, linewidth=0.9, label=name)
            f, m, _ = spectrum_near(t, tr.phi_rad[:, k], f0)
            axes[k, 1].plot(f, m, color=colour, linewidth=0.9, label=name)
        axes[k, 0].set_ylabel(f"carrier-band envelope of phi{k + 1} (rad)")
        axes[k, 1].set_ylabel(f"|spectrum| of phi{k + 1} (rel.)")
        for ax in axes[k]:
            ax.grid(True, alpha=0.3)
    legend_outside(axes[0, 1], fontsize=8)  # one key for all four: to the right of the right column
    axes[1, 0].set_xlabel("t (s)")
    axes[1, 1].set_xlabel("frequency (Hz)")
    axes[0, 0].set_title("swing envelope (beats)")
    axes[0, 1].set_title(f"spectrum near the main frequency {f0:.3f} Hz")
    save(fig, "compare_envelope_and_spectrum.png")
    return out


COMPARISON_FILES = (
    "summary.json", "compare_angles.png", "compare_difference_and_tilt.png", "compare_envelope_and_spectrum.png",
)  # fmt: skip


def write_comparison(comparison, out_dir: str | Path, *, replace: bool = False) -> list[Path]:
    """summary.json and the three comparison PNGs (``COMPARISON_FILES``) into ``out_dir``,
    published together (never over files of the same names unless ``replace``)."""
    out = Path(out_dir)
    with atomic_directory(out, replace=replace) as tmp:
        (tmp / "summary.json").write_text(json.dumps(comparison.to_json(), indent=1))
        names = ["summary.json"] + [p.name for p in comparison_figures(comparison, tmp)]
    return [out / name for name in names]
