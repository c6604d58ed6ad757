"""Plain per-cycle process data at the edge of the fieldbus, in SI units.

One entry per controlled node (node 1 = joint 1 first), numpy arrays of shape (N,).
Joint side: rad, rad/s, N·m. Controlwords and statuswords are CiA 402 integers.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Self

import numpy as np

from fieldbus.cia402 import motion_enabled

# element type of each per-node array by field name; any other field is float64 (SI units)
_DTYPES = {"controlword": np.int64, "statusword": np.int64, "error_code": np.int64, "fault_code": np.int64,
           "fresh": np.bool_, "comm_fault": np.bool_, "node_fault": np.bool_}


class _PerNode:
    """Base of the records below: every field an array of shape (N,), one entry per node."""

    __slots__ = ()

    @classmethod
    def zeros(cls, nodes: int) -> Self:
        """Zeros (False for flags) for ``nodes`` nodes."""
        return cls(*(np.zeros(nodes, dtype=_DTYPES.get(f.name, np.float64)) for f in fields(cls)))

    def copy(self) -> Self:
        """A copy with arrays of its own."""
        return type(self)(*(getattr(self, f.name).copy() for f in fields(self)))


@dataclass(slots=True)
class Setpoints(_PerNode):
    """What the controller commands for the next cycle (goes into the PReqs).

    controlword: CiA 402 controlword per node (0x6040).
    position: target joint angle in rad (0x607A after scaling).
    torque_offset: feed-forward joint torque in N·m (0x60B2 after scaling).
    """

    controlword: np.ndarray
    position: np.ndarray
    torque_offset: np.ndarray


@dataclass(slots=True)
class DriveActuals(_PerNode):
    """What the drives report, sampled at the SoC (goes into the PRes).

    statusword: CiA 402 statusword per node (0x6041).
    position: joint angle in rad (0x6064), velocity in rad/s (0x606C),
    torque: joint torque in N·m (0x6077), error_code: 0x603F.
    """

    statusword: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    torque: np.ndarray
    error_code: np.ndarray


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
    """

    controlword: np.ndarray
    position: np.ndarray
    torque_offset: np.ndarray
    fresh: np.ndarray
    comm_fault: np.ndarray
    fault_code: np.ndarray


@dataclass(slots=True)
class ObservedActuals(_PerNode):
    """What the controller sees after this cycle's PRes frames (latched at this SoC).

    Values of a node whose PRes did not arrive valid are held from before, with
    fresh False. node_fault is True where the managing node's threshold counter for
    that node tripped (cleared by a fault reset once the counter is below threshold):
    the controller must stop commanding motion.
    """

    statusword: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    torque: np.ndarray
    error_code: np.ndarray
    fresh: np.ndarray
    node_fault: np.ndarray

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
