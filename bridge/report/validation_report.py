"""A validation's results and how they are written: the ``ValidationReport`` that
``pendsim_bridge.run.validate`` makes (per engine, start and window, the paper's metrics of every
validated quantity), its ``report.json`` and figures (``write_outputs``) and its printed table
(``table``).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pendsim_mj.engines import dispatch as engines
from pendsim_mj.engines.dispatch import whole_steps_s
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.estimation.alignment import MeasuredRun
from pendsim_mj.estimation.quantities import VALIDATED
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.params import RigParams

from ..io.outputs import atomic_directory
from ..io.recording_layout import NODES
from .figure_lines import DrawnLines

if TYPE_CHECKING:  # types only: a report loads neither the identification nor scipy
    from pendsim_mj.estimation.identification import DampingFit, LogDecrement, ModalDecrement
    from pendsim_mj.estimation.validation import Comparison

NOMINAL_RELEASE_RAD = (math.pi / 6, 0.0)  # paper: the simulation releases M1 from 30 deg
AT_REST_RAD_S = 0.1  # a start slower than this on both hinges is at rest: compared from 30 deg too


@dataclasses.dataclass(frozen=True)
class Identification:
    """The damping a recording's free decay gives (``run.validate.identify``), and its start."""

    log_decrement: list[LogDecrement]
    fit: DampingFit
    release_angle_rad: tuple[float, float]
    release_time_s: float
    release_rate_rad_s: tuple[float, float] = (0.0, 0.0)
    start_kind: str = "release"
    modal_decrement: ModalDecrement | None = None  # None: a mode without three amplitude peaks
    driven: bool = False  # the fit used the recorded drive; the decrements (free decay only) are skipped
    warnings: tuple[str, ...] = ()  # the alignment's and the fit's (``identification.fit_warnings``), one line each


@dataclasses.dataclass(frozen=True)
class CaseResult:
    """One model against the recording: an engine, from one start, over one window."""

    engine: str
    release: str  # "estimated" or "nominal"
    window: str  # "5 s" or "whole"
    comparisons: dict[str, Comparison]


@dataclasses.dataclass(frozen=True)
class ValidationReport:
    """A validation (``run.validate.validate``): the rig validated, the aligned measured run and
    every case's comparisons."""

    path: Path
    params: RigParams
    damping_source: str
    identification: Identification | None
    run: MeasuredRun
    cases: list[CaseResult]
    mjcf_xml: str | None  # the recording's MJCF attachment, if any
    model_choice: dict[str, Any] | None = None  # --model spatial: planar vs spatial (spatial_validate)
    drive: Drive | None = None  # a driven recording's drive from the start on (every model run has it)
    lines: dict[tuple[str, str, str], DrawnLines] = dataclasses.field(default_factory=dict)
    """What the whole-run figures draw: (engine, release, quantity) -> its lines (``FIGURES``)."""
    model_warnings: tuple[str, ...] = ()
    """The model's own: its run not resolved by its step (``analysis.BlockBalance``)."""

    @property
    def warnings(self) -> tuple[str, ...]:
        """One-line warnings: the alignment's and, with an identified damping, the fit's; the model's."""
        found = self.identification.warnings if self.identification is not None else self.run.warnings
        return found + self.model_warnings

    @functools.cached_property
    def model_run(self) -> Trajectory:
        """MuJoCo from the estimated start with the validated parameters, the whole Trajectory
        (simulated when first asked for: the validation itself keeps only what it compares)."""
        start = self.run.start
        state = [(start.phi_rad, start.omega_rad_s)]
        return _runs("mujoco", self.params, state, self.run.duration_s + 0.02, drive=self.drive)[0]

    def case(self, engine: str = "mujoco", release: str = "estimated", window: str = "whole") -> CaseResult:
        for c in self.cases:
            if (c.engine, c.release, c.window) == (engine, release, window):
                return c
        raise KeyError((engine, release, window))

    @property
    def has_nominal(self) -> bool:
        """The nominal 30 deg release is compared too (the run starts from rest)."""
        return any(c.release == "nominal" for c in self.cases)


def _runs(
    engine: str,
    params: RigParams,
    starts: list[tuple[tuple[float, float], tuple[float, float]]],
    duration_s: float,
    dt_s: float = 0.01,
    drive: Drive | None = None,
) -> list[Trajectory]:
    """One trajectory per start state (angles, rates), computed as one batch (the planar
    reference on its compiled kernel, ``engines.FAST_PATH``), driven by ``drive`` (time 0 at
    the start) or free."""
    engine = engines.FAST_PATH.get(engine, engine)
    phi0 = np.array([s[0] for s in starts], dtype=float)
    omega0 = np.array([s[1] for s in starts], dtype=float)
    batch = engines.run_batch(engine, params, phi0, omega0, whole_steps_s(duration_s, dt_s), dt_s, drive=drive)
    return [batch.member(i) for i in range(len(starts))]  # fmt: skip


