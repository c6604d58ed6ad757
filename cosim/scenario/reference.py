"""The scenario-key reference, generated from the job schemas (the schemas are the truth).

``scenario_keys(job)`` walks a registered job type's document schema (:mod:`cosim.scenario.schema`)
and lists every key with its type, unit, default, whether it is required and its ``doc`` text;
``scenario_keys_markdown()`` renders all job types as the page ``reference/scenario_keys.md``
of the docs site (built by the MkDocs hook ``docs/hooks/reference.py``);
``undocumented_keys()`` lists the keys whose ``Field`` has no ``doc`` (a test keeps it empty).

Key paths are written the TOML way: ``simulation.stop_time``, ``fmus[].parameters`` (``[]``: every
item of an array of tables), ``fmus[].parameters.<key>`` (free-form keys of a table).
"""
from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cosim.scenario.registry import JOB_MODULES, get_job, job_names as _all_job_names
from cosim.scenario.schema import MISSING, AnyValue, Boolean, Field, FilePath, Integer, List, Number, Spec, String, Table


@dataclass(frozen=True)
class KeyDoc:
    """One key of a scenario document, as the schema declares it."""

    path: str          # "simulation.stop_time", "fmus[].name", "fmus[].parameters.<key>"
    type: str          # "number", "string", "table", "array of tables", ...
    unit: str          # SI unit of a Number ("" when none)
    default: str       # the default as TOML text ("" when none)
    required: bool
    doc: str           # the Field's doc ("" when the schema gives none)
    accepts: str       # what the validator accepts (the spec's ``expected`` text)


def job_names() -> list[str]:
    """The job types the reference documents: those the modules of ``JOB_MODULES`` register (a job
    registered at run time by a script or a test is not part of it)."""
    return [name for name in _all_job_names() if get_job(name).runner.__module__ in JOB_MODULES]


def _type_of(spec: Spec) -> str:
    if isinstance(spec, Table):
        return "table"
    if isinstance(spec, List):
        if isinstance(spec.item, Table):
            return "array of tables"
        return f"array of {_type_of(spec.item)}"
    if isinstance(spec, Number):
        return "number"
    if isinstance(spec, Integer):
        return "integer"
    if isinstance(spec, Boolean):
        return "boolean"
    if isinstance(spec, FilePath):
        return "path"
    if isinstance(spec, String):
        return "string"
    if isinstance(spec, AnyValue):
        return "any"
    return "value"


def _unit_of(spec: Spec) -> str:
    if isinstance(spec, Number):
        return spec.unit or ""
    if isinstance(spec, List):
        return _unit_of(spec.item)
    return ""


def toml_text(value: Any) -> str:
    """A default value written as it would be in a TOML file."""
    if value is MISSING:
        return ""
    if value is None:
        return "(none)"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, (str, Path)):
        return '"' + str(value).replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_text(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {toml_text(v)}" for k, v in value.items()) + "}"
    return str(value)


def _accepts(spec: Spec) -> str:
    try:
        return str(spec.expected)
    except Exception:  # noqa: BLE001 - a custom spec whose description needs more context
        return ""


def _walk(table: Table, prefix: str) -> Iterator[KeyDoc]:
    for name, field in table.fields.items():
        yield from _walk_field(field, f"{prefix}{name}")
    if table.extra is not None:
        yield from _walk_field(Field(table.extra, doc=_EXTRA_DOC), f"{prefix}<key>")


_EXTRA_DOC = "free-form keys of this table"


def _walk_field(field: Field, path: str) -> Iterator[KeyDoc]:
    spec = field.spec
    doc = field.doc
    if not doc and isinstance(spec, Table) and spec.doc not in ("", "a table"):
        doc = spec.doc
    yield KeyDoc(path, _type_of(spec), _unit_of(spec), toml_text(field.default), field.required, doc,
                 "" if isinstance(spec, Table) or (isinstance(spec, List) and isinstance(spec.item, Table))
                 else _accepts(spec))
    if isinstance(spec, Table):
        yield from _walk(spec, path + ".")
    elif isinstance(spec, List) and isinstance(spec.item, Table):
        yield from _walk(spec.item, path + "[].")


def scenario_keys(job: str) -> list[KeyDoc]:
    """Every key of the document schema of job type ``job``, in declaration order."""
    job_type = get_job(job)
    if job_type is None:
        raise KeyError(job)
    keys = list(_walk(job_type.schema, ""))
    # the base-scenario key is read before validation (cosim/scenario/inherit.py), not by the schema
    if not any(k.path == "extends" for k in keys):
        keys.insert(0, KeyDoc("extends", "string", "", "", False,
                              "a base scenario this one starts from: a path relative to this file, or the "
                              "name of an installed scenario (\"iso9283\"); every key given here overrides "
                              "the base's", "a path or a scenario name"))
    return keys


#: A doc that only names the table ("the [tracker] table") says nothing about it.
_PLACEHOLDER = re.compile(r"(the|a) \[+[A-Za-z0-9_.]+\]+ table")


