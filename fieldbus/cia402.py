"""CiA 402 device control: controlword commands, statusword states, the enable sequence.

The drive-side state machine runs in the servo-drive FMU; this module gives the
controller (and the tests) names for what travels in the telegrams:

* :class:`Command` - controlword values (0x6040): shutdown 0x06, switch on 0x07,
  enable operation 0x0F, disable voltage 0x00, quick stop 0x02, disable operation
  0x07, fault reset 0x80 (acts on the rising edge of bit 7).
* :func:`decode_statusword` - the state (0x6041 bits 0-3, 5, 6) as :class:`DriveState`.
* :func:`statusword_for` - the statusword a drive in a state shows (for drive models).
* :class:`EnableSequencer` - the controller's side of the start-up: given the observed
  state, the next controlword on the way to *Operation enabled*, including the fault
  reset edge.
"""
from __future__ import annotations

from enum import Enum, IntEnum

# controlword bits
CW_SWITCH_ON = 1 << 0
CW_ENABLE_VOLTAGE = 1 << 1
CW_QUICK_STOP = 1 << 2  # active low: 0 requests a quick stop
CW_ENABLE_OPERATION = 1 << 3
CW_FAULT_RESET = 1 << 7
CW_HALT = 1 << 8

# statusword bits
SW_READY_TO_SWITCH_ON = 1 << 0
SW_SWITCHED_ON = 1 << 1
SW_OPERATION_ENABLED = 1 << 2
SW_FAULT = 1 << 3
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5  # active low: 0 = quick stop active
SW_SWITCH_ON_DISABLED = 1 << 6
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
SW_DRIVE_FOLLOWS_COMMAND = 1 << 12  # cyclic synchronous modes: target value ignored = 0

# modes of operation (0x6060 / display 0x6061) whose set-points the telegrams carry
MODE_CYCLIC_SYNCHRONOUS_POSITION = 8   # target position, velocity offset, torque offset
MODE_CYCLIC_SYNCHRONOUS_VELOCITY = 9   # target velocity, velocity offset, torque offset
MODE_CYCLIC_SYNCHRONOUS_TORQUE = 10    # target torque, torque offset


class Command(IntEnum):
    """Controlword (0x6040) device-control commands (bits 0-3 and 7)."""

    DISABLE_VOLTAGE = 0x0000
    QUICK_STOP = 0x0002
    SHUTDOWN = 0x0006
    SWITCH_ON = 0x0007
    DISABLE_OPERATION = 0x0007
    ENABLE_OPERATION = 0x000F
    FAULT_RESET = 0x0080


class DriveState(Enum):
    """CiA 402 power drive system states (value = the name used in the standard)."""

    NOT_READY_TO_SWITCH_ON = "Not ready to switch on"
    SWITCH_ON_DISABLED = "Switch on disabled"
    READY_TO_SWITCH_ON = "Ready to switch on"
    SWITCHED_ON = "Switched on"
    OPERATION_ENABLED = "Operation enabled"
    QUICK_STOP_ACTIVE = "Quick stop active"
    FAULT_REACTION_ACTIVE = "Fault reaction active"
    FAULT = "Fault"


# (mask, value) of statusword bits 0-3, 5, 6 per state (CiA 402 table)
_STATE_PATTERNS: tuple[tuple[int, int, DriveState], ...] = (
    (0x4F, 0x00, DriveState.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, DriveState.SWITCH_ON_DISABLED),
    (0x6F, 0x21, DriveState.READY_TO_SWITCH_ON),
    (0x6F, 0x23, DriveState.SWITCHED_ON),
    (0x6F, 0x27, DriveState.OPERATION_ENABLED),
    (0x6F, 0x07, DriveState.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, DriveState.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, DriveState.FAULT),
)

_STATUS_BITS = {
    DriveState.NOT_READY_TO_SWITCH_ON: 0x00,
    DriveState.SWITCH_ON_DISABLED: 0x40,
    DriveState.READY_TO_SWITCH_ON: 0x21,
    DriveState.SWITCHED_ON: 0x23,
    DriveState.OPERATION_ENABLED: 0x27,
    DriveState.QUICK_STOP_ACTIVE: 0x07,
    DriveState.FAULT_REACTION_ACTIVE: 0x0F,
    DriveState.FAULT: 0x08,
}

