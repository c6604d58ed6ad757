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

import csv
import dataclasses
import json
import math
import shutil
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cosim.scenario.errors import ScenarioError

if TYPE_CHECKING:  # pragma: no cover
    from cosim.scenario.loader import Scenario as ValidatedScenario
    from cosim.sweep.execute import SweepResult
    from cosim.sweep.loader import Sweep

#: Labels used as ``ScenarioError.file`` for documents that are no file.
DICT_LABEL, STRING_LABEL, PYTHON_LABEL = "<dict>", "<string>", "<python>"
#: File name patterns of what a run writes, by kind (cosim.results; docs/reference/output_files.md).
TIMESERIES_SUFFIXES = (".parquet", ".csv")
FIGURE_SUFFIXES = (".png", ".svg", ".pdf")
CAN_LOG_SUFFIXES = (".blf", ".asc", ".trc", ".mf4")
CAN_LOG_PREFIX = "can_"
"""``can_<mode>.parquet`` is the columnar CAN log (fieldbus.canlog), not a time series."""


def _is_can_log(path: Path) -> bool:
    return path.suffix.lower() in CAN_LOG_SUFFIXES or (path.name.startswith(CAN_LOG_PREFIX)
                                                       and path.suffix.lower() == ".parquet")


def read_can_log(path: str | Path):
    """The frames of a CAN log a run wrote, as ``can.Message`` objects (an iterable reader, also a
    context manager): the columnar ``can_<mode>.parquet`` (``fieldbus.canlog``; the Messages
    ``can.BLFReader`` gives for the same log as BLF) or a BLF/ASC file (``can.LogReader``)."""
    from fieldbus.canlog import open_log

    return open_log(path)


def export_blf(path: str | Path, out: str | Path | None = None) -> Path:
    """Write the columnar CAN log ``path`` as BLF (``out``, default: the same name with ``.blf``),
    byte for byte the file python-can's ``BLFWriter`` writes for the same frames."""
    from fieldbus.canlog import to_blf

    path = Path(path)
    return to_blf(path, Path(out) if out is not None else path.with_suffix(".blf"))


def __getattr__(name: str) -> Any:
    if name == "OutputFolderError":   # cosim.results.outdir (imported on use)
        from cosim.results.outdir import OutputFolderError

        return OutputFolderError
    raise AttributeError(f"module 'cosim.api' has no attribute {name!r}")


class RunFailed(RuntimeError):
    """A run started and ended with status ``failed``.

    Attributes:
        result: the :class:`RunResult` (its folder holds everything written before the stop).
        summary: ``result.summary`` (``.reason``, ``.stopped_at_s``, ``.raw``).
        reason: the summary's reason.
    """

    def __init__(self, result: "RunResult") -> None:
        self.result = result
        self.summary = result.summary
        self.reason = self.summary.reason or "unknown reason"
        at = self.summary.stopped_at_s
        where = f" at t = {at:.6g} s" if isinstance(at, (int, float)) else ""
        super().__init__(f"{result.scenario.name}: run failed{where}: {self.reason} (results in {result.out}/)")


