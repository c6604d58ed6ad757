"""Test model (built into an FMU by pythonfmu): a joint-space controller for the cell.

Inputs: the measured joint angles q1..q6 and the reference q_ref1..q_ref6 (rad); output the
torque offsets tau1..tau6 = kp * (q_ref - q) (N m), which the cell sends in CSP mode with
the reference as target position. ``fail_after`` (s, < 0: never) makes doStep fail then."""
from pythonfmu.fmi2slave import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real


class PdController(Fmi2Slave):
    author = "rx130l-cosim tests"
    description = "Proportional joint torque offset from reference and measured angles"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.kp = 50.0
        self.fail_after = -1.0
        self.register_variable(Real("kp", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Real("fail_after", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.tunable))
        for i in range(1, 7):
            for name in (f"q{i}", f"q_ref{i}"):
                setattr(self, name, 0.0)
                self.register_variable(Real(name, causality=Fmi2Causality.input))
            setattr(self, f"tau{i}", 0.0)
            self.register_variable(Real(f"tau{i}", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))

    def do_step(self, current_time, step_size):
        if 0.0 <= self.fail_after <= current_time:
            return False
        for i in range(1, 7):
            setattr(self, f"tau{i}", self.kp * (getattr(self, f"q_ref{i}") - getattr(self, f"q{i}")))
        return True
