"""Controllers against the open loop, in both engines, with the exact state and through the nodes:
each normal mode's decay time to 1/e, energy used, peak torque and the share of steps at the
limit, from the issue's 30 deg release (M1 at 30 deg, M2 at rest: both modes excited); and the
cost of a closed-loop step against an open-loop step of the same engine, measured in the same run.

Run: python bench/bench_control.py [--duration-s 30] [--release-deg 30,0]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from pendsim_mj.control.controllers import LQR, BeatingSuppressor, EnergyRegulator, OpenLoop, ScheduledLQR
from pendsim_mj.control.linear import decay_time_s, linearise
from pendsim_mj.control.loop import closed_loop
from pendsim_mj.control.observe import NodeObserver
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.rig.params import DEFAULT_PARAMS
from pendsim_mj.sensors.bno055 import Bno055
from pendsim_mj.sensors.imperfections import Imperfections

NODES = Bno055(imperfections=Imperfections(packet_loss=0.05, loss_burst_samples=3.0, latency_s=0.005))


def open_loop_decay(release: tuple[float, float]) -> np.ndarray:
    free = simulate(DEFAULT_PARAMS, release, (0.0, 0.0), 300.0, 0.01)
    amplitudes = linearise(DEFAULT_PARAMS).mode_amplitudes_rad(np.hstack([free.phi_rad, free.omega_rad_s]))
    return np.array([decay_time_s(free.t_s, amplitudes[:, i]) for i in range(2)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=30.0)
    parser.add_argument("--release-deg", default="30,0")
    args = parser.parse_args()
    release = tuple(math.radians(float(v)) for v in args.release_deg.split(","))
    assert len(release) == 2
    reference = open_loop_decay(release)  # type: ignore[arg-type]
    print(f"open loop (MuJoCo, 300 s): decay to 1/e mode 1 {reference[0]:.2f} s, mode 2 {reference[1]:.2f} s\n")
    cases = [
        ("lqr m1+m2", lambda: LQR(DEFAULT_PARAMS)),
        ("lqr m1 only", lambda: LQR(DEFAULT_PARAMS, motors=("m1",))),
        ("lqr m2 only", lambda: LQR(DEFAULT_PARAMS, motors=("m2",))),
        ("scheduled-lqr", lambda: ScheduledLQR(DEFAULT_PARAMS)),
        ("energy (damp)", lambda: EnergyRegulator(DEFAULT_PARAMS)),
        ("beating", lambda: BeatingSuppressor(DEFAULT_PARAMS)),
        ("none", lambda: OpenLoop(DEFAULT_PARAMS)),
    ]
    header = (
        f"{'controller':<15}{'engine':<8}{'sees':<7}{'mode 1 s':>9}{'x':>7}{'mode 2 s':>10}{'x':>7}"
        f"{'energy J':>10}{'peak N m':>10}{'limit %':>9}{'M2/M1':>7}{'us/step':>9}"
    )
    print(header)
    for name, make in cases:
        for engine in ("fast", "mujoco"):
            for sees in ("state", "nodes"):
                observer = NodeObserver(NODES, seed=1) if sees == "nodes" else None
                start = time.perf_counter()
                loop = closed_loop(
                    make(), engine=engine, phi0_rad=release, duration_s=args.duration_s, observer=observer
                )
                per_step = (time.perf_counter() - start) / (len(loop.t_s) - 1) * 1e6
                m = loop.metrics()
                speed = reference / m.decay_s
                print(
                    f"{name:<15}{engine:<8}{sees:<7}{m.decay_s[0]:>9.2f}{speed[0]:>7.1f}{m.decay_s[1]:>10.2f}"
                    f"{speed[1]:>7.1f}{m.energy_used_j:>10.4f}{np.max(m.peak_torque_n_m):>10.4f}"
                    f"{100 * m.saturated_share:>9.1f}{m.largest_ratio_m2_m1:>7.3f}{per_step:>9.0f}"
                )
    start = time.perf_counter()
    simulate(DEFAULT_PARAMS, release, (0.0, 0.0), args.duration_s, 0.01)  # type: ignore[arg-type]
    rollout = (time.perf_counter() - start) / (args.duration_s / 0.01) * 1e6
    print(f"\nopen-loop MuJoCo rollout of the same run: {rollout:.1f} us/step (the closed loop's baseline)")


if __name__ == "__main__":
    main()
