"""pendsim_bridge (the folder ``bridge/``): everything between the physics (``pendsim_mj``) and
the outside world: the ``pendsim`` command line, ROS 2 CDR codec, MCAP files, recordings,
validation runs, Rerun views and replay.

Installed under the distinctive name ``pendsim_bridge`` so that it can neither shadow nor be
shadowed by another package called ``bridge``. Imports pendsim_mj; pendsim_mj never imports it.
"""