# ------------------------------------------------------------------------------------------ scenarios
class Scenario:
    """A validated scenario (nothing has run). Build with :func:`load_scenario`.

    Attributes:
        name: ``[scenario] name``.
        job: the job type (``[scenario] job``).
        description: ``[scenario] description``.
        path: the TOML file it was read from (None for a dict or a TOML text).
        source: the file path as text, or ``"<dict>"`` / ``"<string>"``.
        overrides: the overrides applied, ``{key path: value}``.
        document: the scenario document with the overrides in (raw TOML values).
        data: the validated document (defaults filled in, quantities in SI, paths resolved).
    """

    def __init__(self, validated: "ValidatedScenario", source: str, overrides: Mapping[str, Any]) -> None:
        self._validated = validated
        self.source = source
        self.overrides = dict(overrides)

    @property
    def validated(self) -> "ValidatedScenario":
        """The :class:`cosim.scenario.Scenario` the job runners take."""
        return self._validated

    @property
    def name(self) -> str:
        return self._validated.name

    @property
    def job(self) -> str:
        return self._validated.job.name

    @property
    def description(self) -> str:
        return self._validated.data["scenario"].get("description", "")

    @property
    def path(self) -> Path | None:
        return None if _is_label(self.source) else self._validated.path

    @property
    def document(self) -> dict[str, Any]:
        return self._validated.raw

    @property
    def data(self) -> dict[str, Any]:
        return self._validated.data

    def with_overrides(self, overrides: Mapping[str, Any]) -> "Scenario":
        """A new scenario with ``overrides`` applied on top of this one's (validated; ScenarioError)."""
        return _apply_overrides(self._validated, self.source, overrides, self.overrides)

    def to_toml(self) -> str:
        """The document as TOML text (file paths made absolute, so it runs from any folder)."""
        import tomli_w

        from cosim.scenario.keypath import absolute_paths

        doc = absolute_paths(self._validated.job.schema, self.document, self._validated.where.base_dir)
        return tomli_w.dumps(doc)

    def describe(self, max_list: int = 8) -> str:
        """What this scenario will run, as text: name, job, source, overrides, then every setting
        of the validated document as ``key path = value`` (SI units, defaults included; lists
        longer than ``max_list`` items shown by their length)."""
        from cosim.scenario.keypath import format_key_path

        lines = [f"scenario {self.name!r}: job {self.job!r}" + (f" - {self.description}" if self.description else ""),
                 f"  from {self.source}"]
        if self._validated.job.description:
            lines.append(f"  job: {self._validated.job.description}")
        if self.overrides:
            lines.append("  overrides: " + ", ".join(f"{k} = {v!r}" for k, v in self.overrides.items()))

        def walk(value: Any, prefix: tuple) -> Iterator[str]:
            if isinstance(value, dict) and value:
                for key, item in value.items():
                    yield from walk(item, prefix + (str(key),))
            elif isinstance(value, list) and len(value) > max_list:
                yield f"    {format_key_path(prefix)} = [{len(value)} items]"
            elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
                for i, item in enumerate(value):
                    yield from walk(item, prefix + (i,))
            else:
                yield f"    {format_key_path(prefix)} = {_show(value)}"

        for table, value in self.data.items():
            if table == "scenario":
                continue
            lines.append(f"  [{table}]" if isinstance(value, dict) else f"  {table}:")
            lines.extend(walk(value, (table,)))
        return "\n".join(lines)

    def __repr__(self) -> str:
        extra = f", overrides={self.overrides!r}" if self.overrides else ""
        return f"<cosim.Scenario {self.name!r} job={self.job!r} from {self.source}{extra}>"


def _show(value: Any) -> str:
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, float):
        return f"{value:.6g}"
    return repr(value)


def _is_label(text: str) -> bool:
    return text.startswith("<") and text.endswith(">")


def _is_toml_text(text: str) -> bool:
    return "\n" in text or ("=" in text and "[" in text)


def load_scenario(scenario: "str | Path | Mapping[str, Any] | Scenario",
                  overrides: Mapping[str, Any] | None = None, *, base_dir: str | Path | None = None) -> Scenario:
    """Read and validate a scenario (nothing runs, nothing is written).

    Args:
        scenario: a path to a TOML file, a TOML text (a string with a newline), a dict (the parsed
            document; file paths in it relative to the working directory) or a :class:`Scenario`.
        overrides: ``{"key.path": value}`` set in the document before validation (sweep-axis syntax).
        base_dir: the folder relative file paths of a dict or TOML text are relative to (default:
            the working directory).

    Raises:
        ScenarioError: the file is missing or not TOML, the document is invalid for its job, an
            override names a key the job does not have (or ``scenario.name``, ``scenario.job``,
            ``output``) or gives a value of the wrong type or unit. ``.file`` is the path,
            ``"<dict>"`` or ``"<string>"``.
    """
    from cosim.scenario.loader import load_scenario, resolve_path

    if isinstance(scenario, Scenario):
        return scenario.with_overrides(overrides) if overrides else scenario
    if isinstance(scenario, Mapping):
        validated = _validate_labelled(dict(scenario), DICT_LABEL, base_dir)
        source = DICT_LABEL
    elif isinstance(scenario, str) and _is_toml_text(scenario):
        import tomllib

        try:
            document = tomllib.loads(scenario)
        except tomllib.TOMLDecodeError as exc:
            raise ScenarioError(STRING_LABEL, "", "valid TOML", problem=str(exc)) from None
        validated = _validate_labelled(document, STRING_LABEL, base_dir)
        source = STRING_LABEL
    elif isinstance(scenario, (str, Path)):
        path = resolve_path(scenario)  # a project scenario of an installed package from any folder
        validated = load_scenario(path)
        source = str(path)
    else:
        raise TypeError(f"scenario: expected a path, a TOML text, a dict or a cosim.Scenario, "
                        f"got {type(scenario).__name__}")
    return _apply_overrides(validated, source, overrides or {}, {})


