"""The rig as a Gymnasium environment: ``CoupledPendulumsEnv``, registered as
``pendsim/CoupledPendulums-v0`` (``gymnasium.make("pendsim_mj.control:pendsim/CoupledPendulums-v0")``,
or ``gymnasium.make("pendsim/CoupledPendulums-v0")`` after ``import pendsim_mj.control``), and
what it shares with the vectorised environment (``vector_env``): the options (``EnvConfig``),
the spaces, the actions' limits and the end of an episode.

One step is one control period (10 ms by default, the rig's step): the action is held over it
(``plant``: the fast engine's force law or MuJoCo, ``engine``), then the rig is observed.

**Actions** (Box, float64, one entry per channel in ``actions``, clipped to the limits):

============  =====  =============================  ==================================================
channel       unit   default limit                  why
============  =====  =============================  ==================================================
torque_m1     N m    0.05 (``torque_limit_n_m``)    the issue's motor (``controllers.
                                                    DEFAULT_TORQUE_LIMIT_N_M``); gravity's moment on
                                                    M1 at 10 deg is 0.12 N m
torque_m2     N m    0.05
support_x     m/s^2  1.0 (``support_limit_m_s2``)   its moment on M1, m1 OC1 a = 0.069 N m, is of the
                                                    motors' size; a 1 m/s^2 sine at mode 1 (0.88 Hz)
                                                    moves the support +-33 mm, a lab shaker's stroke
                                                    (the stroke itself is not modelled: a held
                                                    acceleration would run any shaker off its end)
============  =====  =============================  ==================================================

``pivot_z``, the vertical support acceleration, is no action: it has no linear effect (a
parametric input, ``linear``); the tongue task drives it (``tasks``). Supports need
``MujocoPlant(targets=...)`` on MuJoCo: the environment compiles the actuators it uses.

**Observations** (Box, float64, clipped to its bounds): ``observation="state"``: (phi1, phi2 rad,
omega1, omega2 rad/s), exact; ``"nodes"``: the same four as the BNO055 nodes deliver them
(``observe.NodeObserver``: 80 Hz, the sensor model's noise, latency and loss of ``nodes``, a
``Bno055``; each node's newest sample carried forward by its rate), then each node's sample age
(s, capped at ``AGE_CAP_S``; the cap also before a node's first sample, when the node's angle
and rate read 0). The tongue task appends cos and sin of its drive's phase. Bounds: angles
+-2 pi, rates +-50 rad/s.

**Episodes** start at a random release (``tasks``; drawn from ``np_random``, so a seed fixes
the episode) or at the state in the reset's options (``phi0_rad``, ``omega0_rad_s``, and for the
hold task ``target_amplitudes_rad``). They end (terminated) when a pendulum goes over the top
(|phi| > pi: the springs would wind up) or spins faster than ``OMEGA_LIMIT_RAD_S``, and are
truncated after ``episode_s`` (20 s, 2000 steps).

**info**: ``state`` (4,) the true state; ``mode_amplitudes_rad`` (2,)
(``LinearRig.mode_amplitudes_rad``); ``task_amplitudes_rad`` and ``targets_rad`` (2,) what
the reward scores; ``energy_j`` the mechanical energy above rest; ``t_s``; for node observations
``age_s`` (2,) uncapped.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any, cast

import gymnasium
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from pendsim_mj.control.controllers import DEFAULT_TORQUE_LIMIT_N_M
from pendsim_mj.control.observe import NodeObserver
from pendsim_mj.control.plant import PLANT_ENGINES, FastPlant, MujocoPlant
from pendsim_mj.control.tasks import DEFAULT_EFFORT_WEIGHT, DEFAULT_TARGET_AMPLITUDES_RAD, Task, check_targets
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.drives import Target
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams
from pendsim_mj.sensors.bno055 import Bno055

Floats = NDArray[np.float64]
ACTION_CHANNELS = ("torque_m1", "torque_m2", "support_x")
"""The channels an action may drive (``drives.Target`` values)."""
OBSERVATIONS = ("state", "nodes")
"""The observation kinds (module docstring)."""
DEFAULT_SUPPORT_LIMIT_M_S2 = 1.0
"""The default limit of the horizontal support acceleration, m/s^2 (module docstring)."""
DEFAULT_EPISODE_S = 20.0
"""The default episode length, s."""
PHI_BOUND_RAD = 2.0 * math.pi
"""The observation space's bound on the angles, rad."""
OMEGA_BOUND_RAD_S = 50.0
"""The observation space's bound on the rates, rad/s."""
OMEGA_LIMIT_RAD_S = 25.0
"""A rate above this ends the episode (terminated), rad/s: about eight times a 30 deg swing's peak."""
AGE_CAP_S = 1.0
"""The largest sample age an observation shows, s."""
RESET_OPTIONS = ("phi0_rad", "omega0_rad_s", "target_amplitudes_rad")
"""The keys a reset's options may hold."""


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """The options of both environments (``gymnasium.make(..., **options)``), checked.

    Attributes:
      task: one of ``tasks.TASKS``.
      engine: "fast" (the fast engine's force law, ``FastPlant``) or "mujoco" (the vector
        environment: "fast" only).
      observation: "state" or "nodes" (module docstring).
      actions: the driven channels, a subset of ``ACTION_CHANNELS`` (order kept as given).
      params: the simulated rig.
      dt_s: the control period, s.
      episode_s: the episode length, s (whole periods).
      torque_limit_n_m: each motor's limit, N m.
      support_limit_m_s2: the support acceleration's limit, m/s^2.
      effort_weight, release_rad, target_amplitudes_rad, tongue_mode, tongue_level_m_s2: the
        task's (``tasks.Task``).
      nodes: the node model of node observations (default ``Bno055()``: noise, no loss or latency).
    """

    task: str = "damp"
    engine: str = "fast"
    observation: str = "state"
    actions: tuple[str, ...] = ("torque_m1", "torque_m2")
    params: RigParams = DEFAULT_PARAMS
    dt_s: float = 0.01
    episode_s: float = DEFAULT_EPISODE_S
    torque_limit_n_m: float = DEFAULT_TORQUE_LIMIT_N_M
    support_limit_m_s2: float = DEFAULT_SUPPORT_LIMIT_M_S2
    effort_weight: float = DEFAULT_EFFORT_WEIGHT
    release_rad: float | None = None
    target_amplitudes_rad: tuple[float, float] = DEFAULT_TARGET_AMPLITUDES_RAD
    tongue_mode: int = 1
    tongue_level_m_s2: float | None = None
    nodes: Bno055 | None = None

    def __post_init__(self) -> None:
        if self.engine not in PLANT_ENGINES:
            raise ParameterError(f"unknown engine {self.engine!r}; allowed: {', '.join(PLANT_ENGINES)}")
        if self.observation not in OBSERVATIONS:
            raise ParameterError(f"unknown observation {self.observation!r}; allowed: {', '.join(OBSERVATIONS)}")
        chosen = (self.actions,) if isinstance(self.actions, str) else tuple(self.actions)
        if not chosen or any(c not in ACTION_CHANNELS for c in chosen) or len(set(chosen)) != len(chosen):
            raise ParameterError(
                f"actions must be distinct channels among {', '.join(ACTION_CHANNELS)}, got {self.actions!r}"
            )
        object.__setattr__(self, "actions", chosen)
        if not isinstance(self.params, RigParams):
            raise ParameterError(f"params must be a RigParams, got {type(self.params).__name__}")
        highs = {"dt_s": 0.1, "episode_s": 1e5, "torque_limit_n_m": 10.0, "support_limit_m_s2": 100.0}
        for name, high in highs.items():
            value = getattr(self, name)
            number = not isinstance(value, bool) and isinstance(value, (int, float))
            if not (number and math.isfinite(value) and 0 < value <= high):
                raise ParameterError(f"{name} must be a number in (0, {high:g}], got {value!r}")
            object.__setattr__(self, name, float(value))
        if self.nstep < 1 or abs(self.nstep * self.dt_s - self.episode_s) > 1e-9 * self.episode_s:
            raise ParameterError(f"episode_s must be whole control periods of {self.dt_s} s, got {self.episode_s}")
        if self.nodes is not None and not isinstance(self.nodes, Bno055):
            raise ParameterError(f"nodes must be a Bno055 node model, got {type(self.nodes).__name__}")
        object.__setattr__(self, "target_amplitudes_rad", check_targets(self.target_amplitudes_rad))

    @classmethod
    def from_options(cls, options: Mapping[str, Any]) -> EnvConfig:
        """The configuration of keyword options, ParameterError naming an unknown one."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ParameterError(f"unknown option(s) {', '.join(unknown)}; allowed: {', '.join(sorted(known))}")
        return cls(**options)

    @property
    def nstep(self) -> int:
        """Steps per episode."""
        return round(self.episode_s / self.dt_s)

    @property
    def channels(self) -> tuple[Target, ...]:
        """The driven channels as ``Target``s, in the action's order."""
        return tuple(Target(c) for c in self.actions)

    @property
    def limits(self) -> Floats:
        """(k,) each action channel's limit (N m or m/s^2)."""
        return np.array([self.support_limit_m_s2 if t.is_support else self.torque_limit_n_m for t in self.channels])

    def task_of(self) -> Task:
        """The task on the configured rig."""
        return Task(
            self.task,
            self.params,
            release_rad=self.release_rad,
            target_amplitudes_rad=self.target_amplitudes_rad,
            tongue_mode=self.tongue_mode,
            tongue_level_m_s2=self.tongue_level_m_s2,
            effort_weight=self.effort_weight,
        )

    def observation_names(self) -> tuple[str, ...]:
        """The observation's entries in order (module docstring)."""
        names = ["phi1_rad", "phi2_rad", "omega1_rad_s", "omega2_rad_s"]
        if self.observation == "nodes":
            names += ["age1_s", "age2_s"]
        if self.task == "tongue":
            names += ["drive_cos", "drive_sin"]
        return tuple(names)


