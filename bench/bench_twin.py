"""The live twin's estimator and health monitor on emulated data (the BNO055 sensor model, all its
noise on, ideal fusion timing, on MuJoCo runs), fed sample by sample as fast as it goes (not in
real time).

The main scenario is the real rig's: no motor; the pendulums are released by hand (the larger
from 10-45 deg, the other anywhere up to it, random signs) and decay freely (the amplitude's time
constant is about 75 s), the twin restarted at each release (``release``).

- ``--hours``: false alarms over healthy emulated hours of releases (``--episode-s`` each), with
  the 95 % upper bound of the rate (Poisson); ``--seed`` picks the releases and the noise (run
  several seeds in parallel processes and add their hours and alarms).
- ``--fault-seeds``: each scripted fault (the coupling springs 5 % weaker, one hinge's damping
  doubled, dry friction 2e-4 N m on one hinge, one node turned 3 deg on its mount; both hinges
  and nodes) 10-30 s after a random release, watched for 60 s: the time to the alarm and the
  parameter it names.
- ``--driven``: the older scenario, a motor on M1 near mode 1 keeping a steady amplitude (each
  fault at 60 s; the twin knows the drive's torque).
- ``--fusion-error-deg``: the fused orientation's slowly varying error (off by default, as in
  the sensor model; the monitor allows the mount offsets that spread).
- the cost of one update against one bare RK4 step of the same batch (measured in the same run).

Run: python bench/bench_twin.py [--hours 1] [--seed 0] [--episode-s 300] [--fault-seeds 3]
     [--driven | --driven-only] [--fusion-error-deg 0] [--no-cost]
     python bench/bench_twin.py --combine OUT1 OUT2 ...  (the healthy hours of several runs' outputs)
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable

import numpy as np
from scipy.stats import chi2

from pendsim_mj.control.plant import FastPlant
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.estimation.swing_frame import twist_angle
from pendsim_mj.rig.drives import Drive, Sine
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055, sample_imu, static_imu
from pendsim_mj.sensors.imperfections import Imperfections
from pendsim_mj.twin.estimator import TRACKABLE, RigEstimator
from pendsim_mj.twin.health import Alarm, HealthMonitor

TRACKED = tuple(TRACKABLE)
STEP_S = 0.0125  # one simulation step per node sample (80 Hz)
REST = static_imu(DEFAULT_PARAMS, 1.0, Bno055(noise=False)).quat_wxyz[0]
HINGE = np.array([0.0, 0.0, 1.0])
PAPER = DEFAULT_PARAMS
SLIP_RAD = math.radians(3.0)
# name -> (rig overrides, each node's mount slip in rad, the parameter an alarm should name)
FAULTS: dict[str, tuple[dict[str, float], tuple[float, float], str]] = {
    "coupling springs -5 %": ({"c1_n_m": 0.95 * PAPER.c1_n_m}, (0.0, 0.0), "coupling_sin_n_m"),
    "damping M1 doubled": ({"b1_n_m_s": 2 * PAPER.b1_n_m_s}, (0.0, 0.0), "b1_n_m_s"),
    "damping M2 doubled": ({"b2_n_m_s": 2 * PAPER.b2_n_m_s}, (0.0, 0.0), "b2_n_m_s"),
    "dry friction M1 2e-4 N m": ({"friction1_n_m": 2e-4}, (0.0, 0.0), "friction1_n_m"),
    "dry friction M2 2e-4 N m": ({"friction2_n_m": 2e-4}, (0.0, 0.0), "friction2_n_m"),
    "mount slip M1 3 deg": ({}, (SLIP_RAD, 0.0), "offset_m1_rad"),
    "mount slip M2 3 deg": ({}, (0.0, SLIP_RAD), "offset_m2_rad"),
}
DRIVE_N_M, DRIVE_HZ = 0.01, 0.877  # the driven scenario: a motor on M1 near mode 1

Samples = tuple[np.ndarray, np.ndarray, np.ndarray]  # t_s (k,), swing angles (k, 2), hinge rates (k, 2)
NODES = {"fusion_error_rad": 0.0}  # the nodes' fused orientation's slow error (--fusion-error-deg)


def nodes(seed: int = 0) -> Bno055:
    """The emulated nodes: all noise on, ideal fusion timing, the fusion error asked for."""
    return Bno055(
        fusion_timing=False, seed=seed, imperfections=Imperfections(fusion_error_rad=NODES["fusion_error_rad"])
    )


def release(rng: np.random.Generator) -> tuple[float, float]:
    """A hand release: the larger angle 10-45 deg, the other up to it, random signs, rad."""
    big = rng.uniform(10.0, 45.0)
    small = rng.uniform(-1.0, 1.0) * big
    angles = (big * rng.choice((-1.0, 1.0)), small)
    return tuple(math.radians(a) for a in (angles if rng.random() < 0.5 else angles[::-1]))  # type: ignore[return-value]


def measured(
    phi0_rad: tuple[float, float],
    pieces: list[tuple[float, dict[str, float], tuple[float, float]]],
    seed: int,
    drive_n_m: float = 0.0,
) -> Samples:
    """Each node's samples over consecutive pieces (until_s, rig overrides, each node's mount
    slip in rad), the rig continuing from where the last piece left it, from rest at phi0_rad."""
    phi0, omega0, start = phi0_rad, (0.0, 0.0), 0.0
    t_all, phi_all, omega_all = [], [], []
    for k, (until_s, rig, slip) in enumerate(pieces):
        drive = None
        if drive_n_m:
            phase = (2 * math.pi * DRIVE_HZ * start) % (2 * math.pi)
            drive = Drive(torque_m1=Sine(drive_n_m, DRIVE_HZ, phase_rad=phase))
        run = simulate(PAPER.with_overrides(**rig), phi0, omega0, until_s - start, STEP_S, drive=drive)
        imu = sample_imu(run, nodes(seed * 1000 + k))
        phi = np.stack([twist_angle(imu.quat_wxyz[:, n], REST[n], HINGE) for n in range(2)], axis=1)
        phi += np.asarray(slip)
        first = 0 if k == 0 else 1  # the shared boundary sample once
        t_all.append(imu.t_s[first:] + start)
        phi_all.append(phi[first:])
        omega_all.append(imu.gyro_rad_s[first:, :, 2])
        phi0, omega0, start = tuple(run.phi_rad[-1]), tuple(run.omega_rad_s[-1]), until_s
    return np.concatenate(t_all), np.concatenate(phi_all), np.concatenate(omega_all)


def watch(
    samples: Samples, torque: Callable[[float], float] | None = None, **monitor_options
) -> tuple[HealthMonitor, list[Alarm]]:
    """A fresh twin (all of ``TRACKABLE`` tracked) started from the first sample and fed the
    rest; its monitor and the alarms raised."""
    t, phi, omega = samples
    estimator = RigEstimator(PAPER, nodes=nodes(), track=TRACKED)
    estimator.start(t[0], [phi[0, 0], phi[0, 1], omega[0, 0], omega[0, 1]])
    monitor = HealthMonitor(estimator, **monitor_options)
    alarms: list[Alarm] = []
    for k in range(1, len(t)):
        tau = (0.0, 0.0) if torque is None else (torque(t[k] - 0.5 * STEP_S), 0.0)  # held over the step
        for node in range(2):
            estimator.update(t[k], node, phi[k, node], omega[k, node], torques_n_m=tau)
        alarms += monitor.check()
    return monitor, alarms


def rate_bound(alarms: int, hours: float, confidence: float = 0.95) -> float:
    """The one-sided upper confidence bound of a Poisson rate, per hour."""
    return float(chi2.ppf(confidence, 2 * alarms + 2) / 2 / hours)


def false_alarms(hours: float, seed: int, episode_s: float) -> dict:
    """Healthy releases, each watched for ``episode_s``, until ``hours`` are covered."""
    rng = np.random.default_rng(seed)
    n = max(1, math.ceil(hours * 3600 / episode_s - 1e-9))
    alarms, dismissed, largest, cpu = [], 0, 0.0, time.process_time()
    for k in range(n):
        phi0 = release(rng)
        monitor, found = watch(measured(phi0, [(episode_s, {}, (0.0, 0.0))], seed=seed * 10000 + k))
        released = f"release {k} ({math.degrees(phi0[0]):.0f}, {math.degrees(phi0[1]):.0f} deg)"
        alarms += [f"{released}: {a.describe()}" for a in found]
        dismissed += len(monitor.dismissed)
        largest = max(largest, *monitor.largest_z().values())
    return {"seed": seed, "fusion_error_rad": NODES["fusion_error_rad"],
            "hours": n * episode_s / 3600, "releases": n, "alarms": alarms, "dismissed": dismissed,
            "largest_g": largest, "cpu_s": time.process_time() - cpu}  # fmt: skip


def faults(seeds: int) -> list[dict]:
    """Each fault 10-30 s after a random release, watched until 60 s after it."""
    out = []
    for name, (rig, slip, parameter) in FAULTS.items():
        for seed in range(seeds):
            rng = np.random.default_rng(5000 + seed)
            phi0, at_s = release(rng), float(round(rng.uniform(10.0, 30.0)))  # whole seconds: whole steps
            samples = measured(phi0, [(at_s, {}, (0.0, 0.0)), (at_s + 60.0, rig, slip)], seed=5000 + seed)
            _, alarms = watch(samples)
            early = [a for a in alarms if a.t_s < at_s]
            first = next((a for a in alarms if a.t_s >= at_s), None)
            out.append({"fault": name, "seed": seed, "release_deg": [round(math.degrees(p)) for p in phi0],
                        "at_s": at_s, "after_s": None if first is None else first.t_s - at_s,
                        "right": first is not None and first.parameter == parameter,
                        "alarm": "" if first is None else first.describe(), "early": len(early)})  # fmt: skip
    return out


def driven(seeds: int) -> list[dict]:
    """The driven scenario: each fault at 60 s, watched for 60 s after it."""

    def torque(t_s: float) -> float:
        return DRIVE_N_M * math.sin(2 * math.pi * DRIVE_HZ * t_s)

    out = []
    for name, (rig, slip, parameter) in FAULTS.items():
        for seed in range(seeds):
            pieces = [(60.0, {}, (0.0, 0.0)), (120.0, rig, slip)]
            samples = measured((math.radians(30), 0.0), pieces, seed=1000 + 10 * seed, drive_n_m=DRIVE_N_M)
            _, alarms = watch(samples, torque)
            first = next((a for a in alarms if a.t_s >= 60.0), None)
            out.append({"fault": name, "seed": seed, "after_s": None if first is None else first.t_s - 60.0,
                        "right": first is not None and first.parameter == parameter,
                        "alarm": "" if first is None else first.describe()})  # fmt: skip
    return out


def cost() -> None:
    """One update's CPU time against one bare RK4 step of the same batch of sigma points."""
    samples = measured((math.radians(30), math.radians(10)), [(60.0, {}, (0.0, 0.0))], seed=1)
    start = time.process_time()
    monitor, _ = watch(samples)
    per_update = (time.process_time() - start) / (2 * (len(samples[0]) - 1))
    n = monitor.estimator.n
    plant = FastPlant(PAPER, nenv=2 * n + 1)
    u = np.zeros((4, plant.nenv))
    start = time.process_time()
    for _ in range(2000):
        plant.advance(u)
    per_step = (time.process_time() - start) / 2000
    print(f"one update with its check: {per_update * 1e6:.0f} us CPU ({n} states, {plant.nenv} sigma points); "
          f"a bare RK4 step of that batch: {per_step * 1e6:.0f} us; two nodes at 80 Hz: "
          f"{100 * per_update * 160:.1f} % of a core", flush=True)  # fmt: skip