def _relabel(exc: ScenarioError, label: str) -> ScenarioError:
    return ScenarioError(label, exc.key, exc.expected, *(() if exc.given is None else (exc.given,)),
                         problem=exc.problem)


def _validate_labelled(document: dict[str, Any], label: str, base_dir: str | Path | None = None
                       ) -> "ValidatedScenario":
    """Validate a document that is no file; errors name ``label`` as their file; relative paths are
    relative to ``base_dir`` (default: the working directory)."""
    from cosim.scenario.loader import load_document

    if not isinstance(document.get("scenario"), dict) or "job" not in document["scenario"]:
        raise ScenarioError(label, "scenario.job" if isinstance(document.get("scenario"), dict) else "scenario",
                            "a [scenario] table with name and job (one of the registered job types: "
                            f"{', '.join(_job_names())})", problem="missing required key")
    # a path that is no file anchors relative paths in base_dir; errors name the label
    anchor = None if base_dir is None else Path(base_dir).resolve() / label
    try:
        return load_document(document, anchor)
    except ScenarioError as exc:
        raise (_relabel(exc, label) if exc.file in (anchor, None) else exc) from None


def _job_names() -> list[str]:
    from cosim.scenario import job_names

    return job_names()


def _apply_overrides(base: "ValidatedScenario", source: str, overrides: Mapping[str, Any],
                     earlier: Mapping[str, Any]) -> Scenario:
    """Put ``overrides`` into ``base``'s document with the sweep's key-path code, then validate."""
    if not overrides:
        return Scenario(base, source, earlier)
    from cosim.scenario.loader import load_document
    from cosim.scenario.schema import Where
    from cosim.scenario.keypath import (KeyPathSyntaxError, absolute_paths, format_key_path, overlapping,
                                     parse_key_path, spec_at, with_value)
    from cosim.sweep.loader import flatten_overrides, scenario_key_path

    file: Any = source if _is_label(source) else base.path
    if not isinstance(overrides, Mapping):
        raise TypeError(f"overrides: expected a dict {{'key.path': value}}, got {type(overrides).__name__}")
    applied: list[tuple[tuple, Any, Where]] = []
    document = base.raw
    for path, value, _ in flatten_overrides(dict(overrides), Where(file)):
        text = format_key_path(path)
        where = Where(file, tuple(path))
        checked = scenario_key_path(text, where, base, what="override")
        try:
            value = absolute_paths(spec_at(base.job.schema, checked, document), value, Path.cwd())
        except KeyPathSyntaxError:  # pragma: no cover - scenario_key_path checked it
            pass
        document = with_value(document, checked, value)
        applied.append((checked, value, where))
    try:
        validated = load_document(document, base.path)
    except ScenarioError as exc:
        try:
            err_path = parse_key_path(exc.key) if exc.key else ()
        except KeyPathSyntaxError:
            err_path = ()
        blamed = [(p, v, w) for p, v, w in applied if err_path and overlapping(p, err_path)]
        if blamed:
            path, value, where = max(blamed, key=lambda b: len(b[0]))
            at = f" (at {exc.key})" if tuple(err_path) != tuple(path) else ""
            raise ScenarioError(where.file, where.key, exc.expected + at, value,
                                problem=f"override: {exc.problem}" if exc.problem else "override") from None
        raise (_relabel(exc, source) if _is_label(source) else exc) from None
    merged = {**earlier, **{format_key_path(p): v for p, v, _ in applied}}
    return Scenario(validated, source, merged)