def observation_bounds(config: EnvConfig) -> tuple[Floats, Floats]:
    """(low, high) of one observation (module docstring)."""
    bound = {"phi1_rad": PHI_BOUND_RAD, "phi2_rad": PHI_BOUND_RAD, "omega1_rad_s": OMEGA_BOUND_RAD_S}
    bound |= {"omega2_rad_s": OMEGA_BOUND_RAD_S, "age1_s": AGE_CAP_S, "age2_s": AGE_CAP_S}
    bound |= {"drive_cos": 1.0, "drive_sin": 1.0}
    names = config.observation_names()
    high = np.array([bound[n] for n in names])
    low = np.array([0.0 if n.startswith("age") else -bound[n] for n in names])
    return low, high


def observation_space(config: EnvConfig) -> spaces.Box[np.float64]:
    """One member's observation space."""
    low, high = observation_bounds(config)
    return cast("spaces.Box[np.float64]", spaces.Box(low, high, dtype=np.float64))


def action_space(config: EnvConfig) -> spaces.Box[np.float64]:
    """One member's action space: +-each channel's limit."""
    return cast("spaces.Box[np.float64]", spaces.Box(-config.limits, config.limits, dtype=np.float64))


def clip_actions(config: EnvConfig, actions: object, n: int | None = None) -> tuple[Floats, Floats]:
    """The actions clipped to the limits, (n, k) (one member, n None: (1, k) from (k,)), and each
    member's effort (n,), the mean over channels of (u / limit)^2. ParameterError for a wrong
    shape or a non-finite entry."""
    k = len(config.actions)
    a = np.asarray(actions, dtype=np.float64)
    expected = (k,) if n is None else (n, k)
    if a.shape != expected:
        raise ParameterError(f"actions must have shape {expected} ({', '.join(config.actions)}), got {a.shape}")
    a = a.reshape(-1, k)
    if not np.all(np.isfinite(a)):
        raise ParameterError("actions must be finite")
    limits = config.limits
    applied = np.clip(a, -limits, limits)
    share = applied / limits
    share *= share
    effort = share[:, 0].copy()
    for c in range(1, k):  # columns, not a reduction along the short axis: 5x faster for a batch
        effort += share[:, c]
    return applied, effort / k


