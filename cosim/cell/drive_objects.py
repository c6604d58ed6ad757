"""The drives' object dictionaries on the cell's bus, and what an SDO write changes in the drive FMUs.

Every execution mode that runs the cyclic bus (in process, paced, split) gives the bus the six
dictionaries (:func:`cell_object_dictionaries`) so its asynchronous phase
(``fieldbus.asynchronous``) answers SDO and NMT, and a :class:`DriveParameterWriter` as the
dictionaries' ``on_write``:

* an object backed by a *tunable* drive parameter (``fmus.servo_drive.spec.TUNABLE_PARAMETERS``:
  0x6065 following error window, 0x6066 following error time-out) is converted from the bus unit
  to SI and set in the drive FMU between two steps: it acts from the cycle the SDO answer is sent;
* an object backed by a fixed drive parameter (0x6072 max torque, 0x6073 max current, gains ...:
  the FMU takes them only at initialisation) is refused with CiA 301 abort 0x08000020 (data cannot
  be transferred or stored to the application), so the dictionary never shows a value the drive
  does not run with;
* every other writable object (communication objects, the process data the PDOs carry) is
  stored in the dictionary; the cyclic PReq overwrites the process data every cycle.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from cosim.cell.wiring import DRIVES, N_JOINTS
from fieldbus.sdo import SdoAbort

#: CiA 301 abort: data cannot be transferred or stored to the application
CANNOT_STORE = 0x08000020
#: object index -> (drive FMU parameter, SI per bus unit: "position" = the dictionary's rad per count)
TUNABLE_OBJECTS: dict[int, tuple[str, Any]] = {0x6065: ("following_error_window", "position"),
                                               0x6066: ("following_error_time", 1e-3)}


def cell_object_dictionaries(fieldbus_config: Any) -> list:
    """The object dictionaries of the cell's six drives (nodes 1..6)."""
    from fmus.servo_drive.object_dictionary import drive_object_dictionary

    return [drive_object_dictionary(axis, fieldbus_config) for axis in range(1, N_JOINTS + 1)]


class DriveParameterWriter:
    """``on_write(node, entry, value)`` of the cell's bus (module docstring). ``set_value(instance,
    name, value)`` sets one variable of a drive FMU between steps."""

    def __init__(self, ods: Sequence[Any], set_value: Callable[[str, str, float], None]) -> None:
        from fmus.servo_drive.spec import TUNABLE_PARAMETERS

        self.ods = {od.node: od for od in ods}
        self.set_value = set_value
        self.tunable = TUNABLE_PARAMETERS
        self.applied: list[tuple[int, str, float]] = []  # (node, parameter, SI value) in the order set

    def __call__(self, node: int, entry: Any, value: Any) -> None:
        target = TUNABLE_OBJECTS.get(entry.index) if entry.subindex == 0 else None
        if target is not None and target[0] in self.tunable and 1 <= node <= len(DRIVES):
            name, scale = target
            factor = self.ods[node].rad_per_count if scale == "position" else scale
            si = float(value) * factor
            self.set_value(DRIVES[node - 1], name, si)
            self.applied.append((node, name, si))
            return
        if str(getattr(entry, "source", "")).startswith("drive parameter"):
            raise SdoAbort(CANNOT_STORE, entry.index, entry.subindex)


__all__ = ["CANNOT_STORE", "DriveParameterWriter", "TUNABLE_OBJECTS", "cell_object_dictionaries"]
