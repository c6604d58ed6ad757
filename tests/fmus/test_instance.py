"""The one FMI 2.0 instance layer (fmus/instance.py) under both the master's FmuComponent and
FastFmu2Slave: the FMU's messages reach the instance that logged them, also with several
instances of one FMU (fmpy's logging proxy keeps one process-wide Python callback)."""
from __future__ import annotations

from cosim.master import Master
from fmus.build import ensure_fmus
from fmus.fast_fmu import FastFmu2Slave
from fmus.instance import FmuInstance
from fmus.servo_drive.params import drive_start_values


def test_master_and_fast_path_share_the_instance_layer_and_route_messages():
    path = ensure_fmus()["servo_drive"]
    master = Master(1e-4)
    components = [master.add_fmu(f"d{a}", path, start_values=drive_start_values(a), debug_logging=True)
                  for a in (1, 2, 3)]
    fast = FastFmu2Slave(path, "fast", drive_start_values(4), logging_on=True)
    try:
        master.initialize(0.01)
        assert all(isinstance(c.instance, FmuInstance) for c in components)
        assert isinstance(fast._fmu, FmuInstance)
        for c in components:  # each instance has its own start-up transition, logged once
            assert sum("Not ready to switch on -> Switch on disabled" in m for m in c.messages) == 1, c.name
        assert sum("Not ready to switch on" in m for _, m in fast.messages) == 1
        fast.set_value("controlword", 0x06)
        fast.do_step(0.0, 1e-4)
        assert any("Ready to switch on" in m for _, m in fast.messages)
        assert not any("Ready to switch on" in m for c in components for m in c.messages)
    finally:
        master.close()
        fast.close()