_STATE_CACHE: dict[int, DriveState | None] = {}


class StatuswordError(ValueError):
    """A statusword whose state bits match no CiA 402 state."""


def decode_statusword(statusword: int) -> DriveState:
    """The CiA 402 state shown by ``statusword`` (0x6041); raises
    :class:`StatuswordError` for a bit pattern that is no state."""
    key = statusword & 0x6F
    state = _STATE_CACHE.get(key, False)
    if state is False:
        state = next((s for mask, value, s in _STATE_PATTERNS if key & mask == value), None)
        _STATE_CACHE[key] = state
    if state is None:
        raise StatuswordError(f"statusword 0x{statusword:04X}: bits 0-3,5,6 = 0x{key:02X} match no CiA 402 state")
    return state  # type: ignore[return-value]


def statusword_for(state: DriveState, voltage_enabled: bool | None = None,
                   remote: bool = True, target_reached: bool = False,
                   warning: bool = False, following: bool = True) -> int:
    """The statusword a drive in ``state`` presents. ``voltage_enabled`` defaults to
    true in the states where the power stage is on."""
    word = _STATUS_BITS[state]
    if voltage_enabled is None:
        voltage_enabled = state in (DriveState.SWITCHED_ON, DriveState.OPERATION_ENABLED,
                                    DriveState.QUICK_STOP_ACTIVE, DriveState.FAULT_REACTION_ACTIVE,
                                    DriveState.READY_TO_SWITCH_ON)
    if voltage_enabled:
        word |= SW_VOLTAGE_ENABLED
    if remote:
        word |= SW_REMOTE
    if target_reached:
        word |= SW_TARGET_REACHED
    if warning:
        word |= SW_WARNING
    if following and state is DriveState.OPERATION_ENABLED:
        word |= SW_DRIVE_FOLLOWS_COMMAND
    return word


def command_name(controlword: int) -> str:
    """Name of the device-control command in ``controlword`` (bits 0-3, 7), following
    the CiA 402 transition table (x = don't care)."""
    if controlword & CW_FAULT_RESET:
        return "fault reset"
    bits = controlword & 0x0F
    if not bits & CW_ENABLE_VOLTAGE:
        return "disable voltage"
    if not bits & CW_QUICK_STOP:
        return "quick stop"
    if not bits & CW_SWITCH_ON:
        return "shutdown"
    if bits & CW_ENABLE_OPERATION:
        return "enable operation"
    return "switch on"


def motion_enabled(statusword: int) -> bool:
    """True when the drive follows set-points (state *Operation enabled*)."""
    return statusword & 0x6F == 0x27


class EnableSequencer:
    """Controller-side CiA 402 start-up for one drive: call :meth:`next_controlword`
    once per cycle with the latest statusword; it walks Switch on disabled -> Ready to
    switch on -> Switched on -> Operation enabled, from Fault it alternates 0x80 and 0
    so every fault reset is a rising edge of bit 7, and in Quick stop active it keeps
    presenting quick stop until the drive has finished its ramp. When the target state is reached it
    keeps presenting enable operation."""

    def __init__(self) -> None:
        self.last_controlword = int(Command.DISABLE_VOLTAGE)

    def next_controlword(self, statusword: int) -> int:
        """Controlword to send next, given the drive's last statusword."""
        state = decode_statusword(statusword)
        if state is DriveState.FAULT:
            # bit 7 must rise: alternate 0x00 and 0x80 while the drive stays in Fault
            word = Command.DISABLE_VOLTAGE if self.last_controlword & CW_FAULT_RESET else Command.FAULT_RESET
        elif state in (DriveState.NOT_READY_TO_SWITCH_ON, DriveState.FAULT_REACTION_ACTIVE):
            word = Command.DISABLE_VOLTAGE
        elif state is DriveState.SWITCH_ON_DISABLED:
            word = Command.SHUTDOWN
        elif state is DriveState.READY_TO_SWITCH_ON:
            word = Command.SWITCH_ON
        elif state is DriveState.QUICK_STOP_ACTIVE:
            word = Command.QUICK_STOP  # never cut the quick-stop ramp short; the drive leaves by itself
        else:  # SWITCHED_ON, OPERATION_ENABLED
            word = Command.ENABLE_OPERATION
        self.last_controlword = int(word)
        return self.last_controlword
