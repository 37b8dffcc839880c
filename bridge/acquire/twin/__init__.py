"""``pendsim twin``: the twin beside the rig, on live packets (``live``) or a replayed recording
(``replay``), through one pipeline (``pipeline``) that feeds the twin (``pendsim_mj.twin``), its
recording and its live views."""