def leaves_envelope(x: Floats) -> NDArray[np.bool_]:
    """(n,) True where a state (n, 4) ends the episode: a pendulum over the top or too fast."""
    return np.asarray(
        (np.abs(x[:, 0]) > math.pi)
        | (np.abs(x[:, 1]) > math.pi)
        | (np.abs(x[:, 2]) > OMEGA_LIMIT_RAD_S)
        | (np.abs(x[:, 3]) > OMEGA_LIMIT_RAD_S)
    )


def check_reset_options(
    options: Mapping[str, Any] | None, task: Task
) -> tuple[Floats | None, tuple[float, float] | None]:
    """(start state (4,) or None, the hold task's targets or None) from a reset's options."""
    if options is None:
        return None, None
    if not isinstance(options, Mapping):
        raise ParameterError(f"reset options must be a dict, got {type(options).__name__}")
    unknown = sorted(set(options) - set(RESET_OPTIONS))
    if unknown:
        raise ParameterError(f"unknown reset option(s) {', '.join(unknown)}; allowed: {', '.join(RESET_OPTIONS)}")
    start = None
    if "phi0_rad" in options or "omega0_rad_s" in options:
        phi = np.asarray(options.get("phi0_rad", (0.0, 0.0)), dtype=float)
        omega = np.asarray(options.get("omega0_rad_s", (0.0, 0.0)), dtype=float)
        if phi.shape != (2,) or not np.all(np.isfinite(phi)) or np.any(np.abs(phi) > math.pi):
            raise ParameterError(f"phi0_rad must be two angles in [-pi, pi] rad, got {options.get('phi0_rad')!r}")
        if omega.shape != (2,) or not np.all(np.isfinite(omega)) or np.any(np.abs(omega) > OMEGA_LIMIT_RAD_S):
            given = options.get("omega0_rad_s")
            raise ParameterError(f"omega0_rad_s must be two rates within +-{OMEGA_LIMIT_RAD_S:g} rad/s, got {given!r}")
        start = np.concatenate([phi, omega])
    targets = None
    if "target_amplitudes_rad" in options:
        if task.name != "hold":
            raise ParameterError(f"target_amplitudes_rad is an option of the hold task only, not of {task.name!r}")
        targets = check_targets(options["target_amplitudes_rad"])
    return start, targets


