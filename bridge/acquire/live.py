"""The live view of an acquisition in Rerun: both nodes' signals and the rig posed from the
measured orientations, sent in batches (``BATCH_HZ`` a second, one ``rr.send_columns`` per stream
and batch, never one log call per packet).

Sinks, any together: an .rrd file (``rrd``), the desktop viewer (``spawn``), or Rerun's web viewer
served on ``bind`` (127.0.0.1 by default) by the ``rerun`` executable in its own process group,
ended with the acquisition.
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from numpy.typing import NDArray

from pendsim_mj.sensors import rotations

from ..errors import ProcessError
from ..io.outputs import publish, temporary_sibling
from ..report import serve as serving
from ..report.rerun_view import log_rig_geometry
from .packets import GROUP_SLICES

APPLICATION_ID = "pendsim_acquire"
TIMELINE = "time"  # seconds since the acquisition started
BATCH_HZ = 20.0
SIGNALS = {"gyro": ("angular velocity (rad/s)", "gyro"), "accel": ("acceleration with gravity (m/s^2)", "accel")}


def pose_angle_rad(quat_wxyz: np.ndarray) -> np.ndarray:
    """A quick pendulum angle (n,) for posing the rig live: from where the sensor's y axis (toward
    the pivot) points in its fusion frame, taking that frame's x axis to lie in the swing plane, as
    pendsim's model does. A real node's NDOF heading is arbitrary, so this is a picture, not a
    measurement: ``pendsim validate`` finds each node's swing from its data (swing_frame)."""
    y_axis = rotations.to_matrix(quat_wxyz)[..., :, 1]
    return np.asarray(np.arctan2(-y_axis[..., 0], y_axis[..., 2]))


def blueprint(nodes: tuple[str, ...]) -> rrb.Blueprint:
    """The rig on the left, each node's angular velocity and acceleration on the right."""
    plots = [
        rrb.TimeSeriesView(origin=f"/live/{n}/{key}", name=f"{n}: {label}")
        for n in nodes
        for key, (label, _) in SIGNALS.items()
    ]
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Spatial3DView(origin="/rig", name="rig (measured)"), rrb.Vertical(*plots)),
        collapse_panels=True,
    )


class LiveView:
    """Feed with ``add``; ``send`` logs what was added once per batch period; ``close`` ends it.

    Args:
      nodes: node names.
      mjcf_xml: the rig's model, for the 3D geometry.
      rrd: save everything to this .rrd file.
      spawn: open the desktop viewer.
      serve: (bind address, web port) to serve the web viewer on (gRPC port = web port + 1).
    """

    def __init__(
        self,
        nodes: tuple[str, ...],
        mjcf_xml: str,
        *,
        rrd: Path | None = None,
        spawn: bool = False,
        serve: tuple[str, int] | None = None,
    ) -> None:
        self.nodes = nodes
        self.batches = 0
        self._closed = False
        self.url: str | None = None
        self._server: subprocess.Popen[bytes] | None = None
        self._pending: dict[str, list[tuple[NDArray[np.int64], NDArray[np.float64]]]] = {n: [] for n in nodes}
        self._t0_ns: int | None = None
        self._last_send = 0.0
        self._rrd = rrd
        self._rrd_partial = temporary_sibling(rrd) if rrd is not None else None
        rr.init(APPLICATION_ID)
        sinks: list[rr.FileSink | rr.GrpcSink] = []
        if self._rrd_partial is not None:
            sinks.append(rr.FileSink(str(self._rrd_partial)))
        if spawn:
            rr.spawn(connect=False)
            sinks.append(rr.GrpcSink())
        if serve is not None:
            bind, port = serve
            try:
                self._server = serving.start_live_server(bind, port)
            except ProcessError:
                if self._rrd_partial is not None:
                    self._rrd_partial.unlink(missing_ok=True)
                raise
            sinks.append(rr.GrpcSink(serving.live_grpc_url(bind, port)))
            self.url = serving.viewer_url(bind, port, port + 1)
        rr.set_sinks(*sinks, default_blueprint=blueprint(nodes))
        log_rig_geometry(mujoco.MjModel.from_xml_string(mjcf_xml))

    def add(self, node: str, t_ns: NDArray[np.int64], rows: NDArray[np.float64]) -> None:
        if self._t0_ns is None:
            self._t0_ns = int(t_ns[0])
        self._pending[node].append((t_ns, rows))

    def send(self, *, force: bool = False) -> None:
        """Log what arrived since the last batch (at most BATCH_HZ times a second)."""
        now = time.monotonic()
        if not force and now - self._last_send < 1.0 / BATCH_HZ:
            return
        if not any(self._pending.values()):
            return
        self._last_send = now
        assert self._t0_ns is not None
        for node in self.nodes:
            parts = self._pending[node]
            if not parts:
                continue
            t_ns = np.concatenate([t for t, _ in parts])
            rows = np.concatenate([r for _, r in parts])
            parts.clear()
            times = rr.TimeColumn(TIMELINE, duration=(t_ns - self._t0_ns) * 1e-9)
            for key, (_, group) in SIGNALS.items():
                values = rows[:, GROUP_SLICES[group]]
                if np.all(np.isfinite(values)):
                    rr.send_columns(f"/live/{node}/{key}", indexes=[times], columns=rr.Scalars.columns(scalars=values))
            quat = rows[:, GROUP_SLICES["quat"]]
            if np.all(np.isfinite(quat)):
                phi = pose_angle_rad(quat)
                body = "m1" if node == "m1" else "m2"
                rr.send_columns(
                    f"/rig/{body}",
                    indexes=[times],
                    columns=rr.Transform3D.columns(
                        quaternion=rotations.wxyz_to_xyzw(rotations.pendulum_quat_wxyz(phi))
                    ),
                )
        self.batches += 1

    def close(self, *, publish_rrd: bool = True) -> None:
        """Send the last batch, publish the .rrd file (unless the acquisition failed), end the web
        viewer. Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self.send(force=True)
            rr.disconnect()
            if publish_rrd and self._rrd is not None and self._rrd_partial is not None:
                publish(self._rrd_partial, self._rrd, replace=True)
        finally:
            if self._rrd_partial is not None:
                self._rrd_partial.unlink(missing_ok=True)
            if self._server is not None:
                serving.stop_group(self._server)
                self._server = None