# ------------------------------------------------------------------------------------------ results
class Summary:
    """A run's ``summary.json``: typed access to the fields every run has, ``raw`` for the rest.

    ``summary["modes.standard.tcp_error_max_mm"]`` reads any leaf by key path (KeyError if absent);
    ``summary.get(key, default)`` likewise with a default.
    """

    def __init__(self, raw: Mapping[str, Any]) -> None:
        self.raw: dict[str, Any] = dict(raw)

    @property
    def status(self) -> str:
        """``"ok"``, ``"limit"``, ``"fault"`` (completed, with the most severe verdict of its cell runs;
        cosim/cell/verdict.py), ``"failed"``, ``"interrupted"`` or ``"running"`` (a run that died
        without finishing)."""
        return str(self.raw.get("status", "running"))

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def reason(self) -> str | None:
        """Why the run failed, or which run hit a limit or faulted and how (None when ok)."""
        return self.raw.get("reason")

    @property
    def stopped_at_s(self) -> float | None:
        """Simulated time the failed run stopped at, s (None when ok or unknown)."""
        return self.raw.get("stopped_at_s")

    @property
    def sim_time_s(self) -> float:
        return float(self.raw.get("sim_time_s") or 0.0)

    @property
    def wall_time_s(self) -> float:
        return float(self.raw.get("wall_time_s") or 0.0)

    @property
    def realtime_factor(self) -> float | None:
        """Simulated / wall time (> 1: faster than real time)."""
        value = self.raw.get("realtime_factor")
        return None if value is None else float(value)

    @property
    def scenario(self) -> str:
        return str(self.raw.get("scenario", ""))

    @property
    def job(self) -> str:
        return str(self.raw.get("job", ""))

    @property
    def started_at(self) -> str:
        """UTC start time, ISO 8601."""
        return str(self.raw.get("started_at", ""))

    def __getitem__(self, key: str) -> Any:
        from cosim.scenario.keypath import get_path, parse_key_path

        if key in self.raw:
            return self.raw[key]
        return get_path(self.raw, parse_key_path(key))

    def get(self, key: str, default: Any = None) -> Any:
        try:
            return self[key]
        except (KeyError, ValueError):
            return default

    def __contains__(self, key: str) -> bool:
        return self.get(key, _ABSENT) is not _ABSENT

    def __repr__(self) -> str:
        return (f"<cosim.Summary {self.scenario!r} status={self.status!r} sim_time_s={self.sim_time_s:g}"
                + (f" reason={self.reason!r}" if self.reason else "") + ">")


_ABSENT = object()


class TimeSeries:
    """A time-series file as numpy columns (what :meth:`RunResult.timeseries` returns without pandas).

    ``ts["time"]`` is a column (numpy array), ``ts.columns`` the names in file order, ``len(ts)``
    the row count, ``ts.to_numpy()`` a 2-D float array (numeric columns), ``ts.to_pandas()`` a
    DataFrame (needs pandas).
    """

    def __init__(self, columns: Sequence[str], data: Mapping[str, Any], path: Path | None = None) -> None:
        self.columns = list(columns)
        self._data = dict(data)
        self.path = path

    def __getitem__(self, column: str):
        try:
            return self._data[column]
        except KeyError:
            raise KeyError(f"{column!r}: no such column in {self.path or 'the time series'} "
                           f"(columns: {', '.join(self.columns[:12])}{', ...' if len(self.columns) > 12 else ''})")\
                from None

    def __contains__(self, column: str) -> bool:
        return column in self._data

    def __len__(self) -> int:
        return len(self._data[self.columns[0]]) if self.columns else 0

    def to_numpy(self):
        import numpy as np

        return np.column_stack([np.asarray(self._data[c], dtype=float) for c in self.columns]) \
            if self.columns else np.zeros((0, 0))

    def to_pandas(self):
        import pandas as pd

        return pd.DataFrame({c: self._data[c] for c in self.columns})

    def __repr__(self) -> str:
        return f"<cosim.TimeSeries {len(self)} rows x {len(self.columns)} columns from {self.path}>"


def read_timeseries(path: str | Path, kind: str = "auto"):
    """Read a time-series file (Parquet or CSV) written by a run.

    ``kind``: ``"auto"`` (a pandas DataFrame when pandas is installed, else a :class:`TimeSeries`),
    ``"pandas"`` or ``"numpy"`` (a :class:`TimeSeries` of numpy arrays).
    """
    path = Path(path)
    if kind not in ("auto", "pandas", "numpy"):
        raise ValueError(f"kind: expected 'auto', 'pandas' or 'numpy', got {kind!r}")
    if kind == "auto":
        try:
            import pandas  # noqa: F401
            kind = "pandas"
        except ImportError:
            kind = "numpy"
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq

        import numpy as np

        from cosim.results.timeseries import is_encoded, read_series

        if is_encoded(pq.read_schema(path)):  # compact columns: decoded to the float64 values written
            names, values = read_series(path)
            schema = pq.read_schema(path)
            columns = {}
            for i, n in enumerate(names):  # plain integer columns stay integers
                f = schema.field(n) if schema.get_field_index(n) >= 0 else None  # None: a derived column
                plain_int = f is not None and str(f.type).startswith("int") and b"cosim.encoding" not in (f.metadata or {})
                columns[n] = values[:, i].astype(np.int64) if plain_int else values[:, i]
            if kind == "pandas":
                import pandas as pd

                return pd.DataFrame(columns)
            return TimeSeries(names, columns, path)
        table = pq.read_table(path)
        if kind == "pandas":
            return table.to_pandas()
        return TimeSeries(table.column_names, {c: table.column(c).to_numpy() for c in table.column_names}, path)
    if kind == "pandas":
        import pandas as pd

        return pd.read_csv(path)
    return _read_csv_columns(path)


