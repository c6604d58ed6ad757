"""The robot cell: assembled in one place, run by one runner, used by every robot job.

A cell run is described once (:mod:`cosim.cell.description`: a frozen
:class:`CellDescription` built by :func:`describe_cell` from the validated scenario: the
true robot, the controller's :class:`controller.ControllerInfo`, fieldbus, tracker,
recording, the FMUs and their generated connections, :mod:`cosim.cell.wiring`), built on
the co-simulation master and run in the execution mode given
(:func:`cosim.cell.runner.run_cell`: ``in_process``, ``paced``, ``split``). The
controller - built-in, a user's class, a controller FMU - is driven through the
controller contract (:mod:`controller.contract`) by the bus-cycle task
(:mod:`cosim.cell.link`). What several robot jobs share lives here too: the scenario
checks of a cell (:mod:`cosim.cell.checks`), the true robot, the controller's models and
a user's controller from the scenario (:mod:`cosim.cell.parts`).
"""
from cosim.cell.description import CellDescription, describe_cell
from cosim.cell.runner import MODES, CellRun, controller_info, run_cell

__all__ = ["MODES", "CellDescription", "CellRun", "controller_info", "describe_cell", "run_cell"]
