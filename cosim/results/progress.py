"""A tqdm progress bar over simulated time, on stderr.

Disabled with ``enabled=False`` (``--quiet``) or when stderr is not a terminal. Updating
is throttled to ``min_interval_s`` of wall time so it costs nothing per macro step.
"""
from __future__ import annotations

import sys
import time

from tqdm import tqdm


class ProgressBar:
    """Progress of a run from 0 to ``total_s`` simulated seconds."""

    def __init__(self, total_s: float, label: str, enabled: bool = True, min_interval_s: float = 0.2) -> None:
        self.enabled = bool(enabled) and sys.stderr.isatty()
        self.min_interval_s = min_interval_s
        self._last = 0.0
        self._shown = 0.0
        self._bar = tqdm(total=round(total_s, 9), desc=label, unit="s sim", file=sys.stderr,
                         disable=not self.enabled, bar_format="{l_bar}{bar}| {n:.3f}/{total:.3f} s sim "
                         "[{elapsed}<{remaining}, {rate_fmt}]") if self.enabled else None

    def update(self, sim_time_s: float, force: bool = False) -> None:
        """Show ``sim_time_s`` reached (throttled unless ``force``)."""
        if self._bar is None:
            return
        now = time.perf_counter()
        if force or now - self._last >= self.min_interval_s:
            self._bar.update(round(sim_time_s - self._shown, 9))
            self._shown = sim_time_s
            self._last = now

    def close(self) -> None:
        """Remove the bar."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