def write_outputs(
    report: ValidationReport, out_dir: str | Path, *, plots: bool = True, replace: bool = False
) -> list[Path]:
    """report.json and (with ``plots``) the paper's Figures 9-15 into ``out_dir``, published
    together when all are written (``atomic_directory``: never over files of the same names
    unless ``replace``). Returns the paths written."""
    from .plots import validation_figures  # start-up: matplotlib, only when the figures are drawn

    out = Path(out_dir)
    with atomic_directory(out, replace=replace) as tmp:
        (tmp / "report.json").write_text(json.dumps(report_json(report), indent=1))
        names = ["report.json"] + ([p.name for p in validation_figures(report, tmp)] if plots else [])
    return [out / name for name in names]


def report_json(report: ValidationReport) -> dict[str, Any]:
    """Everything a machine needs: alignment, coverage, damping, and every metric of every case."""

    def clean(v):
        return None if isinstance(v, float) and not math.isfinite(v) else v

    ident = None
    if report.identification is not None:
        i = report.identification
        ident = {
            "log_decrement": [
                {"b_n_m_s": d.b_n_m_s, "a0_rad": d.a0_rad, "at_rad": d.at_rad, "window_s": d.window_s}
                for d in i.log_decrement
            ],
            "modal_decrement": None
            if i.modal_decrement is None
            else {
                "b_n_m_s": i.modal_decrement.b_n_m_s.tolist(),
                "decay_rate_1_s": i.modal_decrement.decay_rate_1_s.tolist(),
                "frequency_hz": i.modal_decrement.frequency_hz.tolist(),
                "window_s": i.modal_decrement.window_s,
            },
            "least_squares": {
                "b_n_m_s": i.fit.b_n_m_s.tolist(),
                "ci95_n_m_s": i.fit.ci95_n_m_s.tolist(),
                "residual_rms_sigma": i.fit.residual_rms_sigma,
                "iterations": i.fit.iterations,
                "seconds": i.fit.seconds,
                "law": i.fit.law,
                "friction_n_m": i.fit.friction_n_m.tolist(),
                "friction_ci95_n_m": i.fit.friction_ci95_n_m.tolist(),
                "timing2_s": i.fit.timing2_s,
                "timing2_ci95_s": i.fit.timing2_ci95_s,
                "laws": [
                    {
                        "law": f.law,
                        "bic": f.bic,
                        "ljung_box_p": list(f.ljung_box_p),
                        "residual_rms_sigma": f.residual_rms_sigma,
                    }
                    for f in i.fit.laws
                ],
            },
        }
    run = report.run
    nodes = {}
    for name, node in zip(NODES, run.nodes, strict=True):
        frame = node.frame
        nodes[name] = {
            "hinge_axis": frame.hinge_axis.tolist(),
            "toward_pivot": frame.toward_pivot.tolist(),
            "tangential": frame.tangential.tolist(),
            "radius_m": frame.radius_m,
            "mirrored_axes": frame.mirrored,
            "frame_fit_rms_m_s2": frame.fit_rms_m_s2,
            "clock_drift_ppm": node.clock.drift_ppm if node.clock is not None else None,
            "fusion_phase_s": node.fusion_phase_s,
            "coverage": node.coverage.summary(),
        }
    return {
        "file": str(report.path),
        "release": {
            "kind": run.start.kind,
            "time_s": run.start.time_s,
            "estimated_angle_rad": list(run.start.phi_rad),
            "estimated_rate_rad_s": list(run.start.omega_rad_s),
            "start_fit_rms_sigma": run.start.fit_rms,
            "start_fit_unexplained": run.start.unexplained,
            "nominal_angle_rad": list(NOMINAL_RELEASE_RAD) if report.has_nominal else None,
        },
        "nodes": nodes,
        "relative_timing_range_s": None if run.relative_timing_range_s is None else list(run.relative_timing_range_s),
        "relative_timing_s": run.relative_timing_s,
        "warnings": list(report.warnings),
        "max_gap_s": run.max_gap_s,
        "damping": {
            "source": report.damping_source,
            "b1_n_m_s": report.params.b1_n_m_s,
            "b2_n_m_s": report.params.b2_n_m_s,
        },
        "identification": ident,
        **({"model_choice": report.model_choice} if report.model_choice is not None else {}),
        "cases": [
            {
                "engine": c.engine,
                "release": c.release,
                "window": c.window,
                "metrics": {q: {k: clean(v) for k, v in cmp.summary().items()} for q, cmp in c.comparisons.items()},
            }
            for c in report.cases
        ],
    }


