"""Sweep files: read, validate, and expand into validated variant scenario documents.

A sweep file names a base scenario and the axes to vary (docs/how-to/sweep_cluster.md)::

    [sweep]
    name = "calibration_noise_mc"
    base = "calibration.toml"          # relative to this file
    metrics = ["calibrated_max_position_error_mm"]   # optional: summary leaves to tabulate (globs)

    [overrides]                        # optional: set in every variant
    "selection.restarts" = 2

    [[axes]]                           # grid axis
    key = "tracker.position_sigma"
    values = ["0.05 mm", "0.1 mm", "0.2 mm"]

    [[axes]]                           # Monte Carlo axis
    key = "tracker.noise_seed"
    seeds = 20

    [report]                           # optional figure
    metric = "calibrated_max_position_error_mm"
    parameter = "tracker.position_sigma"

The variants are the cartesian product of the grid axes (first axis slowest) times the
Monte Carlo draws (all Monte Carlo axes have the same number of draws and are zipped:
draw i takes the i-th value of each). ``load_sweep`` checks everything before anything
runs: the sweep file's own keys, each axis key against the base job's schema, and every
variant document with the job's full validation (``load_document``), so a value of the
wrong type or unit is a ``ScenarioError`` naming the sweep file, the axis value and what
the job expected.
"""
from __future__ import annotations

import hashlib
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.scenario import ScenarioError, load_document, load_scenario
from cosim.scenario.loader import NAME_PATTERN, Scenario, read_toml_file, resolve_path
from cosim.scenario.schema import AnyValue, Field, FilePath, Integer, List, String, Table, Where, validate
from cosim.sweep.axes import DISTRIBUTION, DISTRIBUTIONS, GRID, SEEDS, Axis, distribution_draws, seed_values
from cosim.scenario.keypath import (FIXED_KEYS, KeyPath, KeyPathSyntaxError, absolute_paths, flatten_overrides,
                                    format_key_path, get_path, overlapping, parse_key_path, scenario_key_path, spec_at,
                                    with_value)

#: Figure kinds of [report]: every variant as a dot plus the mean per x value, or a box per x value.
REPORT_KINDS = ("points", "box")

#: Default largest number of variants of a sweep ([sweep] max_variants raises it): every variant is
#: validated (tens of ms each) before anything runs, and 10,000 variants of the main job are ~2 days
#: on one 2-core machine; a bigger count is usually a typo in seeds/samples or a too fine grid.
MAX_VARIANTS = 10_000

SWEEP_TABLE = Table({
    "name": Field(String(pattern=NAME_PATTERN, pattern_doc="of letters, digits, '_', '.', '-' (used as folder name)"),
                  required=True, doc="the sweep's name: its results folder is results/<name>/ unless --out says otherwise"),
    "base": Field(FilePath(must_exist=True, suffix=".toml"), required=True,
                  doc="the base scenario: a path to a .toml file relative to the sweep file"),
    "description": Field(String(nonempty=False), default="", doc="free text, kept in sweep.json"),
    "metrics": Field(List(String(), min_len=1),
                     doc="summary.json leaves to tabulate, as key paths with globs (* within one key, ** across keys: "
                         "'modes.*.tcp_error_max_mm'; default: every numeric leaf)"),
    "retries": Field(Integer(min=0, max=20), default=2,
                     doc="re-runs of a variant whose worker died or whose task raised"),
    "max_variants": Field(Integer(min=1), default=None,
                          doc=f"the most variants the sweep may have (default {MAX_VARIANTS:,})"),
    "collect": Field(List(String()), default=[],
                     doc="what a variant run elsewhere brings back besides its summary row: 'timeseries', "
                         "'figures', 'can_log', 'all', or globs relative to the variant's folder"),
    "store": Field(String(), doc="an fsspec URL (a local path, s3://bucket/prefix, ...) the workers write the "
                                 "collected files to, under <store>/variants/<id>-<hash8>/"),
}, doc="the [sweep] table")

#: The [sweep] table of a sweep built in Python around an already loaded base scenario (no ``base`` key).
SWEEP_TABLE_GIVEN_BASE = Table({k: f for k, f in SWEEP_TABLE.fields.items() if k != "base"},
                               doc="the [sweep] table")


