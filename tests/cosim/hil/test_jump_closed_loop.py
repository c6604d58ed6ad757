"""The closed loop (controller, POWERLINK-timed bus, drive and plant FMUs, tracker) with the
controller stalling as a split controller does on a loaded host: in chosen cycles it computes
nothing and sends no PReq (the cell loses those PReqs), then answers the next cycle as a jump.
With the set-point look-ahead (k = 4) and stalls of up to 3 cycles (jumps of up to 4), the drives
take the lost set-points from their buffer, the managing node interpolates the set-points the
controller never computed, and the set-point shaper shapes over the jump: the ISO 9283
model-based TCP error is the run's without stalls to the last digit. Before the shaper knew
the jump (it shaped the new target as one sample after the last), the same stalls on the whole
path cost 0.34 mm against 0.0104 mm (the set-point shaper after a jumped cycle).

Deterministic: the stalls are injected in process (no wall clock); the served cell and the split
controller use the same managing node, controlled nodes and controller code."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from cosim.cell import link
from cosim.cli import main
from fieldbus import PowerlinkNetwork, nodes

ROOT = Path(__file__).resolve().parents[3]
STALLS = {2000: 1, 2600: 2, 3100: 3, 3700: 1, 4300: 3, 4900: 2, 5500: 3, 6100: 1}  # first cycle: cycles
SKIPPED = {start + i for start, n in STALLS.items() for i in range(n)}


def scenario(tmp_path: Path, stalls: bool) -> Path:
    text = (ROOT / "tests" / "long_forms" / "iso9283_rigid.toml").read_text()
    for pattern, new in ((r"^modes = \[.*$", 'modes = ["model_based"]'), (r'^stop_time = ".*"', 'stop_time = "2.8 s"'),
                         (r"^figures = true", "figures = false"),
                         (r"^cycle_time_us = 400.*$",
                          "cycle_time_us = 400\nsetpoint_lookahead = 4\n[fieldbus.thresholds]\ncn_loss_of_soc = 0\n"
                          'cn_loss_of_preq = 0\nmn_loss_of_pres = 0\n[fieldbus.reaction]\nmissing_setpoint = "extrapolate"')):
        text, count = re.subn(pattern, new, text, count=1, flags=re.MULTILINE)
        assert count == 1, pattern
    if stalls:  # the cell loses the PReqs of every node in the stalled cycles
        text += "\n[fieldbus.faults]\nbursts = [\n" + "".join(
            f'  {{ node = {n}, start_cycle = {s}, cycles = {c}, frames = "preq", kind = "loss" }},\n'
            for s, c in STALLS.items() for n in range(1, 7)) + "]\n"
    path = tmp_path / ("stalls.toml" if stalls else "reference.toml")
    path.write_text(text)
    return path


def run(tmp_path: Path, stalls: bool) -> dict:
    out = tmp_path / ("out_stalls" if stalls else "out_reference")
    assert main(["run", str(scenario(tmp_path, stalls)), "--out", str(out), "--quiet"]) == 0
    return json.loads((out / "summary.json").read_text())


def test_stalls_covered_by_the_lookahead_cost_nothing_in_the_closed_loop(tmp_path, monkeypatch):
    reference = run(tmp_path, stalls=False)
    steps: list[int] = []
    send = nodes.ManagingNode._lookahead_frames
    call = link.FieldbusLink.__call__

    def lookahead_frames(self, cycle, build=True):  # a stalled controller sends nothing in its skipped cycles
        return self._frames_sent if cycle in SKIPPED else send(self, cycle, build)

    def cycle(self, t):  # ... and does not compute the set-points for them
        if self.cycle + 1 not in SKIPPED:
            steps.append(self.cycle)
            return call(self, t)
        port = self.port
        port.step = lambda *args: self.setpoints
        try:
            return call(self, t)
        finally:
            del port.step

    monkeypatch.setattr(nodes.ManagingNode, "_lookahead_frames", lookahead_frames)
    monkeypatch.setattr(link.FieldbusLink, "__call__", cycle)
    stalled = run(tmp_path, stalls=True)
    assert stalled["status"] == "ok"
    assert len(steps) > 6000 and not SKIPPED & {k + 1 for k in steps}
    tally = stalled["modes"]["model_based"]["fieldbus"]["event_tally"]
    assert tally["cn.loss_of_preq.error"] == tally["mn.loss_of_pres.error"] == 6 * len(SKIPPED)
    a, b = reference["modes"]["model_based"], stalled["modes"]["model_based"]
    assert b["tcp_error_max_mm"] == a["tcp_error_max_mm"]
    assert abs(b["tcp_error_rms_mm"] - a["tcp_error_rms_mm"]) < 1e-3 * a["tcp_error_rms_mm"]


# ---------------------------------------------------------------------------------------------
# Set-point buffer ([fieldbus] setpoint_buffer = 64, CiA 402 0x60C4): stalls of tens of cycles

BUFFER = ("cycle_time_us = 400\nsetpoint_lookahead = 4\nsetpoint_buffer = 64\n[fieldbus.thresholds]\n"
          'cn_loss_of_soc = 0\ncn_loss_of_preq = 0\nmn_loss_of_pres = 0\n[fieldbus.reaction]\nmissing_setpoint = "extrapolate"')


def buffered_scenario(tmp_path: Path, name: str, stalls: dict[int, int]) -> Path:
    text = (ROOT / "tests" / "long_forms" / "iso9283_rigid.toml").read_text()
    for pattern, new in ((r"^modes = \[.*$", 'modes = ["model_based"]'), (r'^stop_time = ".*"', 'stop_time = "2.8 s"'),
                         (r"^figures = true", "figures = false"), (r"^cycle_time_us = 400.*$", BUFFER)):
        text, count = re.subn(pattern, new, text, count=1, flags=re.MULTILINE)
        assert count == 1, pattern
    if stalls:
        text += "\n[fieldbus.faults]\nbursts = [\n" + "".join(
            f'  {{ node = {n}, start_cycle = {s}, cycles = {c}, frames = "preq", kind = "loss" }},\n'
            for s, c in stalls.items() for n in range(1, 7)) + "]\n"
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


def run_stalled(tmp_path: Path, name: str, stalls: dict[int, int], monkeypatch) -> dict:
    """The closed loop with the controller stalled in ``stalls`` (first cycle: cycles): it computes
    and sends nothing there, then, as the split controller does (cosim.execution.split.paced), computes the
    outputs of the cycles it skipped into the managing node's plan
    (``ManagingNodeEndpoint.plan_ahead``) before its step for the current cycle."""
    skipped = {start + i for start, n in stalls.items() for i in range(n)}
    send = nodes.ManagingNode._lookahead_frames
    call = link.FieldbusLink.__call__
    last_run = [-1]

    def lookahead_frames(self, cycle, build=True):  # nothing sent, nothing planned in a stalled cycle
        return self._frames_sent if build and cycle in skipped else send(self, cycle, build)

    def cycle(self, t):
        port = self.port
        if self.cycle + 1 in skipped:  # this controller cycle does not run
            port.step = lambda *args: self.setpoints
            try:
                return call(self, t)
            finally:
                del port.step
        pending = range(last_run[0] + 1, self.cycle)
        last_run[0] = self.cycle
        if not pending:
            return call(self, t)
        real = port.step

        def step(k, t_k, observed, *args):
            for j in pending:
                self.network.mn_side.plan_ahead(j + 1, real(j, j * self.period_s, observed))
            return real(k, t_k, observed, *args)

        port.step = step
        try:
            return call(self, t)
        finally:
            del port.step

    if stalls:
        monkeypatch.setattr(nodes.ManagingNode, "_lookahead_frames", lookahead_frames)
        monkeypatch.setattr(link.FieldbusLink, "__call__", cycle)
    networks: list[dict] = []
    summary = PowerlinkNetwork.summary
    monkeypatch.setattr(PowerlinkNetwork, "summary", lambda self: networks.append(summary(self)) or networks[-1])
    out = tmp_path / f"out_{name}"
    try:
        assert main(["run", str(buffered_scenario(tmp_path, name, stalls)), "--out", str(out), "--quiet"]) == 0
    finally:
        monkeypatch.undo()
    result = json.loads((out / "summary.json").read_text())
    result["network"] = networks[-1]  # the whole fieldbus summary (summary.json keeps a digest)
    return result


def test_a_stall_within_the_set_point_buffer_costs_nothing_and_a_longer_one_falls_back(tmp_path, monkeypatch):
    reference = run_stalled(tmp_path, "reference", {}, monkeypatch)
    within = run_stalled(tmp_path, "within", {2500: 40, 4500: 25}, monkeypatch)
    beyond = run_stalled(tmp_path, "beyond", {2500: 90}, monkeypatch)
    a, b, c = (s["modes"]["model_based"] for s in (reference, within, beyond))
    assert within["status"] == beyond["status"] == "ok"
    # 65 cycles of lost PReqs (26 ms), every one counted, none costing anything
    tally = b["fieldbus"]["event_tally"]
    assert tally["cn.loss_of_preq.error"] == tally["mn.loss_of_pres.error"] == 6 * 65
    buffer = within["network"]["setpoint_lookahead"]
    base = reference["network"]["setpoint_lookahead"]["cycles_without_setpoint_per_node"]
    assert buffer["cycles_covered_per_node"] == {str(n): 65 for n in range(1, 7)}
    assert buffer["cycles_without_setpoint_per_node"] == base
    assert b["tcp_error_max_mm"] == a["tcp_error_max_mm"] and b["tcp_error_rms_mm"] == a["tcp_error_rms_mm"]
    # 90 cycles (36 ms) > 64: the drives apply the buffer's 64 exactly, then the missing-set-point
    # reaction for the rest (counted per node), and the path error shows it
    held = beyond["network"]["setpoint_lookahead"]
    assert held["cycles_covered_per_node"] == {str(n): 64 for n in range(1, 7)}
    assert {k: v - base[k] for k, v in held["cycles_without_setpoint_per_node"].items()} == {
        str(n): 90 - 64 for n in range(1, 7)}
    assert c["tcp_error_max_mm"] > 10 * a["tcp_error_max_mm"]
