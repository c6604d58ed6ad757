"""Co-simulation master overhead: the main job's FMU set (plant + six drives) stepped four ways.

Setup (what the ISO 9283 job runs, without bus and controller work): the rx130l_plant
FMU and six servo_drive FMUs; connections drive_i.tau_out -> plant.tau[i] and
plant.q[i]/qd[i] -> drive_i.q_meas/qd_meas (6 to the plant, 12 back); a 400 us Python
task writes the six target positions, torque offsets and controlwords (CiA 402 enable
sequence, then hold the start pose). Every FMU steps at the macro step.

Ways to step the same thing (same FMUs, same connections, same task):
  fmpy_api     hand-written loop over fmpy's FMU2Slave.setReal/getReal/doStep
  fast_fmu     hand-written loop over fmus.fmu.Fmu (the one FMU class: prepared I/O arrays)
  master_py    cosim.master.Master, Python engine (ctypes call per FMI function)
  master_c     cosim.master.Master, compiled kernel (one ctypes call per stretch of steps)
  master_c3    the same with the FMI 3.0 builds of the plant and drives (build/fmus/fmi3/),
               stepped by the kernel through the master's FMI 3.0 adapter (fmi3_adapter.c)
"FMU compute" is the wall time spent inside the FMUs' fmi2DoStep, timed by the kernel
(clock_gettime around each call) during the master_c runs; "overhead" = a way's wall
time minus that compute, per FMU and macro step: what the loop around the FMUs (I/O
calls, connection copies, the 400 us Python task) costs.

Prints, per macro step (100/200/400 us), the median over REPEATS runs of SIM_TIME_S of:
wall us per macro step, us per macro step per FMU, speed-up over fmpy_api, real-time
factor, overhead per FMU and macro step.
Run: python benchmarks/bench_master.py [--sim-time 0.2] [--repeats 5]
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from cosim.master import Master
from fmus.build import ensure_fmus
from fmus.fmu import Fmu
from fmus.servo_drive.params import drive_start_values

Q0 = (0.0, -0.3, 1.2, 0.0, 0.6, 0.0)  # start pose, rad
CONTROL_PERIOD = 4e-4  # s
ENABLE = (0x06, 0x07, 0x0F)  # CiA 402 shutdown, switch on, enable operation
N_FMUS = 7
DRIVE_IN = ("target_position", "torque_offset", "q_meas", "qd_meas")
DRIVE_OUT = ("tau_out", "position_actual", "velocity_actual", "current_actual", "current_demand", "torque_actual",
             "following_error")


def controlword(cycle: int) -> int:
    """Controlword of the enable sequence at controller cycle ``cycle``."""
    return ENABLE[min(cycle, len(ENABLE) - 1)]


def plant_start() -> dict[str, float]:
    return {f"q0[{i + 1}]": q for i, q in enumerate(Q0)}


# ----------------------------------------------------------------------------- master
def run_master(paths, h: float, sim_time: float, engine: str) -> tuple[float, float]:
    """(wall s, s spent inside fmi2DoStep) to simulate sim_time with the master (profiled)."""
    m = Master(h, engine=engine, profile=True)
    m.add_fmu("plant", paths["rx130l_plant"], start_values=plant_start())
    for i in range(1, 7):
        m.add_fmu(f"drive{i}", paths["servo_drive"], start_values=drive_start_values(i))
    targets = m.add_variables("ctrl", [f"target[{i}]" for i in range(1, 7)])
    offsets = m.add_variables("ctrl", [f"offset[{i}]" for i in range(1, 7)])
    words = m.add_variables("ctrl", [f"cw[{i}]" for i in range(1, 7)], type="Integer")
    for i in range(1, 7):
        m.connect(f"drive{i}.tau_out", f"plant.tau[{i}]")
        m.connect(f"plant.q[{i}]", f"drive{i}.q_meas")
        m.connect(f"plant.qd[{i}]", f"drive{i}.qd_meas")
        m.connect(targets[i - 1], f"drive{i}.target_position")
        m.connect(offsets[i - 1], f"drive{i}.torque_offset")
        m.connect(words[i - 1], f"drive{i}.controlword")
    io = {}
    state = {"cycle": 0}

    def setup(master):
        io["target"] = master.view(targets, writable=True)
        io["cw"] = master.view(words, writable=True)
        io["q"] = master.view([f"plant.q[{i}]" for i in range(1, 7)])

    def controller(t):
        io["target"][:] = Q0
        io["cw"][:] = controlword(state["cycle"])
        state["cycle"] += 1

    m.add_task(controller, CONTROL_PERIOD, setup=setup, name="controller")
    with m:
        m.initialize(sim_time)
        w0 = time.perf_counter()
        m.run()
        wall = time.perf_counter() - w0
        assert np.all(np.abs(io["q"] - Q0) < 0.05), io["q"]  # the drives hold the pose
        compute = sum(m.fmu_step_seconds.values())
    return wall, compute


# ----------------------------------------------------------------------------- fmpy API
def run_fmpy_api(paths, h: float, sim_time: float) -> float:
    """The same loop written against fmpy's FMU2Slave API (Jacobi, like the master)."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    def make(path, name, start):
        md = read_model_description(str(path))
        slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        vr = {v.name: v.valueReference for v in md.modelVariables}
        for k, v in start.items():
            (slave.setInteger if isinstance(v, int) else slave.setReal)([vr[k]], [v])
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        return slave, vr

    plant, pvr = make(paths["rx130l_plant"], "plant", plant_start())
    drives = [make(paths["servo_drive"], f"drive{i}", drive_start_values(i)) for i in range(1, 7)]
    tau_vr = [pvr[f"tau[{i}]"] for i in range(1, 7)]
    qqd_vr = [pvr[f"q[{i}]"] for i in range(1, 7)] + [pvr[f"qd[{i}]"] for i in range(1, 7)]
    din = [[d[1][n] for n in DRIVE_IN] for d in drives]
    dout = [[d[1][n] for n in DRIVE_OUT] for d in drives]
    dcw = [[d[1]["controlword"]] for d in drives]
    dsw = [[d[1]["statusword"]] for d in drives]
    n_steps = round(sim_time / h)
    k_ctrl = round(CONTROL_PERIOD / h)
    qqd = plant.getReal(qqd_vr)
    taus = [d[0].getReal(dout[i])[0] for i, d in enumerate(drives)]
    cycle = 0
    cw = 0
    w0 = time.perf_counter()
    for n in range(n_steps):
        t = n * h
        if n % k_ctrl == 0:
            cw = controlword(cycle)
            cycle += 1
        plant.setReal(tau_vr, taus)
        for i, (slave, _) in enumerate(drives):
            slave.setReal(din[i], [Q0[i], 0.0, qqd[i], qqd[6 + i]])
            slave.setInteger(dcw[i], [cw])
        plant.doStep(t, h)
        for slave, _ in drives:
            slave.doStep(t, h)
        qqd = plant.getReal(qqd_vr)
        for i, (slave, _) in enumerate(drives):
            taus[i] = slave.getReal(dout[i])[0]
            slave.getInteger(dsw[i])
    wall = time.perf_counter() - w0
    assert max(abs(qqd[i] - Q0[i]) for i in range(6)) < 0.05
    for slave, _ in [(plant, None), *drives]:
        slave.terminate()
        slave.freeInstance()
    return wall


