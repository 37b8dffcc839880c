"""What a twin's run says on the terminal: the status line while it runs (``status_text``) and
the summary at its end (``summary_text``: innovations and their whiteness, the fusion timing,
whether the model fits, the forecasts' scores, the tracked parameters, the health checks, alarms
and events, the packets, latency)."""

from __future__ import annotations

import math
from collections.abc import Callable

from pendsim_mj.twin.estimator import TRACKABLE
from pendsim_mj.twin.health import NON_NEGATIVE, time_of_day_utc
from pendsim_mj.twin.session import RUN_MISFIT_NIS

from .pipeline import TwinPipeline, TwinResult


def status_text(pipeline: TwinPipeline, elapsed_s: float) -> str:
    s = pipeline.session
    nis = s.recent_nis()
    alarms = len(pipeline.alarms)
    state = (
        s.waiting_text()
        if math.isnan(s.started_s)
        else (f"phi1 {math.degrees(s.estimator.x[0]):+6.1f} deg  phi2 {math.degrees(s.estimator.x[1]):+6.1f} deg")
    )
    return (
        f"{elapsed_s:6.1f} s  samples m1 {s.samples[0]} m2 {s.samples[1]}  {state}  "
        f"NIS {nis[0]:.2f}/{nis[1]:.2f}  alarms {alarms}"
    )


EVENT_SAID = {
    "held": "the rig is held still: the estimate waits for its release",
    "released": "the rig was released: tracking",
    "tracking": "the rig is swinging: tracking",
    "touched": "touched: the rig stopped moving as its model does (a hand on it?): the estimate waits until "
    "it swings free, the tracked parameters as before",
}
"""The session's own events (``TwinSession.events``) as a live twin says them; others as they are."""


def event_line(at_s: float, what: str, start_utc_ns: int) -> str | None:
    """What a live twin says of a session event at ``at_s`` (s on its clock, with the time of day
    in UTC), or None for an event it has said already (a node's clock jump: said when seen)."""
    if "its clock jumped" in what:
        return None
    return f"twin: {EVENT_SAID.get(what, what)} (at {at_s:.1f} s, {time_of_day_utc(start_utc_ns, at_s)})"


class Narrator:
    """What a running twin (live or replayed) says as it happens: each new alarm and session event
    once (``event_line``), with the twin's seconds and the time of day in UTC (a replay's: that of
    the recorded run). Called with the pipeline's alarms and the session's events so far."""

    def __init__(self, say: Callable[[str], None], start_utc_ns: int) -> None:
        self.say, self.start_utc_ns = say, start_utc_ns
        self.alarms = self.events = 0

    def __call__(self, pipeline: TwinPipeline) -> None:
        for alarm in pipeline.alarms[self.alarms :]:
            self.say(f"twin: alarm: {alarm.describe(self.start_utc_ns)}")
        self.alarms = len(pipeline.alarms)
        events = pipeline.session.events
        for at_s, what in events[self.events :]:  # held, released, touched, checks held...
            line = event_line(at_s, what, self.start_utc_ns)
            if line is not None:
                self.say(line)
        self.events = len(events)


STOPPED = {"duration": "--duration-s reached", "end of recording": "end of the recording"}
"""How the summary's first line says why the run stopped (``TwinResult.stop_reason``)."""
WHITE_P = 0.01  # a channel whose Ljung-Box p-value is at most this is named as not white
TOUCHED_MANY = 5  # a run "touched" this often while its health checks were held: the misfit is named


