"""Generate the plant's forward dynamics as C with CasADi.

The SX function ``rx130l_fd(q, qd, tau, p[78], payload[4]) -> qdd`` of
:mod:`robot.symbolic` is renamed ``rx130l_plant_fd`` and generated with the internal
symbol prefix ``rx130l_plant_fd_`` and without export attributes, so that (compiled
with ``-fvisibility=hidden``) no generated symbol can clash with another library in the
importing process.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import casadi as ca

from robot.symbolic import forward_dynamics_function

GENERATED_NAME = "rx130l_plant_fd"
GENERATED_FILE = "rx130l_plant_fd.c"


def plant_dynamics_function() -> ca.Function:
    """The forward dynamics under the plant's own function name (same inputs and outputs)."""
    fd = forward_dynamics_function()
    inputs = [ca.SX.sym(fd.name_in(k), fd.size_in(k)) for k in range(fd.n_in())]
    return ca.Function(GENERATED_NAME, inputs, fd.call(inputs), fd.name_in(), fd.name_out(), {"cse": True})


def generated_dynamics_sources() -> dict[str, str]:
    """``{file name: text}`` of the generated C file and its header."""
    generator = ca.CodeGenerator(GENERATED_FILE, {
        "with_header": True,
        "with_export": False,
        "prefix": f"{GENERATED_NAME}_",
    })
    generator.add(plant_dynamics_function())
    with tempfile.TemporaryDirectory() as tmp:
        generator.generate(tmp + "/")
        c_text = (Path(tmp) / GENERATED_FILE).read_text()
        h_text = (Path(tmp) / GENERATED_FILE.replace(".c", ".h")).read_text()
    return {GENERATED_FILE: c_text, GENERATED_FILE.replace(".c", ".h"): h_text}
