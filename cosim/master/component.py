"""One FMI 2.0 or FMI 3.0 co-simulation FMU instance as the master sees it.

An FMI 2.0 instance is a :class:`fmus.instance.FmuInstance`, the project's one FMI 2.0
instance layer (also under ``fmus.fast_fmu.FastFmu2Slave``): extraction, instantiation
with the FMU's messages routed to this instance, and the per-step calls
(fmi2Set*/fmi2Get*/fmi2DoStep) bound once as raw C function pointers so that the
engines call them with prepared value-reference arrays and bus addresses, without
per-step allocation; the lifecycle calls go through fmpy. An FMI 3.0
instance is bound through the C adapter of ``fmi3.py`` (fmi3_adapter.c), which offers
the same call shapes over the FMU's flattened variables.
The FMU's log messages go to a bounded per-instance buffer (``messages``) that a
``SimulationError`` quotes when the FMU fails.
"""
from __future__ import annotations

from collections import deque
from functools import lru_cache
from pathlib import Path

from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave
from fmpy.model_description import ModelDescription, ScalarVariable

from cosim.master.errors import MasterConfigError, SimulationError
from cosim.master.fmi3 import Fmi3Binding, flatten
from fmus.instance import SET_T, STEP_T, FmuInstance, FmuInstantiateError, extracted_dir

_STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")


def _unzip_dir(path: Path) -> str:
    """The FMU archive extracted once per process (``fmus.instance.extracted_dir``; used by proxy.py)."""
    return extracted_dir(Path(path))


def status_name(status: int, api: str = "fmi2") -> str:
    """``3 -> "fmi2Error"`` (``api="fmi3"``: ``"fmi3Error"``)."""
    return api + _STATUS[status] if 0 <= status < len(_STATUS) else f"status {status}"


@lru_cache(maxsize=64)
def _read_description(path: str, mtime: float) -> ModelDescription:
    return read_model_description(path, validate=False)


#: What the master runs, in words (for error messages).
SUPPORTED_FMUS = "an FMI 2.0 or FMI 3.0 co-simulation FMU"


def fmu_kind_problem(md: ModelDescription) -> str | None:
    """None when the master can run ``md``; otherwise what it is, in one sentence (no "expected")."""
    version = str(md.fmiVersion)
    if version not in ("2.0",) and not version.startswith("3."):
        return f"its modelDescription.xml declares fmiVersion {version!r}, which the master does not run"
    if md.coSimulation is not None:
        return None
    interfaces = [name for name, attr in (("model exchange", "modelExchange"),
                                          ("scheduled execution", "scheduledExecution"))
                  if getattr(md, attr, None) is not None]
    kind = " and ".join(interfaces) or "no"
    return (f"it is an FMI {version} FMU with {kind} interface{'s' if len(interfaces) > 1 else ''} only "
            f"(no <CoSimulation> element); the master steps FMUs through their co-simulation interface")


def load_model_description(path: str | Path) -> ModelDescription:
    """Read (and cache) the modelDescription of an FMU file; MasterConfigError naming the file
    when it is missing, unreadable, or not an FMI 2.0/3.0 co-simulation FMU."""
    path = Path(path)
    if not path.is_file():
        raise MasterConfigError(f"FMU file {str(path)!r} does not exist (expected a path to a .fmu file)")
    try:
        md = _read_description(str(path.resolve()), path.stat().st_mtime)
    except Exception as exc:  # fmpy raises plain Exceptions for broken archives
        raise MasterConfigError(f"FMU file {str(path)!r} cannot be read: {exc}") from exc
    problem = fmu_kind_problem(md)
    if problem:
        error = MasterConfigError(f"FMU file {str(path)!r}: {problem}; expected {SUPPORTED_FMUS}")
        error.problem = problem
        raise error
    return md


def variables_of(md: ModelDescription) -> dict:
    """Variable name -> variable as the master sees it (FMI 3.0: flattened bus elements, ``fmi3.flatten``)."""
    if str(md.fmiVersion).startswith("3."):
        return {e.name: e for e in flatten(md)}
    return {v.name: v for v in md.modelVariables}


