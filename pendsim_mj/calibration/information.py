"""What recordings determine: the Fisher information of the rig's free parameters, its directions
and their intervals, and how far a quantity depends on what the data leave open.

The fit's normal equations (``fit``) hold the information of every unknown: the free parameters
x (relative units, ``parameters.ParameterSpace``) and each recording's own start state. The
information about x alone is the Schur complement S = N_xx - N_xl N_ll^-1 N_lx summed over the
recordings (each one's start state eliminated: it costs the information it shares with x). With
the residuals in noise sigmas and their variance s^2 (RSS / (n - P)), a unit direction v of x is
known to the 95 % half-width 1.96 s / sqrt(v' S v); the eigenvectors of S are the directions from
best to worst determined, and one with a zero eigenvalue is a change of the rig that no recording
sees (e.g. all moments and inertias scaled together: every equation of motion is divided by its
inertia).

A direction is **determined** when its half-width is below ``DETERMINED_HALF_WIDTH`` (relative):
the fit moves the rig only along those, and holds the rest at the stated values. A quantity
(``parameters.QUANTITIES`` or a free parameter) is determined when the held directions cannot move
it by more than ``HELD_BIAS_FRACTION`` of its interval, with each held direction anywhere within
``PLAUSIBLE_CHANGE`` of the stated rig, or by no more than ``NEGLIGIBLE_BIAS`` of its value (then
its interval is widened by that bias).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

Floats = NDArray[np.float64]

DETERMINED_HALF_WIDTH = 0.01  # a direction known to within 1 % (relative) is fitted, others are held
PLAUSIBLE_CHANGE = 0.05  # how far a rig built to the drawings may differ from them (relative), for the held bias
HELD_BIAS_FRACTION = 0.2  # a quantity the held directions can move by more than this of its interval is not determined
# ... unless that is below this fraction of its value (a fifth of DETERMINED_HALF_WIDTH): then it is
# determined with its interval widened by the bias
NEGLIGIBLE_BIAS = HELD_BIAS_FRACTION * DETERMINED_HALF_WIDTH
Z95 = 1.959964
_IN_SPAN = 1e-4  # a vector this close (relative) to the held directions' span lies in it


@dataclasses.dataclass(frozen=True)
class Direction:
    """One eigen-direction of the information about the free parameters.

    Attributes:
      vector: (nfree,) unit vector in relative units (x).
      half_width95: its 95 % half-width, relative (inf: not seen at all).
      determined: fitted (below DETERMINED_HALF_WIDTH) or held at the stated rig.
    """

    vector: Floats
    half_width95: float
    determined: bool

    def describe(self, names: Sequence[str]) -> str:
        """The direction in words: which parameters change together and how."""
        v = self.vector / np.max(np.abs(self.vector))
        big = [(n, float(c)) for n, c in zip(names, v, strict=True) if abs(c) > 0.2]
        if len(big) > 2 and all(abs(abs(c) - 1.0) < 0.1 for _, c in big):
            up = [n for n, c in big if c > 0]
            down = [n for n, c in big if c < 0]
            words = f"{', '.join(up)} scaled together by the same factor"
            if down:
                words += f" and {', '.join(down)} by its inverse"
            return words
        return " ".join(f"{c:+.2f} {n}" for n, c in sorted(big, key=lambda p: -abs(p[1])))


def schur_complement(normal: Floats, nglobal: int) -> Floats:
    """S = N_gg - N_gl N_ll^+ N_lg of normal equations N (Q, Q) whose first ``nglobal`` unknowns
    are shared and the rest a recording's own (pseudo-inverse: a start-state unknown the data do
    not see adds nothing)."""
    gg = normal[:nglobal, :nglobal]
    if normal.shape[0] == nglobal:
        return gg.copy()
    gl = normal[:nglobal, nglobal:]
    ll = normal[nglobal:, nglobal:]
    return np.asarray(gg - gl @ np.linalg.pinv(ll, rcond=1e-12, hermitian=True) @ gl.T)


def directions(information: Floats, residual_variance: float) -> list[Direction]:
    """The eigen-directions of the information S (nfree, nfree) about x, best determined first,
    with their half-widths at the residual variance s^2."""
    w, v = np.linalg.eigh(0.5 * (information + information.T))
    top = max(float(w.max()), 1e-300)
    out = []
    for k in np.argsort(-w):
        lam = float(w[k])
        half = Z95 * math.sqrt(residual_variance / lam) if lam > 1e-12 * top else math.inf
        vec = v[:, k] * (1.0 if v[np.argmax(np.abs(v[:, k])), k] > 0 else -1.0)
        out.append(Direction(vec, half, half < DETERMINED_HALF_WIDTH))
    return out


def held_bias(gradient: Floats, held: Sequence[Direction], shifts: Sequence[Floats] | None = None) -> float:
    """The most the held directions can move a quantity of gradient d q / d x (nfree,): each held
    direction v anywhere within PLAUSIBLE_CHANGE per parameter (|x_i| <= 0.05: |x . v| <= 0.05
    |v|_1). ``shifts``: what the fit makes of a unit step along each held direction (``compensated``)
    where the model is not exactly blind to it; default: the direction itself."""
    moved = shifts if shifts is not None else [d.vector for d in held]
    return float(
        sum(
            abs(float(gradient @ m)) * PLAUSIBLE_CHANGE * float(np.abs(d.vector).sum())
            for d, m in zip(held, moved, strict=True)
        )
    )


def compensated(held: Floats, determined: Sequence[Floats], information: Floats) -> Floats:
    """The change of x (nfree,) that a rig differing by ``held`` (a held direction, unit step)
    leaves in the fit: the held part stays at the stated value, so the fitted directions move to
    make up for what the model does see of it (least squares with the information S:
    d = -(D' S D)^-1 D' S h), and the estimate is off by h + D d from that rig. Zero compensation
    where the model is blind to h (S h = 0, the planar model's common scale)."""
    if not determined:
        return np.asarray(held, dtype=float)
    d = np.column_stack(determined)
    shift = -np.linalg.lstsq(d.T @ information @ d, d.T @ information @ held, rcond=None)[0]
    return np.asarray(held + d @ shift, dtype=float)


def describe_held(held: Sequence[Direction], names: Sequence[str], scale: Floats | None) -> list[str]:
    """The held directions' span in words: a common scale of all moments and inertias (``scale``:
    the x that scales every force-law constant by one factor, if the free parameters have one),
    parameters not seen at all, pairs that trade against each other, then whatever is left, as
    its components."""
    if not held:
        return []
    basis, _ = np.linalg.qr(np.array([d.vector for d in held]).T)  # (n, k) orthonormal

    def outside(v: Floats) -> Floats:
        return np.asarray(v - basis @ (basis.T @ v))

    found: list[Floats] = []
    words: list[str] = []
    if scale is not None and np.linalg.norm(outside(scale)) < _IN_SPAN * np.linalg.norm(scale):
        moved = [n for n, c in zip(names, scale, strict=True) if abs(c) > 1e-9]
        words.append(
            f"{', '.join(moved)} scaled together by one factor (every moment and inertia: each equation of motion "
            "is divided by its inertia, so no free swing sees it)"
        )
        found.append(scale)
    eye = np.eye(len(names))
    single = [i for i in range(len(names)) if np.linalg.norm(outside(eye[i])) < _IN_SPAN]
    for i in single:
        words.append(f"{names[i]}: not seen at all")
        found.append(eye[i])
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if i in single or j in single:
                continue
            pair = np.column_stack([outside(eye[i]), outside(eye[j])])
            _, sv, vt = np.linalg.svd(pair)
            if sv[-1] < _IN_SPAN * max(sv[0], 1e-300):
                a, b = vt[-1]
                words.append(
                    f"{names[i]} and {names[j]} trade: +1 % of {names[i]} with {b / a:+.3g} % of {names[j]} "
                    "looks the same"
                )
                found.append(a * eye[i] + b * eye[j])
    if found:
        done, _ = np.linalg.qr(np.array(found).T)
        rest = basis - done @ (done.T @ basis)
    else:
        rest = basis
    u, sv, _ = np.linalg.svd(rest, full_matrices=False)
    for k in range(int(np.sum(sv > 1e-3))):
        words.append(f"the combination {Direction(u[:, k], math.inf, False).describe(names)}")
    return words


def _project(v: Floats, vectors: Sequence[Floats]) -> Floats:
    if not vectors:
        return np.zeros_like(v)
    q, _ = np.linalg.qr(np.array(vectors).T)
    return np.asarray(q @ (q.T @ v))
