"""The Dask backend with real processes on loopback: a 10 000-case sweep run serially and on a
running cluster reached by its address with one worker process killed (SIGKILL) mid-sweep, and a
MuJoCo-engine sweep serially and on a LocalCluster of fewer workers than cores (``pendsim sweep
--workers N``), give the same rows; the killed worker's task is retried, no case is written twice,
and no process is left running, also when ``pendsim sweep --workers N`` itself gets SIGTERM or
SIGKILL. As many workers as cores run in this process (the engines' own threads)."""

import logging
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from dask.distributed import Client, LocalCluster

from pendsim_bridge.cli import main
from pendsim_bridge.run.sweep import run_sweep
from pendsim_mj.sweep.plan import SweepPlan

FEATURES = ["frequency", "amplitude", "decay", "energy", "poincare", "lyapunov"]
VARY = {
    "c1_n_m": {"from": 3.0, "to": 9.0},
    "phi1_deg": {"from": -80.0, "to": 80.0},
    "phi2_deg": {"from": -30.0, "to": 30.0},
}
# short runs (1 s) keep 10 000 cases quick; 250 cases per task make 40 tasks
PLAN = SweepPlan.from_mapping(
    {"method": "random", "samples": 10_000, "seed": 7, "vary": VARY, "duration_s": 1.0, "features": FEATURES}
)
CASES_PER_TASK = 250


def _children() -> set[int]:
    """Processes below this one, but multiprocessing's resource tracker: the first spawned process
    starts it and it lives as long as its parent (the subprocess tests below see it end too)."""
    found = set()
    for p in psutil.Process().children(recursive=True):
        try:  # zombies (other tests' reaped-late orphans under the suite's subreaper) have no command line
            if p.status() != psutil.STATUS_ZOMBIE and "multiprocessing.resource_tracker" not in " ".join(p.cmdline()):
                found.add(p.pid)
        except psutil.Error:
            continue
    return found


def _tree(pid: int) -> set[int]:
    return {pid} | {p.pid for p in psutil.Process(pid).children(recursive=True)}


def _alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.Error:
        return False


