"""Measuring and judging how the robot cell tracks its path: the laser tracker that measures
the true robot's flange during a co-simulation (:mod:`cosim.tracking.laser_tracker`, its
compiled sample in ``tracker_kernel.c``) and the tracking metrics of a cell run - lag and TCP
errors, ISO 9283 path accuracy, residual vibration (:mod:`cosim.tracking.metrics`)."""