def shown_nodes(state: Floats, age_s: Floats) -> tuple[Floats, Floats]:
    """What a node observation shows of the nodes' newest samples: 0 for a node without one yet,
    ages capped at ``AGE_CAP_S``."""
    return np.where(np.isfinite(state), state, 0.0), np.minimum(age_s, AGE_CAP_S)


class CoupledPendulumsEnv(gymnasium.Env[Floats, Floats]):
    """The rig as a Gymnasium environment (module docstring).

    Args:
      render_mode: None or "rgb_array" (a side view of both pendulums, ``render_rgb``).
      **options: ``EnvConfig``'s attributes (task, engine, observation, actions, params, ...).

    Raises:
      ParameterError: an unknown or bad option, naming it.
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 100}  # noqa: RUF012 (Gymnasium's)

    def __init__(self, *, render_mode: str | None = None, **options: Any) -> None:
        self.config = EnvConfig.from_options(options)
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ParameterError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        cfg = self.config
        self.task = cfg.task_of()
        self.observation_space = observation_space(cfg)
        self.action_space = action_space(cfg)
        self._low, self._high = observation_bounds(cfg)
        self._index = np.array([t.index for t in cfg.channels], dtype=int)
        driven = (*cfg.channels, Target.PIVOT_Z) if self.task.drives_pivot else cfg.channels
        self.plant: FastPlant | MujocoPlant = (
            FastPlant(cfg.params, dt_s=cfg.dt_s)
            if cfg.engine == "fast"
            else MujocoPlant(cfg.params, dt_s=cfg.dt_s, targets=driven)
        )
        self._nodes: NodeObserver | None = None
        self._x: Floats | None = None
        self._k = 0
        self._targets = np.zeros((1, 2))
        self._age = np.zeros(2)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Floats, dict[str, Any]]:
        """Start an episode: a random release (``tasks``) or the state in ``options``."""
        super().reset(seed=seed)
        start, targets = check_reset_options(options, self.task)
        release = self.task.release(self.np_random)  # drawn also when options give the state: one stream
        node_seed = int(self.np_random.integers(2**63))
        x0 = release if start is None else start
        self._x = self.plant.reset(x0[:2], x0[2:])[0]
        self._k = 0
        self._targets = self.task.targets(self._x[None], targets)
        if self.config.observation == "nodes":
            self._nodes = NodeObserver(self.config.nodes, dt_s=self.config.dt_s, seed=node_seed)
            seen = self._nodes.reset(self._x)
            shown, self._age = seen.state, seen.age_s
        else:
            shown = self._x
        amplitudes = self.task.amplitudes(self._x[None])
        return self._observation(shown), self._info(amplitudes)

    def step(self, action: Floats) -> tuple[Floats, float, bool, bool, dict[str, Any]]:
        """Hold ``action`` over one control period; (observation, reward, terminated, truncated, info)."""
        if self._x is None:
            raise ParameterError("call reset() before step()")
        cfg = self.config
        applied, effort = clip_actions(cfg, action)
        u = np.zeros(4)
        u[self._index] = applied[0]
        if self.task.drives_pivot:
            u[Target.PIVOT_Z.index] = self.task.pivot_m_s2(np.array([(self._k + 0.5) * cfg.dt_s]))[0]
        x_prev = self._x
        self._x = self.plant.step(u)[0]
        self._k += 1
        amplitudes = self.task.amplitudes(self._x[None])
        reward = float(self.task.reward(amplitudes, self._targets, effort)[0])
        terminated = bool(leaves_envelope(self._x[None])[0])
        truncated = self._k >= cfg.nstep
        if self._nodes is not None:
            seen = self._nodes.observe(self._k * cfg.dt_s, x_prev, self._x)
            shown, self._age = seen.state, seen.age_s
        else:
            shown = self._x
        return self._observation(shown), reward, terminated, truncated, self._info(amplitudes)

    def _observation(self, shown: Floats) -> Floats:
        parts = [shown]
        if self.config.observation == "nodes":
            state, age = shown_nodes(shown, self._age)
            parts = [state, age]
        if self.task.drives_pivot:
            parts.append(self.task.phase(np.array([self._k * self.config.dt_s]))[0])
        return np.clip(np.concatenate(parts), self._low, self._high)

    def _info(self, amplitudes: Floats) -> dict[str, Any]:
        assert self._x is not None
        info: dict[str, Any] = {
            "state": self._x.copy(),
            "mode_amplitudes_rad": amplitudes[0].copy()
            if self.task.modal
            else self.task.linear.mode_amplitudes_rad(self._x),
            "task_amplitudes_rad": amplitudes[0].copy(),
            "targets_rad": self._targets[0].copy(),
            "energy_j": float(self.plant.energy_j()[0]),
            "t_s": self._k * self.config.dt_s,
        }
        if self.config.observation == "nodes":
            info["age_s"] = self._age.copy()
        return info

    def render(self) -> NDArray[np.uint8] | None:
        """A side view of both pendulums (``render_rgb``) for render_mode "rgb_array", else None."""
        if self.render_mode != "rgb_array" or self._x is None:
            return None
        return render_rgb(self._x, self.config.params)


def render_rgb(x: Floats, params: RigParams, size_px: int = 240) -> NDArray[np.uint8]:
    """(size_px, size_px, 3) a side view of the rig at state x (4,): M1's rod and disk blue, M2's
    red, the pivot at the top centre; drawn in numpy (no plotting library), about 1 ms."""
    image = np.full((size_px, size_px, 3), 255, dtype=np.uint8)
    rod_m = params.rod_length_m
    scale = 0.8 * size_px / rod_m  # px per m
    pivot = np.array([0.12 * size_px, 0.5 * size_px])  # (row, column)
    colours = ((31, 119, 180), (214, 39, 40))
    disks_m = (params.om1_m, params.om2_m)
    for n in (1, 0):  # M2 behind M1
        direction = np.array([math.cos(x[n]), math.sin(x[n])])  # paper frame: x down, y right
        points = pivot + np.outer(np.linspace(0.0, rod_m * scale, 4 * size_px), direction)
        _dot(image, points, 1, colours[n])
        _dot(image, (pivot + disks_m[n] * scale * direction)[None], 7, colours[n])
    _dot(image, pivot[None], 3, (0, 0, 0))
    return image


def _dot(image: NDArray[np.uint8], points: Floats, radius: int, colour: Sequence[int]) -> None:
    """Fill discs of ``radius`` px around (row, column) points (m, 2), clipped to the image."""
    size = image.shape[0]
    offsets = np.arange(-radius, radius + 1)
    dr, dc = np.meshgrid(offsets, offsets, indexing="ij")
    inside = dr * dr + dc * dc <= radius * radius
    rows = (np.rint(points[:, 0])[:, None] + dr[inside][None]).astype(int).ravel()
    cols = (np.rint(points[:, 1])[:, None] + dc[inside][None]).astype(int).ravel()
    keep = (rows >= 0) & (rows < size) & (cols >= 0) & (cols < size)
    image[rows[keep], cols[keep]] = colour
