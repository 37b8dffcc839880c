"""The unscented filter's arithmetic, compiled: Merwe's scaled sigma points of an estimate, the
predicted measurement's moments over them, and the gain's correction; and the filter's two steps
whole, each in one call: the prediction (``predict``: the points advanced by the force law with
their own tracked parameters, ``advanced``, the moments, the process noise) and an unscented
update's measurement side (``update_moments``: the points, run back for a late sample, a node's
swing or accelerometer readings, ``readings``, the moments). The filter (``estimator``) draws
sigma points two or three times per node sample and updates once or twice; numpy's per-call
overhead on a 16-state estimate (a Cholesky factor and its scaling, weighted sums, small solves)
was 90 us of each draw and about as much per update, most of the twin's cost; a whole prediction
in numpy took 125 us on 20 states, compiled in one call 46 us.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from pendsim_mj import compile_notice
from pendsim_mj.engines.fast_planar.kernel import _accel, _rk4
from pendsim_mj.engines.fast_planar.step import accel_readings

Floats = NDArray[np.float64]
IntArray = NDArray[np.intp]
JITTER = 1e-12  # relative to each variance (an absolute one would add a random walk to every parameter)

compile_notice.watch()  # the cache folder; one line on a cold compile (the CLI prints it)


@numba.njit(cache=True)
def sigma_points(x: Floats, p: Floats, scale: float, out: Floats) -> None:
    """The 2n + 1 points of the estimate x (n,) with covariance p (n, n) into out (2n + 1, n): x,
    then x + and x - each column of the lower Cholesky factor of scale p. The factor is taken of
    the correlation matrix with ``JITTER`` on its diagonal and scaled back by the standard
    deviations (a variance near 0, a parameter held, stays near 0 instead of being floored)."""
    n = x.shape[0]
    d = np.empty(n)
    for i in range(n):
        d[i] = math.sqrt(max(scale * p[i, i], 1e-300))
    c = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            c[i, j] = scale * p[i, j] / (d[i] * d[j])
        c[i, i] += JITTER
    root = np.linalg.cholesky(c)
    for j in range(n):
        out[0, j] = x[j]
    for i in range(n):  # the i-th column of the scaled factor
        for j in range(n):
            v = root[j, i] * d[j]
            out[1 + i, j] = x[j] + v
            out[1 + n + i, j] = x[j] - v


@numba.njit(cache=True)
def moments(points: Floats, x: Floats, zs: Floats, wm: Floats, wc: Floats, r: Floats) -> tuple[Floats, Floats, Floats]:
    """The predicted measurement over the sigma points (m, n) with their measurements zs (m, k):
    its mean (k,), its covariance with the noise r (k, k) added, and its cross covariance with the
    state (n, k) about the estimate x (n,); weights wm, wc (m,)."""
    m, n = points.shape
    k = zs.shape[1]
    mean = np.zeros(k)
    for i in range(m):
        for a in range(k):
            mean[a] += wm[i] * zs[i, a]
    s = r.copy()
    pxz = np.zeros((n, k))
    for i in range(m):
        w = wc[i]
        for a in range(k):
            da = zs[i, a] - mean[a]
            for b in range(k):
                s[a, b] += w * da * (zs[i, b] - mean[b])
            for j in range(n):
                pxz[j, a] += w * (points[i, j] - x[j]) * da
    return mean, s, pxz


@numba.njit(cache=True)
def corrected(x: Floats, p: Floats, s: Floats, pxz: Floats, nu: Floats) -> tuple[Floats, Floats]:
    """The Kalman update of a 2-vector measurement, as new arrays: gain K = pxz s^-1 (s (2, 2) in
    closed form), x + K nu, p - K s K' = p - K pxz' (kept symmetric). In loops: LAPACK's inverse
    and BLAS's products on a 2 x 2 and an (n, 2) cost more in their calls than in their arithmetic."""
    n = x.shape[0]
    det = s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0]
    i00, i01, i10, i11 = s[1, 1] / det, -s[0, 1] / det, -s[1, 0] / det, s[0, 0] / det
    gain = np.empty((n, 2))
    x_new = np.empty(n)
    for j in range(n):
        gain[j, 0] = pxz[j, 0] * i00 + pxz[j, 1] * i10
        gain[j, 1] = pxz[j, 0] * i01 + pxz[j, 1] * i11
        x_new[j] = x[j] + gain[j, 0] * nu[0] + gain[j, 1] * nu[1]
    p_new = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            a = p[i, j] - (gain[i, 0] * pxz[j, 0] + gain[i, 1] * pxz[j, 1])
            b = p[j, i] - (gain[j, 0] * pxz[i, 0] + gain[j, 1] * pxz[i, 1])
            v = 0.5 * (a + b)
            p_new[i, j] = v
            p_new[j, i] = v
    return x_new, p_new


