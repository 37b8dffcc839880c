"""MJCF from an untrusted source (a recording's attachment), checked before MuJoCo sees it.

MuJoCo's compiler opens every file an MJCF names (``<include file=...>``, meshes, textures,
height fields, skins, plugins, asset folders) and allocates whatever sizes it asks for (a height
field of 100 000 x 100 000, ``<size memory="100G">``, ``<replicate count=...>``). A recording is
data, so its MJCF is accepted only if it

- is at most ``MAX_BYTES`` long, with at most ``MAX_ELEMENTS`` elements nested at most
  ``MAX_DEPTH`` deep, and holds no DOCTYPE (no XML entities);
- uses only elements from ``ALLOWED_ELEMENTS`` (bodies, joints, geoms, sites, tendons, sensors,
  materials without textures, keyframes, ...: nothing that names a file or sizes a buffer);
- has no attribute naming a file or a folder (``file``, ``fileup``, ``meshdir``, ...).

``compile_untrusted`` applies these checks and compiles with MuJoCo's warnings captured; every
refusal is a ``ModelError`` with one line saying why. Imports MuJoCo only to compile.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING
from xml.etree import ElementTree

from pendsim_mj.errors import ModelError

if TYPE_CHECKING:
    import mujoco

MAX_BYTES = 256 * 1024  # pendsim's own models are about 6 KB
MAX_ELEMENTS = 2000  # pendsim's own models have under 100
MAX_DEPTH = 32

REFUSED_ELEMENTS = {
    "include": "includes another file",
    "mesh": "loads a mesh",
    "texture": "loads or builds a texture",
    "hfield": "loads or allocates a height field",
    "skin": "loads a skin",
    "plugin": "loads a plugin",
    "extension": "loads a plugin",
    "instance": "configures a plugin",
    "model": "loads another model",
    "attach": "attaches another model",
    "replicate": "replicates elements",
    "composite": "generates elements",
    "flexcomp": "generates or loads a flex",
    "flex": "allocates a flex",
    "size": "sets memory sizes",
    "custom": "allocates custom data",
    "numeric": "allocates custom data",
    "text": "allocates custom data",
    "tuple": "allocates custom data",
    "visual": "sets rendering buffers",
}
"""Elements refused, with the reason given in the error."""

ALLOWED_ELEMENTS = frozenset(
    {
        "mujoco", "compiler", "option", "flag", "statistic", "default", "asset", "material",
        "worldbody", "body", "frame", "inertial", "joint", "freejoint", "geom", "site", "camera", "light",
        "tendon", "spatial", "fixed", "pulley",
        "equality", "connect", "weld",
        "contact", "pair", "exclude",
        "actuator", "motor", "position", "velocity", "general", "damper",
        "sensor", "accelerometer", "gyro", "velocimeter", "magnetometer", "touch", "force", "torque",
        "jointpos", "jointvel", "tendonpos", "tendonvel", "actuatorpos", "actuatorvel", "actuatorfrc",
        "framepos", "framequat", "framexaxis", "frameyaxis", "framezaxis", "framelinvel", "frameangvel",
        "framelinacc", "frameangacc", "subtreecom", "subtreelinvel", "subtreeangmom",
        "e_potential", "e_kinetic", "clock", "user",
        "keyframe", "key",
    }
)  # fmt: skip
"""Elements accepted: none of them names a file or sizes a buffer."""

_FILE_ATTRIBUTE = re.compile(r"file|dir$|^content_type$", re.IGNORECASE)


def check_untrusted(xml: str) -> None:
    """Refuse MJCF that names files, sizes buffers or is too large (see the module docstring).

    Raises:
      ModelError: one line naming the first problem found.
    """
    if not isinstance(xml, str):
        raise ModelError(f"the MJCF must be text, got {type(xml).__name__}")
    size = len(xml.encode("utf-8", "surrogatepass"))
    if size > MAX_BYTES:
        raise ModelError(f"the MJCF is {size} bytes, over the limit of {MAX_BYTES}")
    if re.search(r"<!(DOCTYPE|ENTITY)", xml, re.IGNORECASE):
        raise ModelError("the MJCF declares a DOCTYPE or entities")
    try:
        root = ElementTree.fromstring(xml)
    except ElementTree.ParseError as exc:
        raise ModelError(f"the MJCF is not well-formed XML: {exc}") from None
    if root.tag != "mujoco":
        raise ModelError(f"the MJCF's root element is <{root.tag}>, not <mujoco>")
    count = 0
    stack = [(root, 1)]
    while stack:
        element, depth = stack.pop()
        count += 1
        if count > MAX_ELEMENTS:
            raise ModelError(f"the MJCF has over {MAX_ELEMENTS} elements")
        if depth > MAX_DEPTH:
            raise ModelError(f"the MJCF nests elements over {MAX_DEPTH} deep")
        tag = element.tag if isinstance(element.tag, str) else "?"
        if tag in REFUSED_ELEMENTS:
            raise ModelError(f"the MJCF has <{tag}>, which {REFUSED_ELEMENTS[tag]}")
        if tag not in ALLOWED_ELEMENTS:
            raise ModelError(f"the MJCF has <{tag}>, which is not among the elements accepted from a file")
        for name, value in element.attrib.items():
            if _FILE_ATTRIBUTE.search(name):
                raise ModelError(f"the MJCF's <{tag}> names a file or folder ({name}={value[:60]!r})")
        stack.extend((child, depth + 1) for child in element)


def compile_untrusted(xml: str) -> mujoco.MjModel:
    """Check (``check_untrusted``) and compile MJCF from an untrusted source.

    Raises:
      ModelError: refused, or MuJoCo could not compile it (its message on one line).
    """
    import mujoco  # start-up: MuJoCo, once a file is checked

    from pendsim_mj.rig import mujoco_warnings

    check_untrusted(xml)
    with mujoco_warnings.captured() as warnings:
        try:
            model = mujoco.MjModel.from_xml_string(xml)
        except ValueError as exc:
            raise ModelError(f"MuJoCo cannot compile the MJCF: {' '.join(str(exc).split())}") from None
    if warnings.messages:
        raise ModelError(f"MuJoCo warned while compiling the MJCF: {warnings.summary()}")
    _check_describes_the_rig(model)
    return model


def _check_describes_the_rig(model: mujoco.MjModel) -> None:
    """The compiled model has every named element pendsim draws and reads (another, valid model
    is refused like a hostile one)."""
    import mujoco  # start-up: MuJoCo

    from pendsim_mj.rig.model import BODIES, HINGES, IMU_SITES, SPRING_ENDS, SPRINGS

    wanted = [
        *((mujoco.mjtObj.mjOBJ_BODY, "body", n) for n in BODIES),
        *((mujoco.mjtObj.mjOBJ_JOINT, "joint", n) for n in HINGES),
        *((mujoco.mjtObj.mjOBJ_SITE, "site", n) for n in (*IMU_SITES, *{p for pair in SPRING_ENDS for p in pair})),
        *((mujoco.mjtObj.mjOBJ_TENDON, "tendon", n) for n in SPRINGS),
    ]
    for kind, label, name in wanted:
        if mujoco.mj_name2id(model, kind, name) < 0:
            raise ModelError(f"the MJCF does not describe the rig (no {label} {name!r})")
