"""The served execution mode (hardware in the loop): the robot cell as the drives' side of a
real-time bus, for a controller that is another program on it.

``python -m cosim serve SCENARIO`` runs the cell side of every robot-cell run of the
scenario's job - plant and drive FMUs, the POWERLINK controlled nodes, the laser tracker,
the recorder - paced by the wall clock at the bus cycle (:mod:`cosim.execution.cell_side`,
settings in :mod:`cosim.execution.serve_settings`). It never waits for the controller: the
controller is any program on the bus (``udpcycle`` interface, wire format in
``docs/reference/fieldbus.md``) that answers the cell's PRes frames with SoC + PReqs in time. See
``docs/how-to/served_cell.md``.
"""
from __future__ import annotations

from typing import Any

from cosim.execution.serve_settings import ServeSettings


def run(cell: Any, controller: Any, ctx: Any, options: Any, *, pacer: Any = None, on_cycle: Any = None) -> Any:
    """The :class:`cosim.execution.Mode` ``run`` of the served mode: the cell side only, paced, for
    a controller that is another program on the bus (``cosim serve``); the job's own controller
    does not run (it is closed at once). ``options.serve`` is the
    :class:`~cosim.execution.serve_settings.ServeSettings` (default: the defaults); ``pacer`` a
    :class:`cosim.execution.timing.pacer.Pacer` to use."""
    from cosim.execution.cell_side import run_served_cell

    controller_close = getattr(controller, "close", None)
    if callable(controller_close):
        controller_close()  # the job's own controller does not run: the controller is elsewhere
    settings = getattr(options, "serve", None) or ServeSettings()
    if settings.canopen:  # a CANopen master on a python-can bus drives the cell with its SYNC
        from cosim.execution.can_side import run_can_served_cell

        return run_can_served_cell(cell, ctx, settings)
    return run_served_cell(cell, ctx, settings, pacer=pacer, start_on_first_frame_s=settings.wait_for_controller_s)


__all__ = ["ServeSettings", "run"]
