"""The split controller side's bookkeeping (cosim/execution/split/paced.py): preallocated per-cycle
timing, its report, and the attribution of every cycle the cell lost to the cell, the
controller (not running / its own work) or the transport."""
from __future__ import annotations

import numpy as np
import pytest

from cosim.execution.split.paced import CONTROLLER_SPIN_S, LOST_CAUSES, ControllerTimes, controller_spin_s, lost_cycle_causes

PERIOD = 400e-6
US = 1000  # ns


def times_of(rows: list[tuple[int, ...]]) -> ControllerTimes:
    t = ControllerTimes(len(rows) + 4)
    for row in rows:
        t.add(*row)
    return t


def test_times_are_preallocated_and_reported():
    t = ControllerTimes(3)
    buffer = t.data
    t.add(0, 300 * US, 20 * US, 25 * US, 44 * US, 5 * US)
    t.add(1, 350 * US, 18 * US, 22 * US, 39 * US, 600 * US)  # its PRes waited 600 us in the socket
    t.add(3, 10 * US, 500 * US, 20 * US, 515 * US, -1)  # a step of 520 us, CPU bound
    t.add(4, 1, 1, 1, 1, 1)  # beyond the capacity: ignored, no reallocation
    assert t.data is buffer and t.count == 3
    np.testing.assert_array_equal(t.column("cycle"), [0, 1, 3])
    r = t.report(PERIOD)
    assert r["compute"]["max_us"] == pytest.approx(520.0) and r["compute"]["max_at_cycle"] == 3
    assert r["compute_step"]["p50_us"] == pytest.approx(20.0)
    assert r["compute_over_one_cycle"] == {"stalled": 0, "own_work": 1}
    assert r["stalls_over_one_cycle"] == 1
    assert r["wakeup_after_pres"]["max_us"] == pytest.approx(600.0)  # the unknown (-1) is left out


def test_lost_cycles_are_attributed_to_one_cause_each():
    grid = int(PERIOD * 1e9)

    def row(cycle, step, cpu, woke, pres_late=0):
        """Answered PRes of ``cycle`` (arrived 50 us into the cycle + ``pres_late``), 20 us send."""
        return cycle, 0, step * US, 20 * US, cpu * US, woke * US, cycle * grid + (50 + pres_late) * US

    rows = [
        row(9, 20, 40, 10),  # answers PRes 9 promptly -> lost 10: transport
        row(19, 20, 40, 900),  # PRes 19 waited 900 us -> lost 20: stalled
        row(29, 600, 610, 10),  # 620 us of own CPU work -> lost 30: compute
        row(39, 600, 50, 10),  # 620 us wall, 50 us CPU -> lost 40: stalled
        row(48, 700, 710, 10),  # long CPU step, PRes 49 never answered -> lost 50: compute
        row(50, 20, 40, 500),
        row(58, 20, 40, 10),  # PRes 59 never answered after a short step -> lost 60: stalled
        row(60, 20, 40, 2000),
        row(69, 20, 40, 10),  # -> lost 70, but the cell overran
        row(79, 20, 40, 10, pres_late=700),  # the cell's PRes came 700 us late -> lost 80: cell late
    ] + [row(k, 20, 40, 10) for k in range(100, 130)]  # the run's usual arrivals
    lost = [{"cycle": k} for k in (10, 20, 30, 40, 50, 60, 70, 80)]
    causes = lost_cycle_causes(lost, {70}, times_of(rows), PERIOD)
    assert set(LOST_CAUSES) <= set(causes)
    assert causes["examples"] == {"transport": [10], "controller_stalled": [20, 40, 60],
                                  "controller_compute": [30, 50], "cell_late": [70, 80]}
    assert (causes["transport"], causes["controller_stalled"], causes["controller_compute"],
            causes["cell_late"]) == (1, 3, 2, 2)
    empty = lost_cycle_causes([], set(), ControllerTimes(1), PERIOD)
    assert all(empty[k] == 0 for k in LOST_CAUSES) and empty["examples"] == {}


def test_controller_spin_has_a_default_and_an_override(monkeypatch):
    monkeypatch.delenv("COSIM_HIL_CONTROLLER_SPIN", raising=False)
    assert controller_spin_s() == CONTROLLER_SPIN_S
    monkeypatch.setenv("COSIM_HIL_CONTROLLER_SPIN", "0")
    assert controller_spin_s() == 0.0
    monkeypatch.setenv("COSIM_HIL_CONTROLLER_SPIN", "120")
    assert controller_spin_s() == pytest.approx(120e-6)
    for bad in ("fast", "-5", "20000"):
        monkeypatch.setenv("COSIM_HIL_CONTROLLER_SPIN", bad)
        with pytest.raises(ValueError, match="COSIM_HIL_CONTROLLER_SPIN"):
            controller_spin_s()
