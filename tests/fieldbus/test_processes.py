"""Controller and drives in two processes, talking over python-can's udp_multicast
interface: enable sequence, set-point tracking with the configured dead time, and the
simulated timestamps survive the trip."""
import json
import os
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import can
import numpy as np

from fieldbus import (DriveState, EnableSequencer, JointScaling, ManagingNodeEndpoint, Setpoints,
                      decode_statusword)

ROOT = Path(__file__).resolve().parents[2]
TRAIN = tomllib.loads((ROOT / "robot" / "rx130l_params.toml").read_text())["drive_train"]
CYCLES = 80

DRIVE_PROCESS = textwrap.dedent("""
    import json, sys
    import numpy as np
    from fieldbus import Cia402DriveModel, DriveActuals, DriveEndpoint, JointScaling
    config, train, cycles = json.loads(sys.argv[1]), json.loads(sys.argv[2]), int(sys.argv[3])
    scaling = JointScaling(train["gear_ratio"], train["encoder"], train["rated_torque"])
    drives = [Cia402DriveModel() for _ in range(6)]
    actuals = DriveActuals.zeros(6)
    with DriveEndpoint(config, scaling) as endpoint:
        print("ready", flush=True)
        for k in range(cycles):
            actuals.statusword[:] = [d.statusword for d in drives]
            applied = endpoint.run_cycle(k, actuals)
            for i, d in enumerate(drives):
                d.step(int(applied.controlword[i]), fault=bool(applied.fault_code[i]))
            actuals.position[:] = applied.position   # an ideal drive: at the target by t_k+1
        print(json.dumps({"states": [d.state.value for d in drives], "missing": endpoint.frames_missing,
                          "sent": endpoint.frames_sent}), flush=True)
""")


def test_controller_and_drives_in_separate_processes(tmp_path):
    port = 43000 + os.getpid() % 2000
    config = {"bus": {"interface": "udp_multicast", "channel": "239.74.163.3", "receive_timeout_s": 10.0,
                      "options": {"port": port}}}
    train = {"gear_ratio": TRAIN["gear_ratio"]["value"], "encoder": TRAIN["encoder_counts_per_motor_rev"]["value"],
             "rated_torque": TRAIN["rated_torque"]["value"]}
    scaling = JointScaling(train["gear_ratio"], train["encoder"], train["rated_torque"])
    child = subprocess.Popen([sys.executable, "-c", DRIVE_PROCESS, json.dumps(config), json.dumps(train), str(CYCLES)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert child.stdout.readline().strip() == "ready"
        sequencers = [EnableSequencer() for _ in range(6)]
        setpoints = Setpoints.zeros(6)
        commanded, observed_positions, states = [], [], []
        with ManagingNodeEndpoint(config, scaling, log_path=tmp_path / "mn.blf") as endpoint:
            for k in range(CYCLES):
                observed = endpoint.run_cycle(k, setpoints)
                commanded.append(setpoints.position.copy())
                observed_positions.append(observed.position.copy())
                states.append(decode_statusword(int(observed.statusword[0])))
                for i, sequencer in enumerate(sequencers):
                    setpoints.controlword[i] = sequencer.next_controlword(int(observed.statusword[i]))
                if all(decode_statusword(int(s)) is DriveState.OPERATION_ENABLED for s in observed.statusword):
                    setpoints.position[:] = 1e-3 * k * np.arange(1, 7)
            missing = endpoint.frames_missing
        out, err = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 0, err
    report = json.loads(out.strip().splitlines()[-1])
    assert report["states"] == ["Operation enabled"] * 6
    assert report["missing"] == 0 and missing == 0
    assert states[-1] is DriveState.OPERATION_ENABLED
    # the drive followed every set-point: measured at the controller two cycles later
    for k in range(CYCLES - 20, CYCLES):
        np.testing.assert_array_equal(observed_positions[k], scaling.quantise_position(commanded[k - 2]))
    # the MN side's log holds both directions with simulated timestamps
    frames = list(can.LogReader(str(tmp_path / "mn.blf")))
    assert len(frames) == CYCLES * 19
    assert frames[-1].timestamp < CYCLES * 400e-6
