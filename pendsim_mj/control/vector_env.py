"""The rig as a Gymnasium vector environment for learning at scale: ``CoupledPendulumsVectorEnv``
steps ``num_envs`` rigs at once on the batched fast plant (``plant.FastPlant.advance``: numpy,
one RK4 step of the fast engine's force law per control period), in ``threads`` chunks of members
(numpy releases the GIL inside its array loops, so two threads use two cores).
``gymnasium.make_vec("pendsim/CoupledPendulums-v0", num_envs=...)`` returns it (the registration's
``vector_entry_point``); it takes the options of ``environment.EnvConfig`` (engine "fast" only).

**Members are single environments.** Member i of ``reset(seed=s)`` is ``CoupledPendulumsEnv``
(engine "fast") reset with seed s + i (the convention of Gymnasium's ``SyncVectorEnv``): its
releases, first and after each autoreset, come from its own generator, drawn as the single
environment draws them, so states, rewards, terminations, truncations and state observations are
the single environment's (tested against ``SyncVectorEnv`` over it).

**Autoreset** is Gymnasium's default, next step (``metadata["autoreset_mode"]`` =
``AutoresetMode.NEXT_STEP``): the step after a member's episode ended (terminated or truncated)
ignores its action and returns its new episode's first observation with reward 0, not terminated,
not truncated.

**Node observations** (``observation="nodes"``): ``BatchNodes`` plays both nodes of every member at
once with ``observe.NodeObserver``'s own numbers (taken from a ``NodeObserver`` of the same node
model: 80 Hz, the gyro's and the orientation's noise, the burst loss process ``loss_chain``, the
exponential latency) and its rules (samples between control instants from ``between``; the newest
arrived sample, carried forward by its rate). Its draws come from one generator for the batch (the
vector environment's ``np_random``), so node observations are not the single environment's draws;
without noise, loss and latency they are its numbers (tested). A sample still in flight
``BatchNodes.slots`` sampling periods after it was taken (8 mean latencies) is dropped.

**info** (arrays over members): ``state`` (n, 4), ``task_amplitudes_rad`` (n, 2), ``t_s`` (n,);
with ``full_info=True`` also ``mode_amplitudes_rad`` (n, 2), ``targets_rad`` (n, 2),
``energy_j`` (n,) and, for node observations, ``age_s`` (n, 2) (the energy's trigonometry costs
about a fifth of a step, so it is asked for).
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

from pendsim_mj.control.environment import (
    EnvConfig,
    action_space,
    check_reset_options,
    clip_actions,
    leaves_envelope,
    observation_bounds,
    observation_space,
    shown_nodes,
)
from pendsim_mj.control.observe import NodeObserver, between, loss_chain
from pendsim_mj.control.plant import FastPlant
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.drives import Target
from pendsim_mj.sensors.bno055 import Bno055

Floats = NDArray[np.float64]
Bools = NDArray[np.bool_]
MIN_CHUNK = 2048
"""The fewest members a thread steps (below this, a thread's start costs more than it saves)."""


class BatchNodes:
    """Both BNO055 nodes of ``n`` members at once (module docstring).

    Args:
      config: the node model (default ``Bno055()``).
      n: members.
      dt_s: the control period, s.
    """

    def __init__(self, config: Bno055 | None, n: int, dt_s: float) -> None:
        model = NodeObserver(config, dt_s=dt_s)  # one definition of the nodes' numbers
        self.n, self.dt_s, self.period_s = n, dt_s, model.period_s
        self.gyro_sigma_rad_s, self.angle_sigma_rad = model.gyro_sigma_rad_s, model.angle_sigma_rad
        self.latency_s, self.loss_share = model.latency_s, model.loss_share
        lossy = model.loss_share > 0
        self.start_p, self.stay_p = loss_chain(model.loss_share, model.burst_samples) if lossy else (0.0, 0.0)
        self.slots = 1 + (math.ceil(8.0 * self.latency_s / self.period_s) if self.latency_s > 0 else 0)
        self.next_sample = np.zeros(n, dtype=np.int64)
        self.lost = np.zeros((2, n), dtype=bool)
        self.held = np.zeros((3, 2, n))  # (taken s, phi rad, omega rad/s) of each node's newest arrived sample
        self.held[0] = -np.inf
        self.flight = np.zeros((4, self.slots, 2, n))  # (taken, phi, omega, arrival) of samples in flight
        self.in_flight = np.zeros((self.slots, 2, n), dtype=bool)

    def reset(self, mask: Bools, x0: Floats, rng: np.random.Generator) -> None:
        """Start the members where ``mask`` (n,) is set at states x0 (m, 4) and take their samples at t = 0."""
        self.next_sample[mask] = 0
        self.lost[:, mask] = False
        self.held[:, :, mask] = 0.0
        self.held[0, :, mask] = -np.inf
        self.in_flight[:, :, mask] = False
        x = np.zeros((self.n, 4))
        x[mask] = x0
        self.take(rng, np.zeros(self.n), x, x, mask)

    def take(self, rng: np.random.Generator, t_s: Floats, x_prev: Floats, x_now: Floats, mask: Bools) -> None:
        """The samples the members where ``mask`` is set take in (t - dt, t] (t_s (n,), their
        times; states (n, 4) at t - dt and t), and the samples that arrive by t."""
        t0 = t_s - self.dt_s
        cols_prev, cols_now = x_prev.T, x_now.T
        while True:
            taken = self.next_sample * self.period_s
            new = mask & (taken <= t_s + 1e-12)
            if not new.any():
                break
            s = np.where(t_s == 0, 1.0, np.clip((taken - t0) / self.dt_s, 0.0, 1.0))
            phi, omega = between(cols_prev, cols_now, s, self.dt_s)  # (2, n) each
            keep = np.broadcast_to(new, (2, self.n))
            if self.loss_share > 0:
                lost = rng.random((2, self.n)) < np.where(self.lost, self.stay_p, self.start_p)
                self.lost = np.where(new, lost, self.lost)
                keep = keep & ~lost
            if self.angle_sigma_rad:
                phi = phi + rng.normal(0.0, self.angle_sigma_rad, (2, self.n))
            if self.gyro_sigma_rad_s:
                omega = omega + rng.normal(0.0, self.gyro_sigma_rad_s, (2, self.n))
            delay = rng.exponential(self.latency_s, (2, self.n)) if self.latency_s > 0 else 0.0
            slot = self.next_sample % self.slots
            node, member = np.nonzero(keep)
            where = (slot[member], node, member)
            self.flight[0][where] = taken[member]
            self.flight[1][where] = phi[node, member]
            self.flight[2][where] = omega[node, member]
            self.flight[3][where] = (taken + delay)[node, member] if self.latency_s > 0 else taken[member]
            self.in_flight[where] = True
            self.next_sample += new
        for c in range(self.slots):
            arrived = self.in_flight[c] & (self.flight[3, c] <= t_s + 1e-12) & mask
            newer = arrived & (self.flight[0, c] > self.held[0])
            self.held = np.where(newer, self.flight[:3, c], self.held)
            self.in_flight[c] &= ~arrived

    def shown(self, t_s: Floats) -> tuple[Floats, Floats]:
        """At the members' times t_s (n,): (n, 4) each node's newest sample carried forward by its
        rate (NaN before the first), (n, 2) the samples' ages, s (inf before the first)."""
        taken, phi, omega = self.held
        has = np.isfinite(taken)
        age = np.where(has, t_s - taken, np.inf)
        angle = np.where(has, phi + omega * np.where(has, age, 0.0), np.nan)
        rate = np.where(has, omega, np.nan)
        return np.concatenate([angle, rate]).T, age.T


class CoupledPendulumsVectorEnv(VectorEnv[Floats, Floats, NDArray[Any]]):
    """``num_envs`` rigs stepped at once (module docstring).

    Args:
      num_envs: members.
      threads: threads that step the members (default: up to 2, one per 2048 members, no more than
        the usable cores); results do not depend on it.
      full_info: add the module docstring's further info keys to every step.
      render_mode: must be None (no rendering).
      **options: ``EnvConfig``'s attributes (engine "fast").

    Raises:
      ParameterError: a bad option, naming it.
    """

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}  # noqa: RUF012

    def __init__(
        self,
        num_envs: int = 4096,
        *,
        threads: int | None = None,
        full_info: bool = False,
        render_mode: str | None = None,
        **options: Any,
    ) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ParameterError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if render_mode is not None:
            raise ParameterError(f"the vector env does not render: render_mode must be None, not {render_mode!r}")
        cfg = EnvConfig.from_options(options)
        if cfg.engine != "fast":
            raise ParameterError(
                f"the vector environment runs on the fast engine only, got engine {cfg.engine!r} "
                "(for MuJoCo: gymnasium.make_vec(..., vectorization_mode='sync'))"
            )
        usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        if threads is None:
            threads = max(1, min(2, usable, num_envs // MIN_CHUNK))
        if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= num_envs:
            raise ParameterError(f"threads must be an integer in [1, num_envs], got {threads!r}")
        self.config, self.task, self.num_envs, self.threads = cfg, cfg.task_of(), num_envs, threads
        self.full_info = bool(full_info)
        self.render_mode = None
        self.single_observation_space = observation_space(cfg)
        self.single_action_space = action_space(cfg)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._low, self._high = observation_bounds(cfg)
        self._index = np.array([t.index for t in cfg.channels], dtype=int)
        edges = np.linspace(0, num_envs, threads + 1).round().astype(int)
        self._slices = [slice(int(a), int(b)) for a, b in itertools.pairwise(edges)]
        self._plants = [FastPlant(cfg.params, nenv=s.stop - s.start, dt_s=cfg.dt_s) for s in self._slices]
        self._pool = ThreadPoolExecutor(threads, thread_name_prefix="pendsim-env") if threads > 1 else None
        self._u = np.zeros((4, num_envs))
        self._k = np.zeros(num_envs, dtype=np.int64)
        self._targets = np.zeros((num_envs, 2))
        self._autoreset = np.zeros(num_envs, dtype=bool)
        self._rngs: list[np.random.Generator] = []
        self._nodes = BatchNodes(cfg.nodes, num_envs, cfg.dt_s) if cfg.observation == "nodes" else None
        self._x: Floats | None = None

    # --- episodes ---------------------------------------------------------------------------------

    def reset(
        self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Floats, dict[str, Any]]:
        """Start every member: member i from seed + i (or seed[i]), as ``CoupledPendulumsEnv``."""
        n = self.num_envs
        if seed is None:
            super().reset()
            if not self._rngs:
                self._rngs = [seeding.np_random(int(s))[0] for s in self.np_random.integers(2**62, size=n)]
        else:
            seeds = list(range(seed, seed + n)) if isinstance(seed, int) else list(seed)
            if len(seeds) != n or not all(isinstance(s, (int, np.integer)) and s >= 0 for s in seeds):
                raise ParameterError(f"seed must be an integer >= 0 or {n} of them, got {seed!r}")
            super().reset(seed=int(seeds[0]))
            self._rngs = [seeding.np_random(int(s))[0] for s in seeds]
        start, override = check_reset_options(options, self.task)
        x0 = self._releases(np.arange(n))
        if start is not None:
            x0[:] = start
        for plant, sl in zip(self._plants, self._slices, strict=True):
            plant.reset(x0[sl, :2], x0[sl, 2:])
        self._k[:] = 0
        self._targets = self.task.targets(x0, override)
        self._autoreset[:] = False
        everyone = np.ones(n, dtype=bool)
        if self._nodes is not None:
            self._nodes.reset(everyone, x0, self.np_random)
        self._x = x0
        amplitudes = self.task.amplitudes(x0)
        return self._observation(x0), self._info(x0, amplitudes)

    def _releases(self, members: NDArray[np.intp]) -> Floats:
        """(m, 4) a release for each member, from its own generator, drawn as the single env draws."""
        out = np.empty((len(members), 4))
        for row, i in enumerate(members):
            rng = self._rngs[i]
            out[row] = self.task.release(rng)
            rng.integers(2**63)  # the single environment's node seed: the same stream
        return out

    def step(self, actions: Floats) -> tuple[Floats, NDArray[Any], NDArray[Any], NDArray[Any], dict[str, Any]]:
        """Hold each member's action over one control period (module docstring)."""
        if self._x is None:
            raise ParameterError("call reset() before step()")
        cfg, n = self.config, self.num_envs
        applied, effort = clip_actions(cfg, actions, n)
        self._u[self._index] = applied.T
        if self.task.drives_pivot:
            self._u[Target.PIVOT_Z.index] = self.task.pivot_m_s2(((self._k + 0.5) * cfg.dt_s).astype(np.float64))
        x_prev = self._x
        x = np.empty((n, 4))
        amplitudes = np.empty((n, 2))
        reward = np.empty(n)

        def advance(c: int) -> None:
            sl, plant = self._slices[c], self._plants[c]
            plant.advance(self._u[:, sl])
            x[sl] = plant.columns.T
            a = self.task.amplitudes(x[sl])
            amplitudes[sl] = a
            reward[sl] = self.task.reward(a, self._targets[sl], effort[sl])

        if self._pool is None:
            advance(0)
        else:
            list(self._pool.map(advance, range(self.threads)))
        self._k += 1
        terminated = leaves_envelope(x)
        truncated = self._k >= cfg.nstep
        restart = self._autoreset
        if self._nodes is not None:
            self._nodes.take(self.np_random, self._t_s(), x_prev, x, ~restart)
        if restart.any():
            members = np.flatnonzero(restart)
            x0 = self._releases(members)
            for plant, sl in zip(self._plants, self._slices, strict=True):
                inside = restart[sl]
                if inside.any():
                    part = x0[(members >= sl.start) & (members < sl.stop)]
                    plant.reset_members(inside, part[:, :2], part[:, 2:])
            x[members] = x0
            self._k[members] = 0
            self._targets[members] = self.task.targets(x0)
            amplitudes[members] = self.task.amplitudes(x0)
            reward[members] = 0.0
            terminated[members] = False
            truncated[members] = False
            if self._nodes is not None:
                self._nodes.reset(restart, x0, self.np_random)
        self._autoreset = terminated | truncated
        self._x = x
        return self._observation(x), reward, terminated, truncated, self._info(x, amplitudes)

    # --- what the members are shown -------------------------------------------------------------

    def _t_s(self) -> Floats:
        """(n,) each member's time in its episode, s."""
        return (self._k * self.config.dt_s).astype(np.float64)

    def _observation(self, x: Floats) -> Floats:
        t_s = self._t_s()
        parts = [x]
        if self._nodes is not None:
            state, age = self._nodes.shown(t_s)
            parts = list(shown_nodes(state, age))
        if self.task.drives_pivot:
            parts.append(self.task.phase(t_s))
        return np.clip(np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0], self._low, self._high)

    def _info(self, x: Floats, amplitudes: Floats) -> dict[str, Any]:
        t_s = self._t_s()
        info: dict[str, Any] = {"state": x.copy(), "task_amplitudes_rad": amplitudes, "t_s": t_s}
        if self.full_info:
            modal = amplitudes.copy() if self.task.modal else self.task.linear.mode_amplitudes_rad(x)
            info["mode_amplitudes_rad"] = modal
            info["targets_rad"] = self._targets.copy()
            info["energy_j"] = np.concatenate([p.energy_j() for p in self._plants])
            if self._nodes is not None:
                info["age_s"] = self._nodes.shown(t_s)[1]
        return info

    def close_extras(self, **kwargs: Any) -> None:
        """Stop the threads."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
