"""A simulated run written to a file: ``.npz`` (every array) or ``.csv`` (the scalar columns)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pendsim_mj.engines.trajectory import Trajectory

from .outputs import atomic_output

SUFFIXES = (".npz", ".csv")


def save_trajectory(traj: Trajectory, path: str | Path, *, replace: bool = False) -> Path:
    """Write a single run to ``.npz`` (all arrays) or ``.csv`` (``Trajectory.table``), atomically.

    The file appears only when complete (``outputs.atomic_output``); an existing file is an
    OutputError unless ``replace``. Returns the path written.
    """
    if traj.is_batch:
        raise ValueError("save one member at a time: save_trajectory(trajectory.member(i), path)")
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"output must end in .npz or .csv, got {path.name!r}")
    with atomic_output(path, replace=replace) as tmp:
        if suffix == ".npz":
            with open(tmp, "wb") as f:
                np.savez(f, t_s=traj.t_s, **{n: getattr(traj, n) for n in traj.ARRAY_FIELDS}, dt_s=traj.dt_s)
        else:
            header, columns = traj.table()
            np.savetxt(tmp, np.column_stack(columns), delimiter=",", header=",".join(header), comments="")
    return path
