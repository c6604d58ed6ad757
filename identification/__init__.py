"""Dynamic parameter identification (paper section 4): base parameters, optimal exciting
trajectories, estimation from measured torques, physical consistency, plausibility, and the
gear stiffness. Geometric calibration is the sibling package :mod:`calibration`."""
