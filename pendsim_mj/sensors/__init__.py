"""The rig's BNO055 nodes: the sensor model (bno055), what real nodes add (imperfections),
quaternion helpers (rotations).
"""
