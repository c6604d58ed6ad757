"""The robot cell: what a cell IS, described in one place and used by every robot job.

A cell run is described once (:mod:`cosim.cell.description`: a frozen
:class:`CellDescription` built by :func:`describe_cell` from the validated scenario: the
true robot, the controller's :class:`controller.ControllerInfo`, fieldbus, tracker,
recording, the FMUs and their generated connections, :mod:`cosim.cell.wiring`), built on
the co-simulation master and run by :mod:`cosim.execution` (:func:`cosim.execution.run_cell`,
in the execution mode given; the data a run yields is :class:`cosim.cell.run.CellRun`). The
controller - built-in, a user's class, a controller FMU - is driven through the
controller contract (:mod:`controller.contract`) by the bus-cycle task
(:mod:`cosim.cell.link`). What several robot jobs share lives here too: the scenario
checks of a cell (:mod:`cosim.cell.checks`), the true robot, the controller's models and
a user's controller from the scenario (:mod:`cosim.cell.parts`). Nothing here imports
:mod:`cosim.execution`.
"""
from cosim.cell.description import CellDescription, describe_cell
from cosim.cell.run import CellRun

__all__ = ["CellDescription", "CellRun", "describe_cell"]
