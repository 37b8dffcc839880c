"""Rerun views of runs: the rig in 3D from the model's own geometry, measured against computed
time series, the phi1 error with cumulative IAE/ISE, and phase portraits.

All time-varying data go through ``rr.send_columns`` (one call per stream), on the timeline
"time" (seconds since the release). The 3D rig follows the computed trajectory: each pendulum
body turns about the pivot axis, its geoms (rods, disk, transverse rod), points and IMU axes
drawn from the compiled MjModel; the four springs are line strips whose colour runs from blue
(slack, the run's lowest tension) to red (its highest).
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from pendsim_mj import rotations
from pendsim_mj.model import BODIES, SPRING_ENDS, SPRINGS
from pendsim_mj.trajectory import Trajectory

TIMELINE = "time"
APPLICATION_ID = "pendsim"
PLOTTED = {
    "phi1": ("phi1 (rad)", lambda tr: tr.phi_rad[:, 0]),
    "phi2": ("phi2 (rad)", lambda tr: tr.phi_rad[:, 1]),
    "omega1": ("omega1 (rad/s)", lambda tr: tr.omega_rad_s[:, 0]),
    "omega2": ("omega2 (rad/s)", lambda tr: tr.omega_rad_s[:, 1]),
    "tangential_m1": ("tangential acceleration M1, accelerometer x (m/s^2)", lambda tr: tr.imu_accel_m_s2[:, 0, 0]),
    "normal_m1": ("normal acceleration M1, accelerometer y (m/s^2)", lambda tr: tr.imu_accel_m_s2[:, 0, 1]),
}


def blueprint() -> rrb.Blueprint:
    """3D rig on the left, stacked plots on the right, phase portraits below them."""
    plots = [rrb.TimeSeriesView(origin=f"/plots/{name}", name=label) for name, (label, _) in PLOTTED.items()]
    plots.append(rrb.TimeSeriesView(origin="/plots/error_phi1", name="phi1 error: Delta, IAE, ISE"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/rig", name="rig (computed)"),
            rrb.Vertical(
                rrb.Vertical(*plots),
                rrb.Horizontal(
                    rrb.Spatial2DView(origin="/phase/m1", name="phase portrait M1 (phi, omega)"),
                    rrb.Spatial2DView(origin="/phase/m2", name="phase portrait M2 (phi, omega)"),
                ),
                row_shares=[4, 1],
            ),
            column_shares=[2, 3],
        ),
        collapse_panels=True,
    )


def _quat_xyzw_about_pivot(phi: np.ndarray) -> np.ndarray:
    """Rotation by phi about the world -y axis (the hinges), x, y, z, w."""
    return np.stack([np.zeros_like(phi), -np.sin(phi / 2), np.zeros_like(phi), np.cos(phi / 2)], axis=-1)


def _geom_rgba(model: mujoco.MjModel, geoms: list[int]) -> np.ndarray:
    """Each geom's colour: its material's where it has one."""
    matid = model.geom_matid[geoms]
    return np.where((matid >= 0)[:, None], model.mat_rgba[np.maximum(matid, 0)], model.geom_rgba[geoms])


def log_rig_geometry(model: mujoco.MjModel, *, root: str = "/rig", x_offset_m: float = 0.0) -> None:
    """Static geometry: the frame in the world, each pendulum's geoms and points in its body
    (a rig drawn ``x_offset_m`` to the side, under ``root``)."""
    rr.log(f"{root}/frame", rr.Transform3D(translation=[x_offset_m, 0.0, 0.0]), static=True)
    for body_id in range(model.nbody):
        name = model.body(body_id).name or "frame"
        entity = f"{root}/{name}" if name in BODIES else f"{root}/frame"
        geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body_id]
        round_types = (int(mujoco.mjtGeom.mjGEOM_CYLINDER), int(mujoco.mjtGeom.mjGEOM_CAPSULE))
        cylinders = [g for g in geoms if int(model.geom_type[g]) in round_types]  # numpy int vs pybind enum
        if cylinders:
            quat = model.geom_quat[cylinders]
            rr.log(
                f"{entity}/geoms",
                rr.Cylinders3D(
                    lengths=2 * model.geom_size[cylinders, 1],
                    radii=model.geom_size[cylinders, 0],
                    centers=model.geom_pos[cylinders],
                    quaternions=[rr.Quaternion(xyzw=[q[1], q[2], q[3], q[0]]) for q in quat],
                    colors=(_geom_rgba(model, cylinders) * 255).astype(np.uint8),
                    labels=[model.geom(g).name for g in cylinders],
                ),
                static=True,
            )
        sites = [s for s in range(model.nsite) if model.site_bodyid[s] == body_id]
        points = [s for s in sites if model.site(s).name.startswith("point_")]
        if points:
            rr.log(
                f"{entity}/points",
                rr.Points3D(
                    model.site_pos[points],
                    radii=0.006,
                    colors=[230, 230, 50],
                    labels=[model.site(s).name.replace("point_", "") for s in points],
                    show_labels=True,
                ),
                static=True,
            )
        for s in (s for s in sites if model.site(s).name.startswith("imu_")):
            axes = np.zeros((3, 3))
            mujoco.mju_quat2Mat(axes.ravel(), model.site_quat[s])
            rr.log(
                f"{entity}/{model.site(s).name}",
                rr.Arrows3D(
                    origins=np.repeat(model.site_pos[s][None], 3, axis=0),
                    vectors=0.05 * axes.T,  # the site's x, y, z axes in the body frame
                    colors=[[220, 40, 40], [40, 200, 40], [40, 80, 230]],
                    labels=["x tangential", "y to pivot", "z pivot axis"],
                ),
                static=True,
            )


def log_trajectory(
    traj: Trajectory,
    model: mujoco.MjModel,
    *,
    time_offset_s: float = 0.0,
    root: str = "/rig",
    x_offset_m: float = 0.0,
    series: str = "model",
) -> None:
    """The computed run: body poses, springs coloured by tension, and every plotted quantity
    (under /plots/<quantity>/<series>)."""
    times = rr.TimeColumn(TIMELINE, duration=traj.t_s + time_offset_s)
    n = len(traj.t_s)
    poses = {}
    for k, body in enumerate(BODIES):
        quat = traj.body_quat_wxyz()[:, k]
        position = model.body(body).pos + np.array([x_offset_m, 0.0, 0.0])
        poses[k] = (rotations.to_matrix(quat), position)
        rr.send_columns(
            f"{root}/{body}",
            indexes=[times],
            columns=rr.Transform3D.columns(
                quaternion=rotations.wxyz_to_xyzw(quat), translation=np.broadcast_to(position, (n, 3))
            ),
        )
    # Spring end points in the world: each body's pose applied to the model's site positions.
    site = {name: model.site(name).pos.copy() for pair in SPRING_ENDS for name in pair}
    owner = {"point_1": 1, "point_5": 1, "point_2": 0, "point_3": 0}

    def world(name: str) -> np.ndarray:
        p = site[name]
        if name not in owner:
            return np.broadcast_to(p + np.array([x_offset_m, 0.0, 0.0]), (n, 3))
        matrix, position = poses[owner[name]]
        return position + matrix @ p

    ends = np.stack([np.stack([world(a), world(b)], axis=1) for a, b in SPRING_ENDS], axis=1)  # (n, 4, 2, 3)
    force = traj.spring_force_n
    low, high = float(force.min()), float(force.max())
    share = (force - low) / (high - low) if high > low else np.zeros_like(force)
    colours = np.stack([255 * share, 60 + 0 * share, 255 * (1 - share)], axis=-1).astype(np.uint8)
    rr.send_columns(
        f"{root}/springs",
        indexes=[times],
        columns=rr.LineStrips3D.columns(strips=ends.reshape(n * 4, 2, 3), colors=colours.reshape(n * 4, 3)).partition(
            [4] * n
        ),
    )
    rr.log(f"{root}/springs", rr.LineStrips3D.from_fields(labels=list(SPRINGS), radii=0.002), static=True)
    for name, (_, pick) in PLOTTED.items():
        rr.send_columns(f"/plots/{name}/{series}", indexes=[times], columns=rr.Scalars.columns(scalars=pick(traj)))
    for k in range(2):
        strip = np.stack([traj.phi_rad[:, k], -traj.omega_rad_s[:, k]], axis=-1)  # 2D views draw y down
        rr.log(f"/phase/m{k + 1}/{series}", rr.LineStrips2D([strip], colors=[255, 140, 0], radii=0.003), static=True)


def log_measured(t_s: np.ndarray, series: dict[str, np.ndarray]) -> None:
    """Measured series (seconds since the release) beside the model's."""
    times = rr.TimeColumn(TIMELINE, duration=t_s)
    for name, values in series.items():
        if name in PLOTTED:
            rr.send_columns(f"/plots/{name}/measured", indexes=[times], columns=rr.Scalars.columns(scalars=values))
    for k in (1, 2):
        if f"phi{k}" in series and f"omega{k}" in series:
            strip = np.stack([series[f"phi{k}"], -series[f"omega{k}"]], axis=-1)
            rr.log(f"/phase/m{k}/measured", rr.LineStrips2D([strip], colors=[30, 30, 30], radii=0.002), static=True)


