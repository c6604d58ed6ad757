"""Defaults of the dynamic identification that the CLI shows in its help, in a module
that imports nothing (``python -m cosim --help`` must not load numpy or scipy).
``signals`` and ``estimation`` use these; each is defined only here."""

DEFAULT_CUTOFF_HZ = 20.0
"""Default low-pass cut-off, Hz: about 30 times the highest harmonic of the default exciting
trajectory (5 x 0.8 rad/s = 0.64 Hz) and above the content of the ISO 9283 path at 1 m/s,
far below the 1250 Hz Nyquist frequency of 400 us samples."""

MAX_CONDITION_NUMBER = 1.0e4
"""Largest accepted condition number of the column-normalised base regressor. Measured on this
arm: optimised order-5 excitation 4.5, random feasible Fourier series of the same order 15-66,
sums of sines of the CLI tests about 240, a record where joint 6 does not move: inf. Above
1e4, torque noise of 0.1 % of rated torque moves the weakest base parameters by more than
their own size."""
