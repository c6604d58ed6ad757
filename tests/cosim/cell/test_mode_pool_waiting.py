"""``run_modes(..., while_waiting=f)``: ``f`` runs once, in a thread of the job's process, after
every mode worker has been forked (the main job imports matplotlib there while the modes run),
and is done when the outcomes run out; an exception from it does not disturb the modes; it is
not called when the modes run in this process or when a worker is still to be forked later."""
from __future__ import annotations

import multiprocessing
from types import SimpleNamespace

from cosim.execution import mode_pool


class _Summary:
    def __init__(self) -> None:
        self.data: dict = {}

    def update(self, **fields) -> None:
        self.data.update(fields)

    def __getattr__(self, name):
        if name.startswith("_"):
            raise AttributeError(name)
        return lambda *args, **kwargs: None


def _fake_worker(connection, ctx, setup, mode, extra_signals):
    mode_pool._send_whole(connection, ("done", mode, {"mode": mode}, f"result {mode}", None, 1.0))
    connection.close()


def _context() -> SimpleNamespace:
    return SimpleNamespace(summary=_Summary(), quiet=True, sim_time_s=0.0, scenario=SimpleNamespace(name="x"),
                           label=None, execution=None)


def test_while_waiting_runs_once_after_the_workers_started(monkeypatch):
    monkeypatch.setattr(mode_pool, "_worker", _fake_worker)
    setup = SimpleNamespace(doc={"simulation": {"stop_time": 1.0}})
    seen = []

    def waiting():
        seen.append(sorted(p.name for p in multiprocessing.active_children()))

    outcomes = list(mode_pool.run_modes(_context(), setup, ["a", "b"], processes=2, while_waiting=waiting))
    assert [(o.mode, o.entry, o.result, o.failure) for o in outcomes] == [
        ("a", {"mode": "a"}, "result a", None), ("b", {"mode": "b"}, "result b", None)]
    assert len(seen) == 1
    assert set(seen[0]) <= {"cosim-mode-a", "cosim-mode-b"}  # started (a fast worker may have ended already)


def test_an_error_in_while_waiting_leaves_the_modes_alone(monkeypatch):
    monkeypatch.setattr(mode_pool, "_worker", _fake_worker)
    setup = SimpleNamespace(doc={"simulation": {"stop_time": 1.0}})

    def broken():
        raise ImportError("no matplotlib here")

    outcomes = list(mode_pool.run_modes(_context(), setup, ["a", "b"], processes=2, while_waiting=broken))
    assert [o.mode for o in outcomes] == ["a", "b"] and all(o.failure is None for o in outcomes)


def test_not_called_when_the_modes_run_in_this_process(monkeypatch):
    calls = []

    def run_mode(ctx, setup, mode, extra_signals):
        return {"mode": mode}, None, SimpleNamespace(failure=None), None

    import cosim.execution.mode_runs as mode_runs

    monkeypatch.setattr(mode_runs, "run_mode", run_mode)
    outcomes = list(mode_pool.run_modes(_context(), SimpleNamespace(doc={}), ["a", "b"], processes=0,
                                        while_waiting=lambda: calls.append(1)))
    assert [o.mode for o in outcomes] == ["a", "b"] and calls == []


def test_not_called_when_a_worker_is_forked_later(monkeypatch):
    monkeypatch.setattr(mode_pool, "_worker", _fake_worker)
    setup = SimpleNamespace(doc={"simulation": {"stop_time": 1.0}})
    calls = []
    outcomes = list(mode_pool.run_modes(_context(), setup, ["a", "b", "c"], processes=2,
                                        while_waiting=lambda: calls.append(1)))
    assert [o.mode for o in outcomes] == ["a", "b", "c"] and calls == []


def test_the_job_process_relays_progress_while_it_waits(monkeypatch):
    """The helper runs beside the relay loop, not before it: a slow ``while_waiting`` does not hold
    back the outcomes."""
    import threading
    import time

    monkeypatch.setattr(mode_pool, "_worker", _fake_worker)
    setup = SimpleNamespace(doc={"simulation": {"stop_time": 1.0}})
    release = threading.Event()
    got = []

    def slow():
        release.wait(10.0)

    started = time.monotonic()
    for outcome in mode_pool.run_modes(_context(), setup, ["a", "b"], processes=2, while_waiting=slow):
        got.append(outcome.mode)
        if len(got) == 1:
            assert time.monotonic() - started < 8.0  # the first outcome came while slow() still ran
            release.set()
    assert got == ["a", "b"]


def _priority_worker(connection, ctx, setup, mode, extra_signals):
    """Reports its own scheduling priority once the parent had time to lower it."""
    import os
    import time

    base = setup.base_priority
    deadline = time.monotonic() + 5.0
    while os.getpriority(os.PRIO_PROCESS, 0) == base and mode == "light" and base < 19 and time.monotonic() < deadline:
        time.sleep(0.01)
    mode_pool._send_whole(connection, ("done", mode, {"nice": os.getpriority(os.PRIO_PROCESS, 0) - base}, None,
                                       None, 1.0))
    connection.close()


def test_niceness_lowers_the_priority_of_the_modes_named(monkeypatch):
    """``run_modes(niceness=...)``: the worker of a mode named gets that much lower a priority (the
    main job's other modes yield to the elastic one); the others keep this process's."""
    import os

    monkeypatch.setattr(mode_pool, "_worker", _priority_worker)
    setup = SimpleNamespace(doc={"simulation": {"stop_time": 1.0}}, base_priority=os.getpriority(os.PRIO_PROCESS, 0))
    outcomes = list(mode_pool.run_modes(_context(), setup, ["light", "long"], processes=2, niceness={"light": 1}))
    lowered = min(1, 19 - setup.base_priority)  # 19: the lowest priority there is
    assert {o.mode: o.entry["nice"] for o in outcomes} == {"light": lowered, "long": 0}


def test_the_main_job_lowers_the_other_modes_for_the_elastic_one(monkeypatch):
    import pytest

    from cosim.jobs.iso9283 import _niceness

    monkeypatch.delenv("COSIM_MODE_NICENESS", raising=False)
    assert _niceness(["standard", "model_based", "model_based_elastic"]) == {"standard": 1, "model_based": 1}
    assert _niceness(["standard", "standard_speed_ff", "model_based"]) == {}
    monkeypatch.setenv("COSIM_MODE_NICENESS", "0")  # all at one priority, to compare
    assert _niceness(["standard", "model_based", "model_based_elastic"]) == {}
    monkeypatch.setenv("COSIM_MODE_NICENESS", "-1")
    with pytest.raises(ValueError, match="COSIM_MODE_NICENESS"):
        _niceness(["standard", "model_based_elastic"])
