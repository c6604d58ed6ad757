"""Test model (pythonfmu): at the end of each step, y = the input u it was given for that step,
t_seen = the start time of that step; counts its steps (Integer) and toggles a Boolean."""
from pythonfmu.fmi2slave import Fmi2Initial, Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real


class Sampler(Fmi2Slave):
    author = "rx130l-cosim tests"
    description = "Holds its input; Integer and Boolean pass-through"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.y = 0.0
        self.t_seen = -1.0
        self.steps = 0
        self.i_in = 0
        self.i_out = 0
        self.b_in = False
        self.b_out = False
        self.offset = 0
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Integer("i_in", causality=Fmi2Causality.input, variability=Fmi2Variability.discrete))
        self.register_variable(Boolean("b_in", causality=Fmi2Causality.input, variability=Fmi2Variability.discrete))
        self.register_variable(Integer("offset", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.tunable))
        self.register_variable(Real("y", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        self.register_variable(Real("t_seen", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        self.register_variable(Integer("steps", causality=Fmi2Causality.output, variability=Fmi2Variability.discrete, initial=Fmi2Initial.exact))
        self.register_variable(Integer("i_out", causality=Fmi2Causality.output, variability=Fmi2Variability.discrete, initial=Fmi2Initial.exact))
        self.register_variable(Boolean("b_out", causality=Fmi2Causality.output, variability=Fmi2Variability.discrete, initial=Fmi2Initial.exact))

    def do_step(self, current_time, step_size):
        self.y = self.u
        self.t_seen = current_time
        self.steps += 1
        self.i_out = self.i_in + self.offset
        self.b_out = not self.b_in
        return True
