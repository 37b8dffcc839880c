"""A short training run on the vectorised environment: the cross-entropy method (CEM), a standard
derivative-free policy search, learns a linear state-feedback policy tau = -K x for the task
"damp" (both motors, 0.05 N m each), from a zero policy, in about a minute on 2 cores.

Each generation draws ``population`` gains K (2 x 4) from a Gaussian, scores each on the same
``members`` random releases (one 5 s episode, all candidates side by side in one
``CoupledPendulumsVectorEnv``: population x members rigs), and refits the Gaussian to the best
``elite``. The learnt policy is then run in the single environment from a 30 deg release of M1,
against no action and against the control room's LQR, and each mode's time to 1/e printed.

Run: python docs/examples/train_linear_policy.py [--generations 20]   (not part of the tests)
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import numpy as np

from pendsim_mj.control import LQR, CoupledPendulumsEnv, CoupledPendulumsVectorEnv, decay_time_s
from pendsim_mj.rig.params import DEFAULT_PARAMS


def episode_returns(env: CoupledPendulumsVectorEnv, gains: np.ndarray, members: int, seed: int) -> np.ndarray:
    """(population,) the mean return of each gain (population, 2, 4) over the same releases."""
    population = len(gains)
    obs, _ = env.reset(seed=[seed + j for _ in range(population) for j in range(members)])
    per_member = np.repeat(gains, members, axis=0)  # (population * members, 2, 4)
    total = np.zeros(population * members)
    for _ in range(env.config.nstep):
        actions = -np.einsum("nij,nj->ni", per_member, obs)
        obs, reward, _, _, _ = env.step(actions)  # clipped to +-0.05 N m inside
        total += reward
    return total.reshape(population, members).mean(axis=1)


def decay_times(
    policy: Callable[[np.ndarray], np.ndarray], release_rad: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, float]:
    """One 20 s episode from ``release_rad``: each mode's time to 1/e (s; inf: not within the
    episode), the share of each mode's amplitude left at its end, and the return."""
    env = CoupledPendulumsEnv(task="damp", episode_s=20.0)
    obs, info = env.reset(seed=0, options={"phi0_rad": release_rad})
    t, amplitudes, total = [0.0], [info["mode_amplitudes_rad"]], 0.0
    for _ in range(env.config.nstep):
        obs, reward, _, _, info = env.step(policy(obs))
        t.append(info["t_s"])
        amplitudes.append(info["mode_amplitudes_rad"])
        total += reward
    a = np.array(amplitudes)
    decay = np.array([decay_time_s(np.array(t), a[:, i]) for i in range(2)])
    return decay, a[-1] / a[0], total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generations", type=int, default=20)
    parser.add_argument("--population", type=int, default=64)
    parser.add_argument("--members", type=int, default=64, help="releases per candidate")
    parser.add_argument("--elite", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    env = CoupledPendulumsVectorEnv(args.population * args.members, task="damp", episode_s=5.0)
    mean, std = np.zeros((2, 4)), np.full((2, 4), 0.1)  # N m per rad, N m per rad/s
    start = time.perf_counter()
    steps = 0
    for generation in range(args.generations):
        gains = mean + std * rng.standard_normal((args.population, 2, 4))
        returns = episode_returns(env, gains, args.members, seed=1000 * generation)
        steps += args.population * args.members * env.config.nstep
        elite = gains[np.argsort(returns)[-args.elite :]]
        mean, std = elite.mean(axis=0), elite.std(axis=0) + 1e-3
        print(f"generation {generation:2d}: best return {returns.max():9.1f}, mean {returns.mean():9.1f}")
    wall = time.perf_counter() - start
    print(f"{steps:.3e} environment steps in {wall:.0f} s ({steps / wall:.2e} steps/s, training included)")
    print("learnt gain K (rows tau1, tau2; columns phi1, phi2, omega1, omega2):")
    print(np.array2string(mean, precision=4))
    lqr = LQR(DEFAULT_PARAMS)
    release = (math.radians(30.0), 0.0)
    print("from a 30 deg release of M1, one 20 s episode (the single environment):")
    for name, policy in (
        ("no action", lambda obs: np.zeros(2)),
        ("learnt (CEM)", lambda obs: -mean @ obs),
        ("LQR", lambda obs: lqr(obs)),
    ):
        decay, left, total = decay_times(policy, release)
        # beyond the episode: the time to 1/e of the exponential through the first and last amplitude
        decay = np.where(np.isfinite(decay), decay, 20.0 / -np.log(left))
        print(
            f"  {name:13s} time to 1/e: mode 1 {decay[0]:7.2f} s, mode 2 {decay[1]:7.2f} s; "
            f"left after 20 s: {left[0]:.1e}, {left[1]:.1e}; return {total:9.1f}"
        )


if __name__ == "__main__":
    main()
