"""The closed loop over UDP: a controller on this host, the rig's nodes and an actuator node with
motors on the network (the real rig, or the emulated one of ``pendsim nodes --motor``).

- ``packets``: the actuator's command and status packets (encoders, strict decoders).
- ``actuator``: what the actuator node does with commands in time: latency, jitter, torque
  limit, watchdog, zero torque on every fault, said in its status.
- ``motor_rig``: the emulated rig with motors, live: the rig stepped in real time with the
  actuator's torques, both nodes sending what they measure, the actuator on its port, a log.
- ``node_view``: what a controller sees of the nodes: each node's samples as they come, its
  clock fit and timeline, the state carried forward by the samples' ages.
- ``rig_loop``: the controller's side: ``run_rig_loop``.
- ``realtime``: real-time scheduling for both loops, where the OS permits it.

Docs: docs/control.md, "The loop over UDP" (with the packets' byte tables).
"""
