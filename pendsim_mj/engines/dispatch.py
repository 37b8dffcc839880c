"""One entry point for the engines: ``run_batch("mujoco" | "reference" | "fast", ...)``.

The MuJoCo model (``pendsim_mj.engines.simulation``), the independent planar reference
(``pendsim_mj.engines.reference``) and the compiled planar kernel (``pendsim_mj.engines.fast_planar``, the
reference's equations in closed form, many times faster) take the same arguments and return the
same ``Trajectory`` (the ``Engine`` protocol); ``ENGINES`` names them, and this module picks one
by name, importing MuJoCo (or numba) only when it is asked for.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator, Mapping, Sequence
from typing import get_args

from numpy.typing import ArrayLike

from pendsim_mj.engines.protocol import Engine, EngineName
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.params import RigParams

ENGINE_NAMES: tuple[EngineName, ...] = get_args(EngineName)
"""("mujoco", "reference", "fast"): the engines' names in the order the command line lists them."""
FAST_PATH: dict[str, EngineName] = {"reference": "fast"}
"""The engine that computes an engine's runs where they must be fast (one or two members, long
runs): the planar reference's on its compiled kernel ``fast_planar``, the same equations, tested
equal to it to 1e-12 rad (``reference`` stays the paper-faithful check the tests use)."""
_PLANAR = {"reference": "the reference is planar", "fast": "the fast engine is planar"}


class _Engines(Mapping[str, Engine]):
    """Each engine's batch entry point by name; its module is imported on the first lookup, so that
    the names (and ``in``) cost no import of MuJoCo or numba (seconds at start-up)."""

    def __getitem__(self, name: str) -> Engine:
        if name == "mujoco":
            from pendsim_mj.engines.simulation import simulate_batch

            return simulate_batch
        if name == "reference":
            from pendsim_mj.engines.reference import solve_batch

            return solve_batch
        if name == "fast":
            from pendsim_mj.engines.fast_planar import solve_batch as solve_fast

            return solve_fast
        raise KeyError(name)

    def __iter__(self) -> Iterator[str]:
        return iter(ENGINE_NAMES)

    def __len__(self) -> int:
        return len(ENGINE_NAMES)

    def __contains__(self, name: object) -> bool:
        return name in ENGINE_NAMES

    def __repr__(self) -> str:
        return f"ENGINES{ENGINE_NAMES}"


ENGINES: Mapping[str, Engine] = _Engines()
"""``ENGINE_NAMES`` -> the engine's batch entry point (``simulation.simulate_batch``,
``reference.solve_batch``, ``fast_planar.solve_batch``), each an ``Engine``."""


def run_batch(
    engine: str,
    params: RigParams | Sequence[RigParams],
    phi0_rad: ArrayLike,
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    spatial: bool = False,
    drive: Drive | None = None,
) -> Trajectory:
    """A batch of runs on the named engine; arguments as ``Engine`` (``simulation.simulate_batch``).

    Args:
      engine: "mujoco", "reference" or "fast".
      spatial: the spatial variant (tilt freedoms; MuJoCo only).
      drive: torques and support motion for every run (``pendsim_mj.rig.drives``), or None.

    Raises:
      ParameterError: an unknown engine, or the spatial variant asked of the reference.
    """
    return _engine(engine, spatial)(params, phi0_rad, omega0_rad_s, duration_s, dt_s, drive=drive)


def run(
    engine: str,
    params: RigParams,
    phi0_rad: ArrayLike,
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    spatial: bool = False,
    drive: Drive | None = None,
) -> Trajectory:
    """One run on the named engine (``run_batch`` with one member)."""
    return run_batch(engine, params, phi0_rad, omega0_rad_s, duration_s, dt_s, spatial=spatial, drive=drive).member(0)


def run_blocks(
    engine: str,
    params: RigParams,
    phi0_rad: ArrayLike,
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    block_steps: int = 3000,
    spatial: bool = False,
    drive: Drive | None = None,
) -> Iterator[tuple[int, Trajectory]]:
    """One run on the named engine, in blocks of ``block_steps`` steps (memory independent of
    the duration; the rows equal those of ``run``). Yields (first row, block); consecutive
    blocks share their boundary row (``simulation.simulate_blocks``). A driven run on the
    reference engine is solved whole and then cut (its support motion is integrated from the
    start), so its memory grows with the duration; so does a driven run on the fast engine."""
    _check_engine(engine, spatial)
    if engine == "mujoco":
        from pendsim_mj.engines.simulation import simulate_blocks
        from pendsim_mj.rig.model import PLANAR, SPATIAL

        variant = SPATIAL if spatial else PLANAR
        return simulate_blocks(
            params, phi0_rad, omega0_rad_s, duration_s, dt_s, block_steps=block_steps, variant=variant, drive=drive
        )
    if drive is not None:
        return _cut(run(engine, params, phi0_rad, omega0_rad_s, duration_s, dt_s, drive=drive), block_steps)
    if engine == "reference":
        from pendsim_mj.engines.reference import solve_blocks
    else:
        from pendsim_mj.engines.fast_planar import solve_blocks
    return solve_blocks(params, phi0_rad, omega0_rad_s, duration_s, dt_s, block_steps=block_steps)


def _check_engine(engine: str, spatial: bool) -> None:
    """ParameterError for a name not in ``ENGINES``, or the spatial variant of a planar engine."""
    if engine not in ENGINES:
        raise ParameterError(f"unknown engine {engine!r}; allowed: {', '.join(ENGINES)}")
    if spatial and engine in _PLANAR:
        raise ParameterError(f"the spatial model runs in MuJoCo only; {_PLANAR[engine]}")


def _engine(engine: str, spatial: bool) -> Engine:
    """The named engine, checked (``_check_engine``); MuJoCo's spatial variant where ``spatial``."""
    _check_engine(engine, spatial)
    if spatial:
        from pendsim_mj.engines.simulation import simulate_batch
        from pendsim_mj.rig.model import SPATIAL

        return functools.partial(simulate_batch, variant=SPATIAL)
    return ENGINES[engine]


def _cut(traj: Trajectory, block_steps: int) -> Iterator[tuple[int, Trajectory]]:
    """A whole run as blocks sharing their boundary rows (as ``simulate_blocks`` yields them)."""
    n = len(traj.t_s) - 1
    for first in range(0, n, block_steps):
        yield first, traj.rows(slice(first, min(first + block_steps, n) + 1))


def whole_steps_s(duration_s: float, dt_s: float = 0.01) -> float:
    """The longest duration of whole steps not over ``duration_s``, s."""
    return math.floor(duration_s / dt_s + 1e-9) * dt_s
