"""The estimation room's nonlinear least-squares solvers: one definition each, and which problem
uses which.

- ``gauss_newton``: plain Gauss-Newton steps on residuals and a Jacobian the caller evaluates
  together (the alignment's start fit, ``pendsim_mj.estimation.start_fit``: a few start
  parameters against a second of both nodes' angles and rates, the Jacobian by finite
  differences from one batch of rollouts).
- ``sysid_least_squares``: MuJoCo's ``minimize.least_squares`` on a ``mujoco.sysid`` residual
  (bounds, Levenberg-Marquardt, the Jacobian at the optimum for the intervals). The two sysid
  fits share it: ``identification.fit_damping`` (b1, b2 on the planar MJCF) and
  ``spatial_identification.fit_tilt`` (tilt and hinge damping on the spatial MJCF).
- scipy's trust-region ``least_squares`` stays in ``planar_fit.fit_law``: its residuals are the
  P + 1 reduced ones built from the compiled kernel's normal equations (no n x P Jacobian), with
  per-kind scales and a stop on the BIC's resolution; no other fit poses that problem.

Linear least squares is numpy's where it is used (``np.linalg.lstsq``: the swing frame's
mounting, M2's first guess of its sign; ``np.polyfit``: decay rates): one call each,
nothing to share.

Why the start fit does not go through ``mujoco.minimize.least_squares`` (which the issue that
split this room expected to replace it): measured with the same residuals and the same batched
finite-difference Jacobian handed to ``minimize`` as its ``jacobian`` (xtol 1e-6, at most the
same iterations), on every start fit of ``tests/estimation/test_alignment.py`` and on 30 s
recordings (free release, real-node imperfections, start in motion, driven):

- the results are not the same numbers: of 138 full start fits, 4 came back bit for bit, 128
  within rounding (median 3e-18, at most 5e-13), 5 by 5e-8 to 1e-6 (fits at 7-245 noise sigmas
  rms) and one poor fit (309 sigmas) 4.9 s away; on every recording the start moved by rounding
  (up to 5e-18: ``report.json`` prints every digit), on the driven one by 7e-8;
- it costs more rollouts: the hand steps take the residuals at x from the same batch as the
  Jacobian (one batch an iteration), ``minimize`` rolls out each candidate once more for
  Armijo's rule and again for each raise of its regulariser when a step at the noise floor
  gains nothing: 1705 batches against 450 on those test fits (20 s against 7.5 s), 301 against
  18 on the driven recording (its fits at the noise floor: 146 against 5 for one).

So the start fit keeps these steps: the full Gauss-Newton step (``lstsq``, no regulariser), half
way back when the cost rose, stop when every component of a step is below the tolerance.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

Floats = NDArray[np.float64]


def gauss_newton(
    linearise: Callable[[Floats], tuple[Floats, Floats]],
    x0: Floats,
    *,
    iterations: int,
    tolerance: float = 1e-6,
) -> Floats:
    """Minimise r(x).r(x) by Gauss-Newton steps.

    Each iteration linearises at x; if the cost rose since the last accepted x (by more than
    1e-9 of it), the step overshot and x goes half way back to that x; else x takes the full
    step, the least-squares solution of J dx = -r.

    Args:
      linearise: x (p,) -> (r (n,), J (n, p)): the residuals at x and their Jacobian, evaluated
        together (the start fit takes both from one batch of rollouts).
      x0: (p,) the first guess.
      iterations: at most this many linearisations.
      tolerance: stop after a step whose every component is below this (x's units).

    Returns:
      (p,) x after the last step (not evaluated: the caller evaluates what it reports there).
    """
    x = np.asarray(x0, dtype=float)
    cost = math.inf
    previous = x
    for _ in range(iterations):
        r0, jac = linearise(x)
        new_cost = float(r0 @ r0)
        if new_cost > cost * (1 + 1e-9):  # the last step overshot: go half way back
            x = 0.5 * (x + previous)
            continue
        cost, previous = new_cost, x
        delta, *_ = np.linalg.lstsq(jac, -r0, rcond=None)
        x = x + delta
        if np.all(np.abs(delta) < tolerance):
            break
    return x


def sysid_least_squares(
    sysid: Any, parameters: Any, residual_fn: Callable[..., Any]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Minimise a ``sysid.build_residual_fn`` residual over ``parameters`` with MuJoCo's
    ``minimize.least_squares`` called directly, as ``sysid.optimize`` would, but with its
    per-iteration printout sent to a buffer through the optimiser's ``output`` argument
    (``sysid.optimize`` cannot pass the backend's ``verbose``: its own argument takes the name).
    Full verbosity is what makes the optimiser keep the Jacobian at the optimum in its log.

    xtol: stop when the relative step is below 1e-5 (b to 0.001 %, under its CI); a tenfold
    mu_factor: at the noise floor the Armijo search gives up in ~14 rollouts, not ~140.

    Args:
      sysid: the ``mujoco.sysid`` module (its caller imports it).
      parameters: a ``sysid.ParameterDict`` (bounds, first values).
      residual_fn: what ``sysid.build_residual_fn`` returns.

    Returns (x, final residuals, covariance from ``sysid.calculate_intervals`` at the optimum,
    iterations).
    """
    from mujoco import minimize  # where it runs: the alignment's Gauss-Newton needs no MuJoCo

    fitted = parameters.copy()
    x, log = minimize.least_squares(
        x0=parameters.as_vector(),
        residual=lambda x: np.concatenate(residual_fn(x, fitted)[0]),
        bounds=parameters.get_bounds(),
        verbose=minimize.Verbosity.FULLITER,
        output=io.StringIO(),
        max_iter=200,
        xtol=1e-5,
        mu_factor=10.0,
    )
    fitted.update_from_vector(x)
    final = np.concatenate(residual_fn(x, fitted)[0])
    covariance, _ = sysid.calculate_intervals([final], log[-1].jacobian, alpha=0.05)
    return np.asarray(x, dtype=float), final, np.asarray(covariance), len(log) - 1  # the last entry: the end point
