"""benchmarks/bench_hil.py: how the deliberately late controller's planned cycles are judged against
what POWERLINK specifies (the real-clock benchmark; the virtual-clock test is tests/fieldbus/test_paced_cell_side.py)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("bench_hil_for_test", ROOT / "benchmarks" / "bench_hil.py")
bench_hil = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_hil)


def _lost(value):
    return {"loss_of_preq": [value] * 6, "loss_of_soc": [value] * 6}


def test_expected_counters_count_up_8_down_1_and_trip_at_the_second_lost_cycle_in_a_row():
    e = bench_hil.expected_counters([10, 20, 30, 31], 40)
    assert e["errors"] == {10: 8, 20: 8, 30: 8, 31: 16} and e["trips"] == [31]
    assert bench_hil.expected_counters([10, 12], 20) == {"errors": {10: 8, 12: 15}, "trips": [12]}


def test_judging_exact_differs_and_each_not_judged_reason():
    soc = set(range(200)) - {50, 100, 101, 150, 160, 169, 170}
    pres = set(range(200))
    observed = {50: _lost(8), 100: _lost(8), 101: _lost(16), 150: _lost(8), 160: _lost(8), 169: _lost(8)}
    trips = {101: set(range(1, 7))}
    cell_late = {149: 420.0}  # the cell started cycle 149 late: 150 not judged
    rows = bench_hil.judge_late_cycles([50, 100, 101, 150, 170, 180], observed, trips, soc, pres, cell_late, 15,
                                       faulted={180})
    status = {r["cycle"]: r["status"] for r in rows}
    assert status[50] == status[100] == status[101] == "exact"
    assert status[150] == bench_hil.NOT_JUDGED and rows[3]["cell_lateness_us"] == [420.0, None]
    assert status[170] == bench_hil.NOT_JUDGED_NO_GROUP  # 169 lost (a stall) right before
    assert status[180] == bench_hil.NOT_JUDGED_FAULTED
    # a planned cycle the cell did not count as lost although it was in time for it: DIFFERS
    rows = bench_hil.judge_late_cycles([60], {}, {}, soc | {60}, pres, {}, 15)
    assert rows[0]["status"] == "DIFFERS" and rows[0]["observed_loss_of_preq_counters"] is None


def test_expected_counter_includes_the_stalls_lost_just_before():
    soc = set(range(100)) - {40, 45}
    rows = bench_hil.judge_late_cycles([45], {40: _lost(8), 45: _lost(11)}, {}, soc, set(range(100)), {}, 15)
    assert rows[0]["expected_counter"] == 8 - 4 + 8 and rows[0]["status"] == "DIFFERS"  # 11 observed, 12 expected
    rows = bench_hil.judge_late_cycles([45], {40: _lost(8), 45: _lost(12)}, {}, soc, set(range(100)), {}, 15)
    assert rows[0]["status"] == "exact"
