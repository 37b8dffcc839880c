"""Measured data in: live acquisition from the rig's two sensor nodes over UDP (``pendsim acquire``),
their emulation (``pendsim nodes``) and lab files (``pendsim import``).

- ``packets``: the three packet formats (pendsim-v1 binary, CSV line, JSON object), each with an
  encoder (the emulator's) and a decoder that turns anything malformed into a ``PacketError``.
- ``clock``: the online fit that maps a node's device time to host time under network jitter.
- ``timeline``: each node's trusted timeline: packets that do not fit it are refused, not learnt.
- ``accounting``: per node sequence tracking, the reorder window and the counters.
- ``sink``: the one adapter between acquisition and the MCAP writer.
- ``receiver``: the sockets, the loop, signals, the status line and the summary.
- ``live``: the Rerun live view, in batches.
- ``lab_files``: lab files (CSV, LabVIEW .lvm, TDMS) read into a table of named columns.
- ``importers``: such a table into a recording, through the same sink.
- ``tdms_check``: a TDMS file's segments walked (either byte order) before npTDMS reads it.
- ``unit_check``: the units of imported values checked against their physics (the gyro against
  the orientation's rotation, gravity's magnitude).
- ``emulator``: the two nodes emulated from a simulated run (``pendsim nodes``); ``rig_faults``:
  the scripted faults it can play (``--fault``: springs, damping, friction, a mount, a clock).
- ``udp_loop``: the closed loop over UDP: the actuator's packets and rules, the emulated rig with
  motors (``pendsim nodes --motor``), the controller's side (``rig_loop.run_rig_loop``).
- ``twin``: the live twin beside the rig (``pendsim twin``): on live packets (``twin.live``) or a
  replayed recording (``twin.replay``), through one pipeline (``twin.pipeline``).

Docs: docs/acquisition.md (with the pendsim-v1 byte table); docs/control.md (the loop over UDP).
"""