def _read_csv_columns(path: Path) -> TimeSeries:
    import numpy as np

    from robot.textfiles import open_text

    with open_text(path) as f:
        reader = csv.reader(f)
        header = next(reader, [])
        rows = list(reader)
    data: dict[str, Any] = {}
    for i, name in enumerate(header):
        cells = [row[i] if i < len(row) else "" for row in rows]
        try:
            data[name] = np.array([float(c) if c != "" else math.nan for c in cells], dtype=float)
        except ValueError:
            data[name] = np.array(cells, dtype=object)
    return TimeSeries(header, data, path)


class RunResult:
    """What a run wrote (returned by :func:`run`; also for a sweep's variant folders).

    Attributes:
        out: the results folder.
        scenario: the :class:`Scenario` that ran (None when opened from a folder).
        temporary: True when ``out`` is a temporary folder made by :func:`run` (removed by
            :meth:`cleanup` or on leaving a ``with`` block).
        error: the exception that stopped the run (None when ok or not known).
    """

    def __init__(self, out: str | Path, scenario: Scenario | None = None, temporary: bool = False,
                 error: BaseException | None = None) -> None:
        self.out = Path(out)
        self.scenario = scenario
        self.temporary = temporary
        self.error = error
        self._summary: Summary | None = None

    @classmethod
    def open(cls, out: str | Path) -> "RunResult":
        """The result in an existing results folder (e.g. ``results/iso9283`` or a sweep variant's)."""
        out = Path(out)
        if not (out / "summary.json").is_file():
            raise FileNotFoundError(f"{out}: no summary.json (not a results folder of cosim run)")
        return cls(out)

    @property
    def summary(self) -> Summary:
        """``summary.json`` (read once; :meth:`reload` reads it again)."""
        if self._summary is None:
            try:
                raw = json.loads((self.out / "summary.json").read_text(encoding="utf-8"))
            except (OSError, ValueError):
                raw = {"status": "failed", "reason": f"no readable summary.json in {self.out}"}
            self._summary = Summary(raw)
        return self._summary

    def reload(self) -> "RunResult":
        self._summary = None
        return self

    @property
    def status(self) -> str:
        return self.summary.status

    @property
    def ok(self) -> bool:
        return self.summary.ok

    def _files(self, suffixes: Sequence[str]) -> list[Path]:
        if not self.out.is_dir():
            return []
        return sorted(p for p in self.out.rglob("*") if p.is_file() and p.suffix.lower() in suffixes)

    @property
    def figures(self) -> list[Path]:
        """The figure files (PNG, SVG, PDF), sorted."""
        return self._files(FIGURE_SUFFIXES)

    @property
    def can_log(self) -> list[Path]:
        """The CAN log files (``can_<mode>.parquet``, ``.blf``, ...; read them with :func:`read_can_log`), sorted (empty with ``[results] can_log = false``)."""
        if not self.out.is_dir():
            return []
        return sorted(p for p in self.out.rglob("*") if p.is_file() and _is_can_log(p))

    @property
    def timeseries_files(self) -> dict[str, Path]:
        """Time-series files by name (file name without suffix, relative to ``out``); Parquet wins over CSV."""
        out: dict[str, Path] = {}
        for suffix in reversed(TIMESERIES_SUFFIXES):   # csv first, parquet replaces it
            for path in self._files((suffix,)):
                if _is_can_log(path):
                    continue
                out[path.relative_to(self.out).with_suffix("").as_posix()] = path
        return dict(sorted(out.items()))

    @property
    def timeseries_names(self) -> list[str]:
        """The names :meth:`timeseries` accepts (``timeseries_standard``, ``tcp_model_based``, ...)."""
        return list(self.timeseries_files)

    def timeseries(self, name: str, kind: str = "auto"):
        """Load the time series ``name`` (see :attr:`timeseries_names`; a file name with suffix works too).

        Returns a pandas DataFrame when pandas is installed (``kind="auto"``), else a
        :class:`TimeSeries` of numpy arrays (``kind="numpy"`` always). Reads the Parquet file
        when the run wrote one, else the CSV.
        """
        files = self.timeseries_files
        key = name
        for suffix in TIMESERIES_SUFFIXES:
            if key.endswith(suffix):
                key = key[: -len(suffix)]
        if key not in files:
            raise KeyError(f"{name!r}: no time series in {self.out} (available: {', '.join(files) or 'none'})")
        return read_timeseries(files[key], kind)

    def cleanup(self) -> None:
        """Remove the folder if :func:`run` made it as a temporary folder (no-op otherwise)."""
        if self.temporary and self.out.exists():
            shutil.rmtree(self.out, ignore_errors=True)

    def __enter__(self) -> "RunResult":
        return self

    def __exit__(self, *exc: object) -> None:
        self.cleanup()

    def __repr__(self) -> str:
        name = self.scenario.name if self.scenario is not None else self.summary.scenario
        return f"<cosim.RunResult {name!r} status={self.status!r} out={str(self.out)!r}>"


