"""From measured data to numbers: alignment and timing of recordings, validation metrics, damping
identification and fits, signal analysis, planar-versus-spatial comparison. Arrays in, frozen
dataclasses out; no file I/O (``pendsim_bridge`` reads the recordings).

Modules and their jobs:

- ``alignment``: ``align`` turns two IMU nodes' raw samples (``NodeSamples``) into the
  ``MeasuredRun`` a model is compared with: clocks, start (release or in motion), swing frames,
  start state, fusion timing, coverage. Its parts: ``measured_run`` (what it takes and gives),
  ``node_alignment`` (node by node: clocks, start detection, frames' window and signs) and
  ``start_fit`` (the start state's least squares, the nodes' relative fusion timing).
- ``timing``: node clocks against the recorder's, fused-value instants and fusion phase, gaps
  and coverage.
- ``swing_frame``: a node's hinge axis, mounting and angle from its own data.
- ``quantities``: the compared quantities (phi1, omega1, omega2, M1's accelerations).
- ``validation``: the paper's metrics of a measured against a computed series: frequency and its
  relative error delta, max |Delta|, IAE, ISE (``compare``, ``Comparison``).
- ``identification``: hinge damping from a free decay: log decrement (the paper's and per
  mode), the planar least squares (``planar_damping``) and ``mujoco.sysid`` (``fit_damping``).
- ``planar_fit``: the planar least-squares fit of hinge losses and start state, law by BIC.
- ``spatial_identification``: tilt stiffness and damping of the support on the spatial model.
- ``comparison``: planar against spatial runs (frequencies, amplitudes, differences).
- ``analysis``: frequencies, amplitudes, beats, log decrement and run summaries of series.
- ``spectral_peaks``: ``analysis``'s spectral peak and second-peak ratio of many rows at once
  (a quarter-length transform and exact refinement: what a sweep computes).
- ``least_squares``: the room's nonlinear least-squares solvers and which fit uses which.

Importing this package imports none of them (no MuJoCo, numba or scipy): each name below is
imported from its module on first use (``pendsim_mj.lazy``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pendsim_mj import lazy

_LAZY = {
    "MeasuredRun": "pendsim_mj.estimation.alignment",
    "NodeRun": "pendsim_mj.estimation.alignment",
    "NodeSamples": "pendsim_mj.estimation.alignment",
    "StartState": "pendsim_mj.estimation.alignment",
    "align": "pendsim_mj.estimation.alignment",
    "Beat": "pendsim_mj.estimation.analysis",
    "RunSummary": "pendsim_mj.estimation.analysis",
    "beat": "pendsim_mj.estimation.analysis",
    "log_decrement_damping": "pendsim_mj.estimation.analysis",
    "peak_amplitudes": "pendsim_mj.estimation.analysis",
    "spectral_peak_hz": "pendsim_mj.estimation.analysis",
    "summarize": "pendsim_mj.estimation.analysis",
    "zero_crossing_hz": "pendsim_mj.estimation.analysis",
    "Comparison3D": "pendsim_mj.estimation.comparison",
    "compare_planar_spatial": "pendsim_mj.estimation.comparison",
    "DampingFit": "pendsim_mj.estimation.identification",
    "LogDecrement": "pendsim_mj.estimation.identification",
    "ModalDecrement": "pendsim_mj.estimation.identification",
    "fit_damping": "pendsim_mj.estimation.identification",
    "log_decrement": "pendsim_mj.estimation.identification",
    "modal_decrement": "pendsim_mj.estimation.identification",
    "planar_damping": "pendsim_mj.estimation.identification",
    "LawFit": "pendsim_mj.estimation.planar_fit",
    "fit_planar": "pendsim_mj.estimation.planar_fit",
    "QUANTITIES": "pendsim_mj.estimation.quantities",
    "VALIDATED": "pendsim_mj.estimation.quantities",
    "Quantity": "pendsim_mj.estimation.quantities",
    "TiltFit": "pendsim_mj.estimation.spatial_identification",
    "fit_tilt": "pendsim_mj.estimation.spatial_identification",
    "SwingFrame": "pendsim_mj.estimation.swing_frame",
    "fit_swing_frame": "pendsim_mj.estimation.swing_frame",
    "DEFAULT_MAX_GAP_S": "pendsim_mj.estimation.timing",
    "ClockRelation": "pendsim_mj.estimation.timing",
    "Coverage": "pendsim_mj.estimation.timing",
    "Comparison": "pendsim_mj.estimation.validation",
    "compare": "pendsim_mj.estimation.validation",
    "resample": "pendsim_mj.estimation.validation",
}

if TYPE_CHECKING:
    from pendsim_mj.estimation.alignment import MeasuredRun, NodeRun, NodeSamples, StartState, align
    from pendsim_mj.estimation.analysis import (
        Beat,
        RunSummary,
        beat,
        log_decrement_damping,
        peak_amplitudes,
        spectral_peak_hz,
        summarize,
        zero_crossing_hz,
    )
    from pendsim_mj.estimation.comparison import Comparison3D, compare_planar_spatial
    from pendsim_mj.estimation.identification import (
        DampingFit,
        LogDecrement,
        ModalDecrement,
        fit_damping,
        log_decrement,
        modal_decrement,
        planar_damping,
    )
    from pendsim_mj.estimation.planar_fit import LawFit, fit_planar
    from pendsim_mj.estimation.quantities import QUANTITIES, VALIDATED, Quantity
    from pendsim_mj.estimation.spatial_identification import TiltFit, fit_tilt
    from pendsim_mj.estimation.swing_frame import SwingFrame, fit_swing_frame
    from pendsim_mj.estimation.timing import DEFAULT_MAX_GAP_S, ClockRelation, Coverage
    from pendsim_mj.estimation.validation import Comparison, compare, resample
else:
    __getattr__, __dir__ = lazy.exports(__name__, _LAZY)

__all__ = [
    "DEFAULT_MAX_GAP_S",
    "QUANTITIES",
    "VALIDATED",
    "Beat",
    "ClockRelation",
    "Comparison",
    "Comparison3D",
    "Coverage",
    "DampingFit",
    "LawFit",
    "LogDecrement",
    "MeasuredRun",
    "ModalDecrement",
    "NodeRun",
    "NodeSamples",
    "Quantity",
    "RunSummary",
    "StartState",
    "SwingFrame",
    "TiltFit",
    "align",
    "beat",
    "compare",
    "compare_planar_spatial",
    "fit_damping",
    "fit_planar",
    "fit_swing_frame",
    "fit_tilt",
    "log_decrement",
    "log_decrement_damping",
    "modal_decrement",
    "peak_amplitudes",
    "planar_damping",
    "resample",
    "spectral_peak_hz",
    "summarize",
    "zero_crossing_hz",
]
