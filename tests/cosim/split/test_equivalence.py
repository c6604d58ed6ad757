"""The same scenario file in one process and split over two processes (controller |
drives + plant, python-can udp_multicast between): the same trajectory, bit for bit,
and the dead time read off each run's CAN log is the configured one."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from cosim.execution.timing.deadtime import handshake_dead_times
from cosim.results.timeseries import read_csv
from realtime_support import ROOT, write_scenario

DEAD_TIME = 2


def _run(scenario, out, *flags):
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(scenario), "--quiet", "--out", str(out), *flags],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return json.loads((out / "summary.json").read_text())


def test_split_run_gives_the_same_trajectory_and_dead_time(tmp_path):
    scenario = write_scenario(tmp_path, "80 ms", dead_time=DEAD_TIME)
    one, two = tmp_path / "one", tmp_path / "split"
    s1 = _run(scenario, one)
    s2 = _run(scenario, two, "--split")
    assert s2["execution"]["mode"] == "split"
    split = s2["execution"]["split"]["model_based"]
    assert split["drive_process_exit_code"] == 0 and split["frames_missing_controller_side"] == 0
    assert split["frames_missing_drive_side"] == 0 and split["cycles"] == 201
    m1, m2 = s1["modes"]["model_based"], s2["modes"]["model_based"]
    assert m1["motion_start_s"] is not None and m1["motion_start_s"] < 0.05   # the arm moves in this window
    assert m1["motion_start_s"] == m2["motion_start_s"]
    for name in ("timeseries_model_based.csv", "controller_model_based.csv", "tcp_model_based.csv"):
        h1, a = read_csv(one / name)
        h2, b = read_csv(two / name)
        assert h1 == h2 and a.shape == b.shape and a.shape[0] > 50, name
        keep = [i for i, c in enumerate(h1) if not c.startswith("compute")]   # wall-clock compute times differ
        np.testing.assert_array_equal(a[:, keep], b[:, keep], err_msg=name)
    h, a = read_csv(one / "timeseries_model_based.csv")
    q = a[:, [h.index(f"plant.q[{i}]") for i in range(1, 7)]]
    assert np.ptp(q[:, 0]) > 1e-4                                      # joint 1 really moved
    for fb in (m1["fieldbus"], m2["fieldbus"]):
        assert fb["frames_dropped"] == 0 and fb["event_tally"] == {} and fb["dead_time_cycles"] == DEAD_TIME
    assert m1["fieldbus"]["frames_sent"] == m2["fieldbus"]["frames_sent"]
    for out in (one, two):
        measured = handshake_dead_times(out / "can_model_based.parquet", 400e-6)
        assert len(measured) >= 3 * 6                                  # the enable handshake of six drives
        assert {d for _, _, d in measured} == {DEAD_TIME}
