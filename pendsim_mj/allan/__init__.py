"""Allan deviation of static IMU records (IEEE 952): the deviations and noise terms (deviation),
their compiled sums (kernel).
"""
