"""The engines that run the rig: MuJoCo (simulation), the planar reference (reference), the
compiled planar engine (fast_planar), and the Trajectory they all return.
"""
