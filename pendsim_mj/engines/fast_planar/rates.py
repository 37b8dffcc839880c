"""One run's rates at given instants with their exact sensitivities (``rates_at``), and the
normal equations of a fit to observed rates summed in the same pass (``normal_equations_at``):
the model of the damping fit, ``pendsim_mj.estimation.planar_fit``. Both run
``kernel._rates_kernel``, the RK4 step of ``integrate`` with the variational equations beside it."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.engines.fast_planar.closed_form import NINPUT, FloatArray, _check_coef
from pendsim_mj.engines.fast_planar.kernel import _rates_kernel
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.drives import NSTAGE

_UNDRIVEN_STEPS = np.zeros((0, NSTAGE, NINPUT))  # ``rates_at`` without inputs

# The force-law constants (rows of ``COEFFICIENTS``) beside the hinge losses whose sensitivity the
# kernel computes (``kernel._coef_partial``, codes 8...): what the calibration differentiates by.
COEF_SENSITIVITIES = (
    "j1_kg_m2",
    "j2_kg_m2",
    "gravity1_n_m",
    "gravity2_n_m",
    "coupling_sin_n_m",
    "coupling_cos_n_m",
    "frame_sin_n_m",
    "frame_cos_n_m",
    "moc1_kg_m",
    "moc2_kg_m",
)
# Unknowns whose sensitivity ``rates_at`` can return (``wrt`` codes): the start state, then the
# hinge losses (rows _B1, _B2, _F1, _F2 of the coefficients), then the other force-law constants.
SENSITIVITY_NAMES = (
    "phi1_0",
    "phi2_0",
    "omega1_0",
    "omega2_0",
    "b1_n_m_s",
    "b2_n_m_s",
    "friction1_n_m",
    "friction2_n_m",
    *COEF_SENSITIVITIES,
)

_NOTHING = np.zeros(0)  # the kernel's arrays a mode does not use
_NOTHING_2D = np.zeros((0, 0))


def _rates_setup(
    coef: FloatArray,
    phi0_rad: Sequence[float] | FloatArray,
    omega0_rad_s: Sequence[float] | FloatArray,
    at_s: tuple[FloatArray, FloatArray],
    dt_s: float,
    release_s: float,
    wrt: Sequence[str],
    inputs: FloatArray | None,
) -> tuple[FloatArray, FloatArray, int, FloatArray, NDArray[np.int64], tuple[FloatArray, ...]]:
    """The checked arguments of ``_rates_kernel`` shared by ``rates_at`` and
    ``normal_equations_at``: (k, y0, nstep, held, wrt codes, instants)."""
    k = _check_coef(coef, 1)
    unknown = [name for name in wrt if name not in SENSITIVITY_NAMES]
    if unknown:
        raise ParameterError(f"rates_at: unknown sensitivity {unknown[0]!r}; allowed: {', '.join(SENSITIVITY_NAMES)}")
    codes = np.array([SENSITIVITY_NAMES.index(name) for name in wrt], dtype=np.int64)
    at = tuple(np.ascontiguousarray(a, dtype=np.float64) for a in at_s)
    end = max((float(a[-1]) for a in at if len(a)), default=0.0) - release_s
    nstep = max(1, math.ceil(end / dt_s) + 1)
    y0 = np.array([*np.asarray(phi0_rad, dtype=float), *np.asarray(omega0_rad_s, dtype=float)])
    held = _UNDRIVEN_STEPS
    if inputs is not None:
        held = np.asarray(inputs, dtype=np.float64)
        if held.ndim == 2 and held.shape[1] == NINPUT:  # held over each step: at its three stages
            held = np.repeat(held[:, None, :], NSTAGE, axis=1)
        if held.ndim != 3 or held.shape[1:] != (NSTAGE, NINPUT) or held.shape[0] < nstep:
            raise ParameterError(
                f"rates_at: inputs must have shape (>= {nstep}, {NSTAGE}, {NINPUT}) or (>= {nstep}, {NINPUT}), "
                f"got {np.shape(inputs)}"
            )
        held = np.ascontiguousarray(held)
    return k, y0, nstep, held, codes, at


def normal_equations_at(
    coef: FloatArray,
    phi0_rad: Sequence[float] | FloatArray,
    omega0_rad_s: Sequence[float] | FloatArray,
    at_s: tuple[FloatArray, FloatArray],
    observed_rad_s: tuple[FloatArray, FloatArray],
    sigma_rad_s: Sequence[float] | FloatArray,
    dt_s: float,
    *,
    release_s: float = 0.0,
    wrt: Sequence[str] = (),
    release_column: bool = False,
    timing_column: bool = False,
    inputs: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, float]:
    """The normal equations of a least-squares fit of the rates of ``rates_at`` to observed rates,
    summed over the instants in one kernel pass: memory independent of the number of instants
    (nothing of size m_n is stored; the same integration as ``rates_at``, its accumulate mode).

    Each instant i of node n contributes the normalised residual r_i = (rate - observed) / sigma_n
    and the Jacobian row J_i = (d rate / d wrt, [d rate / d release_s], [0 for node 1,
    -d rate / d release_s for node 2]) / sigma_n: the sensitivities of ``rates_at``, then the
    release offset's column where ``release_column``, then, where ``timing_column``, that of a
    shift of node 2's instants (a later instant: d rate / d t = -d rate / d release_s). Instants
    before the release: rate 0, a zero row.

    Args:
      coef, phi0_rad, omega0_rad_s, at_s, dt_s, release_s, wrt, inputs: as ``rates_at``.
      observed_rad_s: each node's observed rate at its instants, rad/s: (m1,), (m2,).
      sigma_rad_s: (2,) each node's noise sigma, rad/s.
      release_column, timing_column: add those columns (above).

    Returns:
      (J^T J (Q, Q), J^T r (Q,), r.r) with Q = len(wrt) + release_column + timing_column
      (J in 1/sigma per unit of each unknown, r dimensionless). Summed in the instants' order
      (not BLAS's blocked order: equal to it to rounding, ~1e-13 relative).
    """
    k, y0, nstep, held, codes, at = _rates_setup(coef, phi0_rad, omega0_rad_s, at_s, dt_s, release_s, wrt, inputs)
    observed = tuple(np.ascontiguousarray(o, dtype=np.float64) for o in observed_rad_s)
    if any(o.shape != a.shape for o, a in zip(observed, at, strict=True)):
        raise ParameterError("normal_equations_at: each node's observed rates must match its instants' shape")
    sigma = np.ascontiguousarray(sigma_rad_s, dtype=np.float64)
    if sigma.shape != (2,) or not np.all(sigma > 0):
        raise ParameterError(f"normal_equations_at: sigma_rad_s must be two positive values, got {sigma_rad_s!r}")
    nq = len(codes) + int(release_column) + int(timing_column)
    jtj, jtr, rr = np.zeros((nq, nq)), np.zeros(nq), np.zeros(1)
    if nq == 0:  # the kernel's accumulate mode needs a column; r.r alone from the rates
        (r1, r2), _, _ = rates_at(coef, phi0_rad, omega0_rad_s, at_s, dt_s, release_s=release_s, inputs=inputs)
        res = np.concatenate([(r1 - observed[0]) / sigma[0], (r2 - observed[1]) / sigma[1]])
        return jtj, jtr, float(res @ res)
    none, no_sens = _NOTHING, np.zeros((0, len(codes)))
    _rates_kernel(k, y0, float(release_s), float(dt_s), nstep, held, codes, at[0], at[1], none, none, no_sens,
                  no_sens, none, none, observed[0], observed[1], sigma, bool(release_column), bool(timing_column),
                  jtj, jtr, rr)  # fmt: skip
    upper = np.triu(jtj)
    return upper + np.triu(upper, 1).T, jtr, float(rr[0])


def rates_at(
    coef: FloatArray,
    phi0_rad: Sequence[float] | FloatArray,
    omega0_rad_s: Sequence[float] | FloatArray,
    at_s: tuple[FloatArray, FloatArray],
    dt_s: float,
    *,
    release_s: float = 0.0,
    wrt: Sequence[str] = (),
    sensitivities_out: tuple[FloatArray, FloatArray] | None = None,
    inputs: FloatArray | None = None,
    slopes: bool = True,
) -> tuple[tuple[FloatArray, FloatArray], tuple[FloatArray, FloatArray], tuple[FloatArray, FloatArray]]:
    """One run's omega1, omega2 at given instants, with exact sensitivities: what a least-squares
    fit needs, without storing the trajectory.

    The member rests at (phi0, omega0 = 0) until ``release_s`` (or moves from omega0 if it is 0),
    then RK4 steps of ``dt_s`` (the kernel's arithmetic: rates equal ``integrate``'s states at the
    steps); between steps the rate is the cubic Hermite of omega and its closed-form derivative.

    Args:
      coef: (NCOEF, 1) from ``coefficients``.
      phi0_rad, omega0_rad_s: (2,) the start state.
      at_s: each node's instants since the start, ascending, s: (m1,), (m2,).
      dt_s: the step, s.
      release_s: the instant the member starts to move, s.
      wrt: names from ``SENSITIVITY_NAMES``: the unknowns to differentiate by.
      sensitivities_out: two (m_n, P) float64 arrays (views allowed) to write the sensitivities
        into, e.g. the columns of a Jacobian (no copy); returned as the sensitivities.
      inputs: (H, NSTAGE, NINPUT) the inputs at the start, midpoint and end of each step from the
        release on (``drives.stage_inputs`` with the drive's time 0 at ``release_s``: fourth
        order), or (H, NINPUT) inputs held over each step (``drives.held_inputs``, MuJoCo's rule);
        H at least the steps the instants need; or None (undriven).
      slopes: compute d rate / d release_s (False: empty slopes, no (m_n,) arrays for them).

    Returns:
      (rates, sensitivities, slopes): each a pair over the nodes: rate (m_n,) rad/s (0 before the
      release); d rate / d wrt (m_n, P); d rate / d release_s (m_n,) (or (0,): ``slopes`` False).
    """
    k, y0, nstep, held, codes, at = _rates_setup(coef, phi0_rad, omega0_rad_s, at_s, dt_s, release_s, wrt, inputs)
    rate = tuple(np.zeros(len(a)) for a in at)
    if sensitivities_out is None:
        sens = tuple(np.zeros((len(a), len(codes))) for a in at)
    else:
        sens = sensitivities_out
        if any(o.shape != (len(a), len(codes)) or o.dtype != np.float64 for o, a in zip(sens, at, strict=True)):
            raise ParameterError(f"rates_at: sensitivities_out must be float64 arrays of shape (m_n, {len(codes)})")
        for o in sens:
            o[...] = 0.0
    slope = tuple(np.zeros(len(a) if slopes else 0) for a in at)
    none = _NOTHING
    _rates_kernel(k, y0, float(release_s), float(dt_s), nstep, held, codes, at[0], at[1], rate[0], rate[1], sens[0],
                  sens[1], slope[0], slope[1], none, none, none, False, False, _NOTHING_2D, none, none)  # fmt: skip
    return (rate[0], rate[1]), (sens[0], sens[1]), (slope[0], slope[1])