# ------------------------------------------------------------------------------------------ running
def run(scenario: "str | Path | Mapping[str, Any] | Scenario", out: str | Path | None = None,
        overrides: Mapping[str, Any] | None = None, *, quiet: bool = True, realtime: bool = False,
        split: bool = False, check: bool = True, timeseries: str | None = None,
        max_output: str | float | None = None, max_memory: str | float | None = None,
        ignore_budget: bool = False) -> RunResult:
    """Validate and run a scenario; return its :class:`RunResult`.

    Args:
        scenario: as for :func:`load_scenario`.
        out: the results folder (created; files in it are replaced; locked while the run goes).
            None: a new temporary folder (``RunResult.temporary``; kept until :meth:`RunResult.cleanup`).
        overrides: ``{"key.path": value}`` applied before validation.
        quiet: no progress bar on stderr.
        realtime, split: pace the robot cell at the wall clock / run controller and drives in two
            processes (as ``cosim run --realtime/--split``; docs/how-to/served_cell.md).
        check: raise :class:`RunFailed` when the run ends ``failed`` (False: return the result).
            A run that completed with verdict ``limit`` or ``fault`` is returned, not raised:
            ``result.status`` says so (and ``result.summary["verdicts"]`` per cell run).
        timeseries: ``"parquet"`` (default, or ``$COSIM_TIMESERIES``) or ``"csv"``: the format
            of the time-series files.
        max_output, max_memory, ignore_budget: the run's budget (``cosim.results.budget``:
            sizes like ``"5 GB"``; default: free disk space, half the RAM); a run estimated
            above it raises :class:`cosim.results.budget.BudgetError` before anything runs.

    Raises:
        ScenarioError: invalid scenario or override (nothing is written, no folder is made).
        OutputFolderError: ``out`` cannot be used (a file, not writable, locked by another run).
        RunFailed: the run failed (``check=True``); summary.json in the folder says why and where.
        KeyboardInterrupt: Ctrl-C (or SIGTERM under the CLI), passed on after summary.json is
            finished as ``interrupted`` (with the signal and where it stopped).
    """
    sc = load_scenario(scenario, overrides)
    options = _execution_options(sc, realtime, split)
    if out is None:
        out_dir, temporary = Path(tempfile.mkdtemp(prefix=f"cosim-{sc.name}-")), True
    else:
        out_dir, temporary = Path(out), False
    result = _execute_into(sc, out_dir, options, quiet=quiet, origin="out", temporary=temporary,
                           timeseries=timeseries, budget=None if ignore_budget else (max_output, max_memory))
    if check and result.status == "failed":
        raise RunFailed(result) from result.error
    return result