DISTRIBUTION_TABLE = Table({
    "kind": Field(String(choices=tuple(DISTRIBUTIONS)), required=True,
                  doc="normal (mean, std), uniform (low, high) or lognormal (median, sigma); numpy PCG64 draws "
                      "seeded with the axis' seed and key"),
    **{name: Field(AnyValue(), doc="a number or a unit string")
       for name in sorted({p for params in DISTRIBUTIONS.values() for p in params})},
}, doc="a distribution table {kind = 'normal', mean = ..., std = ...}")


def _check_distribution(table: dict, where: Where) -> None:
    wanted = DISTRIBUTIONS[table["kind"]]
    for name in wanted:
        if name not in table:
            raise (where / name).error(f"the parameters {', '.join(wanted)} of a {table['kind']} distribution",
                                       problem="missing required key")
    for name in table:
        if name != "kind" and name not in wanted:
            raise (where / name).error(f"only the parameters {', '.join(wanted)} of a {table['kind']} distribution",
                                       problem="unknown key")


DISTRIBUTION_TABLE.check_fn = _check_distribution

AXIS_TABLE = Table({
    "key": Field(String(), required=True, doc="a key path of the base scenario, e.g. 'tracker.noise_sigma'"),
    "values": Field(List(AnyValue()), doc="grid values"),
    "seeds": Field(Integer(min=0), doc="the number of integer seeds (Monte Carlo)"),
    "first_seed": Field(Integer(min=0), doc="the first seed (with seeds; default 0)"),
    "distribution": Field(DISTRIBUTION_TABLE, doc="a Monte Carlo axis of random draws (with samples)"),
    "samples": Field(Integer(min=0), doc="the number of draws (with distribution)"),
    "seed": Field(Integer(min=0), doc="the random seed of the draws (with distribution; default 0)"),
}, one_of=[("values", "seeds", "distribution")], doc="an [[axes]] table")


def _check_axis(table: dict, where: Where) -> None:
    only = {"first_seed": SEEDS, "samples": DISTRIBUTION, "seed": DISTRIBUTION}
    for key, owner in only.items():
        if key in table and owner not in table:
            raise (where / key).error(f"{key} only together with {owner}", table[key], problem="misplaced key")
    if "distribution" in table and "samples" not in table:
        raise (where / "samples").error("the number of draws: an integer >= 1", problem="missing required key")
    for key in ("values", "seeds", "samples"):
        if key in table and table[key] in ([], 0):
            raise (where / key).error("at least one value (an empty axis gives no variants)", table[key],
                                      problem="empty axis")


AXIS_TABLE.check_fn = _check_axis

REPORT_TABLE = Table({
    "metric": Field(String(), required=True,
                    doc="the table column to plot (a summary.json leaf such as 'calibrated.e_x.max'; * globs)"),
    "parameter": Field(String(), required=True, doc="the axis key on the x axis"),
    "group": Field(String(), doc="an axis key: one series per value"),
    "kind": Field(String(choices=REPORT_KINDS), default="points",
                  doc="every variant as a dot plus the mean per x value, or a box per x value"),
    "file": Field(String(pattern=r"[A-Za-z0-9_.-]+\.png", pattern_doc="naming a .png file in the sweep folder"),
                  default="sweep.png", doc="the figure's file in the sweep's results folder"),
    "title": Field(String(nonempty=False), default="", doc="the figure's title"),
    "x_scale": Field(String(choices=("linear", "log")), default="linear", doc="the x axis' scale"),
    "y_scale": Field(String(choices=("linear", "log")), default="linear", doc="the y axis' scale"),
}, doc="the sweep's figure: a table column against an axis key")

SWEEP_SCHEMA = Table({
    "sweep": Field(SWEEP_TABLE, required=True, doc="a [sweep] table with name and base"),
    "overrides": Field(Table({}, extra=AnyValue(), doc="a table of <key path> = <value>"), default={}),
    "axes": Field(List(AXIS_TABLE, min_len=1), required=True, doc="at least one [[axes]] table"),
    "report": Field(REPORT_TABLE, doc="the sweep's figure: a table column against an axis key"),
}, doc="a sweep document")
SWEEP_SCHEMA_GIVEN_BASE = Table({**SWEEP_SCHEMA.fields, "sweep": Field(SWEEP_TABLE_GIVEN_BASE, required=True,
                                                                       doc="a [sweep] table with name")},
                                doc="a sweep document")

#: Named groups of ``[sweep] collect`` -> the globs they stand for.
COLLECT_GROUPS: dict[str, tuple[str, ...]] = {
    "timeseries": ("*.csv", "*.parquet"),
    "figures": ("*.png", "*.svg", "*.pdf"),
    "can_log": ("can_*.parquet", "*.blf", "*.asc", "*.trc", "*.mf4"),
    "all": ("**/*",),
}