def _all_gone(pids: set[int], timeout_s: float = 15.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        alive = [p for p in pids if _alive(p)]
        if not alive:
            return True
        time.sleep(0.1)
    return False


@pytest.fixture(scope="module")
def serial_rows(tmp_path_factory) -> pa.Table:
    out = tmp_path_factory.mktemp("sweeps") / "serial"
    summary = run_sweep(PLAN, out, cases_per_task=CASES_PER_TASK, progress=False, plots=False)
    assert summary.backend == "serial" and summary.tasks == 40
    return pq.read_table(summary.results)


def _assert_same_rows(expected: pa.Table, got: pa.Table, ncases: int = 10_000) -> None:
    assert got.column_names == expected.column_names and got.num_rows == expected.num_rows == ncases
    np.testing.assert_array_equal(got.column("case_id").to_numpy(), np.arange(ncases))  # each case once
    for name in expected.column_names:
        a, b = expected.column(name), got.column(name)
        if pa.types.is_list(a.type):
            assert [len(x) for x in a.to_pylist()] == [len(x) for x in b.to_pylist()], name
            a, b = pa.concat_arrays(a.chunks).flatten(), pa.concat_arrays(b.chunks).flatten()
        a_np, b_np = a.to_numpy(zero_copy_only=False), b.to_numpy(zero_copy_only=False)
        if a_np.dtype == bool:
            np.testing.assert_array_equal(a_np, b_np, err_msg=name)
        else:
            np.testing.assert_allclose(b_np, a_np, rtol=0, atol=1e-12, equal_nan=True, err_msg=name)


MUJOCO_FEATURES = ["frequency", "amplitude", "decay", "energy", "poincare"]


def _sweep_args(engine: str, out: Path, *more: str) -> list[str]:
    args = ["sweep", "--engine", engine, "--random", "400", "--seed", "7", "--duration-s", "1", "--features"]
    args += [",".join(MUJOCO_FEATURES), *(f"--vary={name}={spec['from']}:{spec['to']}" for name, spec in VARY.items())]
    return [*args, "--cases-per-task", "25", "--no-plots", *more, "-o", str(out)]


CORES = os.cpu_count() or 1
FEWER = max(1, CORES - 1)
"""Local workers fewer than the cores (a LocalCluster; 1 on CI's 2 cores): as many or more run here."""


def test_pendsim_sweep_on_local_workers_gives_the_serial_rows_and_leaves_no_process(tmp_path, capsys):
    # the MuJoCo engine: 400 cases in 16 tasks on worker processes, the rows of a serial run
    assert main(_sweep_args("mujoco", tmp_path / "serial")) == 0
    assert "in this process, serially: computed 400" in capsys.readouterr().out
    before = _children()
    assert main(_sweep_args("mujoco", tmp_path / "local", "--workers", str(FEWER))) == 0
    assert f"on LocalCluster ({FEWER} worker{'s' if FEWER > 1 else ''}): computed 400" in capsys.readouterr().out
    expected, got = (pq.read_table(tmp_path / name / "results.parquet") for name in ("serial", "local"))
    _assert_same_rows(expected, got, 400)
    assert _all_gone(_children() - before)


def test_workers_on_the_fast_engine_run_in_this_process_on_the_kernels_threads(tmp_path, capsys):
    # one machine: the fast kernel already threads over every core, so worker processes would
    # only add their start-up (issue 24); no process is started and the output says why
    before = _children()
    assert main(_sweep_args("fast", tmp_path / "fast", "--workers", "2")) == 0
    out = capsys.readouterr().out
    assert "on this process (the fast engine threads over the cores; --workers 2 splits a MuJoCo sweep" in out
    assert "computed 400" in out and _children() == before


def test_as_many_workers_as_cores_on_a_mujoco_engine_run_in_this_process_with_the_serial_rows(tmp_path, capsys):
    # the MuJoCo engines run a thread per core here: worker processes, one thread each, measured
    # slower on 2 cores (docs/sweeps.md); the rows are the serial run's and no process is started
    assert main(_sweep_args("spatial", tmp_path / "serial")) == 0
    capsys.readouterr()
    before = _children()
    assert main(_sweep_args("spatial", tmp_path / "here", "--workers", str(CORES))) == 0
    out = capsys.readouterr().out
    cores = f"{CORES} core{'s' if CORES > 1 else ''}"
    assert f"on this process (the MuJoCo engines run a thread per core; --workers {CORES} on {cores} would" in out
    assert "computed 400" in out and _children() == before
    expected, got = (pq.read_table(tmp_path / name / "results.parquet") for name in ("serial", "here"))
    _assert_same_rows(expected, got, 400)


def test_a_worker_killed_mid_sweep_loses_only_its_task_which_is_retried(serial_rows, tmp_path):
    # a cluster started here and reached by its address (--scheduler); a worker process busy with
    # a task is killed (SIGKILL) when the first task is in; its nanny starts a new one
    before = _children()
    killed: list[int] = []
    with (
        LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            silence_logs=logging.ERROR,
        ) as cluster,
        Client(cluster) as client,
    ):
        pids = client.run(os.getpid)  # worker address -> process id

        def kill_a_busy_worker(done: int) -> None:
            if done != 1:
                return
            busy = [addr for addr, ws in list(cluster.scheduler.workers.items()) if ws.processing]
            victim = pids[busy[0] if busy else next(iter(pids))]
            os.kill(victim, signal.SIGKILL)
            killed.append(victim)

        summary = run_sweep(
            PLAN,
            tmp_path / "killed",
            scheduler=cluster.scheduler_address,
            cases_per_task=CASES_PER_TASK,
            progress=False,
            plots=False,
            on_task_done=kill_a_busy_worker,
        )
        # each worker process loaded the kernels once, not per task (numba's dispatcher counts
        # every load from the cache and every compile, per signature)
        loads = client.run(
            lambda: {
                name: sum(getattr(kernel, name).stats.cache_hits.values())
                + sum(getattr(kernel, name).stats.cache_misses.values())
                for name in ("_integrate_kernel_undriven", "_integrate_serial_undriven")
                for kernel in [__import__("pendsim_mj.engines.fast_planar.kernel", fromlist=["kernel"])]
            }
        )
        runs: dict[str, int] = {}
        for entry in cluster.scheduler.transition_log:
            if str(entry[0]).startswith("pendsim-sweep") and entry[2] == "processing":
                runs[str(entry[0])] = runs.get(str(entry[0]), 0) + 1
    assert len(killed) == 1 and _all_gone(set(killed))
    per_worker = [n["_integrate_kernel_undriven"] for n in loads.values()]  # 40 tasks over 2 (then 3) processes
    assert len(per_worker) == 2 and max(per_worker) == 1, loads
    assert len(runs) == 40 and max(runs.values()) >= 2  # the killed worker's task ran again elsewhere
    assert summary.tasks == 40 and len(list((tmp_path / "killed" / "parts").iterdir())) == 40  # each written once
    _assert_same_rows(serial_rows, pq.read_table(summary.results))
    assert _all_gone(_children() - before)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL, signal.SIGINT], ids=["SIGTERM", "SIGKILL", "Ctrl-C"])
def test_a_signal_to_pendsim_sweep_on_workers_leaves_no_process_running(tmp_path, sig):
    # SIGTERM: the sweep stops cleanly (exit 130) and closes its cluster; SIGKILL cannot be
    # caught, and the worker processes then notice that their parent is gone and exit. Ctrl-C at a
    # terminal reaches the whole process group: the workers leave it to pendsim, which says one
    # line (each worker printed a KeyboardInterrupt traceback, 34 lines in all, in a new user's trial)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "pendsim_bridge.cli", "sweep", "--engine", "mujoco", "--random", "400", "--vary",
           "c1_n_m=4:8", "--duration-s", "30", "--cases-per-task", "5", "--workers", str(FEWER), "--no-plots",
           "-o", str(out)]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 240  # the workers may compile MuJoCo models first
        while time.monotonic() < deadline and not list((out / "parts").glob("part-*.parquet")):
            time.sleep(0.05)
        assert list((out / "parts").glob("part-*.parquet")), "the sweep did not start"
        started = _tree(proc.pid)
        assert len(started) >= 1 + FEWER  # pendsim, its workers (and multiprocessing's tracker)
        if sig == signal.SIGINT:
            os.killpg(proc.pid, sig)  # as a terminal's Ctrl-C: to every process of the group
        else:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
        proc.wait()
    if sig == signal.SIGTERM:
        assert proc.returncode == 130 and "pendsim: interrupted" in err
    elif sig == signal.SIGINT:
        lines = err.strip().splitlines()
        assert proc.returncode == 130 and len(lines) == 1 and lines[0].startswith("pendsim: interrupted: "), err
        assert re.search(r"\d+ of 400 cases saved in .*; the same command resumes", lines[0]), err
    else:
        assert proc.returncode == -signal.SIGKILL
    assert _all_gone(started, timeout_s=30), [p for p in started if psutil.pid_exists(p)]