def execute(scenario: Scenario, out: str | Path, *, quiet: bool = True, realtime: bool = False,
            split: bool = False, origin: str = "out", timeseries: str | None = None, serve: Any = None,
            max_output: str | float | None = None, max_memory: str | float | None = None,
            ignore_budget: bool = False, clock_from_process_start: bool = False,
            report: bool | None = None) -> RunResult:
    """Run an already loaded scenario into ``out`` and return the result whatever its status
    (the layer under :func:`run` and ``cosim run``; ``origin`` names where ``out`` came from in
    an OutputFolderError, e.g. ``"--out"``). ``serve`` (a :class:`cosim.execution.serve_settings.ServeSettings`):
    run only the cell side of each robot-cell run, paced, for a controller elsewhere on the bus
    (``cosim serve``). ``max_output``, ``max_memory``, ``ignore_budget``: as for :func:`run`.
    ``clock_from_process_start``: summary.json's ``wall_time_s`` and ``realtime_factor`` count
    from this process's start (``cosim run``: the whole command, interpreter start and imports
    included; ``wall_time_from = "process start"``) instead of from this call. ``report``: write
    report.html (None: unless the scenario's ``[results] report`` is false; docs/how-to/view_results.md).
    Raises ScenarioError, OutputFolderError, KeyboardInterrupt as :func:`run` does (and
    BudgetError); never RunFailed."""
    if serve is not None:
        options = _execution_options(scenario, True, False)
        options = dataclasses.replace(options, mode="serve", realtime=True, serve=serve)
    else:
        options = _execution_options(scenario, realtime, split)
    return _execute_into(scenario, Path(out), options, quiet=quiet, origin=origin, temporary=False,
                         timeseries=timeseries, budget=None if ignore_budget else (max_output, max_memory),
                         clock_from_process_start=clock_from_process_start, report=report)


def _execution_options(sc: Scenario, realtime: bool, split: bool):
    """The cell execution options, or None (one process, unpaced); ScenarioError for a job without a cell."""
    from cosim.execution.config import execution_options
    from cosim.execution.cell_execution import CELL_JOBS

    options = execution_options(sc.data, realtime=realtime or None, split=split or None)
    if not options.active:
        return None
    if sc.job not in CELL_JOBS:
        raise ScenarioError(sc.source if _is_label(sc.source) else sc.path, "execution",
                            f"a job that runs a robot cell ({', '.join(sorted(CELL_JOBS))}) for realtime, split and "
                            f"[execution] realtime/mode = 'split'", sc.job,
                            problem=f"job {sc.job!r} runs no robot cell")
    return options


def _execute_into(sc: Scenario, out_dir: Path, options, *, quiet: bool, origin: str, temporary: bool,
                  timeseries: str | None = None, budget: tuple | None = (None, None),
                  clock_from_process_start: bool = False, report: bool | None = None) -> RunResult:
    """Lock ``out_dir``, run the job, finish summary.json, write report.html (``report``: None = as the
    scenario's ``[results] report`` says; never for a temporary folder); the result (``error``: what
    failed the run)."""
    wall_origin, wall_time_from = None, "run call"
    if clock_from_process_start:
        from cosim.results.summary import process_started_perf_counter

        wall_origin = process_started_perf_counter()
        if wall_origin is not None:
            wall_time_from = "process start"
    from cosim.commands.exits import describe_os_error
    from cosim.results.outdir import OutputFolderError, open_results_folder
    from cosim.scenario import RunContext

    execution = None
    if options is not None:
        from cosim.execution.cell_execution import CellExecution

        execution = CellExecution(options)
    with open_results_folder(out_dir, origin):
        if budget is not None:  # the folder is usable: the estimate, before anything runs or is written
            from cosim.results.budget import check_budget, estimate_run
            from cosim.results.timeseries import default_format

            held = execution is not None and bool(getattr(execution, "active", False))
            check_budget(estimate_run(sc.data, timeseries or default_format(), in_memory=held), out_dir, *budget)
        try:
            ctx = RunContext(sc.validated, out_dir, quiet=quiet, execution=execution, timeseries_format=timeseries,
                             wall_origin=wall_origin, wall_time_from=wall_time_from)
        except OSError as exc:
            raise OutputFolderError(describe_os_error(exc, f"{origin} {str(out_dir)!r}: cannot write summary.json"))\
                from None
        try:
            error = _run_job(sc, ctx)
        except BaseException:
            from cosim.results import report as report_module

            report_module.cancel(out_dir)  # interrupted: 'cosim view' shows what is there
            raise
        if report is None:
            from cosim.results import report as report_module

            report = not temporary and report_module.wanted(sc.data)
        _write_report(out_dir, report)
    return RunResult(out_dir, sc, temporary, error)