def summary_text(result: TwinResult) -> str:
    """What a twin's run found, for the terminal."""
    s = result.summary
    stopped = STOPPED.get(result.stop_reason, result.stop_reason)
    timed = bool(s.alarms) or any(what != "tracking" for _, what in s.events)
    lines = [
        f"twin: {stopped} after {result.duration_s:.1f} s of running; samples given to the twin m1 {s.samples[0]}, "
        f"m2 {s.samples[1]}" + (" (times below: s on the twin's clock, from its start)" if timed else "")
    ]
    if math.isnan(s.started_s):
        if min(s.samples) == 0:
            lines.append("the estimator never started: it needs a sample from each node")
        else:
            lines.append(
                "the estimator never started: no pendulum swung free (a node's frame and fusion phase are "
                "learned from its first second of swinging; one that barely swings falls back on gravity 3 s "
                "after the other measures)"
            )
        if result.path is not None:
            lines.append(f"wrote {result.path} ({result.messages} messages: the measured data)")
        return "\n".join(lines)

    def p(value: float) -> str:
        return f"{value:.3f}" if math.isfinite(value) else "n/a (too few)"

    def nis(value: float) -> str:
        return f"{value:.2f}" if math.isfinite(value) else "n/a (none after the first 2 s)"

    lines.append(
        "innovations: mean NIS m1 {}, m2 {} (2 on a healthy rig); whiteness p (angle, rate; > 0.01 white) "
        "m1 {}, {}; m2 {}, {}".format(*(nis(v) for v in s.nis_mean), *(p(v) for node in s.whiteness_p for v in node))
    )
    lines.append(
        "accelerometer: mean NIS m1 {}, m2 {}; whiteness p (tangential, normal) m1 {}, {}; m2 {}, {}".format(
            *(nis(v) for v in s.accel_nis_mean), *(p(v) for node in s.accel_whiteness_p for v in node)
        )
    )
    channels = (
        ("angle", "rate", s.whiteness_p),
        ("accelerometer tangential", "accelerometer normal", s.accel_whiteness_p),
    )
    coloured = [
        f"m{k + 1} {name}"
        for first, second, per_node in channels
        for k, node in enumerate(per_node)
        for name, p_value in zip((first, second), node, strict=True)
        if p_value <= WHITE_P
    ]
    if coloured:
        lines.append(
            f"note: not white (p <= {WHITE_P:g}): {', '.join(coloured)}: the innovations keep some structure the "
            "model does not explain (on healthy emulated runs mostly the angle's: the node states' random walks and "
            "the fused orientation's slow error; docs/twin.md, Whiteness on the whole twin)"
        )
    drifting = [(k, v) for k, v in enumerate(s.phase_drift_ppm) if math.isfinite(v) and v]
    if drifting:
        rates = ", ".join(f"m{k + 1} {v:+.1f} ppm" for k, v in drifting)
        unfollowed = [f"M{k + 1}'s mean NIS {s.nis_mean[k]:.1f}" for k, _ in drifting if s.nis_mean[k] > RUN_MISFIT_NIS]
        lines.append(
            f"fusion timing: the chip's ticks drift on the twin's clock ({rates}; negative: the chip's clock "
            "runs fast), "
            + (
                f"NOT followed well ({', '.join(unfollowed)}: a drift faster than about 200 ppm is not followed)"
                if unfollowed
                else "followed"
            )
            + " (docs/twin.md, Measurement)"
        )
    unsteady = [
        f"M{k + 1}'s at about {ppm:+.0f} ppm, scattered {rms:.1f} ms about that line"
        for k, moving in enumerate(s.phase_moving_unfollowed)
        if moving is not None and s.nis_mean[k] > RUN_MISFIT_NIS
        for ppm, rms in (moving,)
    ]
    if unsteady:
        lines.append(
            f"fusion timing NOT followed: the fusion phase found moves ({'; '.join(unsteady)}) too unsteadily to "
            "follow: the chip's ticks drift faster than the twin can follow (followed in tests up to 200 ppm), or "
            "the node's timing jumped; its values' instants are off by up to a fusion period, and its 'angle "
            "jumped' events are most likely that, not its mount (docs/twin.md, Measurement)"
        )
    unfit = [f"M{k + 1}'s mean NIS {v:.1f}" for k, v in enumerate(s.nis_mean) if v > RUN_MISFIT_NIS]
    unfit += [
        f"M{k + 1}'s accelerometer's mean NIS {v:.1f}" for k, v in enumerate(s.accel_nis_mean) if v > RUN_MISFIT_NIS
    ]
    if unfit:
        lines.append(
            f"warning: the model does not fit the data ({', '.join(unfit)}; 2 on a healthy rig): those estimates "
            "are less certain than their sigmas say (a node's timing the twin does not follow, a drive it is not "
            "given, a fault, or a rig unlike its model: `pendsim calibrate` on its recordings, then --params-file; "
            "docs/twin.md)"
        )
    f = s.forecast
    lows = [0.0, *f.horizon_s][: len(f.horizon_s)]  # each bin's lower edge
    bins = zip(lows, f.horizon_s, f.count, f.rms_error_rad, f.within_3_sigma, strict=True)
    scored = [(lo, h, e, w) for lo, h, n, e, w in bins if n]  # each horizon's own bin (lo, h], not cumulative
    if scored:
        lines.append(
            "forecast, measured afterwards: "
            + "; ".join(
                f"{lo:g}-{h:g} s ahead: rms {math.degrees(e):.3f} deg, {100 * w:.0f} % within 3 sigma"
                for lo, h, e, w in scored
            )
        )
    if s.parameters:
        lines.append("tracked at the end (+- 2 sigma):")
    width = max((len(name) for name in s.parameters), default=0)
    for name, (value, sigma) in s.parameters.items():
        line = f"  {name:<{width}} {value:.5g} +- {2 * sigma:.2g} {TRACKABLE[name][1]}"
        if name in s.stated:
            line += f" (the model's rig: {s.stated[name]:.5g})"
        if name in NON_NEGATIVE and value < 0:
            line += (
                " (below 0, but 0 is within 2 sigma: none found)"
                if value + 2 * sigma >= 0
                else (" (below 0 beyond 2 sigma, which a rig cannot have: the model misses something)")
            )
        lines.append(line)
    held = [what for _, what in s.events if what.startswith("health checks held")]
    touched = sum(what == "touched" for _, what in s.events)
    if math.isnan(s.monitored_from_s) and held:
        lines.append("health: never checked: the model never fitted the data well enough to check (events below)")
    elif math.isnan(s.monitored_from_s) and touched:
        lines.append(
            f"health: never checked: the estimate stopped {touched} time{'s' if touched > 1 else ''} (touched: the rig "
            "did not move as its model does) before its references were taken: the model most likely does not "
            "fit this rig (events below)"
        )
    elif math.isnan(s.monitored_from_s):
        lines.append("health: never checked (the references were not taken: --baseline-s past the end?)")
    lines.append(f"alarms: {len(s.alarms)}" + "".join(f"\n  {a.describe(result.start_utc_ns)}" for a in s.alarms))
    shown = [(t, what) for t, what in s.events if what != "tracking"]
    if shown:
        lines.append("events: " + "; ".join(f"{what} at {t:.1f} s" for t, what in shown[:10])
                     + (f"; ... {len(shown) - 10} more" if len(shown) > 10 else ""))  # fmt: skip
    touched = sum(what == "touched" for _, what in s.events)
    if held and touched >= TOUCHED_MANY:
        lines.append(
            f"note: 'touched' {touched} times while the model did not fit: the innovations a hand on the rig "
            "leaves, which a model unlike the rig leaves too (most likely that here: the health checks were held)"
        )
    for name, (received, used, waiting, other) in zip(("m1", "m2"), result.packets, strict=False):
        lines.append(
            f"{name}: {received} datagrams, {used} samples used; {waiting} came before its clock fit was "
            f"established (not used), {other} others not used (stale, off time, malformed, implausible)"
        )
    if result.late:
        per_node = [sum(1 for node, _ in result.late if node == k) for k in range(2)]
        lines.append(
            f"{len(result.late)} samples (m1 {per_node[0]}, m2 {per_node[1]}) came after later ones had been taken "
            "in: used by the receiver, left out by the twin"
        )
    if math.isfinite(result.latency_ms[0]):
        p50, p99 = result.latency_ms
        lines.append(f"latency, sample arrival -> estimate: median {p50:.1f} ms, p99 {p99:.1f} ms")
    if result.path is not None:
        lines.append(f"wrote {result.path} ({result.messages} messages)")
    return "\n".join(lines)


__all__ = ["STOPPED", "WHITE_P", "status_text", "summary_text"]
