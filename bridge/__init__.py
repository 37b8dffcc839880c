"""bridge: everything between the physics (pendsim_mj) and the outside world: the ``pendsim``
command line today; MCAP recording and reading, Rerun views, replay and live input as they land.
Imports pendsim_mj; pendsim_mj never imports bridge."""
