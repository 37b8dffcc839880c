"""The names the control room's choices go by, importing nothing (the command line lists them
without loading scipy or MuJoCo); ``controllers.CONTROLLERS`` and ``run.control`` hold the
classes and check that they agree."""

from __future__ import annotations

CONTROLLER_NAMES = ("none", "lqr", "scheduled-lqr", "energy", "beating")
"""``controllers.CONTROLLERS``' keys, in its order."""
MOTOR_NAMES = ("m1", "m2")
"""A motor at each hinge: ``controllers.MOTORS``' keys."""
OBSERVERS = ("state", "nodes")
"""What a controller reads: the exact state, or what the BNO055 nodes deliver (``observe``)."""
LOOP_ENGINES = ("mujoco", "fast")
"""The engines a closed loop runs on (``plant.PLANT_ENGINES``)."""
