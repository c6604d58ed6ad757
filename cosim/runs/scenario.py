"""A scenario loaded and validated for a run, nothing run yet: :class:`Scenario` and
:func:`load_scenario` (a file, a TOML text, a dict; overrides in the sweep-axis key-path syntax).

Part of :mod:`cosim.runs` (one run of a scenario), re-exported by :mod:`cosim.api`, the public
module for scripts (docs/how-to/scripting.md).
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cosim.scenario.errors import ScenarioError

if TYPE_CHECKING:  # pragma: no cover
    from cosim.scenario.loader import Scenario as ValidatedScenario

#: Labels used as ``ScenarioError.file`` for documents that are no file.
DICT_LABEL, STRING_LABEL, PYTHON_LABEL = "<dict>", "<string>", "<python>"


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
    from cosim.scenario.keypath import (KeyPathSyntaxError, absolute_paths, flatten_overrides, format_key_path,
                                        overlapping, parse_key_path, scenario_key_path, spec_at, with_value)

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


__all__ = ["DICT_LABEL", "PYTHON_LABEL", "STRING_LABEL", "Scenario", "load_scenario"]
