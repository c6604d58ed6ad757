"""Errors raised by the fieldbus package (all are ``ValueError`` subclasses)."""
from __future__ import annotations


class FieldbusConfigError(ValueError):
    """A ``[fieldbus]`` configuration value is missing, unknown or out of range.

    The message names the source (file or ``<dict>``), the dotted key, the value
    given and what was expected.
    """

    def __init__(self, source: str, key: str, given: object, expected: str) -> None:
        self.source = source
        self.key = key
        self.given = given
        self.expected = expected
        super().__init__(f"{source}: fieldbus.{key} = {given!r}: expected {expected}")


class FrameDecodeError(ValueError):
    """A received frame cannot be decoded (unknown id, wrong length, error frame...).

    ``reason`` is a short machine-readable tag (``unknown_id``, ``short_frame``,
    ``long_frame``, ``error_frame``, ``remote_frame``); ``node`` is the node the
    frame was addressed to or came from (0 when unknown).
    """

    def __init__(self, reason: str, arbitration_id: int, node: int, detail: str) -> None:
        self.reason = reason
        self.arbitration_id = arbitration_id
        self.node = node
        super().__init__(f"frame 0x{arbitration_id:03X} (node {node}): {reason}: {detail}")


class ScalingError(ValueError):
    """Invalid joint scaling configuration (gear ratio, encoder resolution, rated torque)."""
