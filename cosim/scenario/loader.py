"""Load a scenario TOML file and validate it completely before anything runs.

``load_scenario(path)`` reads the file with tomllib, checks the ``[scenario]`` table,
looks up the job type, validates the whole document against the job's schema and runs
the job's semantic check (FMU files, parameters, connections, steps). Any problem is
a ``ScenarioError`` naming the file, the key path, the value and what was expected.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.scenario.errors import ScenarioError
from cosim.scenario.files import PACKAGED_SCENARIOS, packaged_scenarios_dir, read_toml_file
from cosim.scenario.inherit import Origins, resolve
from cosim.scenario.registry import JobType, get_job, job_names
from cosim.scenario.schema import Field, String, Table, Where, validate

NAME_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_.-]*"

#: The ``[scenario]`` table every scenario has.
SCENARIO_TABLE = Table({
    "name": Field(String(pattern=NAME_PATTERN, pattern_doc="of letters, digits, '_', '.', '-' (used as folder name)"),
                  required=True,
                  doc="a string of letters, digits, '_', '.', '-': the scenario's name and its results folder "
                      "(results/<name>)"),
    "job": Field(String(), required=True, doc="a registered job type"),
    "description": Field(String(nonempty=False), default="", doc="free text for the reader of the scenario file"),
}, doc="the [scenario] table")

#: Field to put under "scenario" in a job's document schema.
SCENARIO_FIELD = Field(SCENARIO_TABLE, required=True, doc="a [scenario] table with name and job")


@dataclass
class Scenario:
    """A validated scenario.

    Attributes:
        path: the file (None when loaded from a dict).
        name: ``[scenario] name``.
        job: the JobType.
        data: the validated, normalized document (defaults filled, quantities in SI, paths resolved).
        raw: the document as parsed, with its ``extends`` chain laid out (the base's relative
            file paths made absolute; see :mod:`cosim.scenario.inherit`).
        origins: where each key came from (file and line) when read from files, else None.
    """

    path: Path | None
    name: str
    job: JobType
    data: dict[str, Any]
    raw: dict[str, Any] = field(repr=False)
    origins: Origins | None = field(default=None, repr=False, compare=False)

    @property
    def where(self) -> Where:
        """Root position in the document (for errors raised while running)."""
        return Where(self.path, (), self.origins)


def load_document(document: dict[str, Any], path: str | Path | None = None, *,
                  origins: Origins | None = None) -> Scenario:
    """Validate an already parsed document (``path`` only names it in errors and anchors relative paths).

    A document with ``extends`` starts from that base scenario (:mod:`cosim.scenario.inherit`);
    ``origins`` (given by :func:`load_scenario`) lets errors name the line of each key."""
    file = None if path is None else Path(path).resolve()
    document, inherited = resolve(document, file)
    if inherited is not None:
        origins = inherited
    where = Where(file, (), origins)
    if "scenario" not in document:
        raise (where / "scenario").error(SCENARIO_FIELD.doc, problem="missing required table")
    if not isinstance(document["scenario"], dict):
        raise (where / "scenario").error("a [scenario] table with keys name, job (and description)",
                                         document["scenario"], problem="not a table")
    try:
        head = validate(SCENARIO_TABLE, document["scenario"], where / "scenario")
    except ScenarioError as exc:
        job_name = document["scenario"].get("job", "")
        raise _with_toml_hint(exc, get_job(job_name) if isinstance(job_name, str) else None, document) from None
    job = get_job(head["job"])
    if job is None:
        raise (where / "scenario" / "job").error(f"one of the registered job types {job_names()}", head["job"])
    try:
        data = validate(job.schema, document, where)
        if job.check is not None:
            job.check(data, where)
    except ScenarioError as exc:
        raise _with_toml_hint(exc, job, document) from None
    return Scenario(where.file, head["name"], job, data, document, origins)


def _with_toml_hint(exc: ScenarioError, job: JobType | None, document: dict[str, Any]) -> ScenarioError:
    """Explain the classic TOML trap: a top-level key written after a [table] header belongs to that table."""
    last = exc.key.rsplit(".", 1)[-1] if exc.key else ""
    if job is not None and "." in exc.key and last in job.schema.fields and last not in document and "unknown key" in str(exc):
        hint = ScenarioError(exc.file, exc.key, f"'{last}' at the top level of the file, before the first [table] "
                             f"header (in TOML, keys after a header belong to that table)",
                             problem="unknown key", line=exc.line, inherited_by=exc.inherited_by)
        return hint
    return exc


def resolve_path(path: str | Path) -> Path:
    """``path`` if it exists; else the installed copy of a project scenario given as
    ``scenarios/NAME.toml``, ``NAME.toml`` or ``NAME`` (so the README's commands work from
    any folder after a non-editable install); else ``path`` unchanged (the caller reports
    it as not found)."""
    path = Path(path)
    if path.is_file() or path.is_absolute() or len(path.parts) > 2 or \
            (len(path.parts) == 2 and path.parts[0] != "scenarios"):
        return path
    folder = packaged_scenarios_dir()
    if folder is None:
        return path
    name = path.name if path.suffix == ".toml" else f"{path.name}.toml"
    return folder / name if (folder / name).is_file() else path


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate the scenario file ``path`` (see :func:`resolve_path`); ScenarioError
    on any problem."""
    path = resolve_path(path)
    return load_document(read_toml_file(path, "scenario"), path, origins=Origins.of_file(Path(path).resolve()))


__all__ = ["PACKAGED_SCENARIOS", "SCENARIO_FIELD", "SCENARIO_TABLE", "Scenario", "load_document", "load_scenario",
           "packaged_scenarios_dir", "read_toml_file", "resolve_path",
           "Table"]
