"""Test model (built into an FMU by pythonfmu): a controller FMU exchanging Integer and Boolean
values with the cell. Inputs: ``status`` (Integer), ``ready`` (Boolean), ``t`` (Real); outputs:
``mode`` (Integer) = ``status`` + 1 when ``ready`` else -1, ``offset`` (Real) = ``gain`` * ``t``
and ``flag`` (Boolean) = ``ready``."""
from pythonfmu.fmi2slave import (Boolean, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer,
                                 Real)


class WordController(Fmi2Slave):
    author = "rx130l-cosim tests"
    description = "Integer/Boolean exchange of a controller FMU"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.gain = 1.0
        self.status, self.ready, self.t = 0, False, 0.0
        self.mode, self.offset, self.flag = 0, 0.0, False
        self.register_variable(Real("gain", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Integer("status", causality=Fmi2Causality.input))
        self.register_variable(Boolean("ready", causality=Fmi2Causality.input))
        self.register_variable(Real("t", causality=Fmi2Causality.input))
        self.register_variable(Integer("mode", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        self.register_variable(Real("offset", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        self.register_variable(Boolean("flag", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))

    def do_step(self, current_time, step_size):
        self.mode = self.status + 1 if self.ready else -1
        self.offset = self.gain * self.t
        self.flag = bool(self.ready)
        return True
