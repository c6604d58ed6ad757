"""What a run wrote, read back: its ``summary.json`` (:class:`Summary`), its time series
(:class:`TimeSeries`, :func:`read_timeseries`), figures and CAN logs (:class:`RunResult`), and
:class:`RunFailed`, the error of a run that ended ``failed``.

Part of :mod:`cosim.runs` (one run of a scenario), re-exported by :mod:`cosim.api`, the public
module for scripts (docs/how-to/scripting.md).
"""
from __future__ import annotations

import csv
import json
import math
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from cosim.runs.scenario import Scenario

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
    from fieldbus.blf import to_blf

    path = Path(path)
    return to_blf(path, Path(out) if out is not None else path.with_suffix(".blf"))


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


__all__ = ["CAN_LOG_PREFIX", "CAN_LOG_SUFFIXES", "FIGURE_SUFFIXES", "RunFailed", "RunResult", "Summary",
           "TIMESERIES_SUFFIXES", "TimeSeries", "export_blf", "read_can_log", "read_timeseries"]
