"""Plain per-cycle process data at the edge of the fieldbus, in SI units.

One entry per controlled node (node 1 = joint 1 first), numpy arrays of shape (N,).
Joint side: rad, rad/s, N·m. Controlwords and statuswords are CiA 402 integers.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Self

import numpy as np

from fieldbus.cia402 import motion_enabled

# element type of each per-node array by field name; any other field is float64 (SI units)
_DTYPES = {"controlword": np.int64, "statusword": np.int64, "error_code": np.int64, "fault_code": np.int64,
           "fresh": np.bool_, "comm_fault": np.bool_, "node_fault": np.bool_,
           "modes_of_operation": np.int64, "modes_of_operation_display": np.int64}
# initial value of a field where it is not zero: cyclic synchronous position (CiA 402 0x6060 = 8)
_INITIAL = {"modes_of_operation": 8, "modes_of_operation_display": 8}


def _initial(name: str, nodes: int) -> np.ndarray:
    return np.full(nodes, _INITIAL.get(name, 0), dtype=_DTYPES.get(name, np.float64))


class _PerNode:
    """Base of the records below: every field an array of shape (N,), one entry per node.

    The fields for the modes of operation come last with default None: left out (as by
    code written before they existed), they get arrays of their own, mode 8 and zeros."""

    __slots__ = ()

    @classmethod
    def zeros(cls, nodes: int) -> Self:
        """Zeros (False for flags, 8 = cyclic synchronous position for modes) for ``nodes`` nodes."""
        return cls(*(_initial(f.name, nodes) for f in fields(cls)))

    def __post_init__(self) -> None:
        missing = [f.name for f in fields(self) if getattr(self, f.name) is None]
        if missing:
            nodes = len(getattr(self, fields(self)[0].name))
            for name in missing:
                setattr(self, name, _initial(name, nodes))

    def copy(self) -> Self:
        """A copy with arrays of its own."""
        return type(self)(*(getattr(self, f.name).copy() for f in fields(self)))


@dataclass(slots=True)
class Setpoints(_PerNode):
    """What the controller commands for the next cycle (goes into the PReqs).

    controlword: CiA 402 controlword per node (0x6040).
    position: target joint angle in rad (0x607A after scaling).
    torque_offset: feed-forward joint torque in N·m (0x60B2 after scaling).
    modes_of_operation: 0x6060 per node, 8 (cyclic synchronous position, default), 9
        (velocity) or 10 (torque); any other value is refused with a ValueError.
    target_velocity: joint speed in rad/s (0x60FF, used in mode 9).
    velocity_offset: joint speed feed-forward in rad/s (0x60B1, modes 8 and 9).
    target_torque: joint torque in N·m (0x6071, used in mode 10).
    """

    controlword: np.ndarray
    position: np.ndarray
    torque_offset: np.ndarray
    modes_of_operation: Any = None
    target_velocity: Any = None
    velocity_offset: Any = None
    target_torque: Any = None


@dataclass(slots=True)
class DriveActuals(_PerNode):
    """What the drives report, sampled at the SoC (goes into the PRes).

    statusword: CiA 402 statusword per node (0x6041).
    position: joint angle in rad (0x6064), velocity in rad/s (0x606C),
    torque: joint torque in N·m (0x6077), error_code: 0x603F.
    modes_of_operation_display: 0x6061, the mode the drive runs in (default 8).
    """

    statusword: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    torque: np.ndarray
    error_code: np.ndarray
    modes_of_operation_display: Any = None


@dataclass(slots=True)
class AppliedSetpoints(_PerNode):
    """What each drive applies from the SoC of this cycle until the next SoC (quantised).

    controlword/position/torque_offset: as received (or held / extrapolated when
        the set-point due now did not arrive), rad and N·m after quantisation.
    fresh: True where the set-point due at this SoC arrived.
    comm_fault: True where the controlled node's threshold counter tripped (latched
        until a fault reset is applied with the node's counters below threshold).
    fault_code: what the runner writes to the drive FMU's ``fault_code`` input: 0, or
        0x8100 (CiA 301 "communication") where comm_fault is set and the abort option
        is 'fault' (default) - the drive then runs its CiA 402 fault reaction. With
        option 'quick_stop' fault_code stays 0 and the controlword is forced to quick
        stop (0x0002) instead.
    modes_of_operation, target_velocity, velocity_offset, target_torque: as received
        (held when the set-point due now did not arrive), rad/s and N·m after quantisation.
    """

    controlword: np.ndarray
    position: np.ndarray
    torque_offset: np.ndarray
    fresh: np.ndarray
    comm_fault: np.ndarray
    fault_code: np.ndarray
    modes_of_operation: Any = None
    target_velocity: Any = None
    velocity_offset: Any = None
    target_torque: Any = None


@dataclass(slots=True)
class ObservedActuals(_PerNode):
    """What the controller sees after this cycle's PRes frames (latched at this SoC).

    Values of a node whose PRes did not arrive valid are held from before, with
    fresh False. node_fault is True where the managing node's threshold counter for
    that node tripped (cleared by a fault reset once the counter is below threshold):
    the controller must stop commanding motion. modes_of_operation_display: 0x6061 of
    each drive.
    """

    statusword: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    torque: np.ndarray
    error_code: np.ndarray
    fresh: np.ndarray
    node_fault: np.ndarray
    modes_of_operation_display: Any = None

    @property
    def motion_allowed(self) -> bool:
        """True when every node answered, none is faulted and every drive is in
        Operation enabled: the controller may command motion."""
        return (bool(self.fresh.all()) and not bool(self.node_fault.any())
                and all(motion_enabled(int(s)) for s in self.statusword))


@dataclass(slots=True)
class CycleResult:
    """Result of one network cycle (arrays are reused: copy what you keep)."""

    cycle: int
    time_s: float
    applied: AppliedSetpoints
    observed: ObservedActuals