def collect_globs(items) -> tuple[str, ...]:
    """The globs of a ``collect`` list (named groups expanded, order kept, duplicates dropped)."""
    out: dict[str, None] = {}
    for item in items or ():
        for glob in COLLECT_GROUPS.get(item, (item,)):
            out.setdefault(glob, None)
    return tuple(out)


def check_store_url(url: str, where: Where, base_dir: Path) -> str:
    """``url`` as the workers will use it: a local path made absolute against ``base_dir``; an fsspec
    protocol must be known to fsspec (ScenarioError at ``where`` otherwise)."""
    import fsspec

    protocol, _, rest = url.partition("://")
    if not rest:
        return str((base_dir / Path(url).expanduser()).resolve())
    try:
        fsspec.get_filesystem_class(protocol)
    except (ValueError, ImportError) as exc:
        raise where.error("a local path or an fsspec URL whose protocol fsspec knows (file://, s3://, gcs://, "
                          "memory://, ...) with its package installed", url, problem=str(exc)) from None
    return url


@dataclass(frozen=True)
class Report:
    """The [report] figure: ``metric`` (a table column, globs allowed) against the axis ``parameter``."""

    metric: str
    parameter: str
    group: str | None = None
    kind: str = "points"
    file: str = "sweep.png"
    title: str = ""
    x_scale: str = "linear"
    y_scale: str = "linear"


@dataclass
class Variant:
    """One point of a sweep.

    Attributes:
        index: position in the sweep (0-based).
        id: ``v0000``, ``v0001``, ... (folder name under ``variants/``).
        params: axis key -> the value put into the scenario (as written, e.g. ``"0.1 mm"``).
        values: axis key -> the same value as the job validated it (SI numbers; the table's columns).
        document: the variant's scenario document (raw TOML values, file paths absolute).
        hash: SHA-256 (hex, 16 chars) of job + document: a finished folder with this hash is reused.
    """

    index: int
    id: str
    params: dict[str, Any]
    values: dict[str, Any]
    document: dict[str, Any] = field(repr=False)
    hash: str = ""


@dataclass
class Sweep:
    """A validated sweep file and its variants (all validated by the base job).

    ``path`` is the sweep file, or a label such as ``"<python>"`` for a sweep built in Python
    (cosim.api.build_sweep); ``collect`` holds the globs of ``[sweep] collect``, ``store``
    the URL of ``[sweep] store``.
    """

    path: Path
    name: str
    description: str
    base: Scenario
    axes: list[Axis]
    overrides: dict[str, Any]
    metrics: list[str] | None
    retries: int
    report: Report | None
    variants: list[Variant]
    collect: tuple[str, ...] = ()
    store: str | None = None

    @property
    def job(self) -> str:
        """The base scenario's job type."""
        return self.base.job.name

    @property
    def parameters(self) -> list[str]:
        """The axis keys (the parameter columns of the table), in file order."""
        return [a.key for a in self.axes]


