"""``simbus``: a lean in-process python-can interface for simulated time.

``can.Bus(interface="simbus", channel="cell")`` (registered through the
``can.interface`` entry point in pyproject.toml, and by :func:`register` as a fallback)
connects every bus object opened on the same channel name in this process. A sent
message is appended to the receive queue of every other bus on the channel, in send
order, without copying and without touching its timestamp, so simulated timestamps
survive and delivery is deterministic. There are no threads: ``recv`` never waits, it
returns the next queued message or ``None``.

Contract: receivers get the very object that was sent. The fieldbus nodes refill their
message objects every cycle (allocation-light hot loop), so a listener that keeps a
message beyond the current cycle must copy it (``copy.copy(msg)``); the recorder does.
"""
from __future__ import annotations

import itertools
from collections import deque
from typing import Any

import can
from can import BusABC, CanProtocol, Message

INTERFACE_NAME = "simbus"

_CHANNELS: dict[str, list["SimulatedTimeBus"]] = {}
_UNIQUE = itertools.count()


def unique_channel(prefix: str = "powerlink") -> str:
    """A channel name no other bus in this process uses yet."""
    return f"{prefix}-{next(_UNIQUE)}"


class SimulatedTimeBus(BusABC):
    """In-process bus that delivers messages in send order, timestamps untouched.

    Args:
        channel: name of the shared medium; buses with equal names see each other.
        receive_own_messages: also queue the bus's own messages to itself.
        can_filters: standard python-can filters (applied in ``recv``).
    """

    def __init__(self, channel: Any = "simbus", can_filters: Any = None,
                 receive_own_messages: bool = False, **kwargs: object) -> None:
        self.channel_id = str(channel)
        self.channel_info = f"simulated-time in-process bus, channel {self.channel_id!r}"
        self.receive_own_messages = receive_own_messages
        self._can_protocol = CanProtocol.CAN_20
        self._queue: deque[Message] = deque()
        self._peers = _CHANNELS.setdefault(self.channel_id, [])
        self._peers.append(self)
        self._targets: tuple[deque[Message], ...] = ()
        self._refresh_targets()
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)

    def _refresh_targets(self) -> None:
        for bus in self._peers:
            bus._targets = tuple(peer._queue for peer in self._peers
                                 if peer is not bus or bus.receive_own_messages)

    def send(self, msg: Message, timeout: float | None = None) -> None:
        """Queue ``msg`` (the same object) at every other bus on the channel."""
        targets = self._targets
        if len(targets) == 1:
            targets[0].append(msg)
            return
        for target in targets:
            target.append(msg)

    def send_many(self, msgs: list[Message]) -> None:
        """Queue ``msgs`` in order, as ``send`` one after the other would; an extension of
        this interface for batch senders (the counterpart of :meth:`drain`)."""
        for target in self._targets:
            target.extend(msgs)

    def _recv_internal(self, timeout: float | None) -> tuple[Message | None, bool]:
        queue = self._queue
        return (queue.popleft() if queue else None), False

    def recv(self, timeout: float | None = None) -> Message | None:
        """Next queued message matching the filters, or None at once (never blocks)."""
        queue = self._queue
        if self._filters is None:
            return queue.popleft() if queue else None
        while queue:
            msg = queue.popleft()
            if self._matches_filters(msg):
                return msg
        return None

    def drain(self) -> list[Message]:
        """All queued messages at once (in order), filtered like ``recv``; an extension
        of this interface for batch receivers."""
        return drain_queue(self, self._queue)

    @property
    def pending(self) -> int:
        """Number of messages waiting in this bus's receive queue."""
        return len(self._queue)

    def shutdown(self) -> None:
        if self in self._peers:
            self._peers.remove(self)
            self._refresh_targets()
            self._targets = ()
            if not self._peers:
                _CHANNELS.pop(self.channel_id, None)
        super().shutdown()

    @staticmethod
    def _detect_available_configs() -> list[can.typechecking.AutoDetectedConfig]:
        return [{"interface": INTERFACE_NAME, "channel": name} for name in _CHANNELS]


def drain_queue(bus: BusABC, queue: deque) -> list[Message]:
    """Everything in ``queue`` (emptied), in order, filtered by ``bus``'s python-can filters."""
    if not queue:
        return []
    messages = list(queue)
    queue.clear()
    if bus._filters is not None:
        messages = [m for m in messages if bus._matches_filters(m)]
    return messages


def register() -> None:
    """Make ``can.Bus(interface="simbus")`` work even without installed entry points."""
    from can import interfaces, util

    if INTERFACE_NAME not in interfaces.BACKENDS:  # package not installed with its entry points
        interfaces.BACKENDS[INTERFACE_NAME] = (__name__, SimulatedTimeBus.__name__)
        interfaces.VALID_INTERFACES = util.VALID_INTERFACES = frozenset(interfaces.BACKENDS)
