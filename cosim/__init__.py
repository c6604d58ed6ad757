"""Composition root: co-simulation master, scenario runner, CLI and results.

The public Python API for scripts lives in :mod:`cosim.api` and is re-exported here
(imported on first use, so ``import cosim`` and ``python -m cosim --help`` stay fast)::

    import cosim
    result = cosim.run("scenarios/iso9283.toml", overrides={"controller.modes": ["standard"]})

See docs/how-to/scripting.md.
"""
from __future__ import annotations

from typing import Any

#: Names re-exported from cosim.api.
_API_NAMES = ("OutputFolderError", "RunFailed", "RunResult", "Scenario", "ScenarioError", "Summary", "TimeSeries",
              "build_sweep", "execute", "export_blf", "load_scenario", "load_sweep", "read_can_log", "read_timeseries", "run",
              "run_sweep")

__all__ = list(_API_NAMES)


def __getattr__(name: str) -> Any:
    if name in _API_NAMES:
        from cosim import api

        value = getattr(api, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'cosim' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API_NAMES))
