"""The public Python API for scenario runner scripts (re-exported from ``cosim``).

Load, check and describe a scenario without running it; run it into a folder (or a
temporary one) and read what it wrote; run sweeps from Python with the same objects::

    import cosim

    scenario = cosim.load_scenario("scenarios/iso9283.toml",
                                   overrides={"true_robot.payload_mass": "5 kg", "controller.modes": ["standard"]})
    print(scenario.describe())
    result = cosim.run(scenario, out="results/my_run")     # RunFailed if the run fails
    result.summary.status, result.summary.realtime_factor, result.summary["modes.standard.tcp_error_max_mm"]
    lag = result.timeseries("tcp_standard")                # pandas.DataFrame if pandas is installed
    result.figures, result.can_log

    study = cosim.build_sweep(scenario, name="payload", axes={"true_robot.payload_mass": ["0 kg", "10 kg"]})
    table = cosim.run_sweep(study, out="results/payload", workers=2)

Scenarios are given as a path to a TOML file, a TOML text (a string holding a newline),
a dict (the parsed TOML document) or a :class:`Scenario`. Overrides are ``{"dotted.key":
value}`` with the syntax and the code of sweep axes (``cosim.scenario.keypath``:
``fmus[0].parameters."q0[2]"``); values follow the scenario's own rules (SI numbers or
unit strings such as ``"5 kg"``), relative file paths in them are relative to the working
directory (as are those of a dict or TOML text).

Errors (documented in docs/how-to/scripting.md):

* :class:`ScenarioError` (a ``ValueError``): invalid scenario, override or sweep, raised
  before anything is written; ``.file`` (a Path, or ``"<dict>"``/``"<string>"``/
  ``"<python>"`` for documents that are no file), ``.key`` (the key path), ``.expected``,
  ``.given``, ``.problem``.
* :class:`RunFailed` (a ``RuntimeError``): the run started and stopped with status
  ``failed`` (simulation error, internal error); ``.result`` is the :class:`RunResult`
  (files written so far), ``.summary`` its summary (reason, stopped_at_s).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cosim.runs.execute import execute, run
from cosim.runs.result import (CAN_LOG_SUFFIXES, FIGURE_SUFFIXES, TIMESERIES_SUFFIXES, RunFailed, RunResult, Summary,
                               TimeSeries, export_blf, read_can_log, read_timeseries)
from cosim.runs.scenario import (DICT_LABEL, PYTHON_LABEL, STRING_LABEL, Scenario, _is_toml_text, load_scenario)
from cosim.scenario.errors import ScenarioError

if TYPE_CHECKING:  # pragma: no cover
    from cosim.scenario.loader import Scenario as ValidatedScenario
    from cosim.sweep.execute import SweepResult
    from cosim.sweep.loader import Sweep


def __getattr__(name: str) -> Any:
    if name == "OutputFolderError":   # cosim.results.outdir (imported on use)
        from cosim.results.outdir import OutputFolderError

        return OutputFolderError
    raise AttributeError(f"module 'cosim.api' has no attribute {name!r}")


# ------------------------------------------------------------------------------------------ sweeps
def load_sweep(sweep: "str | Path | Mapping[str, Any]", on_count=None) -> "Sweep":
    """Read and validate a sweep (a sweep TOML file, its text, or its parsed dict; docs/how-to/sweep_cluster.md).

    Every variant is validated by the base job; ScenarioError on any problem, nothing runs.
    A dict or text names its base scenario relative to the working directory. ``on_count(n)`` is
    called with the number of variants before they are validated.
    """
    from cosim.sweep.loader import load_sweep as load_file, load_sweep_document

    if isinstance(sweep, Mapping):
        return load_sweep_document(dict(sweep), DICT_LABEL, on_count=on_count)
    if isinstance(sweep, str) and _is_toml_text(sweep):
        import tomllib

        try:
            document = tomllib.loads(sweep)
        except tomllib.TOMLDecodeError as exc:
            raise ScenarioError(STRING_LABEL, "", "valid TOML", problem=str(exc)) from None
        return load_sweep_document(document, STRING_LABEL, on_count=on_count)
    return load_file(sweep, on_count=on_count)


def _relabelled_sweep(document: dict[str, Any], label: str, base: "ValidatedScenario | None" = None) -> "Sweep":
    from cosim.sweep.loader import load_sweep_document

    return load_sweep_document(document, label, base)


def build_sweep(base: "str | Path | Mapping[str, Any] | Scenario", axes: "Mapping[str, Sequence[Any]] | "
                "Sequence[Mapping[str, Any]]", *, name: str, overrides: Mapping[str, Any] | None = None,
                metrics: Sequence[str] | None = None, report: Mapping[str, Any] | None = None,
                collect: Sequence[str] = (), store: str | None = None, retries: int = 2,
                description: str = "") -> "Sweep":
    """A sweep built in Python around a base scenario (validated like a sweep file, docs/how-to/sweep_cluster.md).

    Args:
        base: the base scenario (as for :func:`load_scenario`; its overrides are kept).
        axes: ``{"key.path": [values...]}`` (grid axes, first slowest) or a list of axis tables as
            in a sweep file (``{"key": ..., "seeds": 20}``, ``{"key": ..., "distribution": {...},
            "samples": N}``).
        name: the sweep's name (folder name of its default results folder).
        overrides: ``{"key.path": value}`` set in every variant.
        metrics: summary leaves to tabulate (globs); default every numeric leaf.
        report: a ``[report]`` table (``{"metric": ..., "parameter": ...}``).
        collect, store: what variants run elsewhere bring back / the fsspec URL they write it to.
        retries: re-runs of a variant whose worker died.

    Raises:
        ScenarioError: file ``"<python>"``, key such as ``axes[0].values[1]`` (every variant is validated).
    """
    sc = load_scenario(base)
    if isinstance(axes, Mapping):
        axis_tables = [{"key": key, "values": list(values)} for key, values in axes.items()]
    else:
        axis_tables = [dict(a) for a in axes]
    head: dict[str, Any] = {"name": name, "description": description, "retries": retries,
                            "collect": list(collect)}
    if metrics is not None:
        head["metrics"] = list(metrics)
    if store is not None:
        head["store"] = store
    document: dict[str, Any] = {"sweep": head, "axes": axis_tables}
    if overrides:
        document["overrides"] = dict(overrides)
    if report is not None:
        document["report"] = dict(report)
    return _relabelled_sweep(document, PYTHON_LABEL, sc.validated)


def run_sweep(sweep: "Sweep | str | Path | Mapping[str, Any]", out: str | Path | None = None, *,
              workers: int | None = None, scheduler: str | None = None, client: Any = None,
              resume: bool = True, progress: bool = False, transfer: str = "auto") -> "SweepResult":
    """Run every variant of a sweep on Dask; return the :class:`cosim.sweep.SweepResult`.

    Args:
        sweep: from :func:`build_sweep` or :func:`load_sweep`, or what :func:`load_sweep` takes.
        out: results folder on the local machine (sweep.csv, sweep.json, figure, ``variants/``);
            default ``results/<sweep name>/``.
        workers: processes of the embedded LocalCluster (default: CPU count).
        scheduler: address of an existing Dask scheduler (``tcp://host:8786``) instead.
        client: an existing ``dask.distributed.Client`` instead.
        resume: reuse variants finished by an earlier run of the same sweep into ``out``.
        progress: a progress bar on stderr.
        transfer: ``"ship"`` (each task carries its scenario and input files to the worker and
            brings its results back), ``"shared"`` (workers read and write the client's paths),
            ``"auto"`` (shared on the embedded cluster, ship otherwise).

    ``result.rows`` / ``result.records()`` hold the table; ``result.variant(i)`` is a
    :class:`RunResult` of variant ``i``'s folder.
    """
    from cosim.sweep.execute import run_sweep as execute
    from cosim.sweep.loader import Sweep

    if not isinstance(sweep, Sweep):
        sweep = load_sweep(sweep)
    return execute(sweep, out, workers=workers, scheduler=scheduler, client=client, progress=progress,
                   resume=resume, transfer=transfer)


__all__ = ["CAN_LOG_SUFFIXES", "DICT_LABEL", "FIGURE_SUFFIXES", "OutputFolderError", "PYTHON_LABEL", "RunFailed",
           "RunResult", "STRING_LABEL", "Scenario", "ScenarioError", "Summary", "TIMESERIES_SUFFIXES", "TimeSeries",
           "build_sweep", "execute", "export_blf", "load_scenario", "load_sweep", "read_can_log", "read_timeseries", "run",
           "run_sweep"]
