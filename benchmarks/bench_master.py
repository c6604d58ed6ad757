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

Section ``engines``: the main job's ``export-ssp`` archive (plant + six drives, the cell's 18
FMU-to-FMU connections, the bus inputs at their start values) run unchanged by three engines
at the archive's step (100 us), ENGINES_SIM_TIME_S each, interleaved: our master (compiled
kernel, the archive read by cosim.ssp.load_ssp), libcosim (libcosimpy, step from the archive's
osp:FixedStepAlgorithm) and Ecos (ecospy, parameter set initialValues). Timed: the stepping
only (loading, instantiation and initialization before the clock starts). Prints the median
wall and CPU us per macro step (CPU: all threads of this process; libcosim and Ecos step FMUs
on worker threads) and the largest |q| difference of each engine's plant from ours at the end.
Run: python benchmarks/bench_master.py [--sim-time 0.2] [--repeats 5] [--section all|ways|engines]
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

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


# ----------------------------------------------------------------------------- other engines
ENGINES_SIM_TIME_S = 2.0
Q_NAMES = [f"q[{i}]" for i in range(1, 7)]


def export_main_job(folder: Path) -> Path:
    """The main job's archive, as ``python -m cosim export-ssp scenarios/iso9283.toml`` writes it."""
    from cosim.cell.ssp_export import export_ssp

    return export_ssp(Path(__file__).resolve().parents[1] / "scenarios" / "iso9283.toml", folder / "iso9283.ssp")


def _timed(step) -> tuple[float, float]:
    w0, c0 = time.perf_counter(), time.process_time()
    step()
    return time.perf_counter() - w0, time.process_time() - c0


def run_ours_on_archive(archive: Path, sim_time: float) -> tuple[float, float, list[float]]:
    """(wall s, CPU s, plant q at the end): our master, compiled kernel, on the archive's FMUs and connections."""
    from cosim.ssp import load_ssp

    system = load_ssp(archive)
    m = Master(system.macro_step, engine="native")
    for f in system.fmus:
        m.add_fmu(f["name"], f["path"], step=f.get("step"), start_values=f["parameters"])
    for c in system.connections:
        m.connect(c)
    with m:
        m.initialize(sim_time)
        wall, cpu = _timed(m.run)
        q = list(m.view([f"plant.{n}" for n in Q_NAMES]))
    return wall, cpu, q


def run_libcosim(archive: Path, sim_time: float) -> tuple[float, float, list[float]]:
    """The same with libcosim: the archive as it is, its own step; the first step (initialization) untimed."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    from libcosimpy._internal import get_last_error_message

    log_output_level(CosimLogLevel.ERROR)
    try:
        execution = CosimExecution.from_ssp_file(str(archive))
    except AssertionError:
        raise RuntimeError(f"libcosim cannot load {archive}: {get_last_error_message()}") from None
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    plant = execution.slave_index_from_instance_name("plant")
    refs = {v.name.decode(): v.reference for v in execution.slave_variables(plant)}
    assert execution.step(1)
    wall, cpu = _timed(lambda: execution.simulate_until(round(sim_time * 1e9)))
    q = observer.last_real_values(plant, [refs[n] for n in Q_NAMES])
    return wall * n_ratio(sim_time), cpu * n_ratio(sim_time), q


def n_ratio(sim_time: float, step: float = 1e-4) -> float:
    """Steps simulated / steps timed when the first step runs untimed (initialization)."""
    n = round(sim_time / step)
    return n / (n - 1)


def run_ecos(archive: Path, sim_time: float) -> tuple[float, float, list[float]]:
    """The same with Ecos: the archive as it is, its step given, the parameter set named; first step untimed."""
    from ecospy import EcosSimulation

    from cosim.ssp import PARAMETER_SET, load_ssp

    step = load_ssp(archive).macro_step
    with EcosSimulation(ssp_path=str(archive), step_size=step) as sim:
        sim.init(parameter_set=PARAMETER_SET)
        sim.step(1)
        wall, cpu = _timed(lambda: sim.step(round(sim_time / step) - 1))
        q = [sim.get_real(f"plant::{n}") for n in Q_NAMES]
        sim.terminate()
    return wall * n_ratio(sim_time, step), cpu * n_ratio(sim_time, step), q


def engines(sim_time: float, repeats: int) -> None:
    """Our master vs libcosim vs Ecos on the main job's exported archive (see the module docstring)."""
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        archive = export_main_job(Path(folder))
        n_steps = round(sim_time / 1e-4)
        ways = {"our master": run_ours_on_archive, "libcosim": run_libcosim, "Ecos": run_ecos}
        walls = {name: [] for name in ways}
        cpus = {name: [] for name in ways}
        q_end = {}
        for _ in range(repeats):
            for name, fn in ways.items():
                wall, cpu, q_end[name] = fn(archive, sim_time)
                walls[name].append(wall)
                cpus[name].append(cpu)
    print(f"\nthe main job's export-ssp archive (7 FMUs, 18 connections, 100 us), unchanged in each engine; "
          f"{sim_time} s simulated, median of {repeats} (engines interleaved); load average "
          f"{open('/proc/loadavg').read().split()[:3]}")
    print(f"{'engine':>11} {'wall us/step':>12} {'CPU us/step':>11} {'x ours (CPU)':>12} {'max |dq| vs ours at end':>24}")
    ours_cpu = statistics.median(cpus["our master"])
    for name in ways:
        wall, cpu = statistics.median(walls[name]), statistics.median(cpus[name])
        dq = max(abs(a - b) for a, b in zip(q_end[name], q_end["our master"]))
        print(f"{name:>11} {wall / n_steps * 1e6:>12.2f} {cpu / n_steps * 1e6:>11.2f} {cpu / ours_cpu:>12.2f} "
              f"{dq:>24.3g}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sim-time", type=float, default=0.2, help="simulated seconds per run")
    parser.add_argument("--repeats", type=int, default=5, help="runs per case (median reported)")
    parser.add_argument("--section", choices=("all", "ways", "engines"), default="all",
                        help="the four ways of stepping the FMU set, the three engines on the archive, or both")
    parser.add_argument("--engines-sim-time", type=float, default=ENGINES_SIM_TIME_S,
                        help="simulated seconds per engine run")
    args = parser.parse_args()
    if args.section in ("all", "ways"):
        ways(args)
    if args.section in ("all", "engines"):
        engines(args.engines_sim_time, args.repeats)


def ways(args: argparse.Namespace) -> None:
    """The four (five) ways of stepping the FMU set: the table of the module docstring."""
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
