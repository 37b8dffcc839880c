"""Speed of the Gymnasium environments of the rig: environment steps per second of the vectorised
environment (``CoupledPendulumsVectorEnv``) against its own engine's bare step, and of the single
environments against Gymnasium's ``SyncVectorEnv`` over them.

Run: python bench/bench_control_env.py [--quick]    (prints ratios measured in this one run)

Target (issue 26): the vectorised environment with the fast engine at least 1e6 environment steps
per second on 2 cores. Baselines measured in the same run: ``FastPlant.advance`` alone on the
same batch (one RK4 step of the force law in numpy, what the environment adds to it is the
ratio), and ``SyncVectorEnv`` over the single environment (what the batched engine gains).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import gymnasium
import numpy as np

from pendsim_mj.control import ENV_ID, CoupledPendulumsEnv, CoupledPendulumsVectorEnv, FastPlant


def interleaved(
    runs: dict[str, tuple[Callable[[], None], int]], repeat: int
) -> tuple[dict[str, float], dict[str, float]]:
    """Steps per wall second and per CPU second (this process, all its threads) of each (run,
    steps per call): the best of ``repeat`` timings taken in turn (run 1, run 2, ..., run 1, ...:
    a shared machine's load moves all alike), after one warm-up call each. CPU seconds count only
    the time this process ran, so its rate is what a core does when it is not shared."""
    wall = dict.fromkeys(runs, float("inf"))
    cpu = dict.fromkeys(runs, float("inf"))
    for fn, _ in runs.values():
        fn()
    for _ in range(repeat):
        for name, (fn, _) in runs.items():
            start, start_cpu = time.perf_counter(), time.process_time()
            fn()
            wall[name] = min(wall[name], time.perf_counter() - start)
            cpu[name] = min(cpu[name], time.process_time() - start_cpu)
    steps = {name: n for name, (_, n) in runs.items()}
    return {k: steps[k] / wall[k] for k in runs}, {k: steps[k] / cpu[k] for k in runs}


def vector_run(nenv: int, threads: int, nstep: int, **options: object) -> tuple[Callable[[], None], int]:
    env = CoupledPendulumsVectorEnv(nenv, threads=threads, **options)
    env.reset(seed=0)
    limits = env.single_action_space.high
    actions = np.random.default_rng(0).uniform(-1, 1, (nstep, nenv, len(limits))) * limits

    def run() -> None:
        for a in actions:
            env.step(a)

    return run, nstep * nenv


def bare_run(nenv: int, nstep: int) -> tuple[Callable[[], None], int]:
    plant = FastPlant(nenv=nenv)
    plant.reset(np.random.default_rng(0).uniform(-0.5, 0.5, (nenv, 2)))
    u = np.zeros((4, nenv))

    def run() -> None:
        for _ in range(nstep):
            plant.advance(u)

    return run, nstep * nenv


def single_run(nstep: int, **options: object) -> tuple[Callable[[], None], int]:
    env = CoupledPendulumsEnv(**options)
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape)

    def run() -> None:
        for _ in range(nstep):
            env.step(action)

    return run, nstep


def sync_run(nenv: int, nstep: int) -> tuple[Callable[[], None], int]:
    env = gymnasium.make_vec(ENV_ID, num_envs=nenv, vectorization_mode="sync")
    env.reset(seed=0)
    actions = np.zeros((nenv, 2))

    def run() -> None:
        for _ in range(nstep):
            env.step(actions)

    return run, nstep * nenv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps and repeats (a smoke run)")
    parser.add_argument("--repeat", type=int, default=5, help="timings per measurement (the best is kept)")
    args = parser.parse_args()
    nstep, repeat = (20, 2) if args.quick else (100, args.repeat)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"{cores} usable cores, load average {os.getloadavg()[0]:.1f} (best of {repeat}, taken in turn)")
    print("vectorised environment (task damp, state observations, fast engine), env steps per second:")
    print(f"  {'members':>8} {'threads':>7} {'env':>10} {'bare advance':>12} {'env / bare':>10} {'env per CPU s':>13}")
    best = 0.0
    for nenv in (4096, 16384):
        runs = {"bare": bare_run(nenv, nstep)} | {t: vector_run(nenv, int(t), nstep) for t in ("1", "2")}
        rates, per_cpu = interleaved(runs, repeat)
        for t in ("1", "2"):
            best = max(best, rates[t])
            ratio = rates[t] / rates["bare"]
            print(f"  {nenv:8d} {t:>7} {rates[t]:10.3e} {rates['bare']:12.3e} {ratio:10.2f} {per_cpu[t]:13.3e}")
    print(f"  best {best:.3e} env steps/s: target >= 1e6 {'met' if best >= 1e6 else 'NOT met'}")
    variants = {
        "node observations": {"observation": "nodes"},
        "0.5 s episodes (an autoreset every 50 steps)": {"episode_s": 0.5},
        "tongue task, three channels": {"task": "tongue", "actions": ("torque_m1", "torque_m2", "support_x")},
    }
    runs = {"plain": vector_run(16384, 1, nstep)} | {k: vector_run(16384, 1, nstep, **v) for k, v in variants.items()}
    rates = interleaved(runs, repeat)[0]
    print("  16384 members, 1 thread:")
    for name, rate in rates.items():
        print(f"    {name:46s} {rate:10.3e}  ({rate / rates['plain']:.2f}x plain)")
    n_single = max(200, 10 * nstep)
    runs = {
        "CoupledPendulumsEnv, fast engine": single_run(n_single),
        "CoupledPendulumsEnv, MuJoCo": single_run(n_single, engine="mujoco"),
        "SyncVectorEnv over 16 (fast)": sync_run(16, nstep),
    }
    rates = interleaved(runs, repeat)[0]
    print("single environments, env steps per second:")
    for name, rate in rates.items():
        print(f"  {name:36s} {rate:10.3e}")
    print(f"  best vectorised / SyncVectorEnv      {best / rates['SyncVectorEnv over 16 (fast)']:10.0f}x")


if __name__ == "__main__":
    main()
