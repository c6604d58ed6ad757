"""Test model (pythonfmu): y = the time at the end of each step; in the first step that starts at or
after ``signal_time`` it sends SIGINT to its own process, so the interpreter's signal handler runs
inside this FMU's ``do_step`` - what Ctrl-C does to a Python-implemented FMU when it comes while
the model computes (pythonfmu reports the exception as an FMI error)."""
import os
import signal

from pythonfmu.fmi2slave import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real


class Interrupter(Fmi2Slave):
    author = "rx130l-cosim tests"
    description = "Sends SIGINT to its own process from inside do_step at signal_time"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.signal_time = 0.5
        self.y = 0.0
        self.sent = False
        self.register_variable(Real("signal_time", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.tunable))
        self.register_variable(Real("y", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))

    def do_step(self, current_time, step_size):
        if current_time >= self.signal_time - 1e-12 and not self.sent:
            self.sent = True
            os.kill(os.getpid(), signal.SIGINT)
            total = 0
            for k in range(1000):  # bytecode after the signal: the handler runs here, inside the step
                total += k
        self.y = current_time + step_size
        return True