def variant_hash(job: str, document: dict[str, Any]) -> str:
    """Hash of what a variant runs: the job and its whole scenario document."""
    text = json.dumps({"job": job, "document": document}, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def _file_value(base: Scenario, path: KeyPath, value: Any, sweep_dir: Path) -> Any:
    """A value given in the sweep file, with relative file paths resolved against the sweep file's folder."""
    return absolute_paths(spec_at(base.job.schema, path, base.raw), value, sweep_dir)


def _axis(table: dict, where: Where, base: Scenario, sweep_dir: Path) -> Axis:
    path = scenario_key_path(table["key"], where / "key", base)
    key = format_key_path(path)
    if "values" in table:
        values = [_file_value(base, path, v, sweep_dir) for v in table["values"]]
        return Axis(key, path, GRID, tuple(values), where, "values")
    if "seeds" in table:
        return Axis(key, path, SEEDS, tuple(seed_values(table["seeds"], table.get("first_seed", 0))), where, "seeds")
    draws = distribution_draws(table["distribution"], table["samples"], table.get("seed", 0), key,
                               where / "distribution")
    return Axis(key, path, DISTRIBUTION, tuple(draws), where, "distribution")


def _problem_of(exc: ScenarioError) -> str:
    """The 'problem' part of a ScenarioError message (between the position and 'expected'), or ''."""
    head = f"{exc.file if exc.file is not None else '<scenario>'}" + (f": {exc.key}" if exc.key else "") + ": "
    text = str(exc)
    rest = text[len(head):] if text.startswith(head) else text
    return rest.split("; expected ", 1)[0] if "; expected " in rest else ""


def blame_variant_error(exc: ScenarioError, sweep_path: Path, variant_id: str, choices: list[tuple[Axis, int]],
           overrides: list[tuple[KeyPath, Any, Where]], base: Scenario) -> ScenarioError:
    """Turn a variant's validation error into one naming the sweep file and the axis value responsible."""
    try:
        err_path = parse_key_path(exc.key) if exc.key else ()
    except KeyPathSyntaxError:
        err_path = ()
    base_name = base.path.name if base.path is not None else "the base scenario"
    problem = _problem_of(exc)
    candidates = [(len(axis.path), axis.value_where(i), axis.key, axis.values[i], axis.where / "key")
                  for axis, i in choices if err_path and overlapping(axis.path, err_path)]
    candidates += [(len(path), w, format_key_path(path), value, w) for path, value, w in overrides
                   if err_path and overlapping(path, err_path)]
    if candidates:
        _, where, key, value, key_where = max(candidates, key=lambda c: c[0])
        if problem.startswith("unknown key") and tuple(err_path) == tuple(parse_key_path(key)):
            # the key itself does not exist for this job (e.g. an FMU parameter the model does not have)
            return ScenarioError(key_where.file, key_where.key, f"{exc.expected} (the {base.job.name!r} job's rule "
                                 f"for {key} in {base_name})", key, problem=f"unknown axis: {problem}")
        where_text = f" at {exc.key}" if exc.key != key else ""
        return ScenarioError(where.file, where.key,
                             f"{exc.expected} (the {base.job.name!r} job's rule for {key}{where_text} "
                             f"in {base_name}; variant {variant_id})",
                             value, problem=(problem or None))
    params = ", ".join(f"{axis.key} = {axis.values[i]!r}" for axis, i in choices)
    return ScenarioError(sweep_path, "axes", f"axis values the base scenario accepts together; the {base.job.name!r} "
                         f"job says: {exc}", problem=f"variant {variant_id} ({params}) is not a valid scenario")


def _variant_id(index: int, count: int) -> str:
    return f"v{index:0{max(4, len(str(count - 1)))}d}"


def variant_count(axes: list[Axis]) -> int:
    """How many variants ``axes`` give: the grid product times the Monte Carlo draws."""
    grid = [a for a in axes if not a.monte_carlo]
    monte_carlo = [a for a in axes if a.monte_carlo]
    total = len(monte_carlo[0].values) if monte_carlo else 1
    for a in grid:
        total *= len(a.values)
    return total


def _expand(sweep_path: Path, base: Scenario, axes: list[Axis],
            overrides: list[tuple[KeyPath, Any, Where]]) -> list[Variant]:
    grid = [a for a in axes if not a.monte_carlo]
    monte_carlo = [a for a in axes if a.monte_carlo]
    draws = len(monte_carlo[0].values) if monte_carlo else 1
    base_doc = absolute_paths(base.job.schema, base.raw, base.where.base_dir)
    for path, value, _ in overrides:
        base_doc = with_value(base_doc, path, value)
    total = draws
    for a in grid:
        total *= len(a.values)
    variants: list[Variant] = []
    for combo in itertools.product(*(range(len(a.values)) for a in grid)):
        for draw in range(draws):
            index = len(variants)
            vid = _variant_id(index, total)
            chosen = dict(zip((id(a) for a in grid), combo))
            choices = [(a, chosen[id(a)] if not a.monte_carlo else draw) for a in axes]
            doc = base_doc
            for axis, i in choices:
                doc = with_value(doc, axis.path, axis.values[i])
            try:
                scenario = load_document(doc, base.path)
            except ScenarioError as exc:
                raise blame_variant_error(exc, sweep_path, vid, choices, overrides, base) from None
            params = {axis.key: axis.values[i] for axis, i in choices}
            values = {axis.key: get_path(scenario.data, axis.path, axis.values[i]) for axis, i in choices}
            variants.append(Variant(index, vid, params, values, doc, variant_hash(base.job.name, doc)))
    return variants


def load_sweep(path: str | Path, on_count=None) -> Sweep:
    """Read and validate the sweep file ``path`` and every variant; ScenarioError on any problem.

    Nothing runs here (the base job's checks may build the project's FMUs once).
    ``on_count(n)`` is called with the number of variants before they are validated.
    """
    path = resolve_path(path)
    return load_sweep_document(read_toml_file(path, "sweep"), path, on_count=on_count)


def load_sweep_document(raw: dict[str, Any], path: str | Path, base: Scenario | None = None,
                        on_count=None) -> Sweep:
    """Validate an already parsed sweep document (``path`` names it and anchors relative paths).

    ``path`` may be a label in angle brackets (``"<python>"``) for a document built in a script:
    relative paths are then relative to the working directory. ``base``: an already validated
    base scenario (then the document has no ``[sweep] base``). ``on_count(n)`` is called with the
    number of variants before they are validated.
    """
    label = isinstance(path, str) and path.startswith("<") and path.endswith(">")
    where = Where(path if label else Path(path).resolve())
    doc = validate(SWEEP_SCHEMA if base is None else SWEEP_SCHEMA_GIVEN_BASE, raw, where)
    head = doc["sweep"]
    if base is None:
        try:
            base = load_scenario(head["base"])
        except ScenarioError as exc:
            raise (where / "sweep" / "base").error("a valid scenario file", raw["sweep"]["base"],
                                                   problem=f"the base scenario is invalid: {exc}") from None
    sweep_dir = where.base_dir
    store = check_store_url(head["store"], where / "sweep" / "store", sweep_dir) if "store" in head else None
    axes: list[Axis] = []
    for i, table in enumerate(doc["axes"]):
        axis = _axis(table, (where / "axes")[i], base, sweep_dir)
        for other in axes:
            if overlapping(axis.path, other.path):
                raise ((where / "axes")[i] / "key").error(
                    f"a key not set by another axis ({other.where.key} sets {other.key})", table["key"],
                    problem="axes overlap")
        axes.append(axis)
    monte_carlo = [a for a in axes if a.monte_carlo]
    for axis in monte_carlo[1:]:
        if len(axis.values) != len(monte_carlo[0].values):
            count_key = "seeds" if axis.kind == SEEDS else "samples"
            raise (axis.where / count_key).error(
                f"the same number of draws as {monte_carlo[0].where.key} ({len(monte_carlo[0].values)}): Monte Carlo "
                f"axes are drawn together", len(axis.values))
    overrides = []
    for opath, value, w in flatten_overrides(doc["overrides"], where / "overrides"):
        checked = scenario_key_path(format_key_path(opath), w, base)
        for axis in axes:
            if overlapping(checked, axis.path):
                raise w.error(f"a key no axis varies ({axis.where.key} varies {axis.key})", value,
                              problem="override of an axis")
        overrides.append((checked, _file_value(base, checked, value, sweep_dir), w))
    report = None
    if "report" in doc:
        report = _report(doc["report"], where / "report", axes)
    count = variant_count(axes)
    limit = head.get("max_variants") or MAX_VARIANTS
    if count > limit:
        raise (where / "sweep" / "max_variants").error(
            f"at most {limit} variants (set [sweep] max_variants to allow more)", count,
            problem=f"the axes give {count} variants")
    if on_count is not None:
        on_count(count)
    variants = _expand(where.file, base, axes, overrides)
    return Sweep(where.file, head["name"], head["description"], base, axes,
                 {format_key_path(p): v for p, v, _ in overrides}, head.get("metrics"), head["retries"], report,
                 variants, collect_globs(head["collect"]), store)


def _report(table: dict, where: Where, axes: list[Axis]) -> Report:
    keys = [a.key for a in axes]

    def axis_key(name: str) -> str:
        try:
            key = format_key_path(parse_key_path(table[name]))
        except KeyPathSyntaxError:
            key = table[name]
        if key not in keys:
            raise (where / name).error(f"one of the axis keys {keys}", table[name])
        return key

    parameter = axis_key("parameter")
    group = axis_key("group") if "group" in table else None
    if group == parameter:
        raise (where / "group").error("an axis key other than the parameter", table["group"])
    return Report(table["metric"], parameter, group, table["kind"], table["file"], table["title"],
                  table["x_scale"], table["y_scale"])


__all__ = ["COLLECT_GROUPS", "FIXED_KEYS", "REPORT_KINDS", "Report", "SWEEP_SCHEMA", "Sweep", "Variant",
           "blame_variant_error", "check_store_url", "collect_globs", "flatten_overrides", "load_sweep",
           "load_sweep_document", "scenario_key_path", "variant_hash"]
