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
