"""The lines a figure draws of a long series, without matplotlib: broken at gaps (``broken``) and,
over ``ENVELOPE_ABOVE`` points, reduced to their min-max envelope (``envelope``). ``validate``
reduces each whole-run line when its comparison is made (``drawn_lines``), so a long run's figures
hold a few thousand points per line instead of its series (``plots.validation_figures`` draws
them); ``FIGURES`` names the validation's figures and what each draws."""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import ArrayLike

FIGURES = (
    ("fig09_tangential_acceleration_m1", "tangential_m1", "short"),
    ("fig10_normal_acceleration_m1", "normal_m1", "short"),
    ("fig11_phi1", "phi1", "short"),
    ("fig12_phi1", "phi1", "whole"),
    ("fig13_omega1", "omega1", "short"),
    ("fig15_omega2", "omega2", "whole"),
)
"""The paper's Figures 9-13 and 15 (``plots.validation_figures``): (file stem, quantity, window).
The whole-run comparisons keep their metrics only; of the quantities a whole-run figure draws,
the lines it draws are kept, reduced to their envelopes when compared (``drawn_lines``, in
``ValidationReport.lines``), so a long run's memory holds none of its whole-run series."""


Line = tuple[np.ndarray, np.ndarray]
"""A line to draw: its instants (k,) s and values (k,), float64, NaN where it breaks."""

ENVELOPE_BUCKETS = 4000
"""A whole-run line longer than ENVELOPE_ABOVE points is drawn as its envelope: the lowest and the
highest point of each of this many runs of samples (in time order), far more than a figure's
pixel columns, so the picture is the same; memory and drawing time no longer grow with the run."""
ENVELOPE_ABOVE = 50_000


def broken(t: ArrayLike, *series: ArrayLike, max_gap_s: float) -> tuple[np.ndarray, ...]:
    """The instants and series with a NaN inserted in every gap longer than ``max_gap_s``, so
    that lines break there instead of bridging it."""
    t = np.asarray(t, dtype=float)
    cuts = np.flatnonzero(np.diff(t) > max_gap_s) + 1
    if not len(cuts):
        return (t, *(np.asarray(x) for x in series))
    return tuple(np.insert(np.asarray(x, dtype=float), cuts, np.nan) for x in (t, *series))


def envelope(t: ArrayLike, y: ArrayLike, max_gap_s: float) -> Line:
    """(t, y) of a line to draw: itself (NaN-broken at gaps, ``broken``) up to ENVELOPE_ABOVE
    points, else each covered segment's min-max envelope over ENVELOPE_BUCKETS runs of samples,
    segments broken by NaN. A float32 ``y`` is searched as it is (the same points as its float64
    values: the conversion keeps order) and only the kept points are converted."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y)
    if y.dtype != np.float32:
        y = y.astype(float, copy=False)
    if len(t) <= ENVELOPE_ABOVE:
        line_t, line_y = broken(t, y.astype(float, copy=False), max_gap_s=max_gap_s)
        return line_t, line_y
    size = -(-len(t) // ENVELOPE_BUCKETS)
    cuts = np.flatnonzero(np.diff(t) > max_gap_s) + 1
    parts_t: list[ArrayLike] = []
    parts_y: list[ArrayLike] = []
    for lo, hi in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(t)]]), strict=True):
        rows = -(-(hi - lo) // size)
        padded = np.full(rows * size, np.nan, dtype=y.dtype)
        padded[: hi - lo] = y[lo:hi]
        padded = padded.reshape(rows, size)
        first = lo + size * np.arange(rows)
        keep = np.unique(np.concatenate([first + np.nanargmin(padded, axis=1), first + np.nanargmax(padded, axis=1)]))
        parts_t += [t[keep], [np.nan]]
        parts_y += [y[keep].astype(float), [np.nan]]
    return np.concatenate(parts_t[:-1]), np.concatenate(parts_y[:-1])


@dataclasses.dataclass(frozen=True)
class DrawnLines:
    """What a whole-run validation figure draws of one comparison, each an ``envelope``.

    Attributes:
      computed: the model's series.
      measured: the measured series (None: not drawn from this comparison).
      difference: computed - measured (None: not drawn).
    """

    computed: Line
    measured: Line | None = None
    difference: Line | None = None


def drawn_lines(
    t_s: np.ndarray,
    measured: np.ndarray,
    computed: np.ndarray,
    max_gap_s: float,
    *,
    with_measured: bool = False,
    with_difference: bool = False,
) -> DrawnLines:
    """The lines of one comparison (t_s, measured, computed: (n,), each as the figure draws it)
    that a figure draws, reduced as it draws them (``envelope``): computed, and measured and
    computed - measured (in the series' own precision) when asked."""
    difference = None
    if with_difference:
        delta = computed - measured
        difference = envelope(t_s, delta, max_gap_s)
        del delta
    return DrawnLines(
        computed=envelope(t_s, computed, max_gap_s),
        measured=envelope(t_s, measured, max_gap_s) if with_measured else None,
        difference=difference,
    )
