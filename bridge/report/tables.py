"""Plain-text tables of results, as the commands print them (one function per result type)."""

from __future__ import annotations

import math
from pathlib import Path

from pendsim_mj.estimation.analysis import RunSummary
from pendsim_mj.estimation.comparison import Comparison3D
from pendsim_mj.units import seconds

from ..io.mcap.reader import McapContents
from ..io.recording_layout import UNIX_2000_S, utc_iso
from .validation_report import Identification, start_words


def run_summary(summary: RunSummary, engine: str, *, dry_friction: bool = False) -> str:
    """``pendsim simulate``: frequencies, amplitudes and the energy balance. With ``dry_friction``
    (either hinge's): how this engine's friction ends a swing, and on MuJoCo, whose friction is a
    soft constraint that the dissipation's ideal law counts only nearly, its part of the residual."""
    s = summary
    lines = [
        f"engine {engine}, {s.duration_s:g} s at dt = {s.dt_s:g} s ({s.samples} samples)",
        f"{'':6} {'dominant f (Hz)':>16} {'first peak (deg)':>17} {'last peak (deg)':>16}   (peaks of |phi|)",
    ]
    for k, name in enumerate(("phi1", "phi2")):
        start, end = math.degrees(s.start_amplitude_rad[k]), math.degrees(s.end_amplitude_rad[k])
        turned = s.largest_rad[k] > math.pi  # |phi| then counts its turns (11397 deg after 31): no swing's peak
        # a decay's or a drift's peak (below one cycle), or the ramp of a pendulum that turned over
        swing = s.swing_hz(k)
        why = "n/a (turned over)" if s.largest_rad[k] > math.pi else "n/a (< 1 cycle)"
        f = f"{swing:16.4f}" if math.isfinite(swing) else f"{why:>16}"
        peaks = f"{start:17.3f} {end:16.3f}" if not turned else f"{'n/a':>17} {'n/a':>16}"
        lines.append(f"{name:6} {f} {peaks}")
    e0 = s.energy_start_j
    share = f" ({100 * abs(s.energy_lost_j) / e0:.1f} % of the initial {e0:.4g} J)" if e0 > 0 else ""
    change = "lost" if s.energy_lost_j >= 0 else "gained"
    lines.append(
        f"energy {change} {abs(s.energy_lost_j):.6g} J{share}; "
        f"dissipated by the hinges (damping, friction) {s.dissipated_j:.6g} J"
    )
    if s.input_work_j:
        lines.append(f"work done by the drive {s.input_work_j:.6g} J")
    soft = dry_friction and engine == "mujoco"
    what = "integration error" + (
        ", and MuJoCo's soft dry friction against the ideal law the dissipation counts" if soft else ""
    )
    lines.append(f"energy balance residual {s.balance_residual_j:.3g} J ({what}; large means reduce --dt-s)")
    if dry_friction:  # the engines' laws agree while it swings, not once it has stopped (docs/identification.md)
        lines.append(
            "dry friction: MuJoCo's soft constraint holds a pendulum off-centre where it stops and lets it creep "
            "down over tens of seconds, the planar engines' smoothed law within seconds: their last peaks differ "
            f"once a swing has died (this run: {engine}; docs/identification.md)"
        )
    return "\n".join(lines)


def contents_table(contents: McapContents) -> str:
    """``pendsim inspect``: topics with schema, count and rate; duration; metadata; attachments."""
    lines = [f"{contents.path}: {contents.file_size / 1e6:.2f} MB, {contents.chunks} chunks, complete"]
    starts = [int(m.log_time_ns[0]) for m in contents.messages.values() if len(m)]
    ends = [int(m.log_time_ns[-1]) for m in contents.messages.values() if len(m)]
    if starts:
        t0, t1 = seconds(min(starts)), seconds(max(ends))
        lines.append(f"duration {t1 - t0:.3f} s (log time {t0:.3f} to {t1:.3f} s)")
        if t0 >= UNIX_2000_S:
            lines.append(f"starts {utc_iso(min(starts))} (log times are UTC)")
        else:
            lines.append(
                "log times are not UTC (as UTC they would fall in 1970): relative to the source's own zero, such as "
                "a node's boot (pendsim import --start-utc places them)"
            )
    lines.append(f"{'topic':32} {'schema':30} {'messages':>9} {'rate (Hz)':>10}")
    for cid, ch in sorted(contents.channels.items(), key=lambda kv: kv[1].topic):
        data = contents.messages.get(cid)
        count = len(data) if data is not None else 0
        span = seconds(int(data.log_time_ns[-1] - data.log_time_ns[0])) if data is not None and count > 1 else 0.0
        rate = f"{(count - 1) / span:10.2f}" if span > 0 else f"{'-':>10}"
        schema = contents.schemas[ch.schema_id].name if ch.schema_id in contents.schemas else "?"
        lines.append(f"{ch.topic:32} {schema:30} {count:9d} {rate}")
    for name, values in sorted(contents.metadata.items()):
        lines.append(f"metadata {name}:")
        lines += [f"  {k} = {v}" for k, v in values.items()]
    for name, a in sorted(contents.attachments.items()):
        lines.append(f"attachment {name} ({a.media_type}, {len(a.data)} bytes)")
    return "\n".join(lines)


