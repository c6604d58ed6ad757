"""Closing once: the base of the fieldbus objects that hold a bus connection or a log file
(the endpoints, ``PowerlinkNetwork``, ``FrameRecorder``)."""
from __future__ import annotations

from typing import Self


class Closeable:
    """``close()`` releases what the object holds the first time it is called and does
    nothing after that; ``with obj:`` closes on leaving the block.

    A subclass implements :meth:`_release`."""

    _closed = False  # set on the instance by the first close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Flush and release what this object holds (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._release()

    def _release(self) -> None:
        raise NotImplementedError


__all__ = ["Closeable"]
