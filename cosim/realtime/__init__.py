"""Wall-clock paced runs: pacing, overrun policies, lateness statistics (docs/timing.md).

Modules: :mod:`~cosim.realtime.config` (the ``[execution]``/``[realtime]`` tables),
:mod:`~cosim.realtime.pacer` (:class:`Pacer`, :class:`VirtualClock`, SCHED_FIFO),
:mod:`~cosim.realtime.policy` (hold / skip / lost_frame), :mod:`~cosim.realtime.network`
(:class:`PacedNetwork`), :mod:`~cosim.realtime.stats` (percentiles, jitter histogram),
(the paced robot cell itself is a mode of :func:`cosim.cell.runner.run_cell`),
:mod:`~cosim.realtime.execution` (:class:`CellExecution`: what ``cosim run`` hands the
jobs), :mod:`~cosim.realtime.deadtime` (dead time measured from a CAN log).

This package module imports nothing heavy: ``cosim.scenario`` imports its config.
"""
from cosim.realtime.config import (EXECUTION_MODES, OVERRUN_POLICIES, ExecutionOptions, RealtimeSettings,
                                   execution_fields, execution_options)
from cosim.realtime.pacer import LatenessLog, Pacer, VirtualClock, realtime_scheduling

__all__ = ["execution_fields", "EXECUTION_MODES", "OVERRUN_POLICIES", "ExecutionOptions", "LatenessLog", "Pacer",
           "RealtimeSettings", "VirtualClock", "execution_options", "realtime_scheduling"]