def identification_table(path: str | Path, result: Identification) -> str:
    """``pendsim identify``: the release, the log decrement and the least-squares fit."""
    how, state = start_words(result.start_kind, result.release_angle_rad, result.release_rate_rad_s)
    lines = [f"{path}: {how}, at {result.release_time_s:.3f} s; from {state}"]
    if result.driven:
        lines.append(
            "driven recording: log and per-mode decrement skipped (they assume a free decay); "
            "the least-squares fit below is driven by the recorded /drive inputs"
        )
    else:
        lines.append(
            "log decrement b = 2 J ln(A0/AT)/t1 (the paper's, per pendulum; biased on the coupled rig: b2 off by"
            " -83 to +108 % on synthetic runs, docs/identification.md):"
        )
    for n, d in enumerate(result.log_decrement, start=1):
        lines.append(
            f"  b{n} = {d.b_n_m_s:.5g} N m s/rad  (A0 {math.degrees(d.a0_rad):.3f} deg, "
            f"AT {math.degrees(d.at_rad):.3f} deg, t1 {d.window_s:.2f} s)"
        )
    m = result.modal_decrement
    if result.driven:
        pass
    elif m is None:
        lines.append("per-mode decrement: not measured (a mode without three amplitude peaks in the window)")
    else:
        lines.append(
            "per-mode decrement (decay of each linearised mode's amplitude, modal damping taken diagonal; "
            "small swings: within 0.1 % up to 10 deg, 0.7 % at 30 deg):"
        )
        lines.append(
            f"  b1 = {m.b_n_m_s[0]:.5g}, b2 = {m.b_n_m_s[1]:.5g} N m s/rad  (mode decay rates "
            f"{m.decay_rate_1_s[0]:.4g}, {m.decay_rate_1_s[1]:.4g} 1/s at {m.frequency_hz[0]:.3f}, "
            f"{m.frequency_hz[1]:.3f} Hz; {m.peaks[0]}, {m.peaks[1]} peaks over {m.window_s:.0f} s)"
        )
    fit = result.fit
    lines.append(
        f"least squares on both gyros ({fit.method}, start state fitted too; {fit.iterations} iterations, "
        f"{fit.seconds:.1f} s), {fit.law} law"
        + (" (NOT chosen: the model does not fit, see below):" if fit.misfit else ":")
    )
    if fit.law != "coulomb":
        for n in range(2):
            lines.append(f"  b{n + 1} = {fit.b_n_m_s[n]:.5g} +- {fit.ci95_n_m_s[n]:.2g} N m s/rad (95 %)")
    if fit.law != "viscous":
        for n in range(2):
            lines.append(
                f"  F{n + 1} = {fit.friction_n_m[n]:.5g} +- {fit.friction_ci95_n_m[n]:.2g} N m (95 %, dry friction)"
            )
    if fit.timing2_s is not None:
        lines.append(
            f"  M2's values {1e3 * fit.timing2_s:+.3f} +- {1e3 * fit.timing2_ci95_s:.2g} ms against M1's "
            "(the nodes' relative fusion timing, fitted within what the alignment leaves open)"
        )
    lines.append(f"  residual rms {fit.residual_rms_sigma:.3f} gyro noise sigmas (1 = explained to the noise level)")
    if fit.laws:
        lines.append("damping law by BIC (smallest wins), residual whiteness by Ljung-Box (p > 0.05: white):")
        for f in fit.laws:
            mark = "  <- chosen" if f.law == fit.law and not fit.misfit else ""
            lines.append(
                f"  {f.law:8} BIC {f.bic:12.1f}  rms {f.residual_rms_sigma:.3f} sigma  "
                f"Ljung-Box p {f.ljung_box_p[0]:.2g} (m1), {f.ljung_box_p[1]:.2g} (m2){mark}"
            )
    lines += [f"warning: {w}" for w in result.warnings]
    return "\n".join(lines)


def comparison_table(result: Comparison3D) -> str:
    """``pendsim compare``: per pendulum the in-plane difference, tilt and beats."""
    s = result
    phi1, phi2 = (math.degrees(a) for a in s.release_rad)
    lines = [
        f"planar vs spatial ({1000 * s.plane_offset_m:g} mm between the planes, tilt freedoms), "
        f"{s.duration_s:g} s from {phi1:g} deg, {phi2:g} deg; main frequency {s.main_frequency_hz:.4f} Hz",
        f"{'':4} {'max|dphi| (deg)':>16} {'>1 deg after (s)':>17} {'tilt amp (deg)':>15} "
        f"{'beat planar':>12} {'beat spatial':>13}",
    ]
    for name, p in s.pendulums.items():
        first = p.first_time_difference_exceeds_1_deg_s
        beats = []
        for variant in ("planar", "spatial"):
            b = p.beats[variant]
            beats.append(f"{b.period_s:.1f} s/{100 * b.depth:.0f}%" if math.isfinite(b.period_s) else "none")
        first_text = f"{first:.2f}" if first is not None else "-"
        row = f"{name:4} {math.degrees(p.in_plane_difference_max_rad):16.2f} {first_text:>17}"
        tilt = math.degrees(p.out_of_plane_amplitude_rad)
        lines.append(f"{row} {tilt:15.2f} {beats[0]:>12} {beats[1]:>13}")
    return "\n".join(lines)
