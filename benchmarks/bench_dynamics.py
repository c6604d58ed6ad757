"""Speed and size of the arm dynamics: numeric (pinocchio), CasADi SX, generated C.

Prints, for the symbolic forward dynamics, the instruction count of the ABA against
``M \\ b`` (CRBA + RNEA + symbolic solve), the size of the generated C and the median
time per call of the compiled C (timed in C, no Python in the loop), plus the Python
call cost of the numeric and CasADi functions and the batch regressor.

Run: ``python benchmarks/bench_dynamics.py``
"""
from __future__ import annotations

import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

from robot.dynamics import RobotDynamics
from robot.symbolic import (
    bias_function, forward_dynamics_function, forward_dynamics_placements_function, inverse_dynamics_function,
    mass_matrix_function,
)

HARNESS = r"""
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "NAME.h"
int main(void) {
    casadi_int n_arg, n_res, n_iw, n_w;
    NAME_work(&n_arg, &n_res, &n_iw, &n_w);
    casadi_real q[6] = {0.1, -0.4, 0.7, 0.2, -0.3, 0.5}, qd[6] = {0.5, -0.2, 0.3, 1.0, -1.0, 2.0};
    casadi_real u[6] = {10, 200, 50, 5, 3, 1}, p[78], load[4] = {5.0, 0.0, 0.0, 0.1}, out[6];
    for (int k = 0; k < 78; ++k) p[k] = 0.1 + 0.01 * k;
    for (int k = 0; k < 60; k += 10) p[k] = 10.0;
    casadi_real g[84] = {0}; /* placements: identity rotations with small offsets (dense enough) */
    for (int k = 0; k < 84; ++k) g[k] = 0.01 * (k % 7);
    const casadi_real* arg[6] = {q, qd, u, p, load, g};
    casadi_real* res[1] = {out};
    casadi_int* iw = malloc(sizeof(casadi_int) * (n_iw + 1));
    casadi_real* w = malloc(sizeof(casadi_real) * (n_w + 1));
    double best[7]; volatile double sink = 0;
    for (int rep = 0; rep < 7; ++rep) {
        struct timespec t0, t1; int n = 100000;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        for (int i = 0; i < n; ++i) { q[0] = 1e-6 * i; NAME(arg, res, iw, w, 0); sink += out[0]; }
        clock_gettime(CLOCK_MONOTONIC, &t1);
        best[rep] = ((t1.tv_sec - t0.tv_sec) * 1e9 + (t1.tv_nsec - t0.tv_nsec)) / n;
    }
    for (int a = 0; a < 7; ++a) for (int b = a + 1; b < 7; ++b) if (best[b] < best[a]) { double t = best[a]; best[a] = best[b]; best[b] = t; }
    printf("%.1f\n", best[3]);
    return sink == 12345.0;
}
"""


def _median_us(call, repeats: int = 2000) -> float:
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        samples.append(time.perf_counter() - start)
    return statistics.median(samples) * 1e6


def _m_backslash_b() -> ca.Function:
    q, qd, tau, p, load = (ca.SX.sym(n, k) for n, k in (("q", 6), ("qd", 6), ("tau", 6), ("p", 78), ("payload", 4)))
    qdd = ca.solve(mass_matrix_function()(q, p, load), tau - bias_function()(q, qd, p, load))
    return ca.Function("rx130l_fd_mb", [q, qd, tau, p, load], [qdd], {"cse": True})


def _compiled_ns(function: ca.Function, folder: Path) -> tuple[float, int]:
    name = function.name()
    generator = ca.CodeGenerator(f"{name}.c", {"with_header": True})
    generator.add(function)
    source = Path(generator.generate(str(folder) + "/"))
    (folder / f"main_{name}.c").write_text(HARNESS.replace("NAME", name))
    exe = folder / f"bench_{name}"
    subprocess.run(["gcc", "-O2", "-I", str(folder), str(source), str(folder / f"main_{name}.c"), "-o", str(exe),
                    "-lm"], check=True)
    out = subprocess.run([str(exe)], check=False, capture_output=True, text=True).stdout
    return float(out.strip()), source.stat().st_size


def main() -> None:
    fd, inv, fd_mb = forward_dynamics_function(), inverse_dynamics_function(), _m_backslash_b()
    fd_g = forward_dynamics_placements_function("rx130l_fd_geo")
    fd_l = forward_dynamics_placements_function("rx130l_fd_link", link_only=True)
    print("CasADi SX instruction counts")
    print(f"  rx130l_fd (ABA)          {fd.n_instructions():6d}")
    print(f"  ABA, placements input    {fd_g.n_instructions():6d}   (the plant FMU's, true geometry)")
    print(f"  ABA, links only, placem. {fd_l.n_instructions():6d}   (the elastic plant's link side)")
    print(f"  M \\ b (CRBA+RNEA+solve)  {fd_mb.n_instructions():6d}")
    print(f"  rx130l_id (RNEA)         {inv.n_instructions():6d}")
    if shutil.which("gcc"):
        with tempfile.TemporaryDirectory() as tmp:
            for function in (fd, fd_g, fd_l, fd_mb, inv):
                ns, size = _compiled_ns(function, Path(tmp))
                print(f"  compiled {function.name():14s} gcc -O2: {ns / 1000:6.2f} us/call (median), C {size / 1024:5.0f} kB")

    dynamics = RobotDynamics(payload=[5.0, 0.0, 0.0, 0.1])
    p, load = dynamics.parameter_vector(), dynamics.payload
    rng = np.random.default_rng(0)
    q, qd, qdd = rng.uniform(-1, 1, (3, 6))
    tau = dynamics.inverse_dynamics(q, qd, qdd)
    print("Python call cost (median)")
    print(f"  RobotDynamics.inverse_dynamics  {_median_us(lambda: dynamics.inverse_dynamics(q, qd, qdd)):6.1f} us")
    print(f"  RobotDynamics.forward_dynamics  {_median_us(lambda: dynamics.forward_dynamics(q, qd, tau)):6.1f} us")
    print(f"  RobotDynamics.mass_matrix       {_median_us(lambda: dynamics.mass_matrix(q)):6.1f} us")
    print(f"  casadi rx130l_fd, numpy args    {_median_us(lambda: fd(q, qd, tau, p, load)):6.1f} us")
    print(f"  casadi rx130l_id, numpy args    {_median_us(lambda: inv(q, qd, qdd, p, load)):6.1f} us")
    fd_args = [ca.DM(x) for x in (q, qd, tau, p, load)]
    print(f"  casadi rx130l_fd, DM args       {_median_us(lambda: fd.call(fd_args)):6.1f} us")
    n = 5000
    batch = rng.uniform(-1, 1, (3, n, 6))
    start = time.perf_counter()
    dynamics.regressor_batch(*batch)
    print(f"  regressor_batch, {n} samples     {(time.perf_counter() - start) * 1e3:6.1f} ms")


if __name__ == "__main__":
    main()
