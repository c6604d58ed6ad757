"""A user's controller talks SDO and NMT to the drives through its contract (``info.asynchronous``,
controller/contract.py): the requests it makes in one cycle go out in the next cycle's asynchronous
slot, the answers are there a cycle later, a written following-error window reads back, an NMT
command to a node that is not on the bus is counted; in one process and split over two processes
alike."""
from __future__ import annotations

import json
import re

import pytest

from cosim.cli import main
from realtime_support import short_scenario_text

TALKER = '''
import json
from controller import ControllerOutput
from controller.tracking_clock import TrackingClock


class Talker:
    def __init__(self, out=""):
        self.path, self.log = out, []

    def setup(self, info):
        self.sdo = info.asynchronous
        self.clock = TrackingClock(info, settle_time_s=0.01)
        self.out = ControllerOutput.zeros(info.n_joints)
        self.pending = []

    def step(self, inputs):
        tau = self.clock.update(inputs, self.out.controlword)
        self.out.target_position[:] = self.clock.reference(tau)[0]
        if inputs.cycle == 10:
            self.pending = [self.sdo.sdo_write(3, 0x6065, 0, 40000), self.sdo.sdo_read(3, 0x6065),
                            self.sdo.sdo_write(3, 0x6072, 0, 100), self.sdo.nmt(42, "stop")]
        for r in self.pending:
            if r.answered_cycle is not None and r.answered_cycle >= 0 and not any(e[0] == id(r) for e in self.log):
                self.log.append((id(r), inputs.cycle, r.sent_cycle, r.answered_cycle, r.answer, r.abort))
        return self.out

    def close(self):
        with open(self.path, "w") as handle:
            json.dump([e[1:] for e in self.log], handle)

    motion_start_s = property(lambda self: self.clock.motion_start_s)
'''


def _run(tmp_path, name, *flags):
    (tmp_path / "my_ctrl.py").write_text(TALKER)
    out = tmp_path / f"{name}.json"
    text = short_scenario_text("40 ms", name="talker", extra=f'[controller.parameters]\nout = "{out}"\n')
    text, n = re.subn(r'modes = \["model_based"\]', 'class = "my_ctrl.py:Talker"', text, count=1)
    assert n == 1
    path = tmp_path / "talker.toml"
    path.write_text(text)
    assert main(["run", str(path), "--out", str(tmp_path / name), "--quiet", *flags]) == 0
    summary = json.loads((tmp_path / name / "summary.json").read_text())
    (mode,) = summary["modes"].values()
    return json.loads(out.read_text()), mode["fieldbus"]["asynchronous"]


@pytest.mark.parametrize("flags", [(), ("--split",)], ids=["in_process", "split"])
def test_a_controller_issues_sdo_and_nmt_and_reads_the_answers(tmp_path, flags):
    seen, summary = _run(tmp_path, "run", *flags)
    write, read, fixed, nmt = sorted(seen, key=lambda e: e[1])
    # (the cycle the controller saw it, sent, answered, answer, abort): asked in cycle 10, out in 11
    assert write[1:] == [11, 12, "ok", None] and write[0] == 12
    assert read[1:] == [13, 14, 40000, None]
    assert fixed[1:] == [15, 16, None, 0x08000020]  # 0x6072 is fixed while the drive runs
    assert nmt[1:] == [17, 17, "no node", None]
    assert summary["bad_input"]["nmt_to_missing_node"] == 1
    assert [r["origin"] for r in summary["results"]] == ["controller"] * 4
    if flags:
        one = _run(tmp_path, "one")
        assert one == (seen, summary)
