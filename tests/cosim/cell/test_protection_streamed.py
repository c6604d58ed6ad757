"""Protection events of a streamed recording (cosim.cell.protection.protection_events on a SeriesFile):
a run without any limit or contact is judged from one chunked pass over the trigger columns, so
the memory it takes does not grow with the run's length (the whole recording's protection columns
were read back after every run: +100 MiB per 100 s of the robot cell, benchmarks/bench_memory.py
--job cell); a run with events gives the same events as the recording held in memory."""
from __future__ import annotations

import tracemalloc
from types import SimpleNamespace

import numpy as np

from cosim.cell.protection import PROTECTION_SIGNALS, protection_events
from cosim.cell.wiring import DRIVES, PLANT
from cosim.results.timeseries import SeriesFile, write_columns

CELL = SimpleNamespace(document={"fmus": [{"name": "drive1", "parameters": {
    "gear_ratio": 100.0, "torque_constant": 0.5, "torque_limit": 40.0, "current_limit": 2.0}}]})


def recording(rows: int) -> dict[str, np.ndarray]:
    """A quiet 1 ms recording: every column a cell records for its protection events, no limit, no contact."""
    t = np.arange(rows) * 1e-3
    columns = {"time": t}
    for name in PROTECTION_SIGNALS:
        columns[name] = np.zeros(rows)
    for k, drive in enumerate(DRIVES, start=1):
        columns[f"{PLANT}.q[{k}]"] = 0.1 * np.sin(t + k)
        columns[f"{PLANT}.qd[{k}]"] = 0.1 * np.cos(t + k)
        columns[f"{drive}.tau_out"] = np.sin(3 * t + k)
        columns[f"{drive}.current_actual"] = 0.2 * np.sin(3 * t + k)
        columns[f"{drive}.following_error"] = 1e-5 * np.cos(t)
    return columns


def in_memory(columns: dict[str, np.ndarray]) -> SimpleNamespace:
    return SimpleNamespace(columns=list(columns), data=np.column_stack(list(columns.values())))


def test_a_quiet_run_is_judged_in_chunks_of_its_trigger_columns(tmp_path):
    rows = 300_000  # 5 min at 1 ms: the columns protection_events would load are 300000 x 50 x 8 B = 120 MB
    columns = recording(rows)
    path = write_columns(tmp_path / "timeseries.parquet", columns)
    del columns
    series = SeriesFile(path)
    read: list[list[str]] = []
    chunks = series.chunks
    series.chunks = lambda names=None, **kw: (read.append(list(names or [])), chunks(names, **kw))[1]
    tracemalloc.start()
    try:
        assert protection_events(CELL, series) == []
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert series._loaded is None
    assert len(read) == 1 and set(read[0]) <= set(PROTECTION_SIGNALS)  # no joint angle, torque, current read
    assert peak < 12 * 2**20, peak  # a few chunks of 18 columns, not the run


def test_a_streamed_run_with_events_gives_the_events_of_the_run_in_memory(tmp_path):
    rows = 50_000
    columns = recording(rows)
    status, history = columns["drive1.limit_status"], columns["drive1.limit_history"]
    status[20_000:20_400] = 1  # torque limit for 0.4 s
    history[20_000:] = 1
    columns["drive1.tau_out"][20_000:20_400] = 40.0
    contacts = columns[f"{PLANT}.end_stop_contacts[3]"]
    contacts[45_000:] = 1  # joint 3 at its end stop from 45 s to the end
    columns[f"{PLANT}.end_stop_impact_speed[3]"][45_000:] = 0.7
    columns[f"{PLANT}.end_stop_impact_time[3]"][45_000:] = 45.0
    columns[f"{PLANT}.q[3]"][45_000:] = 10.0
    expected = protection_events(CELL, in_memory(columns))
    assert [e["kind"] for e in expected] == ["torque_limit", "end_stop"]
    assert protection_events(CELL, SeriesFile(write_columns(tmp_path / "timeseries.parquet", columns))) == expected
    history[:] = 0  # only the history's last sample shows the limit (it came and went between two samples)
    status[:] = 0
    history[-1] = 1
    contacts[:] = 0
    expected = protection_events(CELL, in_memory(columns))
    assert [e["kind"] for e in expected] == ["torque_limit"]
    assert protection_events(CELL, SeriesFile(write_columns(tmp_path / "again.parquet", columns))) == expected
