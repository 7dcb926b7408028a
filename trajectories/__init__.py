"""Calibration waypoint generators and named presets."""
