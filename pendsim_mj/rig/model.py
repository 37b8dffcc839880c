"""Build the MuJoCo model of the rig from models/pendulums.xml and a RigParams.

Every parameter is written into the model through ``mujoco.MjSpec`` (never by editing XML
text), so any override reaches the compiled model.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
from collections.abc import Collection
from pathlib import Path
from xml.etree import ElementTree

import mujoco
import numpy as np

from pendsim_mj.errors import ModelError
from pendsim_mj.rig import mujoco_warnings  # noqa: F401  (MuJoCo's warnings captured, no MUJOCO_LOG.TXT)
from pendsim_mj.rig.drives import Target
from pendsim_mj.rig.params import DEFAULT_PARAMS, RigParams


def _models_dir() -> Path:
    """models/ of a source checkout (editable install), else the copy a wheel installs as
    package data in the package (pendsim_mj/models)."""
    package = Path(__file__).resolve().parents[1]  # pendsim_mj/
    for candidate in (package.parent / "models", package / "models"):
        if (candidate / "pendulums.xml").is_file():
            return candidate
    return package.parent / "models"  # reported as missing by the first build_spec call


MODELS_DIR = _models_dir()
PENDULUMS_XML = MODELS_DIR / "pendulums.xml"
SCENE_XML = MODELS_DIR / "scene.xml"

HINGES = ("hinge_phi1", "hinge_phi2")
TILTS = ("tilt_m1", "tilt_m2")  # out-of-plane freedoms of the spatial variant
BODIES = ("m1", "m2")
IMU_SITES = ("imu_m1", "imu_m2")
SPRINGS = ("spring_12", "spring_13", "spring_56", "spring_57")
# (point on one end, point on the other end) for each spring, as in SPRINGS.
SPRING_ENDS = (("point_1", "point_2"), ("point_1", "point_3"), ("point_5", "point_6"), ("point_5", "point_7"))
# Which pendulum carries each spring anchor point (0: M1, 1: M2; absent: the frame).
SPRING_POINT_OWNER = {"point_1": 1, "point_5": 1, "point_2": 0, "point_3": 0}
# World direction of the hinge axis (paper +z): a positive phi is a rotation about it.
HINGE_AXIS_WORLD = np.array([0.0, -1.0, 0.0])

# Drives (pendsim_mj.rig.drives). A torque is a motor actuator on the hinge (gear 1: ctrl in N m).
# Support motion: every part of the frame (pivot axis, points 6-8, frame geoms) and both
# pendulums move into a body "support" on slide joints (world x: horizontal in the swing plane,
# world z: vertical), only those driven. The support's motion is prescribed by its acceleration:
# the slide carries an armature of SUPPORT_ARMATURE_KG and a motor of that gear, so ctrl = 1 gives
# the support 1 m/s^2; the pendulums' reactions (under 10 N) change it by under 1e-11 m/s^2, below
# the integration's round-off (tests/rig/test_drives.py checks the engines agree to 1e-9 rad). The
# support's own 1 kg is weightless (gravcomp) and only keeps the compiler's positive-mass rule.
SUPPORT_BODY = "support"
SUPPORT_ARMATURE_KG = 1e12
SUPPORT_JOINTS = {Target.SUPPORT_X: ("support_x", "1 0 0"), Target.PIVOT_Z: ("support_z", "0 0 1")}
DRIVE_ACTUATORS = {
    Target.TORQUE_M1: "drive_torque_m1",
    Target.TORQUE_M2: "drive_torque_m2",
    Target.SUPPORT_X: "drive_support_x",
    Target.PIVOT_Z: "drive_support_z",
}


class Clamp(enum.Enum):
    """Which pendulum, if any, is held at rest (its hinge removed: welded to the frame)."""

    NONE = "none"
    M1 = "m1"
    M2 = "m2"


@dataclasses.dataclass(frozen=True)
class Variant:
    """Structural options of the model (the numbers are in RigParams).

    tilt: give each pendulum a hinge about the horizontal axis across the pivot (world x), before
      its swing hinge, so that the support can rock and the pendulum leave its plane; its
      stiffness, damping and range are RigParams.tilt_*.
    fixed_points_plane: the plane points 6, 7 (and 8) lie in: "m1" (y = 0) or "m2" (y = the
      plane offset). Springs 5-6 and 5-7 are in M2's plane with "m2".
    """

    tilt: bool = False
    fixed_points_plane: str = "m2"

    def __post_init__(self) -> None:
        if self.fixed_points_plane not in ("m1", "m2"):
            raise ModelError(f"fixed_points_plane must be 'm1' or 'm2', got {self.fixed_points_plane!r}")


PLANAR = Variant()
SPATIAL = Variant(tilt=True)


@functools.cache
def _xml_text() -> str:
    if not PENDULUMS_XML.is_file():
        raise ModelError(f"model file not found: {PENDULUMS_XML}")
    return PENDULUMS_XML.read_text()


def _drive_targets(targets: Collection[Target]) -> tuple[Target, ...]:
    try:
        return tuple(t for t in Target if t in set(targets))
    except TypeError:
        raise ModelError(f"drive_targets must be drives.Target values, got {targets!r}") from None


@functools.cache
def _model_xml(targets: tuple[Target, ...]) -> str:
    """models/pendulums.xml with the structure the driven targets need (see DRIVE_ACTUATORS);
    the text itself when nothing is driven."""
    if not targets:
        return _xml_text()
    root = ElementTree.fromstring(_xml_text())
    slides = [SUPPORT_JOINTS[t] for t in targets if t.is_support]
    if slides:
        world = root.find("worldbody")
        assert world is not None, "models/pendulums.xml has a worldbody"
        support = ElementTree.Element("body", {"name": SUPPORT_BODY, "gravcomp": "1"})
        support.append(ElementTree.Comment(" the frame, on slides whose acceleration is prescribed (model.py) "))
        support.append(ElementTree.Element("inertial", {"pos": "0 0 0", "mass": "1", "diaginertia": "1 1 1"}))
        for name, axis in slides:
            support.append(
                ElementTree.Element(
                    "joint", {"name": name, "type": "slide", "axis": axis, "armature": repr(SUPPORT_ARMATURE_KG)}
                )
            )
        for child in list(world):
            world.remove(child)
            support.append(child)
        world.append(support)
        for key in root.iter("key"):  # the support's coordinates come first in qpos and qvel
            for field in ("qpos", "qvel"):
                key.set(field, " ".join(["0"] * len(slides) + key.get(field, "0 0").split()))
    actuator = ElementTree.Element("actuator")
    for t in targets:
        joint = {Target.TORQUE_M1: HINGES[0], Target.TORQUE_M2: HINGES[1]}.get(t) or SUPPORT_JOINTS[t][0]
        gear = "1" if not t.is_support else repr(SUPPORT_ARMATURE_KG)
        actuator.append(ElementTree.Element("motor", {"name": DRIVE_ACTUATORS[t], "joint": joint, "gear": gear}))
    sensor = root.find("sensor")
    root.insert(list(root).index(sensor) if sensor is not None else len(root), actuator)
    return ElementTree.tostring(root, encoding="unicode")


def paper_to_world(x_m: float, y_m: float) -> list[float]:
    """Paper-frame point (x down, y horizontal in the swing plane) to MuJoCo world (z up)."""
    return [y_m, 0.0, -x_m]


@dataclasses.dataclass(frozen=True)
class Assignment:
    """One parameter-derived value of the model: element ``tag`` named ``name``.

    ``spec_attr`` is the MjSpec attribute, ``xml_attr`` the MJCF attribute (on the element, or
    on its ``<inertial>`` child for tag "inertial"); ``xml_value`` defaults to ``spec_value``.
    """

    tag: str
    name: str | None
    spec_attr: str
    xml_attr: str
    spec_value: float | list[float]
    xml_value: float | list[float] | None = None


def assignments(params: RigParams, timestep_s: float = 0.01, variant: Variant = PLANAR) -> list[Assignment]:
    """Every value the parameters set in the model, in one table (applied to an MjSpec by
    ``build_spec`` and to MJCF text by ``exact_mjcf``)."""
    p = params
    out = [
        Assignment("option", None, "gravity", "gravity", [0.0, 0.0, -p.g_m_s2]),
        Assignment("option", None, "timestep", "timestep", timestep_s),
    ]
    for n, body in ((1, "m1"), (2, "m2")):
        rod_radius = p.rod_diameter_m / 2
        disk_size = [p.disk_diameter_m / 2, p.disk_thickness_m / 2]
        out += [
            Assignment("inertial", body, "mass", "mass", getattr(p, f"m{n}_kg")),
            Assignment("inertial", body, "ipos", "pos", [0.0, 0.0, -getattr(p, f"oc{n}_m")]),
            Assignment("inertial", body, "inertia", "diaginertia", list(p.inertia_about_com_kg_m2(n))),
            # MuJoCo 4: damping is a polynomial [linear, quadratic, cubic]; the paper's is linear.
            Assignment("joint", HINGES[n - 1], "damping", "damping", [getattr(p, f"b{n}_n_m_s"), 0.0, 0.0]),
            # dry friction: a soft-constraint moment of at most F opposing the swing
            Assignment("joint", HINGES[n - 1], "frictionloss", "frictionloss", getattr(p, f"friction{n}_n_m")),
            Assignment("site", f"imu_m{n}", "pos", "pos", [0.0, 0.0, -getattr(p, f"om{n}_m")]),
            Assignment("geom", f"m{n}_rod", "fromto", "fromto", [0.0, 0.0, 0.0, 0.0, 0.0, -p.rod_length_m]),
            Assignment("geom", f"m{n}_rod", "size", "size", [rod_radius, 0.0, 0.0], [rod_radius]),
            Assignment("geom", f"m{n}_disk", "pos", "pos", [0.0, 0.0, -getattr(p, f"om{n}_m")]),
            Assignment("geom", f"m{n}_disk", "size", "size", [*disk_size, 0.0], disk_size),
        ]
    half = p.transverse_rod_length_m / 2
    radius = p.transverse_rod_diameter_m / 2
    out += [
        Assignment("geom", "m1_transverse_rod", "fromto", "fromto", [-half, 0.0, -p.l04_m, half, 0.0, -p.l04_m]),
        Assignment("geom", "m1_transverse_rod", "size", "size", [radius, 0.0, 0.0], [radius]),
    ]
    # M2 and the points it carries sit plane_offset_m behind M1, along the pivot axis (world +y).
    out.append(Assignment("body", "m2", "pos", "pos", [0.0, p.plane_offset_m, 0.0]))
    frame_y = p.plane_offset_m if variant.fixed_points_plane == "m2" else 0.0
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
    for name in ("point_6", "point_7", "point_8"):
        sites[name][1] = frame_y
    out += [Assignment("site", name, "pos", "pos", pos) for name, pos in sites.items()]
    for name in SPRINGS:
        c = p.c1_n_m if name in ("spring_12", "spring_13") else p.c2_n_m
        # linear spring (polynomial terms zero) of zero free length (spec section 3)
        out.append(Assignment("tendon", name, "stiffness", "stiffness", [c, 0.0, 0.0]))
        out.append(Assignment("tendon", name, "springlength", "springlength", [0.0, 0.0]))
    return out


@functools.cache
def _parsed_spec(targets: tuple[Target, ...]) -> mujoco.MjSpec:
    """``_model_xml(targets)`` parsed, once per process (``build_spec`` edits a copy of it)."""
    try:
        return mujoco.MjSpec.from_string(_model_xml(targets))
    except ValueError as exc:  # MuJoCo reports XML errors as ValueError
        raise ModelError(f"{PENDULUMS_XML}: {exc}") from exc


def build_spec(
    params: RigParams = DEFAULT_PARAMS,
    *,
    clamp: Clamp = Clamp.NONE,
    timestep_s: float = 0.01,
    variant: Variant = PLANAR,
    drive_targets: Collection[Target] = (),
) -> mujoco.MjSpec:
    """The rig's MjSpec with every field of ``params`` applied.

    Args:
      params: rig parameters (SI units).
      clamp: hold one pendulum at phi = 0 by deleting its hinge.
      timestep_s: integration step, s.
      variant: structural options (tilt freedoms, plane of the fixed points).
      drive_targets: the inputs to drive (``drives.Target``): motors at the hinges, the support
        on slides (see DRIVE_ACTUATORS); ctrl then holds the inputs in ``Target`` order.

    Returns:
      An uncompiled ``mujoco.MjSpec``; ``.compile()`` gives the MjModel.
    """
    targets = _drive_targets(drive_targets)
    if clamp is not Clamp.NONE and any(t.value == f"torque_{clamp.value}" for t in targets):
        raise ModelError(f"pendulum {clamp.value} is clamped: it cannot carry a torque drive")
    spec = _parsed_spec(targets).copy()  # parsing is a third of a build: once per structure
    spec.modelfiledir = str(MODELS_DIR)
    for a in assignments(params, timestep_s, variant):
        if a.tag == "option":
            target = spec.option
        elif a.tag == "inertial":
            target = spec.body(a.name)
            target.explicitinertial = True
        else:
            target = getattr(spec, a.tag)(a.name)
        setattr(target, a.spec_attr, a.spec_value)

    if variant.tilt:
        if clamp is not Clamp.NONE:
            raise ModelError("clamping applies to the planar model only")
        _add_tilt(spec, params)
    if clamp is not Clamp.NONE:
        index = 0 if clamp is Clamp.M1 else 1
        spec.delete(spec.joint(HINGES[index]))
        for key in spec.keys:  # the hinges' coordinates are the last two (after the support's)
            *qpos, a, b = list(key.qpos)
            key.qpos = [*qpos, (b, a)[index]]
            *qvel, a, b = list(key.qvel)
            key.qvel = [*qvel, (b, a)[index]]
    return spec


def _add_tilt(spec: mujoco.MjSpec, p: RigParams) -> None:
    """A tilt hinge about world x before each swing hinge (re-added after it, so that it turns
    about the rocked axis); keyframes get a zero tilt for each pendulum."""
    for body_name, hinge, tilt in zip(BODIES, HINGES, TILTS, strict=True):
        body = spec.body(body_name)
        swing = spec.joint(hinge)
        damping = list(swing.damping)
        frictionloss = swing.frictionloss
        spec.delete(swing)
        body.add_joint(
            name=tilt,
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=[1.0, 0.0, 0.0],
            pos=[0.0, 0.0, 0.0],
            stiffness=[p.tilt_stiffness_n_m_rad, 0.0, 0.0],
            damping=[p.tilt_damping_n_m_s_rad, 0.0, 0.0],
        )
        body.add_joint(
            name=hinge,
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=[0.0, -1.0, 0.0],
            pos=[0.0, 0.0, 0.0],
            damping=damping,
            frictionloss=frictionloss,
        )
    for key in spec.keys:  # after the support's coordinates, if any
        *qpos, a, b = list(key.qpos)
        key.qpos = [*qpos, 0.0, a, 0.0, b]
        *qvel, a, b = list(key.qvel)
        key.qvel = [*qvel, 0.0, a, 0.0, b]


def exact_mjcf(
    params: RigParams = DEFAULT_PARAMS,
    *,
    timestep_s: float = 0.01,
    variant: Variant = PLANAR,
    drive_targets: Collection[Target] = (),
) -> str:
    """models/pendulums.xml with every parameter written at full precision (17 digits).

    ``MjSpec.to_xml()`` rounds numbers to 6 significant digits, so it cannot reproduce a run;
    this text compiles to the same model as ``build_model`` (tests/rig/test_model.py checks it).
    """
    root = ElementTree.fromstring(_model_xml(_drive_targets(drive_targets)))
    for a in assignments(params, timestep_s, variant):
        if a.tag == "option":
            element = root.find("option")
        elif a.tag == "inertial":
            element = root.find(f".//body[@name='{a.name}']/inertial")
        elif a.tag == "body":
            element = root.find(f".//body[@name='{a.name}']")
        else:
            element = root.find(f".//{'spatial' if a.tag == 'tendon' else a.tag}[@name='{a.name}']")
        if element is None:
            raise ModelError(f"{PENDULUMS_XML}: no {a.tag} {a.name!r} to write {a.xml_attr} into")
        value = a.spec_value if a.xml_value is None else a.xml_value
        values = value if isinstance(value, list) else [value]
        element.set(a.xml_attr, " ".join(repr(float(v)) for v in values))
    if variant.tilt:
        p = params
        for body_name, hinge, tilt in zip(BODIES, HINGES, TILTS, strict=True):
            body = root.find(f".//body[@name='{body_name}']")
            swing = body.find(f"joint[@name='{hinge}']") if body is not None else None
            if body is None or swing is None:
                raise ModelError(f"{PENDULUMS_XML}: no body {body_name!r} with joint {hinge!r}")
            joint = ElementTree.Element(
                "joint",
                {
                    "name": tilt,
                    "type": "hinge",
                    "pos": "0 0 0",
                    "axis": "1 0 0",
                    "stiffness": repr(p.tilt_stiffness_n_m_rad),
                    "damping": repr(p.tilt_damping_n_m_s_rad),
                },
            )
            body.insert(list(body).index(swing), joint)  # before the swing hinge, as build_spec
        for key in root.iter("key"):
            for field in ("qpos", "qvel"):
                *support, first, second = key.get(field, "0 0").split()
                key.set(field, " ".join([*support, "0", first, "0", second]))
    root.insert(0, ElementTree.Comment(" pendsim: models/pendulums.xml with this run's parameters, full precision "))
    return ElementTree.tostring(root, encoding="unicode")


def build_model(
    params: RigParams = DEFAULT_PARAMS,
    *,
    timestep_s: float = 0.01,
    clamp: Clamp = Clamp.NONE,
    variant: Variant = PLANAR,
    drive_targets: Collection[Target] = (),
) -> mujoco.MjModel:
    """Compile the rig with ``params`` at the given step (s), RK4 as in the XML, with the
    actuators and support slides of ``drive_targets`` (see build_spec)."""
    spec = build_spec(params, clamp=clamp, timestep_s=timestep_s, variant=variant, drive_targets=drive_targets)
    try:
        return spec.compile()
    except ValueError as exc:
        raise ModelError(f"cannot compile the rig model: {exc}") from exc
