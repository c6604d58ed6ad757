"""Jobs of ``python -m cosim run`` and their figures: the ISO 9283 experiment (``iso9283``,
the paper's section 2), planners, comparison, fieldbus faults, calibration and identification.
They run the robot cell of :mod:`cosim.cell` (built there, once) and evaluate it with
:mod:`cosim.tracking` (laser tracker, tracking metrics)."""
