"""PNG plots (matplotlib, no display needed)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib import ticker

from pendsim_mj.allan import AllanCurve, NoiseTerms

AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")


def allan_plot(
    curves: Sequence[AllanCurve],
    terms: Sequence[NoiseTerms],
    labels: Sequence[str],
    *,
    title: str,
    unit: str,
    path: str | Path,
) -> Path:
    """Log-log Allan deviation of several axes with confidence bands; tau = 1/fs marked.

    Args:
      curves, terms, labels: one per axis.
      title: figure title.
      unit: the data's unit, for the y label (e.g. "m/s^2").
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
        if term.white is not None:
            parts.append(f"N={term.white:.3g}")
        if term.bias_instability is not None:
            parts.append(f"B={term.bias_instability:.3g}")
        if term.rate_random_walk is not None:
            parts.append(f"K={term.rate_random_walk:.3g}")
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
    ax.set_title(title)
    ax.grid(True, which="major", alpha=0.3)
    ax.xaxis.set_minor_formatter(ticker.NullFormatter())
    ax.yaxis.set_minor_formatter(ticker.NullFormatter())
    ax.xaxis.set_major_formatter(ticker.LogFormatter())
    ax.yaxis.set_major_formatter(ticker.LogFormatter())
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path


def validation_figures(report, directory: str | Path) -> list[Path]:
    """The paper's Figures 9-15 for a ValidationReport: measured against computed (MuJoCo and
    the planar reference, from the estimated release; MuJoCo from the nominal 30 deg dashed)."""
    from bridge.validate import QUANTITIES

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    short = next(c.window for c in report.cases if c.window != "whole")

    def series(quantity: str, window: str):
        m = report.case("mujoco", "estimated", window).comparisons[quantity]
        r = report.case("reference", "estimated", window).comparisons[quantity]
        n = report.case("mujoco", "nominal", window).comparisons[quantity]
        return m, r, n

    figures = [
        ("fig09_tangential_acceleration_m1", "tangential_m1", short),
        ("fig10_normal_acceleration_m1", "normal_m1", short),
        ("fig11_phi1", "phi1", short),
        ("fig12_phi1", "phi1", "whole"),
        ("fig13_omega1", "omega1", short),
        ("fig15_omega2", "omega2", "whole"),
    ]
    out = []
    for stem, quantity, window in figures:
        m, r, n = series(quantity, window)
        label, unit, what = QUANTITIES[quantity]
        fig, ax = plt.subplots(figsize=(9, 4.2), dpi=100)
        ax.plot(m.t_s, m.measured, color="black", linewidth=1.0, label="measured (IMU)")
        ax.plot(m.t_s, m.computed, color="tab:orange", linewidth=1.0, label="computed: MuJoCo, estimated release")
        ax.plot(r.t_s, r.computed, color="tab:blue", linewidth=0.8, linestyle=":", label="computed: planar reference")
        ax.plot(
            n.t_s,
            n.computed,
            color="tab:green",
            linewidth=0.8,
            linestyle="--",
            label="computed: MuJoCo, nominal 30 deg",
        )
        ax.set_xlabel("time since release t (s)")
        ax.set_ylabel(f"{label} ({unit})")
        ax.set_title(f"{what}, {'first ' + window if window != 'whole' else 'whole run'}")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
        fig.tight_layout()
        path = directory / f"{stem}_{'whole' if window == 'whole' else window.replace(' ', '')}.png"
        fig.savefig(path)
        plt.close(fig)
        out.append(path)
    # Figure 14: Delta, IAE and ISE of phi1 over the short window.
    m = report.case("mujoco", "estimated", short).comparisons["phi1"]
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), dpi=100, sharex=True)
    for ax, values, ylabel in (
        (axes[0], m.delta, "Delta phi1 = computed - measured (rad)"),
        (axes[1], m.iae_curve, "IAE (rad s)"),
        (axes[2], m.ise_curve, "ISE (rad^2 s)"),
    ):
        ax.plot(m.t_s, values, color="tab:red", linewidth=1.0)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[0].set_title(f"phi1 error, MuJoCo from the estimated release, first {short}")
    axes[2].set_xlabel("time since release t (s)")
    fig.tight_layout()
    path = directory / f"fig14_error_phi1_{short.replace(' ', '')}.png"
    fig.savefig(path)
    plt.close(fig)
    out.append(path)
    return sorted(out)


def comparison_figures(comparison, directory: str | Path) -> list[Path]:
    """Planar against spatial: angles, in-plane difference, tilt, envelopes, spectra near f0."""
    from pendsim_mj.comparison import envelope, spectrum_near

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    planar, spatial = comparison.planar, comparison.spatial
    t = planar.t_s
    f0 = comparison.summary["main_frequency_hz"]
    offset_mm = 1000 * comparison.summary["plane_offset_m"]
    out = []

    def save(fig, name):
        fig.tight_layout()
        path = directory / name
        fig.savefig(path)
        plt.close(fig)
        out.append(path)

    fig, axes = plt.subplots(2, 1, figsize=(10, 6), dpi=100, sharex=True)
    for k, ax in enumerate(axes):
        ax.plot(t, planar.phi_rad[:, k], color="tab:blue", linewidth=0.7, label="planar")
        ax.plot(t, spatial.phi_rad[:, k], color="tab:orange", linewidth=0.7, label=f"spatial ({offset_mm:g} mm, tilt)")
        ax.set_ylabel(f"phi{k + 1} (rad)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
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
        ax.legend(fontsize=8, loc="upper right")
    save(fig, "compare_difference_and_tilt.png")

    fig, axes = plt.subplots(2, 2, figsize=(11, 6), dpi=100)
    for k in range(2):
        for name, tr, colour in (("planar", planar, "tab:blue"), ("spatial", spatial, "tab:orange")):
            axes[k, 0].plot(t, envelope(t, tr.phi_rad[:, k]), color=colour, linewidth=0.9, label=name)
            f, m, _ = spectrum_near(t, tr.phi_rad[:, k], f0)
            axes[k, 1].plot(f, m, color=colour, linewidth=0.9, label=name)
        axes[k, 0].set_ylabel(f"envelope of phi{k + 1} (rad)")
        axes[k, 1].set_ylabel(f"|spectrum| of phi{k + 1} (rel.)")
        for ax in axes[k]:
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=8, loc="upper right")
    axes[1, 0].set_xlabel("t (s)")
    axes[1, 1].set_xlabel("frequency (Hz)")
    axes[0, 0].set_title("swing envelope (beats)")
    axes[0, 1].set_title(f"spectrum near the main frequency {f0:.3f} Hz")
    save(fig, "compare_envelope_and_spectrum.png")
    return out
