"""Hardware-in-the-loop: the robot cell as the drives' side of a real-time bus.

``python -m cosim serve SCENARIO`` runs the cell side of every robot-cell run of the
scenario's job - plant and drive FMUs, the POWERLINK controlled nodes, the laser tracker,
the recorder - paced by the wall clock at the bus cycle. It never waits for the
controller: the controller is any program on the bus (``udpcycle`` interface, wire format
in ``fieldbus/README.md``) that answers the cell's PRes frames with SoC + PReqs in time.
See ``docs/hil.md``.
"""
from cosim.hil.settings import ServeSettings

__all__ = ["ServeSettings"]
