"""Files: MCAP reading and writing (mcap), the ROS 2 codec, recordings, lab-file importers, atomic
publication of outputs.
"""
