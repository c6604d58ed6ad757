"""One run of a scenario, the floor under the sweeps and the public API: load and validate it
(:mod:`cosim.runs.scenario`), run its job into a results folder (:mod:`cosim.runs.execute`), read
what it wrote (:mod:`cosim.runs.result`). :mod:`cosim.api` re-exports these names for scripts;
:mod:`cosim.sweep` runs every variant through :func:`cosim.runs.execute.execute`.
"""