@numba.njit(cache=True)
def swing_moments(
    x: Floats, p: Floats, node: int, offset_col: int, var_angle: float, var_rate: float
) -> tuple[Floats, Floats, Floats]:
    """A node's swing reading where it is linear in the state (no tracked delay, not late): its
    angle x[node] plus its mount's offset x[offset_col] (< 0: not tracked) with variance
    ``var_angle`` (rad^2), its rate x[2 + node] with ``var_rate`` ((rad/s)^2); the predicted
    reading (2,), its covariance (2, 2) and the cross covariance (n, 2), as ``moments`` gives them
    for the unscented update (H x, H P H' + R, P H')."""
    n = x.shape[0]
    pxz = np.empty((n, 2))
    for j in range(n):
        pxz[j, 0] = p[j, node] + (p[j, offset_col] if offset_col >= 0 else 0.0)
        pxz[j, 1] = p[j, 2 + node]
    mean = np.empty(2)
    mean[0] = x[node] + (x[offset_col] if offset_col >= 0 else 0.0)
    mean[1] = x[2 + node]
    s = np.empty((2, 2))
    s[0, 0] = pxz[node, 0] + (pxz[offset_col, 0] if offset_col >= 0 else 0.0) + var_angle
    s[0, 1] = pxz[node, 1] + (pxz[offset_col, 1] if offset_col >= 0 else 0.0)
    s[1, 0] = s[0, 1]
    s[1, 1] = pxz[2 + node, 1] + var_rate
    return mean, s, pxz


@numba.njit(cache=True)
def accelerations_at(state: Floats, coef: Floats, tau0: float, tau1: float) -> tuple[float, float]:
    """phi1'', phi2'' (rad/s^2) of one state (4,) (phi1, phi2 rad, omega1, omega2 rad/s) under the
    force law's constants coef (NCOEF,) with hinge torques tau0, tau1 (N m): ``kernel._accel``
    from Python in one call (numpy's closed form on one state costs 15-25 us, most of it calls)."""
    c = (coef[0], coef[1], coef[2], coef[3], coef[4], coef[5], coef[6], coef[7], coef[8], coef[9], coef[10],
         coef[11], coef[12], coef[13])  # fmt: skip
    return _accel(state[0], state[1], state[2], state[3], c, (tau0, tau1, 0.0, 0.0))


