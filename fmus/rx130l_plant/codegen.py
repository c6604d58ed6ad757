"""Generate the plant's dynamics as C with CasADi.

Three SX functions of :mod:`robot.symbolic`, generated into one C file with the internal
symbol prefix ``rx130l_plant_fd_`` and without export attributes, so that (compiled with
``-fvisibility=hidden``) no generated symbol can clash with another library in the
importing process:

- ``rx130l_plant_geometry(errors[39]) -> placements[84]``: the joint and flange placements
  with the true robot's geometric errors folded in (:func:`robot.symbolic.placements_function`),
  evaluated once at initialisation;
- ``rx130l_plant_fd(q, qd, tau, p[78], payload[4], placements[84]) -> qdd``: the rigid
  joints' forward dynamics (ABA with rotor inertia and friction) on those placements;
- ``rx130l_plant_fd_link(...)`` (same inputs): the links alone, without rotor inertia and
  friction (the link side of the elastic joints).
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import casadi as ca

from robot.symbolic import forward_dynamics_placements_function, placements_function

GENERATED_NAME = "rx130l_plant_fd"
GEOMETRY_NAME = "rx130l_plant_geometry"
LINK_NAME = "rx130l_plant_fd_link"
GENERATED_FILE = "rx130l_plant_fd.c"


def plant_functions() -> list[ca.Function]:
    """The generated functions under the plant's own names (see the module docstring)."""
    return [placements_function(name=GEOMETRY_NAME), forward_dynamics_placements_function(GENERATED_NAME),
            forward_dynamics_placements_function(LINK_NAME, link_only=True)]


def generated_dynamics_sources() -> dict[str, str]:
    """``{file name: text}`` of the generated C file and its header."""
    generator = ca.CodeGenerator(GENERATED_FILE, {
        "with_header": True,
        "with_export": False,
        "prefix": f"{GENERATED_NAME}_",
    })
    for function in plant_functions():
        generator.add(function)
    with tempfile.TemporaryDirectory() as tmp:
        generator.generate(tmp + "/")
        c_text = (Path(tmp) / GENERATED_FILE).read_text()
        h_text = (Path(tmp) / GENERATED_FILE.replace(".c", ".h")).read_text()
    return {GENERATED_FILE: c_text, GENERATED_FILE.replace(".c", ".h"): h_text}
