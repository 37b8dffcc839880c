"""Build the MuJoCo model of the rig from models/pendulums.xml and a RigParams.

Every parameter is written into the model through ``mujoco.MjSpec`` (never by editing XML
text), so any override reaches the compiled model.
"""

from __future__ import annotations

import enum
import functools
from pathlib import Path

import mujoco
import numpy as np

from pendsim_mj.errors import ModelError
from pendsim_mj.params import DEFAULT_PARAMS, RigParams


def _models_dir() -> Path:
    """models/ of a source checkout (editable install), else the copy a wheel installs as
    package data beside this module (pendsim_mj/models)."""
    here = Path(__file__).resolve().parent
    for candidate in (here.parent / "models", here / "models"):
        if (candidate / "pendulums.xml").is_file():
            return candidate
    return here.parent / "models"  # reported as missing by the first build_spec call


MODELS_DIR = _models_dir()
PENDULUMS_XML = MODELS_DIR / "pendulums.xml"
SCENE_XML = MODELS_DIR / "scene.xml"

HINGES = ("hinge_phi1", "hinge_phi2")
BODIES = ("m1", "m2")
IMU_SITES = ("imu_m1", "imu_m2")
SPRINGS = ("spring_12", "spring_13", "spring_56", "spring_57")
# (point on one end, point on the other end) for each spring, as in SPRINGS.
SPRING_ENDS = (("point_1", "point_2"), ("point_1", "point_3"), ("point_5", "point_6"), ("point_5", "point_7"))
# World direction of the hinge axis (paper +z): a positive phi is a rotation about it.
HINGE_AXIS_WORLD = np.array([0.0, -1.0, 0.0])


class Clamp(enum.Enum):
    """Which pendulum, if any, is held at rest (its hinge removed: welded to the frame)."""

    NONE = "none"
    M1 = "m1"
    M2 = "m2"


@functools.cache
def _xml_text() -> str:
    if not PENDULUMS_XML.is_file():
        raise ModelError(f"model file not found: {PENDULUMS_XML}")
    return PENDULUMS_XML.read_text()


def paper_to_world(x_m: float, y_m: float) -> list[float]:
    """Paper-frame point (x down, y horizontal in the swing plane) to MuJoCo world (z up)."""
    return [y_m, 0.0, -x_m]


def build_spec(params: RigParams = DEFAULT_PARAMS, *, clamp: Clamp = Clamp.NONE) -> mujoco.MjSpec:
    """The rig's MjSpec with every field of ``params`` applied.

    Args:
      params: rig parameters (SI units).
      clamp: hold one pendulum at phi = 0 by deleting its hinge.

    Returns:
      An uncompiled ``mujoco.MjSpec``; ``.compile()`` gives the MjModel.
    """
    try:
        spec = mujoco.MjSpec.from_string(_xml_text())
    except ValueError as exc:  # MuJoCo reports XML errors as ValueError
        raise ModelError(f"{PENDULUMS_XML}: {exc}") from exc
    spec.modelfiledir = str(MODELS_DIR)
    p = params
    spec.option.gravity = [0.0, 0.0, -p.g_m_s2]

    for n, body_name in ((1, "m1"), (2, "m2")):
        body = spec.body(body_name)
        body.mass = getattr(p, f"m{n}_kg")
        body.ipos = [0.0, 0.0, -getattr(p, f"oc{n}_m")]
        body.inertia = list(p.inertia_about_com_kg_m2(n))
        body.explicitinertial = True
        # MuJoCo 4: damping is a polynomial [linear, quadratic, cubic]; the paper's is linear.
        spec.joint(HINGES[n - 1]).damping = [getattr(p, f"b{n}_n_m_s"), 0.0, 0.0]
        spec.site(f"imu_m{n}").pos = [0.0, 0.0, -getattr(p, f"om{n}_m")]
        _set_visuals(spec, n, p)

    sites = {
        "point_1": paper_to_world(p.l01_m, 0.0),
        "point_2": paper_to_world(p.l04_m, p.l24_m),
        "point_3": paper_to_world(p.l04_m, -p.l34_m),
        "point_4": paper_to_world(p.l04_m, 0.0),
        "point_5": paper_to_world(p.l05_m, 0.0),
        "point_6": paper_to_world(p.l08_m, p.l68_m),
        "point_7": paper_to_world(p.l08_m, -p.l78_m),
        "point_8": paper_to_world(p.l08_m, 0.0),
    }
    for name, pos in sites.items():
        spec.site(name).pos = pos
    for name in SPRINGS:
        stiffness = p.c1_n_m if name in ("spring_12", "spring_13") else p.c2_n_m
        tendon = spec.tendon(name)
        tendon.stiffness = [stiffness, 0.0, 0.0]  # linear spring, polynomial terms zero
        tendon.springlength = [0.0, 0.0]  # zero free length (spec section 3)

    if clamp is not Clamp.NONE:
        index = 0 if clamp is Clamp.M1 else 1
        spec.delete(spec.joint(HINGES[index]))
        for key in spec.keys:
            key.qpos = [key.qpos[1 - index]]
            key.qvel = [key.qvel[1 - index]]
    return spec


def _set_visuals(spec: mujoco.MjSpec, n: int, p: RigParams) -> None:
    rod = spec.geom(f"m{n}_rod")
    rod.fromto = [0.0, 0.0, 0.0, 0.0, 0.0, -p.rod_length_m]
    rod.size = [p.rod_diameter_m / 2, 0.0, 0.0]
    disk = spec.geom(f"m{n}_disk")
    disk.pos = [0.0, 0.0, -getattr(p, f"om{n}_m")]
    disk.size = [p.disk_diameter_m / 2, p.disk_thickness_m / 2, 0.0]
    if n == 1:
        trod = spec.geom("m1_transverse_rod")
        half = p.transverse_rod_length_m / 2
        trod.fromto = [-half, 0.0, -p.l04_m, half, 0.0, -p.l04_m]
        trod.size = [p.transverse_rod_diameter_m / 2, 0.0, 0.0]


def build_model(
    params: RigParams = DEFAULT_PARAMS, *, timestep_s: float = 0.01, clamp: Clamp = Clamp.NONE
) -> mujoco.MjModel:
    """Compile the rig with ``params`` at the given step (s), RK4 as in the XML."""
    spec = build_spec(params, clamp=clamp)
    spec.option.timestep = timestep_s
    try:
        return spec.compile()
    except ValueError as exc:
        raise ModelError(f"cannot compile the rig model: {exc}") from exc
