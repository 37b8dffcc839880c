"""The live twin's health monitoring on the product's own path, offline: ``pendsim nodes``'s plan
(the simulated rig through the BNO055 model, every sensor imperfection on, its scripted faults)
fed in time order into ``TwinSession`` (the measurement front end, the estimator, the monitor),
as fast as it runs. Measured:

- **false alarms** over healthy free decays (random release 10-45 deg, random heading, nodes
  glued 2 deg askew, fusion error 0.2 deg, hold wobble, 2 % packet loss, seeds in turn), with the
  rate's one-sided 95 % upper bound (zero alarms in T hours: 3 / T per hour);
- each **scripted fault** (springs -5 %, damping doubled, dry friction 2e-4 N m, a 3 deg mount
  slip; on each hinge or node) 20 s after the release: the time to its alarm and whether the
  first alarm names the right parameter;
- each **ramp** (the same changes of the rig's parameters, linear from 20 s to 80 s after the
  release, runs of 100 s): the time to the first alarm, its parameter (a hinge's change whose
  law the alarm leaves open counts as the hinge's, "law open"), and when the alarms first said the
  change was still going on (on the first alarm, or on a second one for the same parameter);
  any alarm on another parameter is listed.

Not measured here: the network (packets are taken at their true instants; tests/acquire/
test_twin_udp.py runs the same twin over loopback UDP).

Run: python bench/bench_twin_faults.py [--healthy-runs 36 --run-s 300] [--fault-seeds 2] [--ramp-seeds 2]
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from pendsim_bridge.acquire.emulator import plan
from pendsim_bridge.acquire.packets import GROUP_SLICES
from pendsim_bridge.cli import build_parser
from pendsim_bridge.commands.nodes import spec_from
from pendsim_mj.twin.session import TwinSession

HOLD_S = 2.0
FAULT_AT_S = 20.0  # after the release
FAULTS = {
    "stiffness:-5%": "coupling_sin_n_m",
    "damping:m1*2": "b1_n_m_s",
    "damping:m2*2": "b2_n_m_s",
    "friction:m1=2e-4": "friction1_n_m",
    "friction:m2=2e-4": "friction2_n_m",
    "mount:m1=3deg": "offset_m1_rad",
    "mount:m2=3deg": "offset_m2_rad",
}


RAMP_S = (20.0, 80.0)  # after the release
RAMPS = {
    "stiffness:-5%": "coupling_sin_n_m",
    "damping:m1*2": "b1_n_m_s",
    "damping:m2*2": "b2_n_m_s",
    "friction:m1=2e-4": "friction1_n_m",
    "friction:m2=2e-4": "friction2_n_m",
}


def imperfect(seed: int) -> list[str]:
    rng = np.random.default_rng(1000 + seed)
    return [
        "--seed", str(seed), "--phi1-deg", f"{rng.uniform(10, 45):.1f}", "--heading-deg", f"{rng.uniform(0, 360):.1f}",
        "--mount-misalignment-deg", "2", "--fusion-error-deg", "0.2", "--hold-wobble-deg", "1", "--loss", "0.02",
    ]  # fmt: skip


def run(duration_s: float, args: list[str]) -> tuple[TwinSession, float]:
    """The twin on one emulated run; (the session, CPU s spent in the twin)."""
    spec = spec_from(build_parser().parse_args(["nodes", "--duration-s", str(duration_s), "--hold-s", str(HOLD_S),
                                                *args]))  # fmt: skip
    p = plan(spec)
    events = p.sent_in_time_order()
    session = TwinSession()
    q, g, a = GROUP_SLICES["quat"], GROUP_SLICES["gyro"], GROUP_SLICES["accel"]
    t0 = time.process_time()
    for t, k, i in events:
        row = p.streams[k].rows[i]
        session.take(k, t, row[q], row[g], row[a])
        session.drain()
    return session, time.process_time() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--healthy-runs", type=int, default=36)
    ap.add_argument("--run-s", type=float, default=300.0)
    ap.add_argument("--fault-seeds", type=int, default=2)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--ramp-seeds", type=int, default=2)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f}")
    hours, alarms, cpu, largest = 0.0, [], 0.0, {}
    for k in range(args.healthy_runs):
        seed = args.first_seed + k
        session, spent = run(args.run_s, imperfect(seed))
        cpu += spent
        hours += (args.run_s - HOLD_S) / 3600
        alarms += [(seed, a.describe()) for a in session.summary().alarms]
        if session.monitor is not None:
            for name, z in session.monitor.largest_z().items():
                largest[name] = max(largest.get(name, 0.0), z)
        print(f"healthy run {seed}: {len(session.summary().alarms)} alarms; {hours:.2f} h so far", flush=True)
    if args.healthy_runs:
        bound = 3.0 / hours if not alarms else math.nan
        print(f"\nhealthy: {len(alarms)} alarms in {hours:.2f} h of emulated free decays"
              + (f" (rate < {bound:.2f} per hour, one-sided 95 %)" if not alarms else ""))  # fmt: skip
        for seed, text in alarms:
            print(f"  seed {seed}: {text}")
        print("  largest |z| per parameter: " + ", ".join(f"{n} {z:.1f}" for n, z in largest.items()))
        share = 100 * cpu / (hours * 3600)
        print(f"  the twin's CPU: {cpu:.0f} s for {hours * 3600:.0f} s of data ({share:.1f} % of a core)")
    print(f"\n{'fault (20 s after the release)':<24} {'seed':>4} {'alarm after':>12}  first alarm on")
    for fault, right in FAULTS.items():
        for seed in range(args.fault_seeds):
            session, _ = run(HOLD_S + FAULT_AT_S + 70.0, [*imperfect(100 + seed), "--fault", f"{fault}@{FAULT_AT_S:g}"])
            found = session.summary().alarms
            fault_t = HOLD_S + FAULT_AT_S
            after = [a for a in found if a.t_s >= fault_t]
            first = after[0] if after else None
            verdict = "none in 70 s" if first is None else (
                f"{first.t_s - fault_t:9.1f} s  {first.parameter} ({'right' if first.parameter == right else 'WRONG'}"
                + (f", law left open: {first.law_open}" if first.law_open else "")
                + (", WRONGLY said maybe from the start" if first.from_start else "") + ")"
                + ("; then said still changing" if any(a.still_changing for a in after) else "")
            )  # fmt: skip
            early = [a.parameter for a in found if a.t_s < fault_t]
            print(f"{fault:<24} {seed:>4} {verdict}" + (f"; before the fault: {early}" if early else ""), flush=True)
    if args.ramp_seeds:
        start, end = RAMP_S
        print(f"\n{'ramp (' + f'{start:g}-{end:g} s after the release)':<28} {'seed':>4} {'first alarm':>12}  on"
              f"{'':30} still changing said")  # fmt: skip
    for fault, right in RAMPS.items() if args.ramp_seeds else ():
        for seed in range(args.ramp_seeds):
            session, _ = run(HOLD_S + 100.0, [*imperfect(200 + seed), "--fault", f"{fault}@{start:g}..{end:g}"])
            found = session.summary().alarms
            ramp_t = HOLD_S + start
            first = next((a for a in found if a.t_s >= ramp_t), None)
            if first is None:
                print(f"{fault:<28} {seed:>4} none in 100 s", flush=True)
                continue
            named = "right" if first.parameter == right else ("law open" if first.law_open == right else "WRONG")
            named += ", law open" if first.parameter == right and first.law_open else ""
            said = next((a.t_s - ramp_t for a in found if a.parameter == first.parameter and a.still_changing), None)
            others = sorted({a.parameter for a in found if a.parameter not in (right, first.parameter)})
            print(
                f"{fault:<28} {seed:>4} {first.t_s - ramp_t:9.1f} s  {first.parameter:<16} ({named}){'':8} "
                + (f"{said:5.1f} s" if said is not None else "not said")
                + (f"; also alarmed: {others}" if others else ""),
                flush=True,
            )


if __name__ == "__main__":
    main()
