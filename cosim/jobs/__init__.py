"""Robot jobs of ``python -m cosim run``: the robot cell wiring shared by the jobs
(plant + six drives + fieldbus + controller + laser tracker) and the job modules
(``iso9283``: the paper's section 2 experiment)."""
