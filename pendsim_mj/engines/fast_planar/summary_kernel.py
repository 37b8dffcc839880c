"""The summary pass of a sweep (``batch.summarise``), compiled: the undriven batch loop with the
reductions a sweep's features need folded in as it goes (``summarise_kernel_undriven``), and the
fold of stored blocks of states for driven batches (``fold_block``). The RK4 step, the sines and
cosines and the member's constants are ``kernel``'s, inlined (the same bits as ``integrate``).

numba's ``cache=True`` notices edits only in the file a cached function is defined in; this file
inlines ``kernel``'s helpers, so pendsim's cache folder is keyed on the sources of this whole
package (``compile_notice.cache_folder``): an edit to ``kernel`` also recompiles what is here.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pendsim_mj import compile_notice
from pendsim_mj.engines.fast_planar.closed_form import _FC, _FS, _G1, _G2, _J1, _J2, _KC, _KS, FloatArray
from pendsim_mj.engines.fast_planar.kernel import _chunk_coefficients, _chunk_state, _member, _rk4, _trig

compile_notice.watch()  # the cache folder; one line on a cold compile (the CLI prints it)


@numba.njit(inline="always", cache=True)
def _energy_at(
    trig: tuple[float, float, float, float, float, float], w1: float, w2: float, c: tuple[float, ...]
) -> float:
    """Total energy above rest, J (``closed_form.kinetic_energy`` + ``potential_energy``), from the
    angles' ``_trig`` (the one the RK4 step's first stage computes at the same state) and the
    member's constants c (``_member``)."""
    _, c1, s2, c2, sd, cd = trig
    springs = c[_KS] * (1.0 - cd) - c[_KC] * sd + c[_FS] * (1.0 - c2) - c[_FC] * s2
    return 0.5 * (c[_J1] * w1 * w1 + c[_J2] * w2 * w2) + c[_G1] * (1.0 - c1) + c[_G2] * (1.0 - c2) + springs


@numba.njit(inline="always", cache=True)
def _member_of(k: FloatArray, b: int) -> tuple[float, ...]:
    """Member b's constants from the (NCOEF, nbatch) array: the tuple of ``_member``."""
    return (
        k[0, b], k[1, b], k[2, b], k[3, b], k[4, b], k[5, b], k[6, b], k[7, b], k[8, b], k[9, b], k[10, b],
        k[11, b], k[12, b], k[13, b],
    )  # fmt: skip


# The summary pass's reductions (``batch.summarise``): rows of its stats array (SUMMARY_ROWS' order).
FOLD_AMP, FOLD_HEAD, FOLD_HEAD_INDEX, FOLD_TAIL, FOLD_TAIL_INDEX = 0, 2, 4, 6, 8
FOLD_ENERGY_START, FOLD_ENERGY_MAX, FOLD_ENERGY_END, FOLD_END, FOLD_NONFINITE = 10, 11, 12, 13, 18


@numba.njit(cache=True)
def _fold_amplitudes(
    acc: FloatArray, nonfinite_row: int, r: int, head: int, tail: int, p1: FloatArray, p2: FloatArray,
    w1: FloatArray, w2: FloatArray,
) -> None:  # fmt: skip
    """Fold sample r of m members (their states p1, p2, w1, w2, (m,) each) into the amplitude
    rows of acc (rows, m): ``FOLD_AMP`` .. ``FOLD_TAIL_INDEX`` (|phi_n| largest over the run, in
    the head window r <= head and the tail window r >= tail with the first sample that reached
    it) and 1.0 in row ``nonfinite_row`` where a state was not finite. A NaN never compares
    larger, so it never wins. The rule of both folds (``fold_block``, the fused pass); compiled
    on its own and called once per sample, so the fused pass's step loop stays free of its
    stores and vectorises."""
    for i in range(len(p1)):
        for n in range(2):
            a = abs(p1[i]) if n == 0 else abs(p2[i])
            if a > acc[FOLD_AMP + n, i]:
                acc[FOLD_AMP + n, i] = a
            if r <= head and a > acc[FOLD_HEAD + n, i]:
                acc[FOLD_HEAD + n, i] = a
                acc[FOLD_HEAD_INDEX + n, i] = r
            if r >= tail and a > acc[FOLD_TAIL + n, i]:
                acc[FOLD_TAIL + n, i] = a
                acc[FOLD_TAIL_INDEX + n, i] = r
        if not (math.isfinite(p1[i]) and math.isfinite(p2[i]) and math.isfinite(w1[i]) and math.isfinite(w2[i])):
            acc[nonfinite_row, i] = 1.0


