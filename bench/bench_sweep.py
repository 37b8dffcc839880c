"""Sweep engines side by side, in one run: trajectory-steps per second of the fast planar kernel
against a naive numpy RK4 batch of the same equations and the paper-chain reference, at batch
sizes 1, 100 and 10 000; and the spatial model on ``mujoco.rollout`` against the bare
single-thread ``mj_step`` rate times the number of cores.

Run: python bench/bench_sweep.py    (about a minute; --quick for a shorter run)

Targets (issue 15): the fast kernel at batch 10 000 reaches at least 3e7 trajectory-steps/s on
this 2-core machine and at least 5x the naive numpy batch. The rollout ratio is reported (no
target: MuJoCo's own threading).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from functools import partial

import mujoco
import numba
import numpy as np
from mujoco import rollout

from pendsim_mj.engines import fast_planar, reference
from pendsim_mj.engines.simulation import _initial_states
from pendsim_mj.rig.model import SPATIAL, build_model
from pendsim_mj.rig.params import DEFAULT_PARAMS

DT_S = 0.01


def best_of(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def naive_numpy_rk4(coef: np.ndarray, y: np.ndarray, nstep: int, h: float) -> np.ndarray:
    """The baseline: classical RK4 of the same closed-form equations, numpy over the batch, a
    Python loop over the steps, every state kept (as the reference keeps them)."""

    def f(s: np.ndarray) -> np.ndarray:
        a1, a2 = fast_planar.accelerations(s[0], s[1], s[2], s[3], coef)
        return np.stack([s[2], s[3], a1, a2])

    out = np.empty((nstep + 1, 4, y.shape[1]))
    out[0] = y
    for step in range(nstep):
        k1 = f(y)
        k2 = f(y + 0.5 * h * k1)
        k3 = f(y + 0.5 * h * k2)
        k4 = f(y + h * k3)
        y = y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        out[step + 1] = y
    return out


def _planar_rates(
    nbatch: int, fast_steps: int, slow_steps: int, repeat: int
) -> tuple[float, float, float, float, float]:
    """Trajectory-steps/s: fast (state at the end only), the same on one thread, fast (every state
    kept), naive numpy, reference; the slow ones over fewer steps (their rate does not depend on
    the count)."""
    params = [DEFAULT_PARAMS] * nbatch
    coef = fast_planar.coefficients(params)
    rng = np.random.default_rng(nbatch)
    phi0 = rng.uniform(-1.0, 1.0, (nbatch, 2))
    omega0 = np.zeros((nbatch, 2))
    y0 = np.concatenate([phi0.T, omega0.T])
    fast_planar.integrate(coef, phi0, omega0, 8, DT_S)  # compiled (or loaded from the cache) before timing
    t_end = best_of(partial(fast_planar.integrate, coef, phi0, omega0, fast_steps, DT_S, save_every=fast_steps), repeat)
    one = partial(fast_planar.integrate, coef, phi0, omega0, fast_steps, DT_S, save_every=fast_steps, nthread=1)
    t_one = best_of(one, repeat)
    t_all = best_of(partial(fast_planar.integrate, coef, phi0, omega0, fast_steps, DT_S), repeat)
    t_naive = best_of(partial(naive_numpy_rk4, coef, y0, slow_steps, DT_S), max(1, repeat // 2))
    t_ref = best_of(partial(reference.integrate, params, phi0, omega0, slow_steps, DT_S), max(1, repeat // 2))
    fast_work, slow_work = nbatch * fast_steps, nbatch * slow_steps
    return fast_work / t_end, fast_work / t_one, fast_work / t_all, slow_work / t_naive, slow_work / t_ref


def bench_planar(repeat: int, quick: bool) -> None:
    print(f"planar engines, trajectory-steps per second ({numba.get_num_threads()} numba threads, dt = {DT_S} s):")
    header = (
        f"  {'batch':>6} {'fast (states only)':>19} {'1 thread':>10} {'fast (every state)':>19} {'naive numpy':>12}"
        f" {'reference':>11} {'fast/naive':>11} {'fast/ref':>9}"
    )
    print(header)
    scale = 10 if quick else 1
    for nbatch, fast_steps, slow_steps in ((1, 20_000, 2_000), (100, 20_000, 2_000), (10_000, 2_000, 200)):
        rates = _planar_rates(nbatch, fast_steps // scale, max(20, slow_steps // scale), repeat)
        end, one, every, naive, ref = rates
        print(
            f"  {nbatch:>6} {end:>19.3e} {one:>10.3e} {every:>19.3e} {naive:>12.3e} {ref:>11.3e}"
            f" {end / naive:>10.1f}x {end / ref:>8.0f}x"
        )
    print("  targets at batch 10 000: fast >= 3e7 steps/s and >= 5x the naive numpy batch")


def bench_spatial_rollout(repeat: int, quick: bool) -> None:
    cores = os.cpu_count() or 1
    params = DEFAULT_PARAMS.with_overrides(plane_offset_m=0.050)
    model = build_model(params, timestep_s=DT_S, variant=SPATIAL)
    data = mujoco.MjData(model)
    nstep = 2_000 if quick else 12_000

    def bare() -> None:
        mujoco.mj_resetData(model, data)
        data.qpos[:] = 0.3
        mujoco.mj_step(model, data, nstep=nstep)

    bare()
    bare_rate = nstep / best_of(bare, repeat)
    nbatch = 8 * cores
    rng = np.random.default_rng(1)
    initial = _initial_states(model, rng.uniform(-0.8, 0.8, (nbatch, 2)), np.zeros((nbatch, 2)))
    per_case = [
        build_model(params.with_overrides(c1_n_m=5.0 + 0.01 * i), timestep_s=DT_S, variant=SPATIAL)
        for i in range(nbatch)
    ]
    datas = [mujoco.MjData(model) for _ in range(cores)]
    rollout_steps = nstep // 4

    def shared() -> None:
        rollout.rollout(model, datas, initial, nstep=rollout_steps, persistent_pool=False)

    def distinct() -> None:
        rollout.rollout(per_case, datas, initial, nstep=rollout_steps, persistent_pool=False)

    shared()
    shared_rate = nbatch * rollout_steps / best_of(shared, repeat)
    distinct_rate = nbatch * rollout_steps / best_of(distinct, repeat)
    print(f"spatial model (tilt freedoms, planes 50 mm apart), {cores} cores, MuJoCo {mujoco.__version__}:")
    print(f"  bare mj_step, one thread                     {bare_rate:12.3e} steps/s ({1e6 / bare_rate:.1f} us/step)")
    print(f"  x {cores} cores (the ideal)                       {bare_rate * cores:12.3e} steps/s")
    for what, rate in (("one model", shared_rate), ("a model per case", distinct_rate)):
        ratio = rate / (bare_rate * cores)
        print(f"  mujoco.rollout, {cores} threads, {what:<17} {rate:12.3e} steps/s  ratio {ratio:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="best of this many runs (default 5)")
    parser.add_argument("--quick", action="store_true", help="a tenth of the steps (a smoke run)")
    args = parser.parse_args()
    print(f"numpy {np.__version__}, numba {numba.__version__}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}")
    bench_planar(args.repeat, args.quick)
    bench_spatial_rollout(args.repeat, args.quick)


if __name__ == "__main__":
    main()
