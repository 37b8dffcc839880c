"""Speed of the nonlinear analyses, as ratios against baselines measured in the same run.

1. One shooting evaluation (residual, monodromy and d/df: 6 runs of one drive period) as one
   batched ``mujoco.rollout`` against the same 6 runs one after the other.
2. A frequency-response curve by continuation against the stepped sine over the same range and
   damping (the continuation gives the unstable branch too; the stepped sine must wait out every
   transient).
3. The tongue map's batched monodromies against one frequency and level at a time.

Targets: (1) >= 1.5x on 2 cores; (2) continuation faster than stepped sine at the default damping.
"""

from __future__ import annotations

import time

import numpy as np

from pendsim_mj.nonlinear import continue_response, stepped_sine
from pendsim_mj.nonlinear.flow import RigFlow
from pendsim_mj.nonlinear.periodic import ForcedShooting
from pendsim_mj.nonlinear.tongues import _RestMonodromy
from pendsim_mj.rig.drives import Drive, Sine, Target
from pendsim_mj.rig.params import DEFAULT_PARAMS


def best_of(fn, repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    drive = Drive(torque_m1=Sine(0.003, 0.85))
    with RigFlow(DEFAULT_PARAMS, drive.targets) as flow:
        shooting = ForcedShooting(flow, drive, steps_per_period=64)
        x0 = np.array([0.2, 0.02, 0.0, 0.0])
        batched = best_of(lambda: [shooting.evaluate(x0, 0.85) for _ in range(20)])
        xs = np.tile(x0, (6, 1))

        def one_at_a_time() -> None:
            for _ in range(20):
                for i in range(6):
                    flow.run(xs[i : i + 1], shooting.dt(0.85), 64, shooting.inputs)

        sequential = best_of(one_at_a_time)
    print(f"shooting evaluation (6 runs x 64 steps): batched {batched / 20 * 1e3:.2f} ms, one at a time "
          f"{sequential / 20 * 1e3:.2f} ms: {sequential / batched:.2f}x")  # fmt: skip

    freqs = np.linspace(0.80, 0.92, 25)
    t0 = time.perf_counter()
    branch = continue_response(DEFAULT_PARAMS, drive, 0.80, 0.92, steps_per_period=64)
    t_cont = time.perf_counter() - t0
    t0 = time.perf_counter()
    stepped_sine(DEFAULT_PARAMS, drive, freqs, steps_per_period=64, max_periods=600)
    t_step = time.perf_counter() - t0
    print(f"response curve 0.80-0.92 Hz: continuation {t_cont:.1f} s ({len(branch.frequency_hz)} orbits, both "
          f"stabilities), stepped sine up and down {t_step:.1f} s (25 steps): {t_step / t_cont:.2f}x")  # fmt: skip

    f = np.linspace(1.7, 1.8, 40)
    with RigFlow(DEFAULT_PARAMS, (Target.PIVOT_Z,)) as flow:
        rest = _RestMonodromy(flow, 64)
        t_batch = best_of(lambda: rest.growth(f, np.full(40, 0.5)), 2)
        t_single = best_of(lambda: [rest.growth(f[i : i + 1], np.array([0.5])) for i in range(40)], 2)
    print(f"tongue map, 40 frequencies: batched {t_batch * 1e3:.0f} ms, one at a time {t_single * 1e3:.0f} ms: "
          f"{t_single / t_batch:.2f}x")  # fmt: skip


if __name__ == "__main__":
    main()
