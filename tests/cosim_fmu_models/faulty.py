"""Test model (pythonfmu): y = time; from fail_time on it fails in the way chosen by `mode`:
1 = do_step returns False, 2 = output becomes NaN, 3 = output becomes +Inf, 4 = do_step raises."""
import math

from pythonfmu.fmi2slave import Fmi2Initial, Fmi2Causality, Fmi2Slave, Fmi2Status, Fmi2Variability, Integer, Real


class Faulty(Fmi2Slave):
    author = "rx130l-cosim tests"
    description = "Fails on purpose"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.fail_time = 1.0
        self.mode = 1
        self.y = 0.0
        self.register_variable(Real("fail_time", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.tunable))
        self.register_variable(Integer("mode", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.tunable))
        self.register_variable(Real("y", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))

    def do_step(self, current_time, step_size):
        t = current_time + step_size
        if t >= self.fail_time - 1e-12:
            if self.mode == 1:
                self.log(f"solver diverged at t={t:.6f}", Fmi2Status.error)
                return False
            if self.mode == 2:
                self.y = math.nan
                return True
            if self.mode == 3:
                self.y = math.inf
                return True
            raise RuntimeError(f"model exploded at t={t:.6f}")
        self.y = t
        return True