# ----------------------------------------------------------------------------- Fmu hand loop
def run_fast_fmu(paths, h: float, sim_time: float) -> float:
    """The same loop over fmus.fmu.Fmu's prepared I/O arrays."""
    plant = Fmu(paths["rx130l_plant"], "plant", plant_start(),
                real_inputs=[f"tau[{i}]" for i in range(1, 7)],
                real_outputs=[f"q[{i}]" for i in range(1, 7)] + [f"qd[{i}]" for i in range(1, 7)]).start()
    drives = [Fmu(paths["servo_drive"], f"drive{i}", drive_start_values(i), real_inputs=DRIVE_IN,
                  real_outputs=DRIVE_OUT, integer_inputs=["controlword"], integer_outputs=["statusword"]).start()
              for i in range(1, 7)]
    n_steps = round(sim_time / h)
    k_ctrl = round(CONTROL_PERIOD / h)
    tau = np.zeros(6)
    din = np.zeros(4)
    cw = np.zeros(1, dtype=np.int32)
    qqd = plant.get_outputs().copy()
    cycle = 0
    w0 = time.perf_counter()
    for n in range(n_steps):
        t = n * h
        if n % k_ctrl == 0:
            cw[0] = controlword(cycle)
            cycle += 1
        plant.set_inputs(tau)
        for i, d in enumerate(drives):
            din[0], din[1], din[2], din[3] = Q0[i], 0.0, qqd[i], qqd[6 + i]
            d.set_inputs(din)
            d.set_integer_inputs(cw)
        plant.do_step(t, h)
        for d in drives:
            d.do_step(t, h)
        qqd = plant.get_outputs()
        for i, d in enumerate(drives):
            tau[i] = d.get_outputs()[0]
            d.get_integer_outputs()
    wall = time.perf_counter() - w0
    assert np.all(np.abs(qqd[:6] - Q0) < 0.05)
    for s in [plant, *drives]:
        s.close()
    return wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sim-time", type=float, default=0.2, help="simulated seconds per run")
    parser.add_argument("--repeats", type=int, default=5, help="runs per case (median reported)")
    args = parser.parse_args()
    paths = ensure_fmus()
    paths3 = ensure_fmus(fmi=3)
    cases = {
        "fmpy_api": lambda p, h, s: (run_fmpy_api(p, h, s), None),
        "fast_fmu": lambda p, h, s: (run_fast_fmu(p, h, s), None),
        "master_py": lambda p, h, s: run_master(p, h, s, "python"),
        "master_c": lambda p, h, s: run_master(p, h, s, "native"),
        "master_c3": lambda p, h, s: run_master(paths3, h, s, "native"),
    }
    print(f"plant + 6 drives, 18 FMU-FMU connections + 18 task->drive, 400 us task; "
          f"{args.sim_time} s simulated, median of {args.repeats} (ways interleaved)")
    print(f"{'step':>6} {'way':>10} {'us/step':>8} {'us/step/FMU':>12} {'x fmpy_api':>10} {'real-time x':>11} "
          f"{'overhead us/FMU/step':>21}")
    for h in (1e-4, 2e-4, 4e-4):
        n_steps = round(args.sim_time / h)
        walls = {name: [] for name in cases}
        computes = []
        for _ in range(args.repeats):
            for name, fn in cases.items():
                wall, compute = fn(paths, h, args.sim_time)
                walls[name].append(wall)
                if name == "master_c":
                    computes.append(compute)
        med = {name: statistics.median(w) for name, w in walls.items()}
        compute = statistics.median(computes)  # s inside the FMUs' fmi2DoStep, measured in C
        for name, wall in med.items():
            per_step = wall / n_steps * 1e6
            overhead = (wall - compute) / n_steps / N_FMUS * 1e6
            print(f"{h * 1e6:>4.0f}us {name:>10} {per_step:>8.1f} {per_step / N_FMUS:>12.2f} "
                  f"{med['fmpy_api'] / wall:>10.1f} {args.sim_time / wall:>11.1f} {overhead:>21.2f}")
        print(f"{'':>6} {'FMU compute':>10} {compute / n_steps * 1e6:>8.1f} {compute / n_steps / N_FMUS * 1e6:>12.2f}"
              f"   (time inside fmi2DoStep, timed in the kernel during the master_c runs)")


if __name__ == "__main__":
    main()
