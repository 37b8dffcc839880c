"""Speed of the simulation API against bare MuJoCo, and of the reference solver per batch size.

Run: python bench/bench_simulation.py    (prints ratios measured in this one run)

Targets (issue 2): the API's 120 s run within 1.2x of a bare mj_step(model, data, nstep=12000)
on the same model; the batched reference solver at least 1e6 trajectory-steps per second.
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from pendsim_mj.engines import reference
from pendsim_mj.engines.simulation import simulate
from pendsim_mj.rig.model import build_model
from pendsim_mj.rig.params import DEFAULT_PARAMS


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def bench_api(repeat: int) -> None:
    model = build_model(DEFAULT_PARAMS)
    data = mujoco.MjData(model)

    def bare() -> None:
        mujoco.mj_resetData(model, data)
        data.qpos[0] = np.pi / 6
        mujoco.mj_step(model, data, nstep=12000)

    def api() -> None:
        simulate(DEFAULT_PARAMS, (np.pi / 6, 0.0), (0.0, 0.0), 120.0)

    api()  # warm up (imports, model compile cache)
    t_bare = best_of(bare, repeat)
    t_api = best_of(api, repeat)
    print(f"120 s at 10 ms, best of {repeat}:")
    print(f"  bare mj_step(nstep=12000)      {t_bare * 1e3:8.1f} ms  ({t_bare / 12000 * 1e6:.1f} us/step)")
    print(f"  simulate() -> Trajectory       {t_api * 1e3:8.1f} ms  (compile + rollout + all derived arrays)")
    print(f"  ratio API / bare               {t_api / t_bare:8.2f}x  (target <= 1.2x)")


def bench_reference(repeat: int) -> None:
    print("reference solver (numpy RK4, states only), trajectory-steps per second:")
    for nbatch, nstep in ((1, 2000), (100, 2000), (10_000, 200)):
        params = [DEFAULT_PARAMS] * nbatch
        rng = np.random.default_rng(0)
        phi0 = rng.uniform(-1.0, 1.0, (nbatch, 2))
        omega0 = np.zeros((nbatch, 2))
        t = best_of(lambda p=params, a=phi0, b=omega0, n=nstep: reference.integrate(p, a, b, n, 0.01), repeat)
        rate = nbatch * nstep / t
        print(f"  batch {nbatch:6d}: {rate:12.3e} steps/s  ({nstep} steps in {t * 1e3:.0f} ms)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    print(f"mujoco {mujoco.__version__}, numpy {np.__version__}")
    bench_api(args.repeat)
    bench_reference(max(1, args.repeat // 2))


if __name__ == "__main__":
    main()