def log_error(t_s: np.ndarray, delta: np.ndarray, iae: np.ndarray, ise: np.ndarray) -> None:
    """Delta phi1 = computed - measured and its cumulative IAE and ISE."""
    times = rr.TimeColumn(TIMELINE, duration=t_s)
    for name, values in (("delta", delta), ("iae", iae), ("ise", ise)):
        rr.send_columns(f"/plots/error_phi1/{name}", indexes=[times], columns=rr.Scalars.columns(scalars=values))


def start(application_id: str = APPLICATION_ID, *, spawn: bool = False) -> None:
    rr.init(application_id, spawn=spawn, default_blueprint=blueprint())


def save(path: str | Path) -> Path:
    """Write everything logged so far (and the blueprint) to an .rrd file."""
    rr.save(str(path), default_blueprint=blueprint())
    return Path(path)


def view_recording(path: str | Path, rrd_path: str | Path) -> Path:
    """A recording and the model's prediction (re-simulated from the recording's parameters and
    MJCF attachment, from the estimated release) to an .rrd file."""
    from bridge.recording import read_recording
    from bridge.validate import align, recorded_params
    from pendsim_mj.simulation import simulate
    from pendsim_mj.validation import compare, resample

    rec = read_recording(path)  # a truncated or damaged file fails here, before Rerun sees it
    params = recorded_params(rec)
    run = align(rec, params)
    duration = math.floor(float(run.t_s[-1]) / 0.01) * 0.01
    traj = simulate(params, run.release_angle_rad, (0.0, 0.0), duration)
    model = mujoco.MjModel.from_xml_string(rec.mjcf_xml) if rec.mjcf_xml else None
    if model is None:
        from pendsim_mj.model import build_model

        model = build_model(params)
    start()
    rr.save(str(rrd_path), default_blueprint=blueprint())
    log_rig_geometry(model)
    log_trajectory(traj, model)
    log_measured(run.t_s, run.series)
    inside = run.t_s <= traj.t_s[-1]
    computed = resample(traj.t_s, traj.phi_rad[:, 0], run.t_s[inside])
    error = compare(run.t_s[inside], run.series["phi1"][inside], computed)
    log_error(error.t_s, error.delta, error.iae_curve, error.ise_curve)
    rr.disconnect()
    return Path(rrd_path)


