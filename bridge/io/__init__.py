"""Files: MCAP reading and writing (mcap), the ROS 2 codec, recordings (their layout, reader and
writer, and the measured arrays a recording gives: ``measured``), atomic publication of outputs.
"""
