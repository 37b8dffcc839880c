"""Sweeps: what a sweep runs (plan), one task of cases through an engine (run), the features of a
batch of runs (features). No I/O.
"""
