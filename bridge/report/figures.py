"""The one way pendsim writes a figure: ``save_figure`` checks that no legend covers a plot area,
writes the PNG atomically (``pendsim_bridge.io.outputs.atomic_output``: a temporary file published
when complete) and closes the figure. Every PNG writer (``plots``, ``analysis_report``,
``sweep_plots``) calls it as ``figures.save_figure``, so that a test can watch every figure at one
place.

Legends go to the right of their axes (``legend_outside``) or below the plots, never over data.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from ..io.outputs import atomic_output

CROP = {"bbox_inches": "tight", "pad_inches": 0.1}
"""``savefig``'s arguments for a figure cropped to what is drawn (the legends outside the axes
included), with a margin of 0.1 in."""


def legend_outside(ax: Any, *, fontsize: float = 7) -> None:
    """The axes' legend to the right of the plot area, never over the data."""
    ax.legend(fontsize=fontsize, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, frameon=False)


def covered_plots(fig: Any) -> list[str]:
    """The plot areas a legend of ``fig`` overlaps (each named by its title, else its y label);
    empty when every legend lies outside every axes. Measured as the figure is laid out now, with
    its own renderer (no drawing)."""
    renderer = fig.canvas.get_renderer()
    areas = [(ax, ax.get_window_extent(renderer)) for ax in fig.axes]
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None] + list(fig.legends)
    covered = []
    for legend in legends:
        box = legend.get_window_extent(renderer)
        for ax, area in areas:
            if box.x0 < area.x1 and area.x0 < box.x1 and box.y0 < area.y1 and area.y0 < box.y1:
                covered.append(ax.get_title() or ax.get_ylabel() or "an untitled plot")
    return covered


def save_figure(fig: Any, path: str | Path, *, replace: bool = False, crop: bool = True) -> Path:
    """Write ``fig`` as a PNG to ``path`` and close it.

    Args:
      fig: a matplotlib figure, laid out (``tight_layout``) as it is to be written.
      path: the .png file.
      replace: replace an existing file (otherwise one is an ``OutputError``).
      crop: cropped to what is drawn (``CROP``); False: the figure's own size.

    Returns:
      ``path``.

    Raises:
      ValueError: a legend covers a plot area (nothing is written).
      OutputError: the file cannot be written.
    """
    path = Path(path)
    try:
        covered = covered_plots(fig)
        if covered:
            raise ValueError(f"{path.name}: a legend covers the plot {covered[0]!r}")
        with atomic_output(path, replace=replace) as tmp:
            fig.savefig(tmp, format="png", **(CROP if crop else {}))
    finally:
        plt.close(fig)
    return path
