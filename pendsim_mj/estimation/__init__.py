"""From measured data to numbers: alignment and timing of recordings, validation metrics, damping
identification and fits, signal analysis, planar-versus-spatial comparison.
"""
