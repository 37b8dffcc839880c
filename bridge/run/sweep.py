"""Run a sweep into a folder of results that survives interruption: serially, or on Dask.

The folder (``out_dir``) holds:

- ``sweep.json``: the definition and a hash of its cases; a later run into the same folder must
  match it, and then resumes: only cases not yet recorded are computed.
- ``parts/part-<first case>.parquet``: one file per finished task, each published atomically (a
  unique temporary name, then a link): a case counts as finished exactly when its part exists, so
  an interrupted sweep loses at most the tasks that were running.
- ``results.parquet``: every case once, ordered by ``case_id``, written when all are finished.
  One row per case: ``case_id``, the inputs (named as defined), for a sensitivity sweep
  ``varied`` and ``relative_change``, ``diverged``, then the feature columns
  (``pendsim_mj.sweep.features``). The definition is in the file's metadata (``pendsim.sweep``).
- ``trajectories.zarr`` (with ``trajectories = true``): arrays ``phi_rad`` and ``omega_rad_s``
  (ncases, nsamples, 2), chunked by cases, and ``t_s``; complete when ``results.parquet`` is.
- ``maps/*.png`` and, for a sensitivity sweep, ``sensitivity.json`` (``pendsim_bridge.report.sweep_plots``).

Backends: serial (this process; the engines use every core), a ``LocalCluster`` of ``workers``
processes on loopback, or a running Dask scheduler at ``scheduler`` (tcp://HOST:PORT; its workers
must have pendsim installed). Cases go out in tasks of ``cases_per_task`` (by default enough
trajectory steps to amortise scheduling); the definition is sent to every worker once. Only this
process writes files, one part per completed task, so a task that Dask recomputes (its worker
died) is still written once, and no case is in the results twice. Every cluster started here is
closed on every exit path: while a sweep runs, SIGTERM is turned into KeyboardInterrupt (as
Ctrl-C), so the cluster's context manager and the temporary files' clean-up run too.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import errno
import json
import logging
import math
import os
import shutil
import signal
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.checks import UNRESOLVED_SHARE
from pendsim_mj.sweep.features import FEATURE_GROUPS
from pendsim_mj.sweep.plan import CaseTable, SweepPlan
from pendsim_mj.sweep.run import TaskResult, light_path, run_task

from ..errors import OutputError
from ..io.outputs import atomic_output, output_error
from ..signals import signal_handlers

STORE_VERSION = 1
META_KEY = b"pendsim.sweep"
# Trajectory steps per task on each engine: about 0.5-2 s of work, so scheduling (ms) is amortised.
TASK_STEPS = {"fast": 30_000_000, "mujoco": 400_000, "spatial": 300_000}
# Bound on a task's sampled states in memory (cases x samples x 5 x 8 bytes).
TASK_STATE_BYTES = 256 * 2**20
CHECK_BLOCK = 1 << 16  # cases whose inputs are checked at once before a sweep starts (bounded memory)
ROW_GROUP_ROWS = 1 << 17  # rows per Parquet row group of results.parquet (about 10 MB at 20 columns)
TASKS_PER_WORKER = 4  # at least this many tasks per worker (balance, progress, little lost on a kill)


@dataclasses.dataclass(frozen=True)
class SweepSummary:
    """What a sweep run did.

    Attributes:
      out_dir: the results folder.
      ncases: cases in the sweep.
      computed: cases computed by this run; resumed: cases found finished before it.
      diverged: cases whose run diverged.
      unresolved: cases whose step does not resolve their run (column ``unresolved``:
        ``features.with_balance``); 0 for results written before that column.
      tasks: tasks this run sent out.
      backend: "serial", "LocalCluster (N workers)" or the scheduler address.
      elapsed_s: wall time of this run, s.
      results: ``results.parquet``; maps: the PNG files; sensitivity: ``sensitivity.json`` or None.
    """

    out_dir: Path
    ncases: int
    computed: int
    resumed: int
    diverged: int
    tasks: int
    backend: str
    elapsed_s: float
    results: Path
    maps: tuple[Path, ...]
    sensitivity: Path | None
    unresolved: int = 0


def run_sweep(
    plan: SweepPlan,
    out_dir: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    cases_per_task: int | None = None,
    progress: bool = True,
    plots: bool = True,
    on_task_done: Callable[[int], None] | None = None,
) -> SweepSummary:
    """Run (or resume) ``plan`` into ``out_dir``; see the module docstring.

    Args:
      plan: the sweep definition.
      out_dir: the results folder (created; an existing one must hold the same sweep).
      workers: start a LocalCluster with this many worker processes (loopback only).
      scheduler: use the running Dask scheduler at this address instead.
      cases_per_task: cases per task (default: from TASK_STEPS and the number of workers).
      progress: show a progress bar with an ETA on stderr (when it is a terminal).
      plots: draw the maps when the sweep is complete.
      on_task_done: called with the number of tasks finished so far after each one is written.

    Raises:
      ParameterError: bad options or cases; OutputError: the folder holds another sweep or
        cannot be written.
    """
    if workers is not None and scheduler is not None:
        raise ParameterError("give either workers (a local cluster) or scheduler (a running one), not both")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ParameterError(f"workers must be a whole number >= 1, got {workers!r}")
    if cases_per_task is not None and (not isinstance(cases_per_task, int) or cases_per_task < 1):
        raise ParameterError(f"cases_per_task must be a whole number >= 1, got {cases_per_task!r}")
    if scheduler is not None:
        check_scheduler(scheduler)
    start = time.perf_counter()
    table = plan.cases()
    for lo in range(0, len(table), CHECK_BLOCK):  # every case's parameters and drive are valid, before any work
        rows = np.arange(lo, min(len(table), lo + CHECK_BLOCK))
        plan.case_inputs(table, rows)
        plan.case_drives(table, rows)
    store = SweepStore.open(Path(out_dir), plan, table)
    try:
        return _run_into(store, plan, table, start, workers, scheduler, cases_per_task, progress, plots, on_task_done)
    except Exception:  # a failure (a full disk, ...): what this run started goes; Ctrl-C keeps it to resume
        store.withdraw()
        raise
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: said with what is kept, and how to go on
        try:
            saved = len(store.finished_ids())
        except OutputError:  # a part that cannot be read: the next run names it
            raise KeyboardInterrupt from None
        raise KeyboardInterrupt(
            f"{saved} of {len(table)} cases saved in {out_dir}; the same command resumes"
            if saved
            else f"no case finished yet in {out_dir}"
        ) from None


def _run_into(
    store: SweepStore,
    plan: SweepPlan,
    table: CaseTable,
    start: float,
    workers: int | None,
    scheduler: str | None,
    cases_per_task: int | None,
    progress: bool,
    plots: bool,
    on_task_done: Callable[[int], None] | None,
) -> SweepSummary:
    remaining = np.setdiff1d(np.arange(len(table)), store.finished_ids())
    resumed = len(table) - len(remaining)
    in_process = _in_process_instead(plan, workers)
    if in_process is not None:  # one machine whose cores this process's threads already use
        workers = None  # and its tasks are a serial run's (smaller ones only add per-task work)
        backend = f"this process ({in_process})"
    else:
        plural = "s" if workers != 1 else ""
        backend = (
            "serial"
            if workers is None and scheduler is None
            else (scheduler or f"LocalCluster ({workers} worker{plural})")
        )
    if cases_per_task is None:
        split = 8 if scheduler is not None else (workers or 1)
        cases_per_task = default_cases_per_task(plan, len(table), split)
    tasks = contiguous_tasks(remaining, cases_per_task)
    if tasks:
        with _terminate_as_interrupt(), _progress_bar(len(table), resumed, progress, backend) as bar:

            def done(result: TaskResult, count: int) -> None:
                store.write_task(result, table)
                bar(len(result.case_ids))
                if on_task_done is not None:
                    on_task_done(count)

            if workers is None and scheduler is None:
                _run_serial(plan, table, tasks, done)
            else:
                _run_dask(plan, table, tasks, done, workers=workers, scheduler=scheduler)
    results = store.combine()
    maps: tuple[Path, ...] = ()
    sensitivity = None
    if plots or plan.method == "sensitivity":
        from ..report import sweep_plots  # start-up: matplotlib, only for the maps

        if plan.method == "sensitivity":
            store.will_create(store.root / "sensitivity.json")
            sensitivity = sweep_plots.write_sensitivity(results, table, out_dir=store.root)
        if plots:
            store.will_create(store.root / "maps")
            maps = tuple(sweep_plots.draw_maps(results, plan, table, store.root / "maps"))
    flags = ["diverged", "unresolved"] if "unresolved" in pq.read_schema(results).names else ["diverged"]
    counts = {
        name: int(np.sum(column.to_numpy()))
        for name, column in zip(flags, pq.read_table(results, columns=flags).columns, strict=True)
    }
    diverged = counts["diverged"]
    return SweepSummary(
        out_dir=store.root,
        ncases=len(table),
        computed=len(remaining),
        resumed=resumed,
        diverged=diverged,
        tasks=len(tasks),
        backend=backend,
        elapsed_s=time.perf_counter() - start,
        results=results,
        maps=maps,
        sensitivity=sensitivity,
        unresolved=counts.get("unresolved", 0),
    )


def _in_process_instead(plan: SweepPlan, workers: int | None) -> str | None:
    """Why a LocalCluster of ``workers`` would only be slower than this process, or None.

    The fast engine's kernel threads over every core; the MuJoCo engines run one share of a
    task's cases per core on threads of their own (``sweep.run``), so N >= cores worker processes,
    one thread each, only add their start-up and a copy of pendsim each (measured on 2 cores with
    ``--workers 2``: 0.80x of this process at 1000 MuJoCo cases, 0.88x at 4000; docs/sweeps.md).
    With fewer workers than cores each worker threads over its share of them (not measured here).
    """
    if workers is None:
        return None
    if plan.engine == "fast":
        return (
            f"the fast engine threads over the cores; --workers {workers} splits a MuJoCo sweep over fewer "
            "workers than cores, --scheduler over more machines"
        )
    cores = os.cpu_count() or 1
    if workers >= cores:
        return (
            f"the MuJoCo engines run a thread per core; --workers {workers} on {cores} core{'s' if cores > 1 else ''} "
            "would only add worker start-up"
        )
    return None


DASK_GREETING_MAX_BYTES = 1 << 20  # a Dask comm's handshake is a few hundred bytes


def check_scheduler(address: str, *, timeout_s: float = 5.0) -> None:
    """A Dask scheduler at tcp://HOST:PORT, checked within ``timeout_s`` before anything is
    written: something listens there, greets as a Dask comm does (a listener writes its handshake
    first: an 8-byte length, then a msgpack map with "pickle-protocol"), and answers the "identity"
    request as a scheduler (not a worker). A plain TCP server, a web server (the dashboard's port)
    or a silent listener fails in one line instead of a traceback or a hang.

    Raises:
      ParameterError: a malformed address, nothing listening there, or not a Dask scheduler.
    """
    host, sep, port = address.removeprefix("tcp://").rpartition(":")
    if not address.startswith("tcp://") or not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ParameterError(f"scheduler must be tcp://HOST:PORT (PORT 1-65535), got {address!r}")
    deadline = time.monotonic() + timeout_s
    try:
        sock = socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s)
    except OSError as exc:
        raise ParameterError(f"cannot reach the Dask scheduler at {address!r}: {exc.strerror or exc}") from None
    not_dask = f"{address!r} is not a Dask scheduler"
    with sock:
        try:
            head = _receive(sock, 8, deadline)
            (size,) = struct.unpack("<Q", head)
            if not 0 < size <= DASK_GREETING_MAX_BYTES:
                raise ParameterError(f"{not_dask}: it answered {head!r}..., not a Dask handshake")
            if b"pickle-protocol" not in _receive(sock, size, deadline):
                raise ParameterError(f"{not_dask}: its greeting is not a Dask handshake")
        except TimeoutError:
            raise ParameterError(
                f"{not_dask}: it sent no Dask handshake within {timeout_s:g} s (a web server, such as the "
                "dashboard's port, waits for a request); give the scheduler's port (default 8786)"
            ) from None
        except OSError as exc:
            raise ParameterError(f"{not_dask}: the connection failed ({exc.strerror or exc})") from None
    kind = _identity(address, max(0.5, deadline - time.monotonic()))
    if kind != "Scheduler":
        raise ParameterError(f"{not_dask}: it is a Dask {kind or 'endpoint of unknown type'}; give the scheduler's")


def _receive(sock: socket.socket, n: int, deadline: float) -> bytes:
    """Exactly ``n`` bytes before ``deadline`` (TimeoutError after it; OSError if the peer closes)."""
    data = bytearray()
    while len(data) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError
        sock.settimeout(left)
        piece = sock.recv(n - len(data))
        if not piece:
            raise ConnectionResetError(errno.ECONNRESET, "closed by the other side")
        data += piece
    return bytes(data)


def _identity(address: str, timeout_s: float) -> str | None:
    """The "type" a Dask server gives for itself ("Scheduler", "Worker", ...), asked within
    ``timeout_s``.

    Raises:
      ParameterError: no answer in time, or the answer is not a Dask identity.
    """
    from distributed.comm import connect  # start-up: Dask, only for a scheduler's check

    async def ask() -> Any:
        comm = await connect(address, timeout=timeout_s)
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    try:
        answer = asyncio.run(asyncio.wait_for(ask(), timeout_s))
    except Exception as exc:  # anything a foreign server can make the protocol raise
        raise ParameterError(
            f"{address!r} is not a Dask scheduler: it did not answer Dask's identity request ({type(exc).__name__})"
        ) from None
    return answer.get("type") if isinstance(answer, dict) else None


def contiguous_tasks(ids: NDArray[np.int64], size: int) -> list[NDArray[np.int64]]:
    """Sorted case ids cut into tasks of at most ``size`` consecutive ids each (a gap, a range
    finished before a resume, ends a task): every part then holds one range of case ids, so the
    parts of a sweep never interleave and ``combine`` streams them in order."""
    runs = np.split(ids, np.flatnonzero(np.diff(ids) != 1) + 1) if len(ids) else []
    return [run[i : i + size] for run in runs for i in range(0, len(run), size)]


def default_cases_per_task(plan: SweepPlan, ncases: int, parallel: int) -> int:
    """Enough cases for TASK_STEPS trajectory steps, within TASK_STATE_BYTES of what a task keeps
    per case (sampled states, or on the light path the angles only; held drive inputs), and at
    most ncases / (TASKS_PER_WORKER * parallel) so every worker gets several tasks."""
    by_steps = TASK_STEPS[plan.engine] // max(1, plan.nstep)
    driven = bool(plan.driven_targets(plan.cases()))
    per_sample = 16 if light_path(plan) else 40  # phi1, phi2 or the five states, float64
    per_case = per_sample * (plan.nstep // plan.save_every + 1) + (32 * plan.nstep if driven else 0)
    by_memory = TASK_STATE_BYTES // per_case
    by_balance = math.ceil(ncases / (TASKS_PER_WORKER * parallel))
    return max(1, min(by_steps, by_memory, by_balance))


# -- the results folder ----------------------------------------------------------------------


def _differences(found: object, wanted: object, at: str = "") -> str:
    """Where two sweep definitions (parsed JSON) differ: the keys, dotted ("plan.base.c1_n_m: 6.5
    there, absent here"), at most three."""
    if isinstance(found, dict) and isinstance(wanted, dict):
        parts = []
        keys = sorted(k for k in set(found) | set(wanted) if found.get(k) != wanted.get(k))
        if len(keys) > 1:  # the cases' hash: said only when nothing else differs
            keys = [k for k in keys if f"{at}{k}" != "cases_sha256"]
        for key in keys:
            if key in found and key in wanted:
                parts.append(_differences(found[key], wanted[key], f"{at}{key}."))
            else:
                side = "there, absent here" if key in found else "here, absent there"
                value = found.get(key, wanted.get(key))
                parts.append(f"{at}{key}: {json.dumps(value)[:40]} {side}")
        return "; ".join(parts[:3]) + (f"; {len(parts) - 3} more" if len(parts) > 3 else "")
    return f"{at.rstrip('.')}: {json.dumps(found)[:40]} there, {json.dumps(wanted)[:40]} here"


class SweepStore:
    """The results folder of one sweep (layout in the module docstring). Only the process that
    runs the sweep writes to it."""

    def __init__(self, root: Path, plan: SweepPlan, table: CaseTable) -> None:
        self.root = root
        self.plan = plan
        self.table = table
        self.parts = root / "parts"
        self.definition = {
            "version": STORE_VERSION,
            "plan": plan.to_mapping(),
            "cases": len(table),
            "cases_sha256": table.digest(),
        }
        self._zarr: Any = None
        self._created: list[Path] = []  # what this run created, in order (``withdraw`` removes it)

    def will_create(self, path: Path) -> None:
        """Note ``path`` as this run's own if it does not exist yet (``withdraw`` removes it)."""
        if not (path.exists() or path.is_symlink()):
            self._created.append(path)

    def withdraw(self) -> None:
        """After a failure: remove what this run created (its parts, a zarr store, sweep.json, the
        results, maps and folders it made), newest first; what existed before is left untouched."""
        for path in reversed(self._created):
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
        self._created.clear()

    @classmethod
    def open(cls, root: Path, plan: SweepPlan, table: CaseTable) -> SweepStore:
        """Create the folder, or check that an existing one holds this sweep. On failure, what
        it created is removed again.

        Raises:
          OutputError: ``root`` is a file, holds a different sweep, or cannot be written.
        """
        store = cls(root, plan, table)
        try:
            store._open()
        except BaseException:
            store.withdraw()
            raise
        return store

    def _open(self) -> None:
        store, root, plan = self, self.root, self.plan
        meta = root / "sweep.json"
        if root.exists() and not root.is_dir():
            raise OutputError(f"output {str(root)!r} is a file; give a folder for the sweep's results")
        if meta.exists():
            try:
                found = json.loads(meta.read_text())
            except (OSError, ValueError) as exc:
                raise OutputError(f"{str(meta)!r} is unreadable ({exc}); delete the folder to start again") from None
            wanted = json.loads(json.dumps(store.definition))
            if found != wanted:
                raise OutputError(
                    f"{str(root)!r} holds a different sweep (its sweep.json differs from this definition in "
                    f"{_differences(found, wanted)}); give another folder, or delete this one to start again"
                )
        elif root.exists() and any(root.iterdir()):
            raise OutputError(f"{str(root)!r} exists and is not a sweep's results folder; give a new or empty folder")
        try:
            for folder in (*reversed(root.parents), root, store.parts):  # outermost first
                store.will_create(folder)
            store.parts.mkdir(parents=True, exist_ok=True)
            if not meta.exists():
                store.will_create(meta)
                with atomic_output(meta) as tmp:
                    tmp.write_text(json.dumps(store.definition, indent=1) + "\n")
        except OSError as exc:
            raise output_error(root, exc) from None
        if plan.trajectories:
            store._open_zarr()

    def finished_ids(self) -> NDArray[np.int64]:
        """Case ids recorded in the parts so far (sorted).

        Raises:
          OutputError: a part cannot be read (named, with what to do).
        """
        ids = [self._read_part(p, columns=["case_id"]).column("case_id").to_numpy() for p in self._part_files()]
        return np.sort(np.concatenate(ids)) if ids else np.zeros(0, dtype=np.int64)

    def write_task(self, result: TaskResult, table: CaseTable) -> Path:
        """Record one finished task: its trajectories (if kept), then its part, atomically."""
        ids = result.case_ids
        if self._zarr is not None and result.trajectories is not None:
            try:
                self._zarr["phi_rad"].oindex[ids] = result.trajectories[..., :2]
                self._zarr["omega_rad_s"].oindex[ids] = result.trajectories[..., 2:]
            except OSError as exc:
                raise output_error(self.root / "trajectories.zarr", exc) from None
        path = self.parts / f"part-{int(ids[0]):09d}.parquet"
        self.will_create(path)
        with atomic_output(path) as tmp:
            pq.write_table(self._arrow(result, table), tmp)
        return path

    def combine(self) -> Path:
        """Publish ``results.parquet``: every case once, by case_id, streamed part by part into row
        groups of ROW_GROUP_ROWS (memory does not grow with the sweep). Parts hold ranges of case
        ids (``contiguous_tasks``); a folder whose parts interleave (written by an older version)
        is merged in memory.

        Raises:
          OutputError: a case is missing or recorded twice (the parts are not one sweep's).
        """
        files = self._part_files()
        if not files:
            raise OutputError(f"{str(self.parts)!r} holds no results")
        ids = [self._read_part(f, columns=["case_id"]).column("case_id").to_numpy() for f in files]
        order = np.argsort([part[0] if len(part) else -1 for part in ids], kind="stable")
        ranges = all(np.array_equal(part, np.arange(part[0], part[0] + len(part))) for part in ids if len(part))
        merged_ids = np.concatenate([ids[i] for i in order])
        if len(merged_ids) != len(self.table) or np.any(np.sort(merged_ids) != np.arange(len(self.table))):
            merged_ids.sort()
            twice: NDArray[np.int64] = np.unique(merged_ids[np.flatnonzero(np.diff(merged_ids) == 0)])
            raise OutputError(
                f"{str(self.parts)!r} holds {len(merged_ids)} rows for {len(self.table)} cases"
                + (f" (case {int(twice[0])} twice)" if len(twice) else "")
                + "; delete the folder to start again"
            )
        path = self.root / "results.parquet"
        self.will_create(path)
        meta = {META_KEY: json.dumps(self.definition).encode()}
        with atomic_output(path, replace=True) as tmp:
            if not (ranges and np.array_equal(merged_ids, np.arange(len(self.table)))):
                merged = pa.concat_tables([self._read_part(f) for f in files]).sort_by("case_id")
                pq.write_table(merged.replace_schema_metadata(meta), tmp, row_group_size=ROW_GROUP_ROWS)
                return path
            schema = self._read_part(files[order[0]]).schema.with_metadata(meta)
            with pq.ParquetWriter(tmp, schema) as writer:
                pending: list[pa.Table] = []
                rows = 0
                for i in order:
                    part = self._read_part(files[i])
                    if part.schema.remove_metadata() != schema.remove_metadata():
                        raise OutputError(
                            f"results part {str(files[i])!r} has other columns than the sweep's; "
                            "delete it and run again to recompute its cases"
                        )
                    pending.append(part)
                    rows += part.num_rows
                    if rows >= ROW_GROUP_ROWS:  # whole row groups out, the rest waits for the next parts
                        held = pa.concat_tables(pending).cast(schema)
                        whole = rows - rows % ROW_GROUP_ROWS
                        writer.write_table(held.slice(0, whole), row_group_size=ROW_GROUP_ROWS)
                        pending, rows = [held.slice(whole)], rows - whole
                if rows:
                    writer.write_table(pa.concat_tables(pending).cast(schema), row_group_size=ROW_GROUP_ROWS)
        return path

    def _part_files(self) -> list[Path]:
        return sorted(p for p in self.parts.glob("part-*.parquet") if not p.name.startswith("."))

    def _read_part(self, path: Path, columns: list[str] | None = None) -> pa.Table:
        try:
            return pq.read_table(path, columns=columns)
        except (OSError, pa.ArrowException) as exc:
            raise OutputError(
                f"results part {str(path)!r} is unreadable ({exc}); delete it and run again to recompute its cases"
            ) from None

    def _arrow(self, result: TaskResult, table: CaseTable) -> pa.Table:
        ids = result.case_ids
        cols: dict[str, pa.Array] = {"case_id": pa.array(ids, type=pa.int64())}
        for j, name in enumerate(table.names):
            cols[name] = pa.array(table.values[ids, j], type=pa.float64())
        if table.varied is not None and table.relative_change is not None:
            cols["varied"] = pa.array([table.varied[i] for i in ids], type=pa.string())
            cols["relative_change"] = pa.array(table.relative_change[ids], type=pa.float64())
        feats = result.features
        cols["diverged"] = pa.array(feats.diverged, type=pa.bool_())
        for j, name in enumerate(feats.names):
            cols[name] = pa.array(feats.values[:, j], type=pa.float64())
        for name, flags in feats.quality.items():
            kind = pa.bool_() if flags.dtype == np.bool_ else pa.float64()
            cols[name] = pa.array(flags, type=kind)
        if feats.poincare is not None:
            for name, values in zip(FEATURE_GROUPS["poincare"], dataclasses.astuple(feats.poincare), strict=True):
                cols[name] = pa.array([v.tolist() for v in values], type=pa.list_(pa.float64()))
        return pa.table(cols)

    def _open_zarr(self) -> None:
        import zarr  # start-up: only for a zarr store

        path = self.root / "trajectories.zarr"
        nsave = self.plan.nstep // self.plan.save_every + 1
        shape = (len(self.table), nsave, 2)
        chunk_cases = max(1, min(len(self.table), (8 * 2**20) // (16 * nsave)))
        self.will_create(path)
        try:
            group = zarr.open_group(str(path), mode="a")
            for name in ("phi_rad", "omega_rad_s"):
                if name not in group:
                    group.create_array(name, shape=shape, chunks=(chunk_cases, nsave, 2), dtype="f8", fill_value=np.nan)
            if "t_s" not in group:
                group.create_array("t_s", shape=(nsave,), dtype="f8")[:] = (
                    np.arange(nsave) * self.plan.dt_s * self.plan.save_every
                )
        except OSError as exc:
            raise output_error(path, exc) from None
        self._zarr = group


# -- backends ----------------------------------------------------------------------------------

Done = Callable[[TaskResult, int], None]


def _run_serial(plan: SweepPlan, table: CaseTable, tasks: list[NDArray[np.int64]], done: Done) -> None:
    for count, ids in enumerate(tasks, start=1):
        done(_task(plan, _rows(table, ids), ids, None), count)


def _rows(table: CaseTable, ids: NDArray[np.int64]) -> CaseTable:
    """The rows ``ids`` of the table (what a task needs of it)."""
    return CaseTable(names=table.names, values=table.values[ids])


def _task(
    plan: SweepPlan, rows: CaseTable, ids: NDArray[np.int64], nthread: int | None, keep: bool | None = None
) -> TaskResult:
    """The function a task runs (a worker imports it from here)."""
    return run_task(plan, rows, ids, nthread=nthread, keep_trajectories=plan.trajectories if keep is None else keep)


@contextlib.contextmanager
def _workers_leave_interrupts_to_this_process() -> Iterator[None]:
    """SIGINT ignored while the worker processes start, so that they inherit it ignored (Python
    leaves an inherited ignore in place): a Ctrl-C at the terminal reaches the whole process group,
    and each worker answered it with a KeyboardInterrupt traceback (about 40 lines of them) while
    this process closed them anyway. This process takes SIGINT again once they have started (a
    Ctrl-C in the second or two before is not seen)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _run_dask(
    plan: SweepPlan,
    table: CaseTable,
    tasks: list[NDArray[np.int64]],
    done: Done,
    *,
    workers: int | None,
    scheduler: str | None,
) -> None:
    from dask.distributed import Client, LocalCluster, as_completed  # start-up: only for a Dask run

    with contextlib.ExitStack() as stack:
        if workers is not None:
            with _workers_leave_interrupts_to_this_process():
                cluster = stack.enter_context(
                    LocalCluster(
                        n_workers=workers,
                        threads_per_worker=1,
                        processes=True,
                        host="127.0.0.1",
                        dashboard_address=None,
                        silence_logs=logging.ERROR,
                    )
                )
            client = stack.enter_context(Client(cluster))
            nthread: int | None = max(1, (os.cpu_count() or 1) // workers)
        else:
            try:
                client = stack.enter_context(Client(scheduler, timeout="10s"))
            except (OSError, TimeoutError) as exc:
                raise ParameterError(f"cannot reach the Dask scheduler at {scheduler!r}: {exc}") from None
            nthread = None
        shared = client.scatter(plan, broadcast=True, hash=False)
        tag = table.digest()[:12]
        futures = [
            client.submit(
                _task, shared, _rows(table, ids), ids, nthread, key=f"pendsim-sweep-{tag}-{int(ids[0])}", retries=2
            )
            for ids in tasks
        ]
        written: set[str] = set()
        for future in as_completed(futures):
            if future.key in written:  # never write a task twice
                continue
            result = future.result()
            written.add(future.key)
            done(result, len(written))
            future.release()


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """While active, SIGTERM raises KeyboardInterrupt (as Ctrl-C does), so every cluster and
    process started inside is closed by its context manager; the previous handler comes back."""

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    with signal_handlers({signal.SIGTERM: interrupt}):
        yield


@contextlib.contextmanager
def _progress_bar(total: int, initial: int, show: bool, backend: str) -> Iterator[Callable[[int], None]]:
    from tqdm import tqdm  # start-up: only when a bar is shown

    with tqdm(
        total=total,
        initial=initial,
        unit="case",
        desc=f"sweep ({backend})",
        disable=None if show else True,
        smoothing=0.1,
    ) as bar:
        yield bar.update


def read_results(path: str | Path) -> tuple[pa.Table, dict[str, Any]]:
    """A results.parquet and the sweep definition stored in it.

    Raises:
      OutputError: the file is missing, unreadable, or not a pendsim sweep's results.
    """
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise OutputError(f"cannot read sweep results {str(path)!r}: {exc}") from None
    meta = (table.schema.metadata or {}).get(META_KEY)
    if meta is None:
        raise OutputError(f"{str(path)!r} is not the results of a pendsim sweep (no {META_KEY.decode()} metadata)")
    return table, json.loads(meta)


def shorten(names: list[str], keep: int = 4) -> str:
    """The names joined, at most ``keep`` of them and then how many more."""
    return ", ".join(names) if len(names) <= keep else ", ".join(names[:keep]) + f", ... {len(names) - keep} more"


def describe(summary: SweepSummary, plan: SweepPlan, *, top: int = 12) -> str:
    """What ``pendsim sweep`` prints: the run, the files, and for a sensitivity sweep the ranking
    of the first feature."""
    names = pq.read_schema(summary.results).names  # the schema and the row count: no rows read
    nrows = pq.ParquetFile(summary.results).metadata.num_rows
    first = names.index("diverged")
    inputs = [c for c in names[1:first] if c not in ("varied", "relative_change")]
    features = names[first + 1 :]
    where = "in this process, serially" if summary.backend == "serial" else f"on {summary.backend}"
    lines = [
        f"sweep of {summary.ncases} case{'s' if summary.ncases != 1 else ''} ({plan.method}, {plan.engine} engine, "
        f"{plan.duration_s:g} s at "
        f"{plan.dt_s:g} s) {where}: computed {summary.computed} in {summary.elapsed_s:.1f} s"
        + (f", {summary.resumed} already done" if summary.resumed else "")
        + f", {summary.diverged} diverged",
        f"results: {summary.results} ({nrows} rows, {len(names)} columns: case_id, "
        f"{len(inputs)} input{'s' if len(inputs) != 1 else ''} ({shorten(inputs)}), diverged, {', '.join(features)})",
    ]
    if summary.unresolved:
        lines.append(
            f"warning: {summary.unresolved} case{'s' if summary.unresolved > 1 else ''} not resolved at dt_s = "
            f"{plan.dt_s:g} s (column 'unresolved': the energy balance off by more than "
            f"{100 * UNRESOLVED_SHARE:g} % of m1 g OC1, a stiff spring or a violent swing): their features are "
            "not to be trusted; run them again with a smaller --dt-s"
        )
    if plan.trajectories:
        lines.append(f"trajectories: {summary.out_dir / 'trajectories.zarr'}")
    if summary.maps:
        lines.append(f"maps: {summary.maps[0].parent}/ ({', '.join(p.name for p in summary.maps)})")
    if summary.sensitivity is not None:
        data = json.loads(summary.sensitivity.read_text())
        for feature, entry in list(data["features"].items())[:1]:
            lines.append(
                f"sensitivity of {feature} (base {entry['base_value']:.6g}) to +/-{100 * data['relative_step']:g} % "
                "of each parameter, elasticity d ln f / d ln p, largest first:"
            )
            for row in entry["ranking"][:top]:
                value = row["elasticity"]
                lines.append(f"  {row['parameter']:<28} {'n/a' if value is None else f'{value:+.4f}'}")
        zero = plan.unscaled()
        if zero:
            lines.append(
                f"not stepped: {', '.join(zero)} (0 in the base: a relative step of 0 is none; --set a value to "
                "include one)"
            )
        lines.append(f"every feature's full ranking: {summary.sensitivity}")
    return "\n".join(lines)
