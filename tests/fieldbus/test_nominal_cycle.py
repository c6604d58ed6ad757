"""The network's inline nominal cycle (``PowerlinkNetwork._run_nominal``) gives exactly what the
endpoints' phases give: every frame on the wire (time, id, bytes, in order), every applied and
observed value, every event and counter, over clean cycles and cycles with injected faults,
latched node faults, fault resets, saturating values and changing modes."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fieldbus import DriveActuals, PowerlinkNetwork, Setpoints
from fieldbus.codec import load_codec
from fieldbus_support import ENABLED, FAULT_CONFIGS, scaling


CONFIGS = {**FAULT_CONFIGS,
           "quick stop, silent node": {"reaction": {"abort_connection_option": "quick_stop"},
                                       "faults": {"silent_nodes": [{"node": 4, "from_cycle": 30, "until_cycle": 60}]}}}

needs_codec = pytest.mark.skipif(load_codec() is None, reason="no C compiler / Python headers for the fieldbus codec")


def trace(config: dict, cycles: int, nominal: bool, tmp_path: Path) -> tuple[list, list, dict, list, int]:
    """Per cycle the applied and observed values; every recorded frame; the summary; the
    events; how many cycles the inline path ran."""
    rng = np.random.default_rng(3)
    setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
    actuals.statusword[:] = ENABLED
    out, frames = [], []
    with PowerlinkNetwork(config, scaling(), log_path=tmp_path / f"can_{nominal}.blf") as network:
        network.nominal_path = nominal and network.nominal_path
        record = network.recorder.add_many

        def spy(msgs):
            frames.extend((m.timestamp, m.arbitration_id, m.is_error_frame, bytes(m.data)) for m in msgs)
            record(msgs)

        network.mn_side._record = network.drive_side._record = spy
        inline = network._run_nominal
        taken = [0]

        def counted(*args):
            result = inline(*args)
            taken[0] += result is not None
            return result

        network._run_nominal = counted
        for k in range(cycles):
            setpoints.controlword[:] = 0x8F if k % 97 == 50 else 0x0F  # fault resets
            setpoints.position[:] = rng.normal(0.0, 1.0, 6)
            setpoints.torque_offset[:] = rng.normal(0.0, 100.0, 6)
            setpoints.modes_of_operation[:] = rng.integers(8, 11, 6) if k % 50 < 25 else 8
            setpoints.target_velocity[:] = rng.normal(0.0, 2.0, 6)
            setpoints.velocity_offset[:] = rng.normal(0.0, 0.5, 6)
            setpoints.target_torque[:] = rng.normal(0.0, 100.0, 6)
            actuals.position[:] = rng.normal(0.0, 1.0, 6)
            actuals.velocity[:] = rng.normal(0.0, 2.0, 6)
            actuals.torque[:] = rng.normal(0.0, 100.0, 6)
            actuals.modes_of_operation_display[:] = rng.integers(8, 11, 6)
            if k % 53 == 7:  # beyond the telegram ranges: saturated on both sides
                setpoints.torque_offset[2] = 1e6
                actuals.velocity[4] = -1e9
            result = network.run_cycle(k, setpoints, actuals)
            out.append((result.cycle, result.time_s, result.applied.copy(), result.observed.copy()))
        summary = network.summary()
        events = [e.as_dict() for e in network.events.events]
    return out, frames, summary, events, taken[0]


@needs_codec
@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_inline_nominal_cycle_equals_the_endpoints(name, tmp_path):
    cycles = 300
    fast, fast_frames, fast_summary, fast_events, taken = trace(CONFIGS[name], cycles, True, tmp_path)
    slow, slow_frames, slow_summary, slow_events, none = trace(CONFIGS[name], cycles, False, tmp_path)
    assert none == 0
    if name == "clean":
        assert taken == cycles
    else:  # both paths ran
        assert 0.3 * cycles < taken < cycles
        assert fast_events and any(e["event"] == "injected" for e in fast_events)
    assert len(fast_frames) > 15 * cycles
    assert fast_frames == slow_frames
    assert fast_events == slow_events
    fast_summary.pop("log_path")
    slow_summary.pop("log_path")
    assert fast_summary == slow_summary
    for (fc, ft, fa, fo), (sc, st, sa, so) in zip(fast, slow):
        assert (fc, ft) == (sc, st)
        for field in ("controlword", "position", "torque_offset", "fresh", "comm_fault", "fault_code",
                      "modes_of_operation", "target_velocity", "velocity_offset", "target_torque"):
            np.testing.assert_array_equal(getattr(fa, field), getattr(sa, field), err_msg=f"cycle {fc} applied.{field}")
        for field in ("statusword", "position", "velocity", "torque", "error_code", "fresh", "node_fault",
                      "modes_of_operation_display"):
            np.testing.assert_array_equal(getattr(fo, field), getattr(so, field), err_msg=f"cycle {fc} observed.{field}")
    assert (tmp_path / "can_True.blf").read_bytes() == (tmp_path / "can_False.blf").read_bytes()


@needs_codec
def test_inline_nominal_cycle_leaves_errors_to_the_endpoints():
    """Cycles out of order and set-points of the wrong type: the endpoints raise, as without it."""
    with PowerlinkNetwork({}, scaling()) as network:
        assert network.nominal_path
        setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
        network.run_cycle(0, setpoints, actuals)
        with pytest.raises(ValueError, match="cycles run consecutively"):
            network.run_cycle(2, setpoints, actuals)
    with PowerlinkNetwork({}, scaling()) as network:
        setpoints = Setpoints.zeros(6)
        setpoints.controlword = setpoints.controlword.astype(float)
        with pytest.raises(ValueError, match="setpoints.controlword has dtype float64"):
            network.run_cycle(0, setpoints, actuals)


def test_inline_nominal_cycle_only_where_it_applies():
    with PowerlinkNetwork({"bus": {"interface": "virtual"}}, scaling()) as network:
        assert not network.nominal_path
    with PowerlinkNetwork({"setpoint_lookahead": 2}, scaling()) as network:
        assert not network.nominal_path


@needs_codec
def test_a_fault_plan_installed_later_is_asked_every_cycle(tmp_path):
    """A plan wrapper given to both endpoints after construction (as cosim.execution.timing's overrun
    policy does) takes its cycles away from the inline path: the PReqs it drops are lost."""
    from fieldbus.faults import CycleFaults

    class LosePreqs:
        def __init__(self, base, cycles):
            self.base, self.cycles = base, cycles

        def for_cycle(self, cycle):
            if cycle not in self.cycles:
                return self.base.for_cycle(cycle)
            return CycleFaults(cycle, {node: "loss" for node in range(1, 7)})

    counts = []
    for nominal in (True, False):
        with PowerlinkNetwork({}, scaling()) as network:
            network.nominal_path = nominal
            plan = LosePreqs(network.mn_side.plan, {20, 21})
            network.mn_side.plan = network.drive_side.plan = plan
            setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
            for k in range(40):
                network.run_cycle(k, setpoints, actuals)
            counts.append(network.summary()["counters"])
    assert counts[0] == counts[1]
    assert all(c["cumulative"] == 2 for c in counts[0] if c["kind"] == "loss_of_preq")