class FmuComponent:
    """An FMU instance: model description, fmpy slave, raw FMI function pointers, log buffer.

    Args:
        name: instance name (no dots).
        path: the .fmu file.
        step_ticks: the FMU's communication step as a multiple of the master's base step.
        start_values: variable name -> start value (checked by the master beforehand).
        debug_logging: passed as ``loggingOn`` to fmi2Instantiate.
        log_capacity: how many log messages to keep.
    """

    def __init__(self, name: str, path: str | Path, step_ticks: int, start_values: dict[str, object],
                 debug_logging: bool = False, log_capacity: int = 50) -> None:
        self.name = name
        self.path = Path(path)
        self.model_description = load_model_description(self.path)
        self.fmi3 = str(self.model_description.fmiVersion).startswith("3.")
        self.api = "fmi3" if self.fmi3 else "fmi2"
        self.variables = variables_of(self.model_description)
        self.binding: Fmi3Binding | None = None
        self.step_ticks = int(step_ticks)
        self.start_values = dict(start_values)
        self.debug_logging = debug_logging
        self.messages: deque[str] = deque(maxlen=log_capacity)
        self.slave: FMU2Slave | FMU3Slave | None = None
        self.instance: FmuInstance | None = None  # FMI 2.0: the instance layer under this component
        self.failed_fatally = False

    # ----------------------------------------------------------------- lifecycle
    def _logger(self, status: int, category: str, text: str) -> None:
        self.messages.append(f"[{status_name(status)}] {category + ': ' if category else ''}{text}")

    def _logger3(self, env, status, category, message) -> None:
        text = message.decode("utf-8", "replace") if message else ""
        cat = category.decode("utf-8", "replace") if category else ""
        self.messages.append(f"[{status_name(status, 'fmi3')}] {cat + ': ' if cat else ''}{text}")

    @property
    def bus_variables(self) -> list:
        """The variables in modelDescription order (FMI 3.0: flattened elements)."""
        return list(self.variables.values())

    def _instantiate3(self, stop_at_address: int | None) -> None:
        md = self.model_description
        self.slave = FMU3Slave(guid=md.guid, unzipDirectory=extracted_dir(self.path),
                               modelIdentifier=md.coSimulation.modelIdentifier, instanceName=self.name)
        event_mode = bool(getattr(md.coSimulation, "hasEventMode", False))
        try:
            self.slave.instantiate(loggingOn=self.debug_logging, eventModeUsed=event_mode, earlyReturnAllowed=False,
                                   logMessage=self._logger3)
        except Exception as exc:
            raise self.error(0.0, f"fmi3InstantiateCoSimulation failed: {exc}") from exc
        self.binding = Fmi3Binding(list(self.variables.values()), self.slave.dll, self.slave.component, event_mode,
                                   stop_at_address)
        self.event_mode_used = event_mode
        self.component = self.binding.address
        self.fn_address = dict(self.binding.fn_address)
        self.do_step_fn = STEP_T(self.fn_address["DoStep"])
        self.set_fn = {t: SET_T(self.fn_address["Set" + t]) for t in ("Real", "Integer", "Boolean")}
        self.get_fn = {t: SET_T(self.fn_address["Get" + t]) for t in ("Real", "Integer", "Boolean")}

    def instantiate(self, stop_at_address: int | None = None) -> None:
        """Load the binary and instantiate it (fmi2Instantiate / fmi3InstantiateCoSimulation); bind the raw
        step functions. ``stop_at_address``: the engines' end-of-run time an FMI 3.0 FMU that ends the
        simulation itself writes (a float64)."""
        if self.fmi3:
            self._instantiate3(stop_at_address)
            return
        try:
            self.instance = FmuInstance(self.path, self.name, self._logger, logging_on=self.debug_logging,
                                        model_description=self.model_description)
        except FmuInstantiateError as exc:
            raise self.error(0.0, str(exc)) from exc
        self.slave = self.instance.slave
        self.component = self.instance.component
        self.fn_address = dict(self.instance.fn_address)
        self.do_step_fn = self.instance.do_step_fn
        self.set_fn = self.instance.set_fn
        self.get_fn = self.instance.get_fn

    def call(self, what: str, time: float, function, *args):
        """Run an fmpy lifecycle call; turn its failure into SimulationError with the log."""
        try:
            return function(*args)
        except Exception as exc:
            status = getattr(exc, "status", None)
            if status == 4:
                self.failed_fatally = True
            raise self.error(time, f"{what} failed: {exc}") from exc

    def enter_initialization(self, start_time: float, stop_time: float | None) -> None:
        """FMI 2.0: fmi2SetupExperiment, start values, fmi2EnterInitializationMode.
        FMI 3.0: start values, fmi3EnterInitializationMode(start_time, stop_time)."""
        if self.fmi3:
            self.apply_start_values(start_time)
            self.call("fmi3EnterInitializationMode", start_time, self.slave.enterInitializationMode, None,
                      start_time, stop_time)
            return
        self.call("fmi2SetupExperiment", start_time, self.slave.setupExperiment, None, start_time, stop_time)
        self.apply_start_values(start_time)
        self.call("fmi2EnterInitializationMode", start_time, self.slave.enterInitializationMode)

    def exit_initialization(self, start_time: float) -> None:
        """fmi2ExitInitializationMode / fmi3ExitInitializationMode (FMI 3.0 with event mode: the event
        iteration that follows it, then step mode)."""
        self.call(f"{self.api}ExitInitializationMode", start_time, self.slave.exitInitializationMode)
        if self.fmi3 and self.event_mode_used:
            self.check("the event iteration after initialization", start_time,
                       self.binding.event_iteration(start_time, enter=False))
            if self.binding.terminated:
                raise self.error(start_time, "the FMU asked to terminate the simulation during initialization")

    def get_binary(self, name: str) -> bytes:
        """The current value of FMI 3.0 Binary output ``name`` (one element)."""
        element = self.variable(name)
        if not self.fmi3 or element.type != "Binary":
            raise MasterConfigError(f"FMU '{self.name}': '{name}' is not an FMI 3.0 Binary variable")
        values = self.call(f"fmi3GetBinary({name})", 0.0, self.slave.getBinary, [element.fmi_value_reference],
                           element.count)
        return bytes(values[element.element])

    def apply_start_values(self, time: float) -> None:
        """Set every start value with the fmpy setter of its type (FMI 3.0: through the adapter)."""
        if self.fmi3:
            values = {self.variables[name]: value for name, value in self.start_values.items()}
            self.check("setting start values", time, self.binding.set_start_values(values))
            return
        for name, value in self.start_values.items():
            var = self.variables[name]
            vr = [var.valueReference]
            if var.type == "Real":
                self.call(f"setting start value {name}", time, self.slave.setReal, vr, [float(value)])
            elif var.type in ("Integer", "Enumeration"):
                self.call(f"setting start value {name}", time, self.slave.setInteger, vr, [int(value)])
            elif var.type == "Boolean":
                self.call(f"setting start value {name}", time, self.slave.setBoolean, vr, [bool(value)])
            else:
                self.call(f"setting start value {name}", time, self.slave.setString, vr, [str(value)])

    def ended_itself(self, t: float, h: float) -> float | None:
        """After fmi2DoStep(t, h) returned fmi2Discard: the FMU's fmi2LastSuccessfulTime (s) when it
        reports fmi2Terminated (it ended the simulation, as fmpy.simulate_fmu accepts) and that time
        lies within the step, after its start: (t, t + h]; else None (an ordinary discard: the run
        fails). An FMU that did not get past the step's start is taken as failing: pythonfmu, for one,
        reports fmi2Terminated after any step its model refused."""
        if self.fmi3 or self.slave is None:
            return None
        try:
            if not self.slave.getBooleanStatus(3):  # fmi2Terminated
                return None
            last = float(self.slave.getRealStatus(2))  # fmi2LastSuccessfulTime
        except Exception:  # noqa: BLE001 - status not provided: an ordinary discard
            return None
        tolerance = 1e-9 * max(1.0, abs(t) + abs(h))
        return last if t + tolerance < last <= t + h + tolerance else None

    def error(self, time: float, reason: str) -> SimulationError:
        """SimulationError for this instance at ``time`` (s) quoting its log messages (and, for FMI 3.0,
        what the adapter found: a value out of range, an early return, the variable concerned)."""
        hint = "" if self.debug_logging else "the FMU logged nothing; debug_logging=True turns its logging on"
        if self.binding is not None and self.binding.message:
            reason = f"{reason} ({self.binding.message})"
            self.binding.clear_message()
        return SimulationError(self.name, time, reason, self.messages, hint)

    def check(self, what: str, time: float, status: int) -> None:
        """Raise SimulationError when ``status`` is Discard/Error/Fatal/Pending."""
        if status > 1:
            if status == 4:
                self.failed_fatally = True
            raise self.error(time, f"{what} returned {status_name(status, self.api)}")

    def close(self, terminate: bool) -> None:
        """fmi2Terminate (when the instance is healthy) and fmi2FreeInstance; never raises."""
        if self.slave is None:
            return
        if self.failed_fatally:  # after fmi2Fatal/fmi3Fatal no function may be called
            if self.instance is not None:
                self.instance.forget()
            self.slave = None
            return
        if self.instance is not None:  # FMI 2.0
            for problem in self.instance.free(terminate):
                self.messages.append(f"[master] {problem}")
            self.slave = None
            return
        try:
            if terminate:
                self.slave.terminate()
        except Exception as exc:
            self.messages.append(f"[master] {self.api}Terminate failed: {exc}")
        try:
            self.slave.freeInstance()
        except Exception as exc:  # pragma: no cover
            self.messages.append(f"[master] {self.api}FreeInstance failed: {exc}")
        self.slave = None

    def variable(self, name: str) -> ScalarVariable:
        """The ScalarVariable called ``name``; MasterConfigError naming the FMU when unknown."""
        try:
            return self.variables[name]
        except KeyError:
            raise MasterConfigError(f"FMU '{self.name}' ({self.path.name}) has no variable '{name}'") from None


