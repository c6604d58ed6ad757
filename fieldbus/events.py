"""POWERLINK threshold counters and the structured record of every fault.

A :class:`ThresholdCounter` adds ``increment`` (8) per error and subtracts
``decrement`` (1) per cycle without that error, never below 0; when it reaches its
threshold (15) the owner's reaction fires once (again only after it fell below the
threshold). Threshold 0 disables counting (the cumulative count still runs).

Every error, every counter change and every reaction is appended to an
:class:`EventLog` as a :class:`FieldbusEvent` (side, node, cycle, simulated time,
counter values), ready for ``summary.json``.
"""
from __future__ import annotations

import logging
from collections import Counter as _Tally
from collections.abc import Callable
from typing import Any, NamedTuple

LOG = logging.getLogger("fieldbus")


class FieldbusEvent(NamedTuple):
    """One recorded fieldbus event.

    side: 'mn' (managing node, controller side) or 'cn' (controlled node, drive side).
    node: controlled node id (1..N), 0 when not attributable (e.g. unknown identifier).
    kind: the error or counter name ('loss_of_preq', 'crc_error', 'unknown_id', ...).
    event: 'error', 'decrement', 'threshold_reached', 'fault_reaction',
        'fault_cleared', 'decode_error', 'emcy_sent', 'emcy_received'.
    counter/cumulative/threshold: threshold-counter state after the event (-1 if none).
    """

    time_s: float
    cycle: int
    side: str
    node: int
    kind: str
    event: str
    counter: int
    cumulative: int
    threshold: int
    detail: str

    def as_dict(self) -> dict[str, Any]:
        return self._asdict()


class EventLog:
    """Append-only list of :class:`FieldbusEvent` with tallies for a summary.

    Errors are also written to the ``fieldbus`` logger (WARNING), at most
    ``max_logged`` of them, then one note that further ones are only counted.
    """

    def __init__(self, max_logged: int = 50) -> None:
        self.events: list[FieldbusEvent] = []
        self.max_logged = max_logged
        self._logged = 0

    def add(self, event: FieldbusEvent) -> None:
        self.events.append(event)
        if event.event in ("error", "decode_error", "threshold_reached", "fault_reaction"):
            if self._logged < self.max_logged:
                LOG.warning("cycle %d t=%.6f s %s node %d %s %s (counter %d/%d) %s",
                            event.cycle, event.time_s, event.side, event.node, event.kind,
                            event.event, event.counter, event.threshold, event.detail)
            elif self._logged == self.max_logged:
                LOG.warning("further fieldbus errors are recorded but not logged")
            self._logged += 1

    def as_dicts(self) -> list[dict[str, Any]]:
        """All events as JSON-ready dicts, in order."""
        return [event._asdict() for event in self.events]

    def tally(self) -> dict[str, int]:
        """Number of events per 'side.kind.event'."""
        return dict(_Tally(f"{e.side}.{e.kind}.{e.event}" for e in self.events))

    def select(self, **match: Any) -> list[FieldbusEvent]:
        """Events whose fields equal all given values, e.g. ``select(event="threshold_reached")``."""
        return [e for e in self.events if all(getattr(e, k) == v for k, v in match.items())]


class ThresholdCounter:
    """One POWERLINK threshold counter of one node and side."""

    __slots__ = ("side", "node", "kind", "threshold", "increment", "decrement",
                 "value", "cumulative", "tripped", "_bank")

    def __init__(self, bank: "CounterBank", side: str, node: int, kind: str,
                 threshold: int, increment: int, decrement: int) -> None:
        self._bank = bank
        self.side = side
        self.node = node
        self.kind = kind
        self.threshold = threshold
        self.increment = increment
        self.decrement = decrement
        self.value = 0
        self.cumulative = 0
        self.tripped = False

    def error(self, cycle: int, time_s: float, detail: str = "") -> bool:
        """Count one error; returns True when this error made the counter reach its threshold."""
        return self._bank.error(self, cycle, time_s, detail)

    def state(self) -> dict[str, int]:
        return {"counter": self.value, "cumulative": self.cumulative, "threshold": self.threshold}


class CounterBank:
    """All threshold counters of one side; decrements the ones without error each cycle.

    ``on_threshold(counter, cycle, time_s)`` is called when a counter reaches its threshold.
    """

    def __init__(self, log: EventLog, on_threshold: Callable[[ThresholdCounter, int, float], None]) -> None:
        self.log = log
        self.on_threshold = on_threshold
        self.counters: list[ThresholdCounter] = []
        # the non-zero counters in the order they became non-zero (a dict: a set's order would follow
        # the objects' addresses, and the decrement events of one cycle would come in any order)
        self._nonzero: dict[ThresholdCounter, None] = {}
        self._errored: set[ThresholdCounter] = set()

    def new(self, side: str, node: int, kind: str, threshold: int, increment: int,
            decrement: int) -> ThresholdCounter:
        counter = ThresholdCounter(self, side, node, kind, threshold, increment, decrement)
        self.counters.append(counter)
        return counter

    def error(self, c: ThresholdCounter, cycle: int, time_s: float, detail: str) -> bool:
        c.cumulative += 1
        reached = False
        if c.threshold > 0:
            before = c.value
            c.value += c.increment
            self._nonzero[c] = None
            reached = before < c.threshold <= c.value
        self._errored.add(c)
        self.log.add(FieldbusEvent(time_s, cycle, c.side, c.node, c.kind, "error",
                                   c.value, c.cumulative, c.threshold, detail))
        if reached:
            c.tripped = True
            self.log.add(FieldbusEvent(time_s, cycle, c.side, c.node, c.kind, "threshold_reached",
                                       c.value, c.cumulative, c.threshold, detail))
            self.on_threshold(c, cycle, time_s)
        return reached

    @property
    def busy(self) -> bool:
        """True when some counter is non-zero or erred this cycle (end_cycle has work)."""
        return bool(self._nonzero or self._errored)

    def end_cycle(self, cycle: int, time_s: float) -> None:
        """Decrement every non-zero counter that saw no error this cycle."""
        if self._nonzero:
            errored = self._errored
            for c in list(self._nonzero):
                if c in errored or c.decrement == 0:
                    continue
                c.value = max(0, c.value - c.decrement)
                if c.value < c.threshold:
                    c.tripped = False
                self.log.add(FieldbusEvent(time_s, cycle, c.side, c.node, c.kind, "decrement",
                                           c.value, c.cumulative, c.threshold, ""))
                if c.value == 0:
                    del self._nonzero[c]
        if self._errored:
            self._errored.clear()

    def node_tripped(self, node: int) -> bool:
        """True while any counter of ``node`` is at or above its threshold."""
        return any(c.tripped for c in self.counters if c.node == node)

    def snapshot(self) -> list[dict[str, Any]]:
        """Current state of every counter (for a summary)."""
        return [{"side": c.side, "node": c.node, "kind": c.kind, **c.state()} for c in self.counters]
