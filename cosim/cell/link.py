"""The bus-cycle task of the robot cell: drives -> fieldbus -> controller -> fieldbus -> drives.

:class:`FieldbusLink` runs once per bus cycle at priority 0 on the master (one-process
and paced runs; the split run's controller side does the same steps in its own loop,
:mod:`cosim.execution.split.controller_side`). The controller is driven through the controller contract
(:class:`controller.port.ControllerPort`), whatever it is.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from controller import CellController, ControllerInfo
from controller.port import ControllerFailure, ControllerPort
from cosim.cell.wiring import APPLIED_FIELD, BUS_INTEGER, BUS_REAL, DRIVES, N_JOINTS
from cosim.master import Master, SimulationError
from fieldbus import AppliedSetpoints, DriveActuals, PowerlinkNetwork


class CellBus:
    """The drives' side of the bus on a cell's master: what the drives report (a
    ``fieldbus.DriveActuals`` whose arrays are views of the master's reused read buffers:
    :meth:`read` refreshes them) and what they apply (a ``fieldbus.AppliedSetpoints`` whose
    arrays are writable views of the ``bus.*`` master variables, connected to the drives'
    inputs). Used by the bus-cycle task here and by the split run's drive process.

    Drive FMUs of the minimal interface (``fmus.servo_drive.interface``): a value not every drive
    has reads as its default (0 rad/s, 0 N·m, error code 0, mode 8 = CSP); bus variables
    without a drive input are written and not connected.
    """

    def __init__(self, master: Master) -> None:
        n = N_JOINTS
        real_names, int_names = ("position_actual", "velocity_actual", "torque_actual"), ("statusword", "error_code")
        display = "modes_of_operation_display"
        try:  # every drive has every value (the servo_drive FMU): two readers, one call each per cycle
            self._readers = [master.reader([f"{d}.{name}" for name in real_names for d in DRIVES]),
                             master.reader([f"{d}.{name}" for name in (*int_names, display) for d in DRIVES])]
            real, ints = (r.read() for r in self._readers)
            fields = {"position": real[:n], "velocity": real[n:2 * n], "torque": real[2 * n:],
                      "statusword": ints[:n], "error_code": ints[n:2 * n], "modes_of_operation_display": ints[2 * n:]}
        except Exception:  # noqa: BLE001 - a drive of the minimal interface: one reader per value it has
            self._readers, fields = [], {}
            for field_name, var, default, dtype in (
                    ("position", "position_actual", 0.0, float), ("velocity", "velocity_actual", 0.0, float),
                    ("torque", "torque_actual", 0.0, float), ("statusword", "statusword", 0, np.int64),
                    ("error_code", "error_code", 0, np.int64), ("modes_of_operation_display", display, 8, np.int64)):
                try:
                    reader = master.reader([f"{d}.{var}" for d in DRIVES])
                except Exception:  # noqa: BLE001 - absent (optional): the controller sees the default
                    fields[field_name] = np.full(n, default, dtype=dtype)
                else:
                    self._readers.append(reader)
                    fields[field_name] = reader.read()
        real_out = master.view([f"bus.{name}[{i}]" for name in BUS_REAL for i in range(1, n + 1)], writable=True)
        integer_out = master.view([f"bus.{name}[{i}]" for name in BUS_INTEGER for i in range(1, n + 1)],
                                  writable=True)
        self.actuals = DriveActuals(**fields)
        views = {name: real_out[k * n:(k + 1) * n] for k, name in enumerate(BUS_REAL)}
        views.update({name: integer_out[k * n:(k + 1) * n] for k, name in enumerate(BUS_INTEGER)})
        self.applied = AppliedSetpoints(fresh=np.zeros(n, dtype=bool), comm_fault=np.zeros(n, dtype=bool),
                                        **{APPLIED_FIELD.get(name, name): view for name, view in views.items()})
        self._pairs = [(view, APPLIED_FIELD.get(name, name)) for name, view in views.items()]
        # the drives latch their actual values at the SoC: their inputs at t_k (the plant's
        # position) are set before their outputs are read (direct feedthrough of position_actual)
        self._refresh = [master.refresher(DRIVES)] + [reader.refresh for reader in self._readers]

    def read(self) -> None:
        """Refresh :attr:`actuals` from the drives' outputs at the current tick ``t_k``: each drive's
        inputs at ``t_k`` are set first, so a drive that latches its position at the sync (the
        servo_drive FMU) reports the position at ``t_k``, not at its previous sample."""
        for refresh in self._refresh:
            refresh()

    def write(self, applied: AppliedSetpoints) -> None:
        """Copy what ``applied`` holds into the ``bus.*`` variables."""
        for view, name in self._pairs:
            view[:] = getattr(applied, name)


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
        self.bus: CellBus | None = None
        self._copy_applied = True
        self._paced = hasattr(network, "last_late")
        self.enabled_at_s: float | None = None
        """Simulated time the drives first all reported Operation enabled (None: not yet)."""

    def setup(self, master: Master) -> None:
        """Bind one reader per bus type for the drives' actual values and one writable
        view per bus type for the ``bus.*`` variables (end of master.initialize); then the
        controller's ``setup(info)`` (a failure there ends the run as a SimulationError)."""
        if self.info is not None:
            network = getattr(self.network, "network", self.network)  # a PacedNetwork wraps the bus
            make_port = getattr(network, "async_port", None)
            port = make_port() if make_port is not None else None
            if port is not None and getattr(self.info, "asynchronous", None) is None:
                self.info = dataclasses.replace(self.info, asynchronous=port)
            try:
                self.port.setup(self.info)
            except ControllerFailure as exc:
                raise SimulationError("controller", 0.0, exc.reason) from exc
        self.bus = CellBus(master)
        self.actuals = self.bus.actuals
        # a PowerlinkNetwork writes what the drives apply straight into the bus.* variables;
        # other networks (e.g. cosim.execution.timing's PacedNetwork wrapper) get it copied each cycle
        bind = getattr(self.network, "bind_applied", None)
        self._copy_applied = bind is None
        if bind is not None:
            bind(self.bus.applied)

    def __call__(self, t: float) -> None:
        bus = self.bus
        bus.read()
        result = self.network.run_cycle(self.cycle, self.setpoints, self.actuals)
        if self._copy_applied:
            bus.write(result.applied)
        try:
            if self._paced:  # a wall-clock network (cosim.execution.timing.network.PacedNetwork) says whether it was late
                network = self.network
                self.setpoints = self.port.step(self.cycle, t, result.observed, network.last_late, network.last_lost)
            else:
                self.setpoints = self.port.step(self.cycle, t, result.observed)
        except ControllerFailure as exc:
            raise SimulationError("controller", exc.time_s, exc.reason) from exc
        self.cycle += 1
        if self.enabled_at_s is None:  # until the drives are enabled once: then no cost per cycle
            self._watch_enable(t)
        stopped_at = getattr(self.controller, "stopped_at_s", None)  # ControllerPort.stopped_at_s, without its call
        if stopped_at is not None and t - stopped_at >= self.stop_grace_s - 1e-12:
            raise SimulationError("controller", stopped_at, f"motion stopped: {self.port.stop_reason}")

    def _watch_enable(self, t: float) -> None:
        """Note when every drive first reports Operation enabled (CiA 402 statusword & 0x6F == 0x27)."""
        if all((int(s) & 0x6F) == 0x27 for s in self.actuals.statusword.tolist()):
            self.enabled_at_s = t