def view_comparison(comparison, params, variant, rrd_path: str | Path) -> Path:
    """Planar and spatial rigs side by side (0.8 m apart) and their angles on shared plots."""
    from pendsim_mj.model import build_model

    start()
    rr.save(str(rrd_path), default_blueprint=blueprint())
    planar_model = build_model(params.with_overrides(plane_offset_m=0.0))
    spatial_model = build_model(params, variant=variant)
    for root, model, traj, x, series in (
        ("/rig/planar", planar_model, comparison.planar, -0.4, "planar"),
        ("/rig/spatial", spatial_model, comparison.spatial, 0.4, "spatial"),
    ):
        log_rig_geometry(model, root=root, x_offset_m=x)
        log_trajectory(traj, model, root=root, x_offset_m=x, series=series)
    times = rr.TimeColumn(TIMELINE, duration=comparison.spatial.t_s)
    for k in range(2):
        rr.send_columns(
            f"/plots/tilt{k + 1}/spatial",
            indexes=[times],
            columns=rr.Scalars.columns(scalars=comparison.spatial.tilt_rad[:, k]),
        )
    rr.disconnect()
    return Path(rrd_path)


def view_trajectory(
    traj: Trajectory, model: mujoco.MjModel, rrd_path: str | Path | None, *, spawn: bool = False
) -> None:
    """A simulated run (no measurement): to an .rrd file and/or a spawned viewer."""
    start(spawn=spawn)
    if rrd_path is not None:
        rr.save(str(rrd_path), default_blueprint=blueprint())
    log_rig_geometry(model)
    log_trajectory(traj, model)
    rr.disconnect()
