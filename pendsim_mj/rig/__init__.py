"""The rig itself: its physical parameters, the MuJoCo model built from the MJCF, the drives, argument checks."""
