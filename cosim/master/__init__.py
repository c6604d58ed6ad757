"""Generic fixed-step, multi-rate co-simulation master on fmpy.

Knows FMUs, connections, periodic tasks and recorders; nothing about robots.
The coupling scheme (who sees which values when): the docstring of cosim/master/master.py and
docs/explanation/architecture.md, "The co-simulation master".
"""
from cosim.master.errors import EndSimulation, MasterConfigError, SimulationError
from cosim.master.master import Master, SignalReader, Task, ticks_of
from cosim.master.recorder import MemorySink, Recorder, Sink
from cosim.master.variables import ConnectionSpec, check_connection_ends, check_start_value, parse_connection
from fmus.fmu import Fmu, load_model_description

__all__ = [
    "ConnectionSpec", "EndSimulation", "Fmu", "Master", "MasterConfigError", "MemorySink", "Recorder",
    "SignalReader", "SimulationError", "Sink", "Task", "check_connection_ends", "check_start_value",
    "load_model_description", "parse_connection", "ticks_of",
]
