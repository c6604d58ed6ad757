"""Timing shared by the paced, split and served executions: pacing, overrun policies,
lateness statistics (docs/explanation/timing.md).

Modules: :mod:`~cosim.execution.config` (the ``[execution]``/``[realtime]`` tables),
:mod:`~cosim.execution.timing.pacer` (:class:`Pacer`, :class:`VirtualClock`, SCHED_FIFO),
:mod:`~cosim.execution.timing.policy` (hold / skip / lost_frame), :mod:`~cosim.execution.timing.network`
(:class:`PacedNetwork`), :mod:`~cosim.execution.timing.stats` (percentiles, jitter histogram),
(the paced robot cell itself is a mode of :func:`cosim.execution.run_cell`),
:mod:`~cosim.execution.cell_execution` (:class:`CellExecution`: what ``cosim run`` hands the
jobs), :mod:`~cosim.execution.timing.deadtime` (dead time measured from a CAN log).

This package module imports nothing heavy.
"""
from cosim.execution.config import (EXECUTION_MODES, OVERRUN_POLICIES, ExecutionOptions, RealtimeSettings,
                                   execution_fields, execution_options)
from cosim.execution.timing.pacer import LatenessLog, Pacer, VirtualClock, realtime_scheduling

__all__ = ["execution_fields", "EXECUTION_MODES", "OVERRUN_POLICIES", "ExecutionOptions", "LatenessLog", "Pacer",
           "RealtimeSettings", "VirtualClock", "execution_options", "realtime_scheduling"]