def _write_report(out_dir: Path, wanted: bool) -> None:
    """report.html in the results folder (``[results] report``, docs/how-to/view_results.md); a report that cannot
    be written is a warning line, never a failed run (``cosim view`` writes it later)."""
    import sys

    from cosim.results import report

    if not wanted:
        report.cancel(out_dir)
        return
    try:
        report.finish(out_dir)
    except Exception as exc:  # noqa: BLE001 - the run's results are complete without it
        report.cancel(out_dir)
        print(f"warning: {out_dir / report.REPORT_NAME} not written ({type(exc).__name__}: {exc}); "
              f"'python -m cosim view {out_dir}' writes it", file=sys.stderr)


def _run_job(sc: Scenario, ctx) -> BaseException | None:
    """Run the job in ``ctx`` and write the final status (ok, failed with the reason and where,
    interrupted); return the exception that failed the run, or None."""
    from cosim.cli import defer_signals, interrupt_raised
    from cosim.commands.exits import describe_os_error, is_disk_full, signal_name_of
    from cosim.master import SimulationError

    try:
        fields = sc.validated.job.runner(sc.validated, ctx) or {}
        status, reason, verdict_fields = _job_verdict(ctx)
        ctx.summary.finish_verdict(status, ctx.sim_time_s, reason, **fields, **verdict_fields)
        return None
    except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM through the CLI's handler
        with defer_signals():
            if getattr(ctx, "verdicts", None):
                ctx.summary.data["verdicts"] = dict(ctx.verdicts)
            ctx.summary.finish_interrupted(signal_name_of(exc), ctx.stopped_at_s, ctx.sim_time_s,
                                           mode=ctx.label or None, interrupted_in=ctx.label or None)
        raise
    except Exception as exc:
        interrupt = interrupt_raised()
        if interrupt is not None:  # Ctrl-C raised inside code that turned it into this error (a Python FMU)
            with defer_signals():
                ctx.summary.finish_interrupted(interrupt.signal_name, ctx.stopped_at_s, ctx.sim_time_s,
                                               mode=ctx.label or None, interrupted_in=ctx.label or None)
            raise interrupt from exc
        with defer_signals():
            extra: dict[str, Any] = {}
            if isinstance(exc, SimulationError):
                reason, stopped = str(exc), exc.time
                extra = {"failed_component": exc.component, "fmu_messages": exc.messages}
                if is_disk_full(exc):
                    reason = "disk full: " + _first_line(str(exc))
            elif isinstance(exc, OSError):
                reason = (("disk full: " if is_disk_full(exc) else "")
                          + describe_os_error(exc, "" if exc.filename else f"writing the results in {ctx.out_dir}"))
                stopped = ctx.stopped_at_s
            elif isinstance(exc, ValueError):
                reason, stopped = _first_line(str(exc)), ctx.stopped_at_s
            else:
                reason, stopped = f"internal error: {type(exc).__name__}: {exc}", ctx.stopped_at_s
            if getattr(ctx, "verdicts", None):
                extra["verdicts"] = dict(ctx.verdicts)
            ctx.summary.finish_failed(reason, stopped, ctx.sim_time_s, failed_in=ctx.label or None,
                                      mode=ctx.label or None, **extra)
        return exc


def _job_verdict(ctx) -> tuple[str, str | None, dict[str, Any]]:
    """The job's status (the most severe verdict of its cell runs, ``ok`` without any), the
    reason naming the first such run and its first violation, and the summary fields
    ``verdicts`` (per run) and ``first_violation`` (of the run the status comes from)."""
    from cosim.cell.verdict import describe_violation, most_severe

    verdicts = dict(getattr(ctx, "verdicts", None) or {})
    if not verdicts:
        return "ok", None, {}
    status = most_severe([v["verdict"] for v in verdicts.values()])
    fields: dict[str, Any] = {"verdicts": verdicts}
    if status == "ok":
        return status, None, fields
    label, worst = next((k, v) for k, v in verdicts.items() if v["verdict"] == status)
    first = worst.get("first_violation")
    fields["first_violation"] = first
    others = [k for k, v in verdicts.items() if v["verdict"] != "ok" and k != label]
    reason = f"{label}: {status}" + (f": {describe_violation(first)}" if first else "")
    if others:
        reason += f" (also not ok: {', '.join(others)})"
    return status, reason, fields


def _first_line(text: str) -> str:
    return text.strip().splitlines()[0] if text.strip() else text


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
