"""Geometric calibration and dynamic parameter identification."""
