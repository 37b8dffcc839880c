"""Pseudo-arclength continuation of the solutions of G(u) = 0, G: R^(n+1) -> R^n.

A generic predictor-corrector (Keller): from a solution u_k with unit tangent t_k (in scaled
coordinates z = u / scale) predict z = z_k + ds t_k, then correct by Newton on

    G(u) = 0,   t_k . (z - z_k) - ds = 0,

with the full Jacobian each iteration (the analyses get it from one batched rollout together with
the residual). The new tangent is the null vector of dG/dz, oriented like the previous one. The
step grows after an easy correction and halves after a failed one.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.errors import ParameterError, SimulationDiverged

# G(u) -> (residual (n,), Jacobian (n, n + 1) with respect to u, extra data kept with the point)
System = Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64], Any]]


@dataclasses.dataclass(frozen=True)
class Settings:
    """Step control: arclength steps in scaled coordinates; Newton tolerance on |G| (in G's
    units) and on the scaled correction."""

    ds: float = 0.02
    ds_min: float = 1e-5
    ds_max: float = 0.05
    max_points: int = 400
    newton_tol: float = 1e-10
    step_tol: float = 1e-9
    max_newton: int = 8
    easy_newton: int = 3


@dataclasses.dataclass(frozen=True)
class Point:
    """One converged solution: u, the unit tangent in scaled coordinates, the residual norm, the
    Newton iterations it took and the system's extra data."""

    u: NDArray[np.float64]
    tangent: NDArray[np.float64]
    residual: float
    iterations: int
    extra: Any


def null_vector(jac_scaled: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit vector spanning the null space of an (n, n + 1) matrix of rank n."""
    _, _, vt = np.linalg.svd(jac_scaled)
    return vt[-1]


def newton(
    system: System,
    u0: NDArray[np.float64],
    *,
    scale: NDArray[np.float64],
    fixed: int | None = None,
    tangent: NDArray[np.float64] | None = None,
    anchor: NDArray[np.float64] | None = None,
    ds: float = 0.0,
    tol: float = 1e-10,
    step_tol: float = 1e-9,
    max_iter: int = 8,
) -> Point:
    """Correct u0 onto G(u) = 0 with one more condition: the component ``fixed`` of u held (a
    natural parameter), or the pseudo-arclength condition tangent . (z - anchor) = ds.

    Raises:
      ParameterError: Newton did not converge within max_iter (the message says how close).
    """
    u = np.array(u0, dtype=float)
    res_norm = np.inf
    for it in range(1, max_iter + 1):
        g, jac, extra = system(u)
        res_norm = float(np.max(np.abs(g)))
        jz = jac * scale  # d G / d z
        if fixed is not None:
            row = np.zeros(len(u))
            row[fixed] = 1.0
            rhs_extra = 0.0
        else:
            assert tangent is not None and anchor is not None
            row = tangent
            rhs_extra = float(tangent @ (u / scale - anchor) - ds)
        a = np.vstack([jz, row])
        rhs = -np.concatenate([g, [rhs_extra]])
        try:
            dz = np.linalg.solve(a, rhs)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(dz)):
            break
        u = u + dz * scale
        if res_norm < tol and np.max(np.abs(dz)) < step_tol:
            jz_new = jz
            t = null_vector(jz_new)
            if tangent is not None and t @ tangent < 0:
                t = -t
            return Point(u - dz * scale, t, res_norm, it, extra)
        if np.max(np.abs(dz)) < step_tol:  # the correction is negligible: evaluate once more
            continue
    raise ParameterError(f"Newton did not converge (residual {res_norm:.2e} after {max_iter} iterations)")


def continue_branch(
    system: System,
    start: Point,
    *,
    scale: NDArray[np.float64],
    settings: Settings = Settings(),
    stop: Callable[[Point], bool] = lambda p: False,
    progress: Callable[[Point], None] | None = None,
) -> tuple[list[Point], str]:
    """Follow the branch through ``start`` along its tangent until ``stop(point)`` is true (the
    stopping point is kept), max_points, or the step falls below ds_min.

    Returns:
      (points, why it ended: "stop", "max_points" or "step too small").
    """
    points = [start]
    ds = settings.ds
    while len(points) < settings.max_points:
        last = points[-1]
        z_last = last.u / scale
        predicted = (z_last + ds * last.tangent) * scale
        try:
            p = newton(
                system,
                predicted,
                scale=scale,
                tangent=last.tangent,
                anchor=z_last,
                ds=ds,
                tol=settings.newton_tol,
                step_tol=settings.step_tol,
                max_iter=settings.max_newton,
            )
        except (ParameterError, SimulationDiverged):
            ds /= 2
            if ds < settings.ds_min:
                return points, "step too small"
            continue
        points.append(p)
        if progress is not None:
            progress(p)
        if stop(p):
            return points, "stop"
        if p.iterations <= settings.easy_newton:
            ds = min(settings.ds_max, ds * 1.5)
        elif p.iterations >= settings.max_newton - 1:
            ds = max(settings.ds_min, ds / 1.5)
    return points, "max_points"
