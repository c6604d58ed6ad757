"""The bus-cycle task of the robot cell: drives -> fieldbus -> controller -> fieldbus -> drives.

:class:`FieldbusLink` runs once per bus cycle at priority 0 on the master (one-process
and paced runs; the split run's controller side does the same steps in its own loop,
:mod:`cosim.split.cell`). The controller is driven through the controller contract
(:class:`controller.port.ControllerPort`), whatever it is.
"""
from __future__ import annotations

import numpy as np

from controller import CellController, ControllerInfo
from controller.port import ControllerFailure, ControllerPort
from cosim.cell.wiring import BUS_INTEGER, BUS_REAL, DRIVES, N_JOINTS
from cosim.master import Master, SimulationError
from fieldbus import AppliedSetpoints, DriveActuals, PowerlinkNetwork


class FieldbusLink:
    """The controller cycle task: drives -> fieldbus -> controller -> fieldbus -> drives.

    At cycle ``k`` (time ``t_k``): the drives' outputs at ``t_k`` are the actual values
    the controlled nodes latch; ``run_cycle(k, setpoints, actuals)`` carries the
    set-points the controller returned in cycle ``k - 1``; what the network applies
    from ``t_k`` (quantised target, torque offset, controlword, fault code of a tripped
    controlled node) is written to the ``bus.*`` master variables (the network writes
    into views of them, ``PowerlinkNetwork.bind_applied``); then the controller
    computes the set-points for cycle ``k + 1`` from what it observed in cycle ``k``.
    ``stop_grace_s`` after the controller stopped (drive fault, node fault) the task
    ends the run with a SimulationError naming the reason.
    """

    def __init__(self, network: PowerlinkNetwork, controller: CellController | ControllerPort, period_s: float,
                 stop_grace_s: float = 0.5, info: ControllerInfo | None = None) -> None:
        self.network = network
        self.info = info
        q_start = info.q_start if info is not None else getattr(controller, "q_start", None)
        self.port = controller if isinstance(controller, ControllerPort) else ControllerPort(
            controller, N_JOINTS, q_start=q_start)
        self.controller = self.port.controller
        self.period_s = period_s
        self.stop_grace_s = stop_grace_s
        self.cycle = 0
        self.actuals = DriveActuals.zeros(N_JOINTS)
        self.setpoints = self.port.setpoints
        self._real = self._integer = None
        self._real_out = self._integer_out = None
        self._copy_applied = True
        self._paced = hasattr(network, "last_late")

    def setup(self, master: Master) -> None:
        """Bind one reader per bus type for the drives' actual values and one writable
        view per bus type for the ``bus.*`` variables (end of master.initialize); then the
        controller's ``setup(info)`` (a failure there ends the run as a SimulationError)."""
        if self.info is not None:
            try:
                self.port.setup(self.info)
            except ControllerFailure as exc:
                raise SimulationError("controller", 0.0, exc.reason) from exc
        self._real = master.reader([f"{d}.{name}" for name in ("position_actual", "velocity_actual", "torque_actual")
                                    for d in DRIVES])
        self._integer = master.reader([f"{d}.{name}" for name in ("statusword", "error_code") for d in DRIVES])
        self._real_out = master.view([f"bus.{name}[{i}]" for name in BUS_REAL for i in range(1, N_JOINTS + 1)],
                                     writable=True)
        self._integer_out = master.view([f"bus.{name}[{i}]" for name in BUS_INTEGER
                                         for i in range(1, N_JOINTS + 1)], writable=True)
        # the actual values are views of the readers' reused buffers: read() refreshes them
        n = N_JOINTS
        real, integer = self._real.read(), self._integer.read()
        self.actuals = DriveActuals(statusword=integer[:n], position=real[:n], velocity=real[n:2 * n],
                                    torque=real[2 * n:], error_code=integer[n:])
        # a PowerlinkNetwork writes what the drives apply straight into the bus.* variables;
        # other networks (e.g. cosim.realtime's PacedNetwork wrapper) get it copied each cycle
        bind = getattr(self.network, "bind_applied", None)
        self._copy_applied = bind is None
        if bind is not None:
            bind(AppliedSetpoints(controlword=self._integer_out[:n], position=self._real_out[:n],
                                  torque_offset=self._real_out[n:], fresh=np.zeros(n, dtype=bool),
                                  comm_fault=np.zeros(n, dtype=bool), fault_code=self._integer_out[n:]))

    def __call__(self, t: float) -> None:
        self._real.read()
        self._integer.read()
        result = self.network.run_cycle(self.cycle, self.setpoints, self.actuals)
        if self._copy_applied:
            n, applied = N_JOINTS, result.applied
            self._real_out[:n] = applied.position
            self._real_out[n:] = applied.torque_offset
            self._integer_out[:n] = applied.controlword
            self._integer_out[n:] = applied.fault_code
        try:
            if self._paced:  # a wall-clock network (cosim.realtime.network.PacedNetwork) says whether it was late
                network = self.network
                self.setpoints = self.port.step(self.cycle, t, result.observed, network.last_late, network.last_lost)
            else:
                self.setpoints = self.port.step(self.cycle, t, result.observed)
        except ControllerFailure as exc:
            raise SimulationError("controller", exc.time_s, exc.reason) from exc
        self.cycle += 1
        stopped_at = self.port.stopped_at_s
        if stopped_at is not None and t - stopped_at >= self.stop_grace_s - 1e-12:
            raise SimulationError("controller", stopped_at, f"motion stopped: {self.port.stop_reason}")
