"""Geometric calibration (paper section 3): the optical tracker's noise and visibility
(:mod:`calibration.optical_tracker`), candidate configurations, observation indices and the
optimal selection of measurement configurations, identifiability, the iterated least-squares
solver, plausibility checks, the calibrated URDF and the simulated campaign
(:mod:`calibration.campaign`)."""
