"""``ScenarioError``: a scenario file is wrong; names the file, the key path, what was given and expected."""
from __future__ import annotations

from pathlib import Path

_MISSING = object()


class ScenarioError(ValueError):
    """A scenario file failed validation.

    Attributes:
        file: the scenario file (a Path), a label in angle brackets for documents that are
            no file (``"<dict>"``, ``"<string>"``: a str), or None.
        key: key path such as ``fmus[2].parameters.Kp`` (empty for the whole file).
        given: the offending value (or None when a key is missing).
        expected: what was expected, in words.
        problem: what is wrong (``"unknown key"``, ...) or None.
        line: the line of the key in ``file`` (1-based) when known, else None.
        inherited_by: the scenario that was run when the key came from a base scenario it
            ``extends`` (``file`` is then the base), else None.
    """

    def __init__(self, file: str | Path | None, key: str, expected: str, given: object = _MISSING,
                 problem: str | None = None, *, line: int | None = None,
                 inherited_by: str | Path | None = None) -> None:
        if file is None or (isinstance(file, str) and file.startswith("<") and file.endswith(">")):
            self.file: Path | str | None = file
        else:
            self.file = Path(file)
        self.key = key
        self.expected = expected
        self.problem = problem
        self.given = None if given is _MISSING else given
        self.line = line
        self.inherited_by = None if inherited_by is None else Path(inherited_by)
        where = f"{self.file}" if self.file is not None else "<scenario>"
        if key:
            where += f": {key}"
        text = f"{where}: {problem + '; ' if problem else ''}expected {expected}"
        if given is not _MISSING:
            text += f", got {given!r}"
        if line is not None or inherited_by is not None:
            at = [f"line {line}"] if line is not None else []
            if inherited_by is not None:
                at.append(f"inherited by {inherited_by}")
            text += f" ({', '.join(at)})"
        super().__init__(text)