@numba.njit(cache=True, nogil=True)
def fold_block(
    states: FloatArray, r0: int, head: int, tail: int, k: FloatArray, stats: FloatArray, lo: int, hi: int
) -> None:
    """Fold samples r0 .. r0 + count - 1 of members lo..hi-1 (states (count, 5, nbatch)) into
    ``stats`` (the rows above, (19, nbatch)): amplitudes |phi_n| (the largest; in the head window
    r <= head and the tail window r >= tail with the first sample that reached it), the energy
    (``closed_form.kinetic_energy`` + ``potential_energy``, ``_energy_at``) at the
    first sample, its largest and at the block's last sample, and 1.0 where a state was not finite.
    A NaN never compares larger, so it never wins (numpy's fmax / argmax of the values with NaN as
    -inf). Releases the GIL: ``batch`` deals the members over threads."""
    count = states.shape[0]
    for s in range(count):
        r = r0 + s
        for b in range(lo, hi):
            p1, p2, w1, w2 = states[s, 0, b], states[s, 1, b], states[s, 2, b], states[s, 3, b]
            energy = _energy_at(_trig(p1, p2), w1, w2, _member_of(k, b))
            if r == 0:
                stats[FOLD_ENERGY_START, b] = energy
            if energy > stats[FOLD_ENERGY_MAX, b]:
                stats[FOLD_ENERGY_MAX, b] = energy
            if s == count - 1:
                stats[FOLD_ENERGY_END, b] = energy
        _fold_amplitudes(stats[:, lo:hi], FOLD_NONFINITE, r, head, tail, states[s, 0, lo:hi], states[s, 1, lo:hi],
                         states[s, 2, lo:hi], states[s, 3, lo:hi])  # fmt: skip


# --- the summary pass fused into the batch loop (undriven) -----------------------------------


_ACC_NONFINITE = FOLD_TAIL_INDEX + 2  # the fused pass's non-finite flag, after the amplitude rows
_ACC_ROWS = _ACC_NONFINITE + 1
_PHI_BLOCK = 64  # samples of angles gathered member by member before they go to phi, member by member


@numba.njit(cache=True)
def _flush_angles(buf: FloatArray, phi: FloatArray, lo: int, r0: int, count: int) -> None:
    """phi[lo + i, q, r0 + j] = buf[j, q, i] for j < count: the buffered samples written along each
    member's row (storing each sample straight into phi touched a page per member and sample,
    one third of the pass)."""
    for i in range(buf.shape[2]):
        for q in range(2):
            for j in range(count):
                phi[lo + i, q, r0 + j] = buf[j, q, i]


