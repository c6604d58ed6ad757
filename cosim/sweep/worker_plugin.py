"""A Dask worker plugin of the embedded cluster (imported only when a sweep starts one)."""
from __future__ import annotations

import logging
from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

#: What ``distributed.worker`` logs (with a traceback, at ERROR) when a heartbeat to the scheduler fails.
HEARTBEAT_FAILED = "Failed to communicate with scheduler during heartbeat"


class _HeartbeatAtCloseFilter(logging.Filter):
    """Drops the worker's heartbeat-failure record while that worker is closing or closed."""

    def __init__(self, worker: Any) -> None:
        super().__init__()
        self._worker = worker

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.getMessage().startswith(HEARTBEAT_FAILED):
            return True
        return getattr(getattr(self._worker, "status", None), "name", "running") not in (
            "closing", "closing_gracefully", "closed")


class QuietHeartbeatAtClose(WorkerPlugin):
    """A Dask worker plugin for the embedded cluster: a heartbeat in flight while its worker closes
    fails (its connection is closed under it) and Dask logs that at
    ERROR with a traceback (dask/distributed#7891). An interrupted sweep closes workers that are still
    running a variant (the nanny kills them after 4 s), so that heartbeat is often in flight under load.
    The record is dropped only for a worker that is already closing; a heartbeat failing while the
    worker runs is still logged."""

    idempotent = True

    def setup(self, worker: Any) -> None:
        logging.getLogger("distributed.worker").addFilter(_HeartbeatAtCloseFilter(worker))

    def teardown(self, worker: Any) -> None:
        """Keeps the filter: ``Worker.close`` removes plugins before it closes the connections."""