@numba.njit(cache=True)
def _terms_into(out: Floats, flat: IntArray, power: Floats, coefficient: Floats, scale: Floats, h: float) -> None:
    """Add sum of coefficient * h**power * scale at each flat index of out (c, c) (``estimator._Terms``)."""
    c = out.shape[0]
    for t in range(flat.shape[0]):
        out[flat[t] // c, flat[t] % c] += coefficient[t] * h ** power[t] * scale[t]


@numba.njit(cache=True)
def _same_motion(points: Floats, rows: IntArray, i: int) -> bool:
    """Whether point i has the first point's state and force-law parameters (rows[j] >= 0: tracked
    parameter j sets one), bit for bit: then its step is the first point's."""
    for j in range(4):
        if points[i, j] != points[0, j]:
            return False
    same = True
    for j in range(rows.shape[0]):
        same = same and not (rows[j] >= 0 and points[i, 4 + j] != points[0, 4 + j])
    return same


@numba.njit(cache=True)
def advanced(
    points: Floats, coef: Floats, rows: IntArray, tau: Floats, h: float, cols: IntArray,
    taylor: tuple[IntArray, Floats, Floats, IntArray],
) -> Floats:  # fmt: skip
    """The points (m, n) moved by one RK4 step of h (s; negative: back in time) of the force law,
    each with its own tracked parameters (``set_rows``) and the torques tau (2,) held; the offset
    chains (states ``cols``) by their Taylor series (``taylor``: ``estimator._Terms``); the other
    tracked parameters ride along unchanged."""
    m = points.shape[0]
    moved = points.copy()
    set_rows(coef, rows, points)
    u = (tau[0], tau[1], 0.0, 0.0)
    for i in range(m):
        if i > 0 and _same_motion(points, rows, i):  # the first point's step, exactly (sigma points along
            for j in range(4):  # the tracked parameters that do not move the rig: half of them)
                moved[i, j] = moved[0, j]
            continue
        k = coef
        c = (k[0, i], k[1, i], k[2, i], k[3, i], k[4, i], k[5, i], k[6, i], k[7, i], k[8, i], k[9, i], k[10, i],
             k[11, i], k[12, i], k[13, i])  # fmt: skip
        p1, p2, w1, w2, _ = _rk4(points[i, 0], points[i, 1], points[i, 2], points[i, 3], 0.0, h, c, u, u, u)
        moved[i, 0] = p1
        moved[i, 1] = p2
        moved[i, 2] = w1
        moved[i, 3] = w2
    nc = cols.shape[0]
    if nc:
        t = np.zeros((nc, nc))
        flat, power, coefficient, _ = taylor
        _terms_into(t, flat, power, coefficient, np.ones(flat.shape[0]), h)
        for i in range(m):
            for b in range(nc):
                acc = 0.0
                for a in range(nc):
                    acc += points[i, cols[a]] * t[a, b]
                moved[i, cols[b]] += acc
    return moved


@numba.njit(cache=True)
def add_process_noise(
    cov: Floats, h: float, drift: Floats, cols: IntArray, walk: tuple[IntArray, Floats, Floats, IntArray], hinge: Floats
) -> None:
    """Add the process noise over h (s) to the upper triangle of cov (n, n) (``predict``'s): each
    tracked parameter's random walk (drift (n - 4,) per sqrt(s)), the offset chains' walks
    integrated into the levels below (states ``cols``, terms ``walk``: ``estimator._Terms``), and a
    white torque on each hinge (hinge (2,): its spectral density over the inertia squared,
    rad^2/s^3; a double integrator per hinge, its exact covariance)."""
    ntrack = cov.shape[0] - 4
    for j in range(ntrack):
        cov[4 + j, 4 + j] += drift[j] * drift[j] * h
    nc = cols.shape[0]
    if nc:
        q = np.zeros((nc, nc))
        flat, power, coefficient, which = walk
        scale_w = np.empty(flat.shape[0])
        for t in range(flat.shape[0]):
            scale_w[t] = drift[which[t]] * drift[which[t]]
        _terms_into(q, flat, power, coefficient, scale_w, h)
        for a in range(nc):
            for b in range(nc):
                ia, ib = cols[a], cols[b]
                if ia <= ib:
                    cov[ia, ib] += q[a, b] if ia == ib else 0.5 * (q[a, b] + q[b, a])
    for k in range(2):
        s = hinge[k]
        cov[k, k] += s * h * h * h / 3.0
        cov[k, 2 + k] += s * h * h / 2.0
        cov[2 + k, 2 + k] += s * h


@numba.njit(cache=True)
def predict(
    x: Floats,
    p: Floats,
    scale: float,
    wm: Floats,
    wc: Floats,
    coef: Floats,
    rows: IntArray,
    tau: Floats,
    h: float,
    cols: IntArray,
    taylor: tuple[IntArray, Floats, Floats, IntArray],
    walk: tuple[IntArray, Floats, Floats, IntArray],
    drift: Floats,
    hinge: Floats,
) -> tuple[Floats, Floats]:
    """The unscented prediction over h (s) in one call: the estimate x (n,) with covariance p (n, n)
    to its mean and covariance h later (``estimator.RigEstimator.predict``, numpy's per-call
    overhead gone: each of the 2n + 1 sigma points (``sigma_points``) advanced by one RK4 step of
    the force law with its own tracked parameters, the offset chains by their Taylor series, then
    the weighted moments plus the process noise).

    coef (NCOEF, 2n + 1): the force law's constants per point (rows[j] >= 0: tracked parameter j
    sets that row); tau (2,): the hinge torques held over h, N m; cols (c,): the offset chains'
    states; taylor and walk (flat, power, coefficient, which tracked
    parameter walks) over their (c, c) block (``estimator._Terms``); drift (n - 4,): the tracked
    parameters' random-walk rates per sqrt(s); hinge (2,): the white torque's spectral density
    over each hinge's inertia squared, rad^2/s^3."""
    n = x.shape[0]
    m = 2 * n + 1
    points = np.empty((m, n))
    sigma_points(x, p, scale, points)
    moved = advanced(points, coef, rows, tau, h, cols, taylor)
    mean = np.zeros(n)
    for i in range(m):
        for j in range(n):
            mean[j] += wm[i] * moved[i, j]
    cov = np.zeros((n, n))
    d = np.empty(n)
    for i in range(m):
        for j in range(n):
            d[j] = moved[i, j] - mean[j]
        w = wc[i]
        for a in range(n):
            wa = w * d[a]
            for b in range(a, n):
                cov[a, b] += wa * d[b]
    add_process_noise(cov, h, drift, cols, walk, hinge)
    for a in range(n):
        for b in range(a + 1, n):
            cov[b, a] = cov[a, b]
    return mean, cov


@numba.njit(cache=True)
def set_rows(coef: Floats, rows: IntArray, points: Floats) -> None:
    """Each point's (m, n) tracked parameters into the force law's constants coef (NCOEF, m): row
    rows[j] (>= 0) of column i takes points[i, 4 + j] (unclipped: a spread about 0 stays symmetric)."""
    for i in range(points.shape[0]):
        for j in range(rows.shape[0]):
            if rows[j] >= 0:
                coef[rows[j], i] = points[i, 4 + j]


@numba.njit(cache=True)
def swing_readings(
    at: Floats, node: int, delay_col: int, offset_col: int, coef: Floats, rows: IntArray, tau: Floats, out: Floats
) -> None:
    """The node's swing angle and hinge rate at each point (m, n) into out (m, 2): with a tracked
    delay d (state ``delay_col`` >= 0) its values d older (phi - d omega, omega - d alpha, alpha from
    the force law with the point's own parameters, ``set_rows``, and the torques tau (2,)), with a
    tracked offset (``offset_col`` >= 0) its angle plus the offset."""
    if delay_col >= 0:
        set_rows(coef, rows, at)
    u = (tau[0], tau[1], 0.0, 0.0)
    for i in range(at.shape[0]):
        out[i, 0] = at[i, node]
        out[i, 1] = at[i, 2 + node]
        if delay_col >= 0:
            k = coef
            c = (k[0, i], k[1, i], k[2, i], k[3, i], k[4, i], k[5, i], k[6, i], k[7, i], k[8, i], k[9, i], k[10, i],
                 k[11, i], k[12, i], k[13, i])  # fmt: skip
            a1, a2 = _accel(at[i, 0], at[i, 1], at[i, 2], at[i, 3], c, u)
            d = at[i, delay_col]
            out[i, 0] -= d * at[i, 2 + node]
            out[i, 1] -= d * (a1 if node == 0 else a2)
        if offset_col >= 0:
            out[i, 0] += at[i, offset_col]


SWING, ACCEL = 0, 1  # ``update_moments``' readings: a node's swing angle and rate, its accelerometer


@numba.njit(cache=True)
def readings(
    at: Floats,
    kind: int,
    node: int,
    delay_col: int,
    offset_col: int,
    turn_col: int,
    radius_m: float,
    g_m_s2: float,
    coef: Floats,
    rows: IntArray,
    tau: Floats,
) -> Floats:
    """The node's readings (m, 2) at each point of at (m, n) (``update_moments``' kind, columns
    and arguments)."""
    m = at.shape[0]
    zs = np.empty((m, 2))
    if kind == SWING:
        swing_readings(at, node, delay_col, offset_col, coef, rows, tau, zs)
        return zs
    set_rows(coef, rows, at)
    state = np.ascontiguousarray(at[:, :4].T)
    u = np.zeros((4, m))
    delay = np.zeros(m)
    turn = np.zeros(m)
    for i in range(m):
        u[0, i] = tau[0]
        u[1, i] = tau[1]
        if delay_col >= 0:
            delay[i] = at[i, delay_col]
        if turn_col >= 0:
            turn[i] = at[i, turn_col]
    out = np.empty((2, m))
    accel_readings(coef, state, u, node, radius_m, g_m_s2, delay, turn, out)
    for i in range(m):
        zs[i, 0] = out[0, i]
        zs[i, 1] = out[1, i]
    return zs


@numba.njit(cache=True)
def update_moments(
    x: Floats,
    p: Floats,
    scale: float,
    wm: Floats,
    wc: Floats,
    coef: Floats,
    rows: IntArray,
    tau: Floats,
    gap: float,
    cols: IntArray,
    taylor: tuple[IntArray, Floats, Floats, IntArray],
    kind: int,
    node: int,
    delay_col: int,
    offset_col: int,
    turn_col: int,
    radius_m: float,
    g_m_s2: float,
    r: Floats,
) -> tuple[Floats, Floats, Floats]:
    """The predicted measurement's moments over the sigma points of x (n,), p (n, n) in one call
    (``estimator.RigEstimator._unscented_update``): the points run back by ``gap`` (s, < 0: a late
    sample; ``advanced``), the node's readings at each (``kind``: ``SWING``, ``swing_readings``
    with the tracked delay's and offset's states; ``ACCEL``, ``step.accel_readings`` at
    ``radius_m`` with the delay and the accelerometer's turn), then ``moments`` with the noise r
    (2, 2): the mean (2,), its covariance (2, 2) and the cross covariance (n, 2). A column index
    < 0: not tracked."""
    n = x.shape[0]
    m = 2 * n + 1
    points = np.empty((m, n))
    sigma_points(x, p, scale, points)
    at = advanced(points, coef, rows, tau, gap, cols, taylor) if gap < 0 else points
    zs = readings(at, kind, node, delay_col, offset_col, turn_col, radius_m, g_m_s2, coef, rows, tau)
    return moments(points, x, zs, wm, wc, r)
