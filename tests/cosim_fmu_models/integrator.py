"""Test model (built into an FMU by pythonfmu): y(t+h) = y(t) + k * u(t) * h; also reports its own time."""
from pythonfmu.fmi2slave import Fmi2Initial, Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class Integrator(Fmi2Slave):
    author = "rx130l-cosim tests"
    description = "Forward-Euler integrator of a held input"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.k = 1.0
        self.y0 = 0.0
        self.y = 0.0
        self.clock = 0.0
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("k", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Real("y0", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Real("y", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        self.register_variable(Real("clock", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))

    def exit_initialization_mode(self):
        self.y = self.y0

    def do_step(self, current_time, step_size):
        self.y += self.k * self.u * step_size
        self.clock = current_time + step_size
        return True
