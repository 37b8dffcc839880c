"""One module per ``pendsim`` command: ``register(subparsers)`` adds its parser (with
``handler=run``), ``run(args)`` parses nothing more, calls one library function and prints. A
command never imports another: the options they share are in ``pendsim_bridge.options`` and
``node_options`` (the sensor nodes' options), which is not a command."""

from . import (
    acquire,
    allan,
    analyze,
    calibrate,
    compare,
    control,
    demo,
    identify,
    import_,
    info,
    inspect,
    nodes,
    record,
    recover,
    replay,
    simulate,
    sweep,
    twin,
    validate,
    view,
)

COMMANDS = (
    demo, simulate, record, acquire, nodes, import_, inspect, validate, identify, calibrate, view, replay, compare,
    analyze, sweep, control, twin, allan, recover, info,
)  # fmt: skip
"""In the order ``pendsim --help`` lists them."""