def undocumented_keys() -> list[tuple[str, str]]:
    """(job, key path) of every schema key without a ``doc`` text (or only a table's name as one)."""
    return [(job, key.path) for job in job_names() for key in scenario_keys(job)
            if not key.doc.strip() or _PLACEHOLDER.fullmatch(key.doc.strip())]


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ").strip()


def _text(text: str) -> str:
    """Prose for a table cell: ``<key>`` shown as text, not taken for HTML."""
    return _cell(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _row(key: KeyDoc, link: str = "") -> str:
    default = "required" if key.required else (f"`{_cell(key.default)}`" if key.default else "")
    meaning = _text(key.doc) or "*(undocumented)*"
    if key.accepts and key.accepts not in key.doc:
        meaning += f" — accepts {_text(key.accepts)}"
    if link:
        meaning += f" ([keys]({link}))"
    return f"| `{_cell(key.path)}` | {key.type} | {key.unit} | {default} | {meaning} |"


_HEADER = ["| key | type | unit | default | meaning |", "|---|---|---|---|---|"]


def _is_table(field: Field) -> bool:
    spec = field.spec
    return isinstance(spec, Table) or (isinstance(spec, List) and isinstance(spec.item, Table))


#: How a scenario combines with the one it ``extends`` (cosim/scenario/inherit.py).
_EXTENDS = [
    "",
    "## Starting from another scenario: `extends` {#extends}",
    "",
    "The top-level key `extends` names a base scenario: a path relative to the file, or the name of",
    "one of the project's scenarios (`\"iso9283\"`, also after a non-editable install); the robot",
    "cell's own bases are [`cell` and `cell_elastic`](#cell-defaults). Top-level keys come before the",
    "first `[table]` header.",
    "",
    "- tables merge key by key at any depth: `[controller] compute_budget = \"150 us\"` changes that key",
    "  and keeps the base's other `[controller]` keys;",
    "- `[[fmus]]` merges FMU by FMU on `name`: a table named like one of the base's FMUs changes only",
    "  the keys it gives, a new name adds an FMU after the base's;",
    "- every other value replaces the base's whole, lists included (`[record] signals`);",
    "- the base may extend another scenario; a circle is an error;",
    "- file paths written in the base stay relative to the base's folder; a user class",
    "  `\"file.py:Class\"` is looked up next to the scenario you run;",
    "- give `[scenario] name`, so the results go to a folder of their own.",
    "",
    "An error in a key that came from the base names the base file and line and the file that",
    "inherited it, e.g. `base.toml: controller.period: expected a number in s > 0, got '-400 us'",
    "(line 7, inherited by derived.toml)`.",
]


def units_markdown() -> list[str]:
    """The section on quantities with a unit, from :data:`cosim.scenario.units.UNITS`."""
    from cosim.scenario.units import UNITS

    lines = ["", "## Quantities with a unit {#units}", "",
             "A number is in the SI unit the key's row names. A string `\"<number> <unit>\"` with a unit of",
             "the same dimension is converted when the file loads (decimal factors exactly: `\"100 us\"` is",
             "the same float as `1e-4`); a unit of another dimension is an error. FMU parameters are plain",
             "numbers in the FMU's own units.", "",
             "| SI unit | also accepted |", "|---|---|"]
    for si, spellings in UNITS.items():
        others = ", ".join(f"`{name}`" for name in spellings if name != si)
        lines.append(f"| `{si}` | {others} |")
    return lines


def scenario_keys_markdown() -> str:
    """The page ``reference/scenario_keys.md``: every key of every registered job type.

    Each job lists its top-level keys; a table (``[simulation]``, ``[[fmus]]``, ...) is listed
    once with all its keys and linked from every job whose schema uses that same table."""
    names = job_names()
    tables: dict[tuple[str, int], list[str]] = {}   # (name, id(spec)) -> jobs using it
    anchors: dict[tuple[str, int], str] = {}
    fields: dict[tuple[str, int], Field] = {}
    for name in names:
        for key, field in get_job(name).schema.fields.items():
            if _is_table(field):
                ident = (key, id(field.spec))
                if ident not in tables:
                    count = sum(1 for other in tables if other[0] == key)
                    anchors[ident] = f"table-{key}" + (f"-{count + 1}" if count else "")
                    tables[ident] = []
                    fields[ident] = field
                tables[ident].append(name)
    lines = [
        "# Scenario keys (reference)",
        "",
        "Generated from the job schemas by `cosim/scenario/reference.py` when the site is built; the",
        "schemas are the truth. A scenario file is a TOML document whose `[scenario] job` names one of",
        "the job types below; each job lists the keys and tables its document accepts, and each table",
        "is listed once below with all its keys. Quantities with a unit accept an SI number or a string",
        "with a unit (`\"400 us\"`, `\"2 ms\"`). Key paths: `a.b` is key `b` of table `[a]`, `a[].b`",
        "is key `b` of every `[[a]]` item, `<key>` stands for a name you choose.",
        "",
        "| job | what it does |",
        "|---|---|",
    ]
    for name in names:
        lines.append(f"| [`{name}`](#job-{name}) | {_text(get_job(name).description)} |")
    lines += _EXTENDS + units_markdown()
    for name in names:
        job = get_job(name)
        lines += ["", f"## Job `{name}` {{#job-{name}}}", ""]
        if job.description:
            lines += [_text(job.description[0].upper() + job.description[1:]) + ".", ""]
        lines += _HEADER
        for key in scenario_keys(name):
            top = key.path.split(".")[0].split("[")[0]
            field = job.schema.fields.get(top)
            if key.path != top:
                continue
            link = ""
            if field is not None and _is_table(field):
                link = "#" + anchors[(top, id(field.spec))]
            lines.append(_row(key, link))
    lines += ["", "## Tables", ""]
    for ident, jobs in tables.items():
        key, _ = ident
        field = fields[ident]
        array = isinstance(field.spec, List)
        title = f"[[{key}]]" if array else f"[{key}]"
        lines += ["", f"### `{title}` ({', '.join(jobs)}) {{#{anchors[ident]}}}", ""]
        rows = list(_walk_field(field, key))
        if rows[0].doc:
            lines += [_text(rows[0].doc[0].upper() + rows[0].doc[1:]) + ".", ""]
        lines += _HEADER + [_row(row) for row in rows[1:]]
    lines += cell_defaults_markdown()
    return "\n".join(lines) + "\n"


def table_keys(table: Table) -> list[KeyDoc]:
    """Every key of a schema outside the job registry (e.g. the sweep file's), in declaration order."""
    return list(_walk(table, ""))


def table_keys_markdown(table: Table) -> str:
    """The keys of ``table`` as the key table of the scenario-key page (key, type, unit, default, meaning)."""
    return "\n".join(_HEADER + [_row(key) for key in table_keys(table)]) + "\n"


CELL_BASES = ("cell", "cell_elastic")
"""The project's base scenarios of the robot cell (``scenarios/<name>.toml``), documented on the page."""


def _leaves(value: Any, path: tuple = ()) -> Iterator[tuple[tuple, Any]]:
    """(key path, value) of every value of a TOML document that is not a table; an ``[[fmus]]``
    item is keyed by its name."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _leaves(item, path + (key,))
    elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        for i, item in enumerate(value):
            for sub, leaf in _leaves(item, ()):
                yield path + (i,) + sub, leaf
    else:
        yield path, value


def cell_defaults_markdown() -> list[str]:
    """The section of ``reference/scenario_keys.md`` on the robot cell's defaults: every key of
    :data:`CELL_BASES` with its value, unit and the reason the file gives for it."""
    import tomllib

    from cosim.scenario.inherit import find_base, key_lines

    schema = {k.path: k for k in scenario_keys("iso9283")}
    lines = ["", "## The robot cell's defaults {#cell-defaults}", "",
             "A scenario of a job that runs the cell starts from `extends = \"cell\"` (rigid gears) or",
             "`extends = \"cell_elastic\"` (the main job's elastic gears) and gives only what differs; an",
             "`[[fmus]]` table with the name of one of these FMUs changes that FMU's keys. Keys these files",
             "leave out have the defaults of the tables above. Generated from the files themselves."]
    for name in CELL_BASES:
        path = find_base(name, None)
        text = path.read_text(encoding="utf-8")
        written, doc = key_lines(text), tomllib.loads(text)
        source = text.splitlines()
        lines += ["", f"### `scenarios/{path.name}`", "", "| key | value | unit | meaning and source |",
                  "|---|---|---|---|"]
        for keys, value in _leaves(doc):
            if len(keys) == 3 and isinstance(keys[1], int) and keys[2] == "name":
                continue  # the FMU's name is in the key shown
            shown, generic = [], []
            for i, part in enumerate(keys):
                if isinstance(part, int):
                    item = doc[keys[0]][part]
                    shown[-1] += f"[{item.get('name', part)}]"
                    generic[-1] += "[]"
                else:
                    shown.append(str(part))
                    generic.append(str(part) if not (i >= 2 and generic[-1] == "parameters") else "<key>")
            key = schema.get(".".join(generic))
            number = written.get(keys)
            comment = source[number - 1].split("#", 1)[1].strip() if number and "#" in source[number - 1] else ""
            meaning = comment or (key.doc if key is not None else "")
            unit = key.unit if key is not None else ""
            lines.append(f"| `{_cell('.'.join(shown))}` | `{_cell(toml_text(value))}` | {unit} | {_text(meaning)} |")
    return lines


__all__ = ["CELL_BASES", "KeyDoc", "cell_defaults_markdown", "job_names", "scenario_keys", "scenario_keys_markdown",
           "table_keys", "table_keys_markdown", "toml_text", "undocumented_keys"]