@numba.njit(parallel=True, cache=True)
def summarise_kernel_undriven(
    k: FloatArray,
    y0: FloatArray,
    nstep: int,
    h: float,
    every: int,
    head: int,
    tail: int,
    stats: FloatArray,
    phi: FloatArray,
    chunk: int,
) -> None:
    """The undriven batch loop (``_integrate_chunk_undriven``'s steps, the same bits) with the
    summary's reductions (``fold_block``'s rules) folded in at every saved sample,
    r = 0 .. nstep // every: no states are stored. stats (19, nbatch) as ``fold_block``'s rows,
    the end state in rows 13..17; phi (nbatch, 2, nstep // every + 1) receives the sampled angles
    (an empty (0, 2, 0) array: not kept).

    Written so the members still vectorise: the step loop also takes the energy at the state it
    steps from, from the sines and cosines its first stage computes there (no transcendental of
    its own), and keeps its largest over the saved samples by a select; the amplitudes are folded
    by ``_fold_amplitudes`` before it. (Folding the amplitudes in the same loop made it scalar, 4x
    slower.) One RK4 step inlined, not two (a loop for saved samples and one for the others):
    the first compile takes half as long."""
    n = y0.shape[1]
    keep = phi.shape[0] > 0
    last = nstep // every
    for ci in numba.prange((n + chunk - 1) // chunk):
        lo = ci * chunk
        hi = min(n, lo + chunk)
        m = hi - lo
        kc = _chunk_coefficients(k, lo, hi)
        p1, p2, w1, w2, d = _chunk_state(y0, lo, hi)
        acc = np.zeros((_ACC_ROWS, m))  # FOLD_AMP .. FOLD_TAIL_INDEX, then the non-finite flag
        for row in (FOLD_AMP, FOLD_AMP + 1, FOLD_HEAD, FOLD_HEAD + 1, FOLD_TAIL, FOLD_TAIL + 1):
            acc[row] = -np.inf
        emax = np.full(m, -np.inf)
        buf = np.empty((_PHI_BLOCK if keep else 0, 2, m))  # the angles of the last samples, member last
        zero = (0.0, 0.0, 0.0, 0.0)
        for i in range(m):
            stats[FOLD_ENERGY_START, lo + i] = _energy_at(_trig(p1[i], p2[i]), w1[i], w2[i], _member(kc, i))
        for step in range(nstep):
            due = step % every == 0  # a saved sample: fold it before stepping from it
            if due:
                r = step // every
                if keep:
                    slot = r % _PHI_BLOCK
                    for i in range(m):
                        buf[slot, 0, i] = p1[i]
                        buf[slot, 1, i] = p2[i]
                    if slot == _PHI_BLOCK - 1:
                        _flush_angles(buf, phi, lo, r - slot, _PHI_BLOCK)
                _fold_amplitudes(acc, _ACC_NONFINITE, r, head, tail, p1, p2, w1, w2)
            for i in range(m):
                c = _member(kc, i)
                e = _energy_at(_trig(p1[i], p2[i]), w1[i], w2[i], c)
                emax[i] = e if due and e > emax[i] else emax[i]
                pa, pb, pc, pe, pf = _rk4(p1[i], p2[i], w1[i], w2[i], d[i], h, c, zero, zero, zero)
                p1[i], p2[i], w1[i], w2[i], d[i] = pa, pb, pc, pe, pf
        if keep:  # the last sample, and those still in the buffer
            slot = last % _PHI_BLOCK
            for i in range(m):
                buf[slot, 0, i] = p1[i]
                buf[slot, 1, i] = p2[i]
            _flush_angles(buf, phi, lo, last - slot, slot + 1)
        _fold_amplitudes(acc, _ACC_NONFINITE, last, head, tail, p1, p2, w1, w2)
        for i in range(m):
            e = _energy_at(_trig(p1[i], p2[i]), w1[i], w2[i], _member(kc, i))
            emax[i] = e if e > emax[i] else emax[i]
            b = lo + i
            for row in range(FOLD_AMP, FOLD_TAIL_INDEX + 2):
                stats[row, b] = acc[row, i]
            stats[FOLD_ENERGY_MAX, b] = emax[i]
            stats[FOLD_ENERGY_END, b] = e
            stats[FOLD_END, b], stats[FOLD_END + 1, b], stats[FOLD_END + 2, b] = p1[i], p2[i], w1[i]
            stats[FOLD_END + 3, b], stats[FOLD_END + 4, b] = w2[i], d[i]
            stats[FOLD_NONFINITE, b] = acc[_ACC_NONFINITE, i]
