"""A Python model of the drive-side CiA 402 state machine.

The co-simulation runs the state machine inside the servo-drive FMU (C). This model
is its executable reference: the fieldbus tests use it as the drive at the far end of
the bus, and the FMU's implementation can be checked against it transition by
transition. Transition numbers follow CiA 402 (figure "state machine")::

    Not ready to switch on --1--> Switch on disabled --2 shutdown--> Ready to switch on
    Ready --3 switch on--> Switched on --4 enable operation--> Operation enabled
    Operation enabled --5 disable operation--> Switched on --6 shutdown--> Ready
    Ready/Switched on --7/10 disable voltage or quick stop--> Switch on disabled
    Operation enabled --8 shutdown--> Ready, --9 disable voltage--> Switch on disabled
    Operation enabled --11 quick stop--> Quick stop active --12 ramp done / disable voltage--> Switch on disabled
    any --13 fault--> Fault reaction active --14 reaction done--> Fault --15 fault reset edge--> Switch on disabled

Quick stop option code 2 (ramp, then Switch on disabled) and a fault reaction that
takes ``fault_reaction_cycles`` are modelled; motion itself is not (this is the
device-control part only).
"""
from __future__ import annotations

from fieldbus.cia402 import CW_FAULT_RESET, DriveState, statusword_for

# command patterns (mask, value) of controlword bits 0-3 and 7
_SHUTDOWN = (0x87, 0x06)
_SWITCH_ON = (0x8F, 0x07)
_ENABLE_OPERATION = (0x8F, 0x0F)
_DISABLE_VOLTAGE = (0x82, 0x00)
_QUICK_STOP = (0x86, 0x02)
_DISABLE_OPERATION = (0x8F, 0x07)


def _is(controlword: int, pattern: tuple[int, int]) -> bool:
    return controlword & pattern[0] == pattern[1]


class Cia402DriveModel:
    """Device-control state machine of one drive, advanced once per cycle.

    Args:
        quick_stop_cycles: cycles the quick-stop ramp takes before the drive reaches
            Switch on disabled (option code 2).
        fault_reaction_cycles: cycles in Fault reaction active before Fault.
        init_cycles: cycles in Not ready to switch on after power-up.
    """

    def __init__(self, quick_stop_cycles: int = 50, fault_reaction_cycles: int = 50,
                 init_cycles: int = 1) -> None:
        self.state = DriveState.NOT_READY_TO_SWITCH_ON
        self.quick_stop_cycles = quick_stop_cycles
        self.fault_reaction_cycles = fault_reaction_cycles
        self._timer = init_cycles
        self._last_controlword = 0
        self.transitions: list[tuple[int, DriveState, DriveState]] = []  # (cycle, from, to)
        self.cycle = 0

    @property
    def statusword(self) -> int:
        """Statusword (0x6041) of the current state."""
        return statusword_for(self.state)

    def _go(self, state: DriveState, timer: int = 0) -> None:
        self.transitions.append((self.cycle, self.state, state))
        self.state = state
        self._timer = timer

    def step(self, controlword: int, fault: bool = False) -> int:
        """Advance one cycle with ``controlword`` applied; ``fault`` raises a drive fault
        (e.g. the fieldbus ``comm_fault`` flag with abort option 'fault'). Returns the
        statusword after the step."""
        s = DriveState
        rising_reset = bool(controlword & CW_FAULT_RESET) and not self._last_controlword & CW_FAULT_RESET
        self._last_controlword = controlword
        state = self.state
        if fault and state not in (s.FAULT_REACTION_ACTIVE, s.FAULT):
            self._go(s.FAULT_REACTION_ACTIVE, self.fault_reaction_cycles)  # 13
        elif state is s.NOT_READY_TO_SWITCH_ON:
            self._timer -= 1
            if self._timer <= 0:
                self._go(s.SWITCH_ON_DISABLED)  # 1
        elif state is s.SWITCH_ON_DISABLED:
            if _is(controlword, _SHUTDOWN):
                self._go(s.READY_TO_SWITCH_ON)  # 2
        elif state is s.READY_TO_SWITCH_ON:
            if _is(controlword, _SWITCH_ON) or _is(controlword, _ENABLE_OPERATION):
                self._go(s.SWITCHED_ON)  # 3
            elif _is(controlword, _DISABLE_VOLTAGE) or _is(controlword, _QUICK_STOP):
                self._go(s.SWITCH_ON_DISABLED)  # 7
        elif state is s.SWITCHED_ON:
            if _is(controlword, _ENABLE_OPERATION):
                self._go(s.OPERATION_ENABLED)  # 4
            elif _is(controlword, _SHUTDOWN):
                self._go(s.READY_TO_SWITCH_ON)  # 6
            elif _is(controlword, _DISABLE_VOLTAGE) or _is(controlword, _QUICK_STOP):
                self._go(s.SWITCH_ON_DISABLED)  # 10
        elif state is s.OPERATION_ENABLED:
            if _is(controlword, _DISABLE_OPERATION):
                self._go(s.SWITCHED_ON)  # 5
            elif _is(controlword, _SHUTDOWN):
                self._go(s.READY_TO_SWITCH_ON)  # 8
            elif _is(controlword, _DISABLE_VOLTAGE):
                self._go(s.SWITCH_ON_DISABLED)  # 9
            elif _is(controlword, _QUICK_STOP):
                self._go(s.QUICK_STOP_ACTIVE, self.quick_stop_cycles)  # 11
        elif state is s.QUICK_STOP_ACTIVE:
            self._timer -= 1
            if _is(controlword, _DISABLE_VOLTAGE) or self._timer <= 0:
                self._go(s.SWITCH_ON_DISABLED)  # 12
        elif state is s.FAULT_REACTION_ACTIVE:
            self._timer -= 1
            if self._timer <= 0:
                self._go(s.FAULT)  # 14
        elif state is s.FAULT:
            if rising_reset and not fault:
                self._go(s.SWITCH_ON_DISABLED)  # 15
        self.cycle += 1
        return self.statusword