def _print_faults(rows: list[dict], title: str) -> None:
    print(f"\n{title}\n{'fault':<27}{'seed':>5}{'release deg':>14}{'at s':>6}{'alarm after':>13}  attributed")
    for r in rows:
        after = "none" if r["after_s"] is None else f"{r['after_s']:.0f} s"
        rel = "" if "release_deg" not in r else f"{r['release_deg'][0]:>4} {r['release_deg'][1]:>4}"
        at = "" if "at_s" not in r else f"{r['at_s']:.0f}"
        mark = "" if r["after_s"] is None else ("right" if r["right"] else "WRONG")
        early = f" [{r['early']} before the fault]" if r.get("early") else ""
        print(f"{r['fault']:<27}{r['seed']:>5}{rel:>14}{at:>6}{after:>13}  {mark} {r['alarm']}{early}")
    found = [r for r in rows if r["after_s"] is not None and r["after_s"] <= 60.0]
    print(f"detected within 60 s: {len(found)}/{len(rows)}; attributed right: {sum(r['right'] for r in found)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=0.0, help="healthy emulated hours (0: none)")
    parser.add_argument("--seed", type=int, default=0, help="the healthy hours' releases and noise")
    parser.add_argument("--episode-s", type=float, default=300.0, help="each release watched this long, s")
    parser.add_argument("--fault-seeds", type=int, default=3, help="releases per fault (0: none)")
    parser.add_argument("--driven", action="store_true", help="also the driven scenario")
    parser.add_argument("--combine", nargs="+", metavar="OUT", help="add up the healthy hours of earlier runs' outputs")
    parser.add_argument("--driven-only", action="store_true", help="only the driven scenario's faults")
    parser.add_argument("--fusion-error-deg", type=float, default=0.0, help="the nodes' slow orientation error, rms")
    parser.add_argument("--no-cost", action="store_true", help="skip the cost measurement")
    args = parser.parse_args()
    NODES["fusion_error_rad"] = math.radians(args.fusion_error_deg)

    if args.combine:
        runs = []
        for path in args.combine:
            with open(path) as f:
                runs += [json.loads(line[5:]) for line in f if line.startswith("json ")]
        hours, n = sum(r["hours"] for r in runs), sum(len(r["alarms"]) for r in runs)
        print(f"{len(runs)} runs (seeds {', '.join(str(r['seed']) for r in runs)}): {hours:.2f} healthy hours, "
              f"{sum(r['releases'] for r in runs)} releases, {n} false alarms, "
              f"{sum(r['dismissed'] for r in runs)} dismissed detections, largest |g| "
              f"{max(r['largest_g'] for r in runs):.2f}; 95 % upper bound "
              f"{rate_bound(n, hours):.2f} per hour")  # fmt: skip
        return
    if not args.no_cost:
        cost()
    if args.hours > 0:
        result = false_alarms(args.hours, args.seed, args.episode_s)
        n, hours = len(result["alarms"]), result["hours"]
        print(f"\nhealthy free decays, seed {args.seed}, fusion error {args.fusion_error_deg:g} deg: {hours:.2f} h "
              f"({result['releases']} releases of "
              f"{args.episode_s:g} s): {n} false alarms ({result['dismissed']} detections dismissed by the "
              f"attribution); largest |g| {result['largest_g']:.2f}; 95 % upper bound "
              f"{rate_bound(n, hours):.2f} per hour; {result['cpu_s']:.0f} s CPU")  # fmt: skip
        for line in result["alarms"]:
            print("  ", line)
        print("json", json.dumps(result), flush=True)
    if args.fault_seeds > 0 and not args.driven_only:
        _print_faults(faults(args.fault_seeds), "faults on free decays (10-30 s after a release, watched 60 s)")
    if args.driven or args.driven_only:
        _print_faults(driven(max(1, args.fault_seeds)), "faults on the driven rig (at 60 s, watched 60 s)")


if __name__ == "__main__":
    main()
