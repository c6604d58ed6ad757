"""Trajectory planners: own time/energy-optimal CP and PtP, TOPP-RA and Ruckig baselines."""
