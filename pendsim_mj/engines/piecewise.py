"""A run whose rig parameters change at given instants: each piece simulated from the state the
previous one ended in, with its own parameters (a rig fault: a spring weakening, a hinge
stiffening; ``bridge.acquire.rig_faults``). Pure: no I/O.

A change happens on the integration grid: piece j holds from step ``first_step[j]`` to the next
piece's first step. The row at a change belongs to the new piece (its state is the old piece's
last state; its accelerations, spring forces and energies are the new parameters'). A linear
ramp is approximated by ``schedule_pieces``: constant pieces, each with the ramp's value at its
midpoint (error in the parameter at most half a piece's change; the mean over the piece exact).

    ramp = ParameterChange("c1_n_m", 5.864, first_step=2000, last_step=8000)  # 20 s to 80 s at 10 ms
    pieces = schedule_pieces(DEFAULT_PARAMS, [ramp], ramp_every=10)  # 0.1 s pieces
    traj = run_pieces("mujoco", pieces, (0.5, 0.0), (0.0, 0.0), 100.0, 0.01)
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from pendsim_mj.engines import dispatch
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.checks import check_step
from pendsim_mj.rig.params import RigParams

Piece = tuple[int, RigParams]
"""(first integration step, the rig's parameters from that step on)."""


def run_pieces(
    engine: str,
    pieces: Sequence[Piece],
    phi0_rad: ArrayLike,
    omega0_rad_s: ArrayLike = (0.0, 0.0),
    duration_s: float = 120.0,
    dt_s: float = 0.01,
) -> Trajectory:
    """One planar run on the named engine (``dispatch.run``) whose parameters change between pieces.

    Args:
      engine: "mujoco", "reference" or "fast".
      pieces: (first step, params) in increasing step order, the first at step 0; a piece
        that starts at or after the run's last step is refused.
      phi0_rad, omega0_rad_s: (2,) release state, rad and rad/s.
      duration_s, dt_s: the whole run and its step, s (``check_step``).

    Returns:
      The run as one Trajectory (n = duration_s / dt_s + 1 rows, t_s = k dt_s); ``params`` is the
      first piece's; ``dissipated_j`` runs on across the pieces.

    Raises:
      ParameterError: pieces out of order, not starting at 0, or past the run's end.
    """
    nstep = check_step(duration_s, dt_s)
    firsts = [first for first, _ in pieces]
    if not firsts or firsts[0] != 0:
        raise ParameterError(f"the first piece must start at step 0, got {firsts[:1]}")
    if any(b <= a for a, b in itertools.pairwise(firsts)) or firsts[-1] >= nstep:
        raise ParameterError(f"pieces must start at increasing steps below {nstep}, got {firsts}")
    phi, omega = np.asarray(phi0_rad, dtype=float), np.asarray(omega0_rad_s, dtype=float)
    parts: list[Trajectory] = []
    dissipated_j = 0.0
    for j, (first, params) in enumerate(pieces):
        last = firsts[j + 1] if j + 1 < len(pieces) else nstep
        part = dispatch.run(engine, params, phi, omega, (last - first) * dt_s, dt_s)
        part = dataclasses.replace(part, dissipated_j=part.dissipated_j + dissipated_j)
        phi, omega = part.phi_rad[-1].copy(), part.omega_rad_s[-1].copy()
        dissipated_j = float(part.dissipated_j[-1])
        parts.append(part if j + 1 == len(pieces) else part.rows(slice(0, -1)))  # the change's row: the new piece's
    return _joined(parts, pieces[0][1], nstep, dt_s)


def _joined(parts: list[Trajectory], params: RigParams, nstep: int, dt_s: float) -> Trajectory:
    """Consecutive pieces' rows as one trajectory."""
    fields: dict[str, Any] = {
        name: np.concatenate([getattr(p, name) for p in parts]) for name in Trajectory.ARRAY_FIELDS
    }
    tilt_rate = None
    if parts[0].tilt_rate_rad_s is not None:
        tilt_rate = np.concatenate([p.tilt_rate_rad_s for p in parts if p.tilt_rate_rad_s is not None])
    joined = dataclasses.replace(
        parts[0], t_s=np.arange(nstep + 1) * dt_s, params=params, tilt_rate_rad_s=tilt_rate, **fields
    )
    assert len(joined.phi_rad) == nstep + 1, "pieces must cover the run"
    return joined


@dataclasses.dataclass(frozen=True)
class ParameterChange:
    """A rig parameter changing to ``value``: a step at ``first_step`` (``last_step`` equal to it) or
    a linear ramp from its value before (at ``first_step``) to ``value`` (at ``last_step``).

    Attributes:
      name: a RigParams field, e.g. "c1_n_m".
      value: the value after the change, in the field's unit.
      first_step, last_step: integration steps (t = step dt_s after the release).
    """

    name: str
    value: float
    first_step: int
    last_step: int

    def __post_init__(self) -> None:
        if self.name not in {f.name for f in dataclasses.fields(RigParams)}:
            raise ParameterError(f"unknown rig parameter {self.name!r}")
        if not 0 <= self.first_step <= self.last_step:
            raise ParameterError(
                f"a change needs 0 <= first_step <= last_step, got {self.first_step}, {self.last_step}"
            )


def schedule_pieces(base: RigParams, changes: Sequence[ParameterChange], *, ramp_every: int) -> list[Piece]:
    """The pieces of a run with ``changes`` (changes of one parameter must not overlap in time:
    each starts from the value the one before left).

    A step changes the parameter at its first step; a ramp is held constant over pieces of
    ``ramp_every`` steps (the last one shorter), each at the ramp's value at the piece's midpoint,
    and reaches ``value`` at its last step. Consecutive pieces with equal parameters merge.

    Returns: [(first step, params)], the first at step 0 with ``base``.
    """
    if ramp_every < 1:
        raise ParameterError(f"ramp_every must be >= 1 step, got {ramp_every}")
    ordered = sorted(changes, key=lambda c: (c.first_step, c.last_step))
    by_name: dict[str, list[ParameterChange]] = {}
    for c in ordered:
        earlier = by_name.setdefault(c.name, [])
        if earlier and c.first_step < max(earlier[-1].last_step, earlier[-1].first_step + 1):
            raise ParameterError(f"two changes of {c.name} overlap (steps {earlier[-1].first_step} and {c.first_step})")
        earlier.append(c)
    starts = {0}
    for c in ordered:
        starts.update(range(c.first_step, c.last_step, ramp_every))
        starts.add(c.last_step)
    edges = sorted(starts)
    pieces: list[Piece] = []
    for j, a in enumerate(edges):
        b = edges[j + 1] if j + 1 < len(edges) else a + 1
        values = {name: _value_at(getattr(base, name), steps, 0.5 * (a + b), a) for name, steps in by_name.items()}
        params = base.with_overrides(**values) if values else base
        if not pieces or pieces[-1][1] != params:
            pieces.append((a, params))
    return pieces


def _value_at(base_value: float, changes: list[ParameterChange], middle: float, first: int) -> float:
    """A parameter's value over the piece that starts at step ``first`` (midpoint ``middle``)."""
    value = base_value
    for c in changes:
        if first >= c.last_step:
            value = c.value
        elif first >= c.first_step:  # within a ramp
            share = (middle - c.first_step) / (c.last_step - c.first_step)
            return value + share * (c.value - value)
        else:
            break
    return value
