"""Split-process execution of the robot cell (``cosim run --split``, docs/explanation/timing.md).

The controller (and the POWERLINK managing node) runs in the process of ``cosim run``;
the drives and the plant (the FMUs on the co-simulation master, the POWERLINK
controlled nodes, the laser tracker, the recorder) run in a second process. The same
CiA 402 telegrams cross between them over python-can's ``udp_multicast`` interface on
loopback. The two sides run in lock-step in simulated time: the drive side waits for
the cycle marker, the SoC and the PReqs of cycle k before it applies set-points and
steps its FMUs to t_k+1; the controller side waits for the PRes frames of cycle k
before it computes the set-points for cycle k+1. Unpaced, a split run gives the same
trajectory as the one-process run (tests/cosim/split/test_equivalence.py).

Modules: :mod:`~cosim.execution.split.protocol` (cycle marker, per-side bus configuration),
:mod:`~cosim.execution.split.drive_side` (the drive process), :mod:`~cosim.execution.split.controller_side`
(:func:`run_split_cell`, the controller side).
"""
from __future__ import annotations

from typing import Any


def run(cell: Any, controller: Any, ctx: Any, options: Any, *, pacer: Any = None, on_cycle: Any = None) -> Any:
    """The :class:`cosim.execution.Mode` ``run`` of the split mode:
    :func:`cosim.execution.split.controller_side.run_split_cell` (paced too when
    ``options.realtime``: :mod:`cosim.execution.split.paced`)."""
    from cosim.execution.split.controller_side import run_split_cell

    return run_split_cell(cell, controller, ctx, options=options, pacer=pacer, on_cycle=on_cycle)