def start_words(kind: str, phi_rad: Sequence[float], omega_rad_s: Sequence[float]) -> tuple[str, str]:
    """How a run starts ("release" found after a hold, "in motion" at the first samples, "given"),
    in words, and the state it starts from, each value named: what validate and identify say.
    A start "in motion" slower than ``AT_REST_RAD_S`` on both hinges is a release at the
    recording's start (``pendsim record``'s default: no hold)."""
    at_rest = max(abs(w) for w in omega_rad_s) < AT_REST_RAD_S
    how = {
        "release": "release from rest found",
        "in motion": (
            "no hold before the release: the recording starts at its release (at rest within "
            f"{AT_REST_RAD_S:g} rad/s); the model starts from its first samples"
            if at_rest
            else "no hold before the release: the recording starts in motion; the model starts from its first samples"
        ),
        "given": "start given",
    }[kind]

    def deg(value: float) -> str:
        return f"{round(math.degrees(value), 2) + 0.0:.2f}"  # no "-0.00"

    state = f"phi1 {deg(phi_rad[0])} deg, phi2 {deg(phi_rad[1])} deg"
    if kind != "release":
        state += f", omega1 {deg(omega_rad_s[0])} deg/s, omega2 {deg(omega_rad_s[1])} deg/s"
    return how, state


def start_line(path: str | Path, run: MeasuredRun) -> str:
    """Where the run starts, how, and from what state; one line."""
    s = run.start
    how, state = start_words(s.kind, s.phi_rad, s.omega_rad_s)
    note = f"; {s.fit_note()}" if s.poor_fit else ""
    return f"{path}: {how}, at {s.time_s:.3f} s on the recording's clock; from {state}{note}"


def _before(count: int) -> str:
    return f" from the start, {count} before it" if count else ""


def coverage_line(run: MeasuredRun) -> str:
    """How much of the run each node's samples cover; one line."""
    parts = []
    for name, node in zip(NODES, run.nodes, strict=True):
        c = node.coverage
        part = (
            f"{name} {100 * c.covered_fraction:.1f} % ({c.samples} samples{_before(node.before_start)}, "
            f"{100 * c.lost_fraction:.1f} % lost, "
            f"{c.gaps} gaps over {run.max_gap_s:g} s, longest {c.longest_gap_s:.3f} s"
        )
        if node.clock is not None and abs(node.clock.drift_ppm) >= 1:
            part += f", clock {node.clock.drift_ppm:+.0f} ppm"
        parts.append(part + ")")
    return f"covered: {'; '.join(parts)}"


def table(report: ValidationReport) -> str:
    """Per quantity: measured and computed frequency and delta, max |Delta|, IAE, ISE."""
    lines = [
        start_line(report.path, report.run),
        coverage_line(report.run),
        f"damping {report.damping_source}: b1 = {report.params.b1_n_m_s:.5g}, "
        f"b2 = {report.params.b2_n_m_s:.5g} N m s/rad",
        *(f"warning: {w}" for w in report.warnings),
    ]
    for case in report.cases:
        if case.release != "estimated":
            continue
        lines.append("")
        lines.append(f"{case.engine} model, from the estimated start, {case.window}:")
        head = f"  {'quantity':14} {'f meas (Hz)':>11} {'f comp (Hz)':>11} {'delta':>9}"
        lines.append(f"{head} {'max|Delta|':>11} {'IAE':>10} {'ISE':>10}  unit")
        for q in VALIDATED:
            cmp = case.comparisons[q.name]
            lines.append(
                f"  {q.label:14} {cmp.f_measured_hz:11.5f} {cmp.f_computed_hz:11.5f} {cmp.delta_f:9.2e} "
                f"{cmp.max_abs:11.4g} {cmp.iae:10.4g} {cmp.ise:10.4g}  {q.unit}"
            )
    if report.model_choice is not None:
        lines += choice_lines(report.model_choice, report.model_choice["plane_offset_m"])
    if report.has_nominal:
        nominal = report.case("reference", "nominal", "whole").comparisons["phi1"]
        lines.append("")
        lines.append(
            "from the nominal 30 deg at rest instead (the paper's simulation, on the planar reference; compared "
            "because the estimated start "
            f"is at rest within {AT_REST_RAD_S:g} rad/s): phi1 max|Delta| {nominal.max_abs:.4g} rad, "
            f"IAE {nominal.iae:.4g} rad s over the whole run"
        )
    return "\n".join(lines)


def choice_lines(choice: dict[str, Any], offset_m: float) -> list[str]:
    """The printed comparison of the planar and the spatial model."""
    lines = [
        "",
        f"planar vs spatial model ({1000 * offset_m:g} mm between the planes, tilt freedoms), MuJoCo, "
        "from the estimated start, whole run:",
        f"  {'quantity':14} {'rms planar':>11} {'rms spatial':>11} {'delta planar':>12} {'delta spatial':>13}  better",
    ]
    for name, q in choice["quantities"].items():
        d = [f"{v:.2e}" if v is not None else "-" for v in (q["delta_f"]["planar"], q["delta_f"]["spatial"])]
        lines.append(
            f"  {name:14} {q['rms']['planar']:11.4g} {q['rms']['spatial']:11.4g} {d[0]:>12} {d[1]:>13}  {q['better']}"
            f"  ({q['unit']})"
        )
    o = choice["overall"]
    lines.append(
        f"  overall (mean rms / std of the measured): planar {o['planar']:.4g}, spatial {o['spatial']:.4g}: "
        f"the {choice['better']} model fits better"
    )
    return lines
