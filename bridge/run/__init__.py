"""The runs the commands orchestrate: record, validate (planar and spatial), replay, sweep, demo."""
