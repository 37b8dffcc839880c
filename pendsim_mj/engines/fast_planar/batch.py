"""``integrate``: the batch driver of the compiled RK4 kernel (``kernel._integrate_kernel``), its
chunks spread over the threads (``kernel._integrate_serial`` on one thread), with the stage (or
held) inputs of drives."""

from __future__ import annotations

import os

import numba
import numpy as np

from pendsim_mj import compile_notice
from pendsim_mj.engines.fast_planar.closed_form import NINPUT, FloatArray, _check_coef
from pendsim_mj.engines.fast_planar.kernel import SUMMARY_ROWS, _integrate_kernel, _integrate_serial, _summary_kernel
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.drives import NSTAGE

compile_notice.watch()  # the cache folder; one line on a cold compile (the CLI prints it)

# Members integrated side by side in one chunk (a multiple of the 8-wide AVX-512 vector); chunks
# are spread over the cores.
CHUNK = 64


def _initial_state(phi0_rad: FloatArray, omega0_rad_s: FloatArray) -> FloatArray:
    y0 = np.zeros((5, len(phi0_rad)))
    y0[0:2] = phi0_rad.T
    y0[2:4] = omega0_rad_s.T
    return y0


def _chunk(nbatch: int, nthread: int) -> int:
    """Members per chunk: CHUNK, or fewer so that a small batch still spreads over the threads;
    a multiple of 8 (one AVX-512 vector), so a batch of 8 or fewer stays on one thread."""
    per_thread = -(-nbatch // max(1, nthread))
    return min(CHUNK, -(-per_thread // 8) * 8)


def _threads(nthread: int | None) -> int:
    limit: int = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
    if nthread is None:
        return min(limit, os.cpu_count() or 1)
    if isinstance(nthread, bool) or not isinstance(nthread, int) or nthread < 1:
        raise ParameterError(f"nthread must be a whole number >= 1, got {nthread!r}")
    return min(nthread, limit)


_UNDRIVEN = np.zeros((0, NSTAGE, NINPUT, 0))


def _run(
    k: FloatArray,
    y0: FloatArray,
    held: FloatArray,
    step0: int,
    nstep: int,
    h: float,
    every: int,
    nthread: int | None,
) -> FloatArray:
    """The kernel on min(chunks, threads) threads, from state y0 (5, nbatch) at t = step0 h with
    the stage inputs (H, NSTAGE, NINPUT, nbatch) (``_held``; H = 0: undriven): a batch that fits one
    chunk runs on the calling thread alone through ``_integrate_serial`` (no thread pool
    started, and a first run compiles that kernel in about a third of the parallel one's time;
    the same arithmetic, bit for bit). Returns (nstep // every + 1, 5, nbatch)."""
    nbatch = y0.shape[1]
    threads = _threads(nthread)
    chunk = _chunk(nbatch, threads)
    out = np.empty((nstep // every + 1, 5, nbatch))
    used = max(1, min(threads, -(-nbatch // chunk)))
    if nbatch <= chunk:  # one chunk: the serial twin (its loop does not vectorise: many chunks run faster in parallel)
        _integrate_serial(k, y0, held, step0, nstep, h, every, out, chunk)
        return out
    previous = numba.get_num_threads()
    numba.set_num_threads(used)
    try:
        _integrate_kernel(k, y0, held, step0, nstep, h, every, out, chunk)
    finally:
        numba.set_num_threads(previous)
    return out


def _held(inputs: FloatArray | None, nbatch: int, nstep: int) -> FloatArray:
    """Stage inputs (nbatch, nstep, NSTAGE, NINPUT), or held inputs (nbatch, nstep, NINPUT) (each
    step's value at its three stages), as the kernel reads them: (nstep, NSTAGE, NINPUT, nbatch)."""
    if inputs is None:
        return _UNDRIVEN
    u = np.asarray(inputs, dtype=np.float64)
    if u.shape == (nbatch, nstep, NINPUT):
        u = np.repeat(u[:, :, None, :], NSTAGE, axis=2)
    if u.shape != (nbatch, nstep, NSTAGE, NINPUT):
        raise ParameterError(
            f"inputs must have shape ({nbatch}, {nstep}, {NSTAGE}, {NINPUT}) (drives.stage_inputs) or "
            f"({nbatch}, {nstep}, {NINPUT}) (drives.held_inputs), got {u.shape}"
        )
    return np.ascontiguousarray(u.transpose(1, 2, 3, 0))


def integrate(
    coef: FloatArray,
    phi0_rad: FloatArray,
    omega0_rad_s: FloatArray,
    nstep: int,
    dt_s: float,
    *,
    inputs: FloatArray | None = None,
    save_every: int = 1,
    nthread: int | None = None,
) -> FloatArray:
    """Classical RK4 over a batch, states only: the lean entry point for sweeps.

    Args:
      coef: (NCOEF, nbatch) from ``coefficients``.
      phi0_rad, omega0_rad_s: (nbatch, 2) initial conditions.
      nstep: number of RK4 steps.
      dt_s: step, s.
      inputs: (nbatch, nstep, NSTAGE, NINPUT) the inputs at each step's start, midpoint and end
        (``drives.drive_stage_inputs``: fourth order), or (nbatch, nstep, NINPUT) inputs held over
        each step (``drives.stack_inputs``: MuJoCo's rule, second order), or None (undriven); the
        layouts of ``reference.integrate``'s ``inputs``.
      save_every: keep the state every this many steps (nstep must be a multiple of it).
      nthread: threads (default: every core numba may use).

    Returns:
      (nstep // save_every + 1, 5, nbatch): (phi1, phi2, omega1, omega2, dissipated_j) at
      t = i * save_every * dt_s, the layout of ``reference.integrate``. A member that diverged holds
      non-finite values from then on; nothing is raised here.
    """
    phi0 = np.asarray(phi0_rad, dtype=np.float64)
    omega0 = np.asarray(omega0_rad_s, dtype=np.float64)
    nbatch = len(phi0)
    k = _check_coef(coef, nbatch)
    if isinstance(save_every, bool) or not isinstance(save_every, int) or save_every < 1 or nstep % save_every:
        raise ParameterError(f"save_every must be a whole number >= 1 that divides nstep = {nstep}, got {save_every!r}")
    held = _held(inputs, nbatch, nstep)
    return _run(k, _initial_state(phi0, omega0), held, 0, int(nstep), float(dt_s), save_every, nthread)


def summarise(
    coef: FloatArray,
    phi0_rad: FloatArray,
    omega0_rad_s: FloatArray,
    nstep: int,
    dt_s: float,
    *,
    head_samples: int,
    inputs: FloatArray | None = None,
    save_every: int = 1,
    keep_phi: bool = False,
    nthread: int | None = None,
) -> tuple[FloatArray, FloatArray | None]:
    """``integrate``'s pass (the same states, bit for bit) reduced on the fly to what a sweep's
    features need, so no trajectory is stored: the light path of a sweep.

    Args:
      coef, phi0_rad, omega0_rad_s, nstep, dt_s, inputs, save_every, nthread: as ``integrate``;
        the reductions see the samples r = 0 .. nstep // save_every (t = r * save_every * dt_s).
      head_samples: the head window is samples 0..head_samples, the tail window the last
        head_samples + 1 samples (1 <= head_samples < nstep // save_every).
      keep_phi: also return the sampled angles.

    Returns:
      stats (len(SUMMARY_ROWS), nbatch): row ``SUMMARY_ROWS.index(name)`` per quantity (amplitudes
      in rad, sample indices as floats, energies in J, the end state, 1.0 where a sample was not
      finite); phi (nbatch, 2, nstep // save_every + 1) rad, or None.
    """
    phi0 = np.asarray(phi0_rad, dtype=np.float64)
    omega0 = np.asarray(omega0_rad_s, dtype=np.float64)
    nbatch = len(phi0)
    k = _check_coef(coef, nbatch)
    if isinstance(save_every, bool) or not isinstance(save_every, int) or save_every < 1 or nstep % save_every:
        raise ParameterError(f"save_every must be a whole number >= 1 that divides nstep = {nstep}, got {save_every!r}")
    nsave = nstep // save_every + 1
    if not 1 <= head_samples < nsave - 1:
        raise ParameterError(f"head_samples must be 1 .. {nsave - 2} for {nsave} samples, got {head_samples!r}")
    held = _held(inputs, nbatch, nstep)
    stats = np.empty((len(SUMMARY_ROWS), nbatch))
    phi = np.empty((nbatch, 2, nsave)) if keep_phi else np.empty((0, 2, 0))
    threads = _threads(nthread)
    chunk = _chunk(nbatch, threads)
    previous = numba.get_num_threads()
    numba.set_num_threads(max(1, min(threads, -(-nbatch // chunk))))
    try:
        _summary_kernel(
            k,
            _initial_state(phi0, omega0),
            held,
            int(nstep),
            float(dt_s),
            save_every,
            int(head_samples),
            chunk,
            phi,
            stats,
        )
    finally:
        numba.set_num_threads(previous)
    return stats, (phi if keep_phi else None)
