"""The ``[execution]`` and ``[realtime]`` tables of a scenario and the run options built from them.

```toml
[execution]
mode = "in_process"          # or "split": controller in this process, drives + plant in another
realtime = false             # true = paced at the controller cycle (same as --realtime)
receive_timeout = "2 s"      # split: WALL time a side waits for the other's frames before counting them lost

[realtime]
overrun_policy = "hold"      # what the drives get in a cycle whose telegrams missed their SoC:
                             # "hold" | "skip" | "lost_frame" (docs/explanation/timing.md)
spin = "100 us"              # busy-wait this long before each wall deadline (sleep before it)
scheduling = "fifo"          # "fifo": ask for SCHED_FIFO (falls back to the normal scheduler) | "normal"
fifo_priority = 10           # SCHED_FIFO priority (1..99)
cpu = "auto"                 # pin the paced loop to one CPU: "auto" (highest-numbered usable), "none", or an index
tolerance = "auto"           # lateness above which a cycle is an overrun; "auto" = the cycle time minus
                             # the isochronous phase of the fieldbus schedule (400 - 136.56 us: a later
                             # start puts the cycle's telegrams on the bus after the next SoC), or a time
histogram_bins = 60
```

``python -m cosim run SCENARIO --realtime`` and ``--split`` override ``realtime`` and
``mode``. Every quantity is SI after validation (seconds).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from cosim.scenario.execution_tables import (DEFAULT_RECEIVE_TIMEOUT_S, DEFAULT_SPIN_S,  # noqa: F401
                                             EXECUTION_MODES, OVERRUN_POLICIES, SCHEDULING, _tables,
                                             execution_fields, execution_tables)


@dataclass(frozen=True)
class RealtimeSettings:
    """The validated ``[realtime]`` table (SI).

    overrun_policy: 'hold' | 'skip' | 'lost_frame'.
    spin_s: busy-wait before each deadline, s.
    scheduling: 'fifo' | 'normal'; fifo_priority: 1..99.
    cpu: pin the paced loop to this CPU ('auto': highest-numbered usable; 'none'/None: no pinning).
    tolerance_s: lateness above which a cycle counts as an overrun, s (None = from the
        fieldbus schedule: cycle time minus the isochronous phase).
    histogram_bins: bins of the jitter histogram figure.
    """

    overrun_policy: str = "hold"
    spin_s: float = DEFAULT_SPIN_S
    scheduling: str = "fifo"
    fifo_priority: int = 10
    cpu: int | str | None = "auto"
    tolerance_s: float | None = None
    histogram_bins: int = 60

    def __post_init__(self) -> None:
        if self.overrun_policy not in OVERRUN_POLICIES:
            raise ValueError(f"overrun_policy = {self.overrun_policy!r}: expected one of {OVERRUN_POLICIES}")
        if self.scheduling not in SCHEDULING:
            raise ValueError(f"scheduling = {self.scheduling!r}: expected one of {SCHEDULING}")
        if not self.spin_s >= 0.0:
            raise ValueError(f"spin_s = {self.spin_s!r}: expected a time >= 0 s")
        if self.tolerance_s is not None and not self.tolerance_s >= 0.0:
            raise ValueError(f"tolerance_s = {self.tolerance_s!r}: expected a time >= 0 s or None (auto)")


@dataclass(frozen=True)
class ExecutionOptions:
    """How a robot-cell run executes: one process or split, paced or not (see module doc).

    Built by ``python -m cosim run`` from the scenario's tables and its flags and handed
    to the job through ``RunContext.execution``; jobs that run a robot cell
    (:func:`cosim.execution.run_cell`) honour it.
    """

    mode: str = "in_process"
    realtime: bool = False
    receive_timeout_s: float = DEFAULT_RECEIVE_TIMEOUT_S
    settings: RealtimeSettings = field(default_factory=RealtimeSettings)
    #: ``cosim serve``: the cell side only, paced, for a controller elsewhere on the bus
    #: (:class:`cosim.execution.serve_settings.ServeSettings`; mode ``"serve"``)
    serve: Any = None

    @property
    def split(self) -> bool:
        return self.mode == "split"

    @property
    def cell_mode(self) -> str:
        """The execution mode of :func:`cosim.execution.run_cell` these options ask for."""
        if self.serve is not None:
            return "serve"
        if self.split:
            return "split"
        return "paced" if self.realtime else "in_process"

    @property
    def active(self) -> bool:
        """True when the run differs from the plain in-process, unpaced run."""
        return self.realtime or self.split or self.serve is not None

    def as_dict(self) -> dict[str, Any]:
        s = self.settings
        if self.serve is not None:
            return {"mode": "serve", "realtime": True, "serve": self.serve.as_dict()}
        return {"mode": self.mode, "realtime": self.realtime, "receive_timeout_s": self.receive_timeout_s,
                "overrun_policy": s.overrun_policy, "spin_us": s.spin_s * 1e6, "scheduling": s.scheduling,
                "cpu": s.cpu,
                "tolerance_us": None if s.tolerance_s is None else s.tolerance_s * 1e6}


def execution_options(doc: dict[str, Any], *, realtime: bool | None = None, split: bool | None = None) -> ExecutionOptions:
    """Options from a validated scenario document; ``realtime``/``split`` (command-line flags)
    override the file when not None."""
    ex, rt = execution_tables(doc)
    settings = RealtimeSettings(overrun_policy=rt["overrun_policy"], spin_s=rt["spin"], scheduling=rt["scheduling"],
                                fifo_priority=rt["fifo_priority"], cpu=rt["cpu"],
                                tolerance_s=None if rt["tolerance"] == "auto" else rt["tolerance"],
                                histogram_bins=rt["histogram_bins"])
    mode = "split" if split else ex["mode"]
    return ExecutionOptions(mode=mode, realtime=bool(realtime) or ex["realtime"],
                            receive_timeout_s=ex["receive_timeout"], settings=settings)
