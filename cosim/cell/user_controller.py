"""A user's controller named in a scenario: ``[controller] class`` (a Python class) or
``[controller] fmu`` (an FMI 2.0 co-simulation controller FMU), checked before anything runs.

The class is loaded by :func:`cosim.scenario.user_class.load_user_class`
(``"path/to/file.py:ClassName"`` relative to the scenario file, or
``"package.module:ClassName"``), must have the methods of the controller contract
(:class:`controller.CellController`: ``setup``, ``step``, ``close``) and is instantiated with
the ``[controller.parameters]`` table as keyword arguments. Every problem is a
ScenarioError at the key that named it.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from controller import contract_problems
from cosim.scenario.schema import Where
from cosim.scenario.user_class import instantiate, load_user_class


def user_controller_label(ctrl: dict[str, Any]) -> str | None:
    """The run name of the scenario's user controller (None: there is none)."""
    if ctrl.get("label"):
        return ctrl["label"]
    if ctrl.get("class"):
        return ctrl["class"].rpartition(":")[2].split(".")[-1]
    if ctrl.get("fmu"):
        return Path(ctrl["fmu"]).stem
    return None


def check_user_controller(ctrl: dict[str, Any], where: Where) -> None:
    """Check ``[controller] class`` / ``fmu`` (and their ``parameters``) without running anything."""
    if ctrl.get("class") and ctrl.get("fmu"):
        raise (where / "fmu").error("either [controller] class or fmu, not both", str(ctrl["fmu"]),
                                    problem="two user controllers")
    if ctrl.get("class"):
        cls = load_controller_class(ctrl, where)
        import inspect

        try:
            inspect.signature(cls).bind(**ctrl.get("parameters", {}))
        except TypeError as exc:
            raise (where / "parameters").error(f"keyword arguments {cls.__name__}{inspect.signature(cls)} accepts",
                                               ctrl.get("parameters", {}), problem=str(exc)) from None
        except ValueError:
            pass  # no signature to inspect (a builtin): instantiation will tell
    if ctrl.get("fmu"):
        from controller.fmu_controller import check_controller_fmu

        check_controller_fmu(ctrl["fmu"], ctrl.get("fmu_inputs", {}), ctrl.get("fmu_outputs", {}),
                             ctrl.get("parameters", {}), where)
    elif ctrl.get("fmu_inputs") or ctrl.get("fmu_outputs"):
        raise (where / "fmu").error("a controller FMU (fmu_inputs / fmu_outputs map its variables)",
                                    problem="fmu_inputs/fmu_outputs without fmu")


def load_controller_class(ctrl: dict[str, Any], where: Where) -> type:
    """The ``[controller] class``, checked against the contract (ScenarioError at ``controller.class``)."""
    cls = load_user_class(ctrl["class"], where / "class", what="controller class")
    problems = contract_problems(cls)
    if problems:
        raise (where / "class").error("a class with setup(info), step(inputs) and close() "
                                      "(controller.CellController)", ctrl["class"],
                                      problem=f"{cls.__name__}: {'; '.join(problems)}")
    return cls


def make_user_controller(ctrl: dict[str, Any], where: Where) -> Any:
    """A new instance of the scenario's user controller (class or FMU)."""
    if ctrl.get("class"):
        cls = load_controller_class(ctrl, where)
        return instantiate(cls, dict(ctrl.get("parameters", {})), where / "parameters", what="controller class")
    return make_controller_fmu(ctrl["fmu"], ctrl.get("fmu_inputs", {}), ctrl.get("fmu_outputs", {}),
                               ctrl.get("parameters", {}), settle_time_s=ctrl.get("settle_time", 0.2))


def open_controller_fmu(path: Any, name: str, start_values: dict[str, Any], **arrays: Any) -> Any:
    """A user's controller FMU as :class:`controller.fmu_controller.FmuController` steps it: the
    project's :class:`fmus.fmu.Fmu` (per-step calls bound to the FMU's own functions, preallocated
    value arrays in the order of ``arrays``' names), instantiated and initialized with ``start_values``."""
    from fmus.fmu import Fmu

    return Fmu(path, name, start_values, **arrays).start()


def make_controller_fmu(path: Any, inputs: dict[str, str], outputs: dict[str, str], parameters: dict[str, Any],
                        settle_time_s: float = 0.2) -> Any:
    """A :class:`controller.fmu_controller.FmuController` on ``path`` opened through :func:`open_controller_fmu`."""
    from controller.fmu_controller import FmuController

    return FmuController(path, inputs=inputs, outputs=outputs, parameters=parameters, settle_time_s=settle_time_s,
                         open_fmu=open_controller_fmu)
